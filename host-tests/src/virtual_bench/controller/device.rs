//! The simulated PI controller: a GCS 2.0 command interpreter over a [`Plant`] and a [`Clock`].
//!
//! It implements what the commands the compensator meets do on a real E-727 (piezo, absolute
//! capacitive sensors) or C-867 (PILine motor, reference switch), as PI describes them in the
//! command reference of the controller manuals; the descriptions quoted are PI's own text as
//! PIPython 2.11 carries it (`pipython/pidevice/common/gcsbasecommands.py`,
//! `gcs2/gcs2commands.py`) and the error codes are PI's (`pidevice/gcserror.py`). The
//! independent E-861 simulator of Delmic's Odemis (`src/odemis/driver/pigcs.py`) was a second
//! reference for the reply framing (address prefixes, single-character commands). What it
//! follows, command by command:
//!
//! - Syntax: `[<target> [<sender>] ]<MNEMONIC> {args}` + LF; mnemonics in any case; an address
//!   prefix for another controller is ignored, one for this controller is answered with
//!   `0 <address> ` (sender and target swapped). Single-character commands act at once.
//! - Errors: only the last one is kept; `ERR?` reports it and clears it. A command with an
//!   error does nothing at all, a query with an error is not answered. Codes: 1 parameter
//!   syntax, 2 unknown command, 5 move with servo off or on an unreferenced axis, 7 position out
//!   of limits, 10 stopped by command (`HLT`, `STP`, `#24`), 15 invalid axis, 79 open-loop
//!   command while servo is on.
//! - `MOV`/`MVR`/`MVE`/`GOH` ("equivalent to moving the axes to positions 0 using MOV"): all
//!   targets are checked against the travel (`TMN?`/`TMX?`) before any axis moves; servo must be
//!   on, and an axis with reference mode on (`RON 1`, C-867) must be referenced.
//! - `HLT`/`STP`/`#24`: "after the axes are stopped, their target positions are set to their
//!   current positions"; error 10. `SVO 1` sets the target to the current position (no jump).
//! - `FRF`/`FNL`/`FPL`: "moves all axes synchronously to the physical reference point and sets
//!   the current positions to the reference position" (the limits for `FNL`/`FPL`); the
//!   controller is busy meanwhile (`#7` answers B0h), `FRF?` reports the result.
//! - `POS` (reference mode off) and `DFH` redefine the current position without motion.
//! - Open-loop and raw-target commands (`STE`, `IMP`, `SVA`, `SVR`, `SMO`, `OMA`, `OMR`, `JOG`,
//!   `WGO` start, `MAC START`, …) are recorded as [`Event::RawMotion`]: a compensating proxy must
//!   never let one through.
//!
//! Every target an axis accepts is recorded as [`Event::Target`], so a test sees exactly what
//! the stage was told to do.

use super::plant::{Clock, Plant};
use std::collections::VecDeque;
use std::sync::Arc;

/// One axis of a simulated controller.
#[derive(Debug, Clone)]
pub struct AxisConfig {
    /// GCS identifier (`1`, `A`).
    pub id: String,
    /// Position unit as `PUN?` reports it (`µm` is sent in cp1252, PI's code page).
    pub unit: String,
    /// Travel limits (`TMN?`/`TMX?`), controller units.
    pub min: f64,
    /// See `min`.
    pub max: f64,
    /// Closed-loop velocity (`VEL?`), units/s.
    pub velocity: f64,
    /// The axis has a reference switch at this position (controller units after referencing);
    /// with reference mode on it must be referenced before it moves. `None`: absolute sensor.
    pub reference: Option<f64>,
    /// Physical position at power-up.
    pub start: f64,
}

/// A simulated controller's configuration.
#[derive(Debug, Clone)]
pub struct Config {
    /// Model name (in `*IDN?`).
    pub name: String,
    /// Serial number (the third field of `*IDN?`, as PI's controllers report it).
    pub serial: String,
    /// GCS syntax version `CSV?` reports (`2.0`; `3.0` plays a GCS 3.0 controller's answer).
    pub syntax_version: String,
    /// Daisy-chain address.
    pub address: u32,
    /// Servo on at power-up.
    pub servo_on_at_start: bool,
    /// The axes.
    pub axes: Vec<AxisConfig>,
    /// Mnemonics the controller knows (listed by `HLP?`); others are error 2. The presets list
    /// the commands the compensator meets on that controller, not its manual's complete set.
    pub commands: Vec<&'static str>,
}

/// The serial number a simulated controller reports unless told another.
pub const DEFAULT_SERIAL: &str = "0123456789";

/// Commands both presets know.
const COMMON: &[&str] = &[
    "#3", "#4", "#5", "#6", "#7", "#8", "#9", "#11", "#24", "#27", "*IDN?", "CCL", "CCL?", "CSV?",
    "ERR?", "HLP?", "HLT", "MAC", "MAC?", "MOV", "MOV?", "MVR", "ONT?", "POS?", "PUN", "PUN?",
    "RBT", "SAI?", "SPA?", "STP", "SVO", "SVO?", "TMN?", "TMX?", "VEL", "VEL?", "VER?",
];

impl Config {
    /// An E-727 digital piezo controller with `axes` closed-loop axes `1`..`n` in µm, absolute
    /// capacitive sensors (no referencing), travel −20…520 µm.
    pub fn e727(axes: usize) -> Self {
        let mut commands = COMMON.to_vec();
        commands.extend([
            "ATZ", "ATZ?", "DRR?", "IMP", "IMP?", "STE", "STE?", "SVA", "SVA?", "SVR", "WAV",
            "WAV?", "WGO", "WGO?", "WSL", "WSL?", "WTR", "WTR?", "FRF?",
        ]);
        Self {
            name: "E-727".into(),
            serial: DEFAULT_SERIAL.into(),
            syntax_version: "2.0".into(),
            address: 1,
            servo_on_at_start: false,
            axes: (1..=axes)
                .map(|a| AxisConfig {
                    id: a.to_string(),
                    unit: "µm".into(),
                    min: -20.0,
                    max: 520.0,
                    velocity: 20_000.0,
                    reference: None,
                    start: 0.0,
                })
                .collect(),
            commands,
        }
    }

    /// A C-867 PILine motion controller with `axes` axes `1`..`n` in `unit`, each with a
    /// reference switch (reference mode on: `FRF` before the first move), travel −20…520
    /// (in `unit`).
    pub fn c867(axes: usize, unit: &str) -> Self {
        let mut commands = COMMON.to_vec();
        commands.extend([
            "DFH", "DFH?", "FNL", "FPL", "FRF", "FRF?", "GOH", "MVE", "POS", "RON", "RON?", "SMO",
            "SMO?", "OMA", "OMR", "JOG", "JOG?", "LIM?", "TRS?",
        ]);
        Self {
            name: "C-867".into(),
            serial: DEFAULT_SERIAL.into(),
            syntax_version: "2.0".into(),
            address: 1,
            servo_on_at_start: false,
            axes: (1..=axes)
                .map(|a| AxisConfig {
                    id: a.to_string(),
                    unit: unit.into(),
                    min: -20.0,
                    max: 520.0,
                    velocity: 50_000.0,
                    reference: Some(250.0),
                    start: 37.0,
                })
                .collect(),
            commands,
        }
    }

    /// Servo on (and every axis referenced) at power-up: a controller someone already set up.
    pub fn ready(mut self) -> Self {
        self.servo_on_at_start = true;
        for a in &mut self.axes {
            if let Some(r) = a.reference {
                a.start = r;
            }
        }
        self
    }
}

/// What happened to the stage (for tests to check).
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// An axis accepted a closed-loop target (controller units), by this command.
    Target {
        /// Axis index in the configuration.
        axis: usize,
        /// The target.
        value: f64,
        /// The command (`MOV`, `MVR`, `MVE`, `GOH`).
        by: String,
    },
    /// A command that moves an axis by another means than a closed-loop target reached the
    /// controller (open loop, wave generator, macro, trajectory, step response, …).
    RawMotion {
        /// The command line (or `#n`).
        command: String,
        /// The axes it names (empty: axes the controller cannot tell from the command — a
        /// wave generator, a macro — so any axis).
        axes: Vec<usize>,
    },
    /// Targets were dropped: the axes stopped (`HLT`, `STP`, `#24`), were referenced, or the
    /// servo changed; the target is now wherever the axis is.
    TargetsReset {
        /// The command.
        by: String,
    },
}

#[derive(Debug, Clone)]
struct Axis {
    target: f64,
    servo: bool,
    referenced: bool,
    reference_mode: bool,
    /// Controller position = physical position + offset.
    offset: f64,
    /// A referencing move ends at this time (then the position is redefined).
    referencing: Option<(f64, f64)>,
    unit: String,
}

/// One command the controller processed (recorded when [`Controller::record`] is on): what a
/// checker needs to judge what the compensator sent and relayed.
#[derive(Debug, Clone, PartialEq)]
pub struct Processed {
    /// The command line (LF removed), or `#n` for a single-character command.
    pub line: String,
    /// Its reply (empty: none — a rejected query is not answered).
    pub reply: Vec<u8>,
    /// The axes' targets before the command.
    pub before: Vec<f64>,
    /// The error code the command set (`None`: it succeeded or set none).
    pub failed: Option<i32>,
}

/// The controller: feed it the bytes the host (or the compensator) sends, get its replies.
pub struct Controller {
    cfg: Config,
    plant: Box<dyn Plant>,
    clock: Arc<dyn Clock>,
    axes: Vec<Axis>,
    error: i32,
    line: Vec<u8>,
    events: Vec<Event>,
    received: VecDeque<String>,
    /// Command level (`CCL 1 advanced` unlocks `PUN`).
    level: u8,
    /// Every command processed, when recording.
    processed: Option<Vec<Processed>>,
    /// The error the command being processed set.
    failure: Option<i32>,
}

/// What [`Controller::input`] produced.
pub type Reply = Vec<u8>;

impl Controller {
    /// A controller in its power-up state.
    pub fn new(cfg: Config, plant: Box<dyn Plant>, clock: Arc<dyn Clock>) -> Self {
        let axes = cfg
            .axes
            .iter()
            .map(|a| Axis {
                target: a.start,
                servo: cfg.servo_on_at_start,
                referenced: a.reference.is_none() || cfg.servo_on_at_start,
                reference_mode: a.reference.is_some(),
                offset: 0.0,
                referencing: None,
                unit: a.unit.clone(),
            })
            .collect();
        Self {
            cfg,
            plant,
            clock,
            axes,
            error: 0,
            line: vec![],
            events: vec![],
            received: VecDeque::new(),
            level: 0,
            processed: None,
            failure: None,
        }
    }

    /// Record every command processed from now on ([`Self::take_processed`]).
    pub fn record(&mut self) {
        self.processed.get_or_insert_with(Vec::new);
    }

    /// The commands processed since the last [`Self::take_processed`] (recording on).
    pub fn peek_processed(&self) -> &[Processed] {
        self.processed.as_deref().unwrap_or(&[])
    }

    /// The commands processed since the last call (recording on).
    pub fn take_processed(&mut self) -> Vec<Processed> {
        self.processed
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// The servo of `axis` goes off behind the host's back (an amplifier's thermal cut-out, a
    /// front-panel switch, another interface): the axis stops where it is, moves are refused
    /// (error 5) until a `SVO` switches it on. Nothing is processed or recorded.
    pub fn servo_fault(&mut self, axis: usize) {
        if let Some(ax) = self.axes.get_mut(axis) {
            ax.servo = false;
            let t = self.clock.now_s();
            self.plant.stop(axis, t);
        }
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Everything that happened to the stage so far (and clear the record).
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    /// Lines (and `#n` single characters) received so far (and clear the record).
    pub fn take_received(&mut self) -> Vec<String> {
        self.received.drain(..).collect()
    }

    /// The current position of an axis (controller units).
    pub fn position(&mut self, axis: usize) -> f64 {
        let t = self.clock.now_s();
        self.update(t);
        self.plant.position(axis, t) + self.axes[axis].offset
    }

    /// The target of an axis (controller units).
    pub fn target(&mut self, axis: usize) -> f64 {
        let t = self.clock.now_s();
        self.update(t);
        self.axes[axis].target
    }

    /// Bytes from the link; returns the reply bytes.
    pub fn input(&mut self, bytes: &[u8]) -> Reply {
        let mut out = vec![];
        for &b in bytes {
            if is_single(b) {
                // single-character commands act at once, even inside a line
                let text = format!("#{b}");
                self.received.push_back(text.clone());
                self.processing(text, &mut out, |c, out| c.single(b, out));
            } else if b == b'\n' {
                let line = std::mem::take(&mut self.line);
                let text: String = line.iter().map(|&c| c as char).collect();
                self.received.push_back(text.clone());
                self.processing(text.clone(), &mut out, |c, out| c.command(&text, out));
            } else {
                self.line.push(b);
            }
        }
        out
    }

    /// Run one command, recording it when recording is on.
    fn processing(
        &mut self,
        line: String,
        out: &mut Vec<u8>,
        f: impl FnOnce(&mut Self, &mut Vec<u8>),
    ) {
        if self.processed.is_none() {
            return f(self, out);
        }
        let before = self.axes.iter().map(|a| a.target).collect();
        let start = out.len();
        self.failure = None;
        f(self, out);
        let p = Processed {
            line,
            reply: out[start..].to_vec(),
            before,
            failed: self.failure.take(),
        };
        if let Some(log) = &mut self.processed {
            log.push(p);
        }
    }

    /// Finish referencing moves whose time has come.
    fn update(&mut self, t: f64) {
        for a in 0..self.axes.len() {
            if let Some((t_end, value)) = self.axes[a].referencing {
                if t >= t_end {
                    let phys = self.plant.position(a, t);
                    let ax = &mut self.axes[a];
                    ax.offset = value - phys;
                    ax.target = value;
                    ax.referenced = true;
                    ax.referencing = None;
                }
            }
        }
    }

    fn busy(&self) -> bool {
        self.axes.iter().any(|a| a.referencing.is_some())
    }

    fn pos(&self, a: usize, t: f64) -> f64 {
        self.plant.position(a, t) + self.axes[a].offset
    }

    fn single(&mut self, b: u8, out: &mut Vec<u8>) {
        if !self.cfg.commands.iter().any(|c| *c == format!("#{b}")) {
            // a single-character command this controller does not know: ignored
            return;
        }
        let t = self.clock.now_s();
        self.update(t);
        let bits = |f: &dyn Fn(usize) -> bool| {
            (0..self.axes.len()).fold(0u32, |m, a| m | (u32::from(f(a)) << a))
        };
        match b {
            0x03 => {
                // #3: like POS? of all axes
                let body = self.axis_lines(&(0..self.axes.len()).collect::<Vec<_>>(), |c, a| {
                    fmt_value(c.pos(a, t))
                });
                out.extend_from_slice(&body);
            }
            0x04 => {
                // status register: servo on, on target (simplified, hexadecimal)
                let v = bits(&|a| self.axes[a].servo) << 12 | bits(&|a| self.plant.settled(a, t));
                out.extend_from_slice(format!("0x{v:x}\n").as_bytes());
            }
            0x05 => {
                let v = bits(&|a| !self.plant.settled(a, t));
                out.extend_from_slice(format!("{v:x}\n").as_bytes());
            }
            0x06 => out.extend_from_slice(b"0\n"),
            0x07 => out.extend_from_slice(if self.busy() { b"\xB0\n" } else { b"\xB1\n" }),
            0x08 => out.extend_from_slice(b"0\n"),
            0x09 => out.extend_from_slice(b"0\n"),
            0x0B => out.extend_from_slice(b"1024\n"),
            0x18 | 0x1B => {
                // #24 stop all (error 10), #27 system abort (stops too)
                self.stop_all(t, "#24");
                self.fail(if b == 0x18 { 10 } else { 716 });
            }
            _ => {}
        }
    }

    /// A command failed with `code` (the controller keeps the last error).
    fn fail(&mut self, code: i32) {
        self.error = code;
        self.failure = Some(code);
    }

    fn stop_all(&mut self, t: f64, by: &str) {
        for a in 0..self.axes.len() {
            self.plant.stop(a, t);
            self.axes[a].target = self.pos(a, t);
            self.axes[a].referencing = None;
        }
        self.events.push(Event::TargetsReset { by: by.into() });
    }

    fn axis_index(&self, id: &str) -> Option<usize> {
        self.cfg.axes.iter().position(|a| a.id == id)
    }

    /// `axis=value` lines (multi-line framing) for `axes`.
    fn axis_lines(&self, axes: &[usize], f: impl Fn(&Self, usize) -> String) -> Vec<u8> {
        let mut out = vec![];
        for (k, &a) in axes.iter().enumerate() {
            out.extend_from_slice(self.cfg.axes[a].id.as_bytes());
            out.push(b'=');
            out.extend_from_slice(&cp1252(&f(self, a)));
            if k + 1 < axes.len() {
                out.push(b' ');
            }
            out.push(b'\n');
        }
        out
    }

    fn command(&mut self, line: &str, out: &mut Vec<u8>) {
        let t = self.clock.now_s();
        self.update(t);
        let toks: Vec<&str> = line.split_whitespace().collect();
        // address prefix
        let mut k = 0;
        let mut nums = vec![];
        while k < toks.len() && k < 2 && toks[k].bytes().all(|b| b.is_ascii_digit()) {
            nums.push(toks[k].parse::<u32>().unwrap_or(u32::MAX));
            k += 1;
        }
        if k == toks.len() {
            if !toks.is_empty() {
                self.fail(2);
            }
            return;
        }
        let prefix = match nums.first() {
            Some(&target) if target != self.cfg.address && target != 255 => return,
            Some(_) => format!(
                "{} {} ",
                nums.get(1).copied().unwrap_or(0),
                self.cfg.address
            ),
            None => String::new(),
        };
        let mut mnemonic = toks[k].to_ascii_uppercase();
        let mut args: Vec<&str> = toks[k + 1..].to_vec();
        if (mnemonic == "MAC" || mnemonic == "SAI?") && !args.is_empty() {
            // MAC <sub>, SAI? ALL
            if mnemonic == "MAC" {
                mnemonic = format!("MAC {}", args[0].to_ascii_uppercase());
                args.remove(0);
            }
        }
        let base = mnemonic.split(' ').next().unwrap_or("").to_string();
        if !self.cfg.commands.contains(&base.as_str()) {
            self.fail(2);
            return;
        }
        match self.execute(&mnemonic, &args, t, line) {
            Ok(Some(reply)) => {
                // the address prefix starts every line of a multi-line reply
                for chunk in reply.split_inclusive(|&b| b == b'\n') {
                    out.extend_from_slice(prefix.as_bytes());
                    out.extend_from_slice(chunk);
                }
            }
            Ok(None) => {}
            Err(code) => self.fail(code),
        }
    }

    /// Axis indices from identifiers (all axes when none).
    fn axes_of(&self, ids: &[&str]) -> Result<Vec<usize>, i32> {
        if ids.is_empty() {
            return Ok((0..self.axes.len()).collect());
        }
        ids.iter().map(|id| self.axis_index(id).ok_or(15)).collect()
    }

    /// `{axis value}` pairs.
    fn pairs(&self, args: &[&str]) -> Result<Vec<(usize, f64)>, i32> {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            return Err(1);
        }
        let mut seen = vec![];
        let mut v = vec![];
        for c in args.chunks(2) {
            let a = self.axis_index(c[0]).ok_or(15)?;
            if seen.contains(&a) {
                return Err(22);
            }
            seen.push(a);
            let x: f64 = c[1].parse().map_err(|_| 1)?;
            if !x.is_finite() {
                return Err(1);
            }
            v.push((a, x));
        }
        Ok(v)
    }

    /// Start closed-loop moves to absolute targets (all checked first).
    fn move_to(&mut self, targets: &[(usize, f64)], t: f64, by: &str) -> Result<(), i32> {
        for &(a, x) in targets {
            let ax = &self.axes[a];
            if !ax.servo || (ax.reference_mode && !ax.referenced) {
                return Err(5);
            }
            let c = &self.cfg.axes[a];
            if !(x >= c.min && x <= c.max) {
                return Err(7);
            }
        }
        if self.busy() {
            return Err(1005);
        }
        for &(a, x) in targets {
            let phys = x - self.axes[a].offset;
            let vel = self.cfg.axes[a].velocity;
            self.plant.drive(a, phys, vel, t);
            self.axes[a].target = x;
            self.events.push(Event::Target {
                axis: a,
                value: x,
                by: by.into(),
            });
        }
        Ok(())
    }

    fn raw(&mut self, line: &str, axes: Vec<usize>) {
        self.events.push(Event::RawMotion {
            command: line.trim().to_string(),
            axes,
        });
    }

    fn execute(
        &mut self,
        m: &str,
        args: &[&str],
        t: f64,
        line: &str,
    ) -> Result<Option<Vec<u8>>, i32> {
        let n = self.axes.len();
        let reply = |s: String| Ok(Some(cp1252(&s)));
        match m {
            "*IDN?" => reply(format!(
                "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, {}, {}, 01.00.00 (simulated)\n",
                self.cfg.name, self.cfg.serial
            )),
            "CSV?" => reply(format!("{}\n", self.cfg.syntax_version)),
            "VER?" => reply(format!("FW_ARM: V1.0.0 (simulated {})\n", self.cfg.name)),
            "ERR?" => {
                let e = std::mem::take(&mut self.error);
                reply(format!("{e}\n"))
            }
            "HLP?" => Ok(Some(self.help())),
            "SAI?" => {
                let ids: Vec<String> = self.cfg.axes.iter().map(|a| a.id.clone()).collect();
                let mut s = String::new();
                for (k, id) in ids.iter().enumerate() {
                    s += id;
                    s += if k + 1 < ids.len() { " \n" } else { "\n" };
                }
                reply(s)
            }
            "CCL" => {
                self.level = if args.first() == Some(&"1") && args.get(1) == Some(&"advanced") {
                    1
                } else if args.first() == Some(&"0") {
                    0
                } else {
                    return Err(56);
                };
                Ok(None)
            }
            "CCL?" => reply(format!("{}\n", self.level)),
            "MOV" | "MVE" => {
                let p = self.pairs(args)?;
                self.move_to(&p, t, m)?;
                Ok(None)
            }
            "MVR" => {
                let p = self.pairs(args)?;
                let abs: Vec<(usize, f64)> = p
                    .iter()
                    .map(|&(a, d)| (a, self.axes[a].target + d))
                    .collect();
                self.move_to(&abs, t, m)?;
                Ok(None)
            }
            "GOH" => {
                let axes = self.axes_of(args)?;
                let abs: Vec<(usize, f64)> = axes.iter().map(|&a| (a, 0.0)).collect();
                self.move_to(&abs, t, m)?;
                Ok(None)
            }
            "MOV?" | "POS?" | "ONT?" | "SVO?" | "FRF?" | "TMN?" | "TMX?" | "VEL?" | "PUN?"
            | "RON?" => {
                let axes = self.axes_of(args)?;
                let body = self.axis_lines(&axes, |c, a| match m {
                    "MOV?" => fmt_value(c.axes[a].target),
                    "POS?" => fmt_value(c.pos(a, t)),
                    "ONT?" => {
                        let on = c.axes[a].servo
                            && c.plant.settled(a, t)
                            && (c.pos(a, t) - c.axes[a].target).abs() < 1e-6;
                        u8::from(on).to_string()
                    }
                    "SVO?" => u8::from(c.axes[a].servo).to_string(),
                    "FRF?" => u8::from(c.axes[a].referenced).to_string(),
                    "RON?" => u8::from(c.axes[a].reference_mode).to_string(),
                    "TMN?" => fmt_value(c.cfg.axes[a].min),
                    "TMX?" => fmt_value(c.cfg.axes[a].max),
                    "VEL?" => fmt_value(c.cfg.axes[a].velocity),
                    _ => c.axes[a].unit.clone(),
                });
                Ok(Some(body))
            }
            "VEL" => {
                for (a, v) in self.pairs(args)? {
                    if v <= 0.0 {
                        return Err(8);
                    }
                    self.cfg.axes[a].velocity = v;
                }
                Ok(None)
            }
            "PUN" => {
                if self.level < 1 {
                    return Err(60);
                }
                if !args.len().is_multiple_of(2) || args.is_empty() {
                    return Err(1);
                }
                for c in args.chunks(2) {
                    let a = self.axis_index(c[0]).ok_or(15)?;
                    self.axes[a].unit = c[1].to_string();
                }
                Ok(None)
            }
            "SVO" => {
                for (a, v) in self.pairs(args)? {
                    let on = v != 0.0;
                    if on && !self.axes[a].servo {
                        // no jump: the target becomes the current position
                        self.plant.stop(a, t);
                        self.axes[a].target = self.pos(a, t);
                    }
                    if !on {
                        self.plant.stop(a, t);
                    }
                    self.axes[a].servo = on;
                }
                self.events.push(Event::TargetsReset { by: "SVO".into() });
                Ok(None)
            }
            "HLT" => {
                let axes = self.axes_of(args)?;
                for a in axes {
                    self.plant.stop(a, t);
                    self.axes[a].target = self.pos(a, t);
                    self.axes[a].referencing = None;
                }
                self.events.push(Event::TargetsReset { by: "HLT".into() });
                // "Error code 10 is set"
                Err(10)
            }
            "STP" => {
                self.stop_all(t, "STP");
                Err(10)
            }
            "FRF" | "FNL" | "FPL" => {
                let axes = self.axes_of(args)?;
                for &a in &axes {
                    // referencing moves run in closed loop
                    if !self.axes[a].servo {
                        return Err(5);
                    }
                    if self.cfg.axes[a].reference.is_none() {
                        // "Axis has no reference sensor"
                        return Err(31);
                    }
                }
                for a in axes {
                    let c = &self.cfg.axes[a];
                    let value = match m {
                        "FRF" => c.reference.unwrap_or(0.0),
                        "FNL" => c.min,
                        _ => c.max,
                    };
                    // the switch sits at this physical position (the power-up coordinates)
                    let phys = value;
                    let dist = (phys - self.plant.position(a, t)).abs();
                    let vel = c.velocity;
                    self.plant.drive(a, phys, vel, t);
                    self.axes[a].referencing = Some((t + dist / vel, value));
                    self.axes[a].referenced = false;
                }
                self.events.push(Event::TargetsReset { by: m.into() });
                Ok(None)
            }
            "RON" => {
                for (a, v) in self.pairs(args)? {
                    self.axes[a].reference_mode = v != 0.0;
                }
                Ok(None)
            }
            "POS" => {
                for (a, v) in self.pairs(args)? {
                    if self.axes[a].reference_mode {
                        return Err(8);
                    }
                    self.axes[a].offset = v - self.plant.position(a, t);
                    self.axes[a].target = v;
                    self.axes[a].referenced = true;
                }
                self.events.push(Event::TargetsReset { by: "POS".into() });
                Ok(None)
            }
            "DFH" => {
                for a in self.axes_of(args)? {
                    self.axes[a].offset = -self.plant.position(a, t);
                    self.axes[a].target = self.pos(a, t);
                }
                self.events.push(Event::TargetsReset { by: "DFH".into() });
                Ok(None)
            }
            "SPA?" => reply("0\n".into()),
            "MAC?" => reply("\n".into()),
            "RBT" => {
                // power-up state again; the stage stays where it is
                for a in 0..n {
                    self.plant.stop(a, t);
                    let c = &self.cfg.axes[a];
                    let ax = &mut self.axes[a];
                    ax.servo = self.cfg.servo_on_at_start;
                    ax.referenced = c.reference.is_none();
                    ax.reference_mode = c.reference.is_some();
                    ax.offset = 0.0;
                    ax.referencing = None;
                    ax.unit = c.unit.clone();
                    ax.target = self.plant.position(a, t);
                }
                self.level = 0;
                self.error = 0;
                self.events.push(Event::TargetsReset { by: "RBT".into() });
                Ok(None)
            }
            // moves that are not closed-loop targets: recorded, then what the controller does
            "STE" | "IMP" | "SVA" | "SVR" | "SMO" | "OMA" | "OMR" | "JOG" | "ATZ" => {
                // the axes named (every other token for {axis value} pairs)
                let step = if m == "ATZ" { 1 } else { 2 };
                let axes: Vec<Option<usize>> = args
                    .iter()
                    .step_by(step)
                    .map(|id| self.axis_index(id))
                    .collect();
                // an axis it does not have: error 15, and nothing moves (recording it as a
                // motion of every axis made `SVA HLT` look like one to the proxy's fuzz target)
                let Some(axes) = axes.into_iter().collect::<Option<Vec<usize>>>() else {
                    return Err(15);
                };
                let axes = if args.is_empty() {
                    (0..n).collect()
                } else {
                    axes
                };
                self.raw(line, axes);
                if matches!(m, "SVA" | "SVR" | "SMO" | "OMA" | "OMR") {
                    let p = self.pairs(args)?;
                    if p.iter().any(|&(a, _)| self.axes[a].servo) {
                        // "Open-loop commands are not allowed when servo is on"
                        return Err(79);
                    }
                }
                Ok(None)
            }
            "WAV" | "WTR" => {
                self.raw(line, vec![]);
                Ok(None)
            }
            "WGO" => {
                if args.chunks(2).any(|c| c.get(1).is_some_and(|v| *v != "0")) {
                    self.raw(line, vec![]);
                }
                Ok(None)
            }
            "MAC START" | "MAC NSTART" | "MAC BEG" | "MAC DEF" => {
                self.raw(line, vec![]);
                Err(1013)
            }
            m if m.starts_with("MAC") => Ok(None),
            "WSL" | "WGO?" | "WSL?" | "WTR?" | "WAV?" | "STE?" | "IMP?" | "SVA?" | "ATZ?"
            | "DRR?" | "DFH?" | "SMO?" | "JOG?" | "LIM?" | "TRS?" => {
                if m.ends_with('?') {
                    let axes = self.axes_of(&[])?;
                    Ok(Some(self.axis_lines(&axes, |_, _| "0".into())))
                } else {
                    Ok(None)
                }
            }
            _ => {
                if std::env::var_os("NANOCAL_GCS_TRACE").is_some() {
                    eprintln!("controller: unknown command {line:?} at t = {t}");
                }
                Err(2)
            }
        }
    }

    /// `HLP?`: a help text long enough to be relayed in many pieces, in PI's framing (every
    /// line but the last ends with a space), one command per line as PIPython parses it.
    fn help(&self) -> Vec<u8> {
        let mut s = String::from("The following commands are valid: \n");
        for c in &self.cfg.commands {
            s += &format!(
                "{c} {} \n",
                "- see the user manual of the simulated controller for its arguments and replies"
            );
        }
        s += "end of help\n";
        cp1252(&s)
    }
}

fn fmt_value(v: f64) -> String {
    // seven decimals: one more than the compensator prints, as a controller's own resolution
    format!("{v:.7}")
}

fn is_single(b: u8) -> bool {
    matches!(b, 0x03..=0x09 | 0x0B | 0x18 | 0x1B)
}

/// Text to PI's code page, cp1252 (µ is B5h); other characters outside Latin-1 as '?'.
fn cp1252(s: &str) -> Vec<u8> {
    s.chars()
        .map(|c| u8::try_from(u32::from(c)).unwrap_or(b'?'))
        .collect()
}
