//! The inline compensator's GCS proxy (pure; the firmware only moves bytes).
//!
//! Host → controller: every command that sets a target of a model axis is corrected — `MOV`,
//! `MVR` (sent as an absolute `MOV`), `MVE` (kept a vector move) and `GOH` (sent as a `MOV` of
//! the corrected home) in every multi-axis form, with or without an address prefix, in any
//! letter case. Commands that would move a model axis to a target the model never saw (open-loop
//! values, step/impulse responses, wave generator, macros, trajectories, scans, …) are refused
//! with a GCS error while compensating, see [`crate::command`]. Commands after which the
//! controller's target is no longer the one the proxy sent (`HLT`, `STP`, `#24`, `FRF`, `SVO`, …,
//! and a non-zero answer of the controller to the host's `ERR?`: it may have refused a move) make
//! the proxy forget it; a later move that needs it re-seeds it from the controller's `MOV?` (the
//! line waits for that one answer). Single-character commands pass at once, even in the
//! middle of a line. Everything else is forwarded untouched; a line longer than the proxy's
//! buffer that it does not have to rewrite is streamed through.
//!
//! Controller → host: replies to `POS?`, `#3` and `MOV?` are mapped back to calibrated
//! coordinates (a `MOV?` value equal to the command sent maps back to its target exactly; other
//! values through the model's own inverse, `Fold::inverse_from`, started at the target, see
//! [`Corrector::inverse`]); every other
//! reply is relayed byte for byte, whatever its length. Several queries may be in flight: each
//! reply is matched to its query in order (`queue`).
//!
//! Refusals: nothing is forwarded and the error is kept for the host's next `ERR?`, which the
//! proxy then answers itself, with the address prefix swapped as a daisy-chained controller
//! does (PIPython asks `ERR?` after every command; the controller's own error, if it has one
//! too, stays for the following `ERR?`).
//!
//! The controller: before correcting the first move the proxy reads the controller's GCS syntax
//! version (`CSV?`, unless the host asked already) and the position unit of the model axes
//! (`PUN?`). The model is in µm: another unit, or no answer, refuses moves (code
//! [`GcsErrorCode::UnitMismatch`]); a GCS 3.0 controller (version > 2, PIPython's own test) is not
//! supported: moves are refused ([`GcsErrorCode::Gcs3`]) and replies relayed untouched.
//!
//! Time enters only as an argument (`now_ms`), for the one timeout the proxy has: queries the
//! controller does not answer within [`REPLY_TIMEOUT_MS`] (an unknown command only sets the
//! controller's error) are dropped from the queue so later replies keep their attribution.

mod corrector;
mod moves;
mod queue;
mod replies;

pub use corrector::{Corrected, Corrector, FoldCorrector};
pub use queue::MAX_IN_FLIGHT;

use crate::command::{self, Action, Affects, Refusal};
use crate::gcs::{self, AxisId, AxisMap, LineBuf, Split, MAP_AXES, MAX_LINE};
use core::fmt;
pub use nanocal_interface::GcsErrorCode;
use nanocal_model::HysteresisState;
use queue::{Expect, Info, Queue};
use replies::ReplyRx;

/// Bytes the proxy can hold from the host: the line being assembled, and the lines that
/// arrive while a line waits for the controller (then the host link pauses when it is full).
pub const INPUT_LEN: usize = 512;
/// Capacity of [`Output::to_stage`].
pub const STAGE_OUT: usize = 2 * MAX_LINE + 128;
/// Capacity of [`Output::to_host`].
pub const HOST_OUT: usize = 1280;
/// A query not answered within this time (ms, counted from the last byte exchanged with the
/// controller) is taken as unanswered. PI controllers answer within milliseconds; PIPython
/// waits seconds before it gives up on a reply.
pub const REPLY_TIMEOUT_MS: u32 = 2_000;

/// Bytes the proxy produced, for each link. Cleared by every call that fills it.
#[derive(Default)]
pub struct Output {
    /// Bytes for the stage controller.
    pub to_stage: LineBuf<STAGE_OUT>,
    /// Bytes for the host.
    pub to_host: LineBuf<HOST_OUT>,
}

impl Output {
    /// Empty buffers.
    pub const fn new() -> Self {
        Self {
            to_stage: LineBuf::new(),
            to_host: LineBuf::new(),
        }
    }
    /// Clear both buffers.
    pub fn clear(&mut self) {
        self.to_stage.clear();
        self.to_host.clear();
    }
    /// True when there is nothing to send.
    pub fn is_empty(&self) -> bool {
        self.to_stage.is_empty() && self.to_host.is_empty()
    }
}

/// Why moves are refused regardless of target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gate {
    /// Moves are corrected and forwarded.
    Open,
    /// A sensor the model needs has failed (see the fault policy).
    SensorFault,
}

/// Counters for the status report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Host lines seen.
    pub host_lines: u32,
    /// Moves corrected and forwarded.
    pub moves: u32,
    /// Commands refused with an error.
    pub refused: u32,
    /// Replies mapped back to calibrated coordinates.
    pub mapped_replies: u32,
    /// Replies whose positions could not be inverted (relayed unmapped).
    pub inverse_failures: u32,
    /// Queries the controller never answered (dropped after [`REPLY_TIMEOUT_MS`]).
    pub unanswered: u32,
}

/// What the proxy knows of the model axes' targets.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Targets {
    /// The calibrated targets the host asked for (micros), where `known` has the axis' bit.
    pub x: [i64; MAP_AXES],
    /// The commands sent for them, as printed (micros): what the controller's `MOV?` reports.
    pub q: [i64; MAP_AXES],
    /// Bit a: axis a's target (and command) are known.
    pub known: u8,
}

impl Targets {
    /// Axis `a`'s calibrated target, when known.
    pub fn x(&self, a: usize) -> Option<i64> {
        (self.known >> a & 1 != 0).then(|| self.x[a])
    }
    /// The command sent for axis `a`'s target, when known.
    pub fn q(&self, a: usize) -> Option<i64> {
        (self.known >> a & 1 != 0).then(|| self.q[a])
    }
    /// Record a target and its command.
    pub fn set(&mut self, a: usize, x: i64, q: i64) {
        self.x[a] = x;
        self.q[a] = q;
        self.known |= 1 << a;
    }
    /// These targets, with `other`'s for the axes not known here.
    pub fn merged(&self, other: &Targets) -> Targets {
        let mut m = *self;
        for a in 0..MAP_AXES {
            if m.known >> a & 1 == 0 && other.known >> a & 1 != 0 {
                m.set(a, other.x[a], other.q[a]);
            }
        }
        m
    }
}

/// The controller's position unit of the model axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Units {
    /// Not read yet (or changed since).
    Unknown,
    /// µm on every model axis (read for this many axes).
    Micrometre(usize),
    /// Another unit on some model axis.
    Mismatch,
    /// `PUN?` went unanswered.
    Unanswered,
}

/// The controller's GCS syntax version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Version {
    /// Not read yet.
    Unknown,
    /// GCS 2.0 (or `CSV?` unanswered: an older GCS 2 controller).
    Gcs2,
    /// GCS 3.0 (`CSV?` > 2).
    Gcs3,
}

/// Controller axis identifiers the proxy keeps (from `SAI?`).
pub(crate) const MAX_CONTROLLER_AXES: usize = 8;

/// What the proxy has read from the controller.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ControllerInfo {
    pub version: Version,
    pub units: Units,
    /// Axis identifiers (`SAI?`), when read.
    pub axes: Option<([Option<AxisId>; MAX_CONTROLLER_AXES], usize)>,
}

impl ControllerInfo {
    const fn new() -> Self {
        Self {
            version: Version::Unknown,
            units: Units::Unknown,
            axes: None,
        }
    }
}

/// A line waiting for the controller's answer to the proxy's own queries.
pub(crate) type Held = LineBuf<MAX_LINE>;

/// A host line longer than [`MAX_LINE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LongLine {
    /// None in progress.
    None,
    /// Forwarded byte by byte up to its LF (a command the proxy passes untouched).
    Stream,
    /// Dropped up to its LF (a command the proxy would have to rewrite or refuse).
    Discard,
}

/// The proxy: the host's bytes assembled into lines, and the [`ProxyState`] they act on.
///
/// Its entry points ([`host_bytes`](Proxy::host_bytes), [`stage_bytes`](Proxy::stage_bytes),
/// [`poll`](Proxy::poll)) take the firmware's corrector, [`FoldCorrector`]; inside, the proxy
/// is written against the [`Corrector`] contract. Being concrete, the entry points and
/// everything they call are compiled once, in this crate and at its optimisation level
/// (`Cargo.toml`), not instantiated again in the firmware's.
///
/// `Proxy` dereferences to its [`ProxyState`] (bypass, gate, counters, targets), so the state
/// reads as the proxy's own fields; the split only lets a line be processed where it was
/// assembled, without a copy.
pub struct Proxy {
    /// Host bytes not yet processed: the line being assembled, and the lines that arrive while
    /// a line waits for the controller.
    input: LineBuf<INPUT_LEN>,
    long: LongLine,
    st: ProxyState,
}

/// Everything the proxy knows apart from the host bytes it holds.
pub struct ProxyState {
    map: AxisMap,
    targets: Targets,
    /// Targets re-seeded from the controller's `MOV?` for the held line that asked; they become
    /// the proxy's targets only if that line's move goes out.
    reseed: Targets,
    dir: [i8; MAP_AXES],
    /// Last error the compensator raised, for the next `ERR?`.
    pending_error: Option<GcsErrorCode>,
    ctrl: ControllerInfo,
    queue: Queue,
    rx: ReplyRx,
    held: Option<Held>,
    /// The model's play operators as the commands sent left them (hysteresis memory): advanced
    /// only when a corrected target goes out, reset whenever the stage may have moved along a
    /// path the proxy did not see (see [`ProxyState::reset_hysteresis`]).
    hyst: HysteresisState,
    now_ms: u32,
    last_rx_ms: u32,
    last_tx_ms: u32,
    /// Forward everything untouched.
    pub bypass: bool,
    /// Refuse all moves when not open.
    pub gate: Gate,
    /// Counters.
    pub counters: Counters,
}

impl Default for Proxy {
    /// A fresh proxy: axes `1`, `2`, `3`, nothing known of the controller or the targets.
    fn default() -> Self {
        Self::new(AxisMap::default())
    }
}

impl core::ops::Deref for Proxy {
    type Target = ProxyState;
    fn deref(&self) -> &ProxyState {
        &self.st
    }
}

impl core::ops::DerefMut for Proxy {
    fn deref_mut(&mut self) -> &mut ProxyState {
        &mut self.st
    }
}

impl Proxy {
    /// A proxy with no targets known.
    pub fn new(map: AxisMap) -> Self {
        Self {
            input: LineBuf::new(),
            long: LongLine::None,
            st: ProxyState {
                map,
                targets: Targets::default(),
                reseed: Targets::default(),
                dir: [0; MAP_AXES],
                pending_error: None,
                ctrl: ControllerInfo::new(),
                queue: Queue::new(),
                rx: ReplyRx::new(),
                held: None,
                hyst: HysteresisState::new(),
                now_ms: 0,
                last_rx_ms: 0,
                last_tx_ms: 0,
                bypass: false,
                gate: Gate::Open,
                counters: Counters::default(),
            },
        }
    }

    /// True while the proxy waits for the controller (a reply expected or under way): only then
    /// does [`poll`](Self::poll) have anything to decide, so the stage link need not wake for it
    /// otherwise.
    pub fn awaiting_controller(&self) -> bool {
        !self.st.queue.is_empty() || self.st.rx.active()
    }

    /// True when host bytes already received can be processed now (call
    /// [`host_bytes`](Self::host_bytes) with no new bytes), or an answer of the proxy's own is
    /// due.
    pub fn has_work(&self) -> bool {
        let st = &self.st;
        let answer_due = !st.rx.active() && matches!(st.queue.front(), Some(Expect::Answer(_)));
        answer_due
            || (st.held.is_none()
                && (self.input.as_bytes().contains(&b'\n') || self.input.len() >= MAX_LINE))
    }

    /// Bytes from the host. Processes at most one line or one single-character command (so that
    /// `out` never overflows) and returns how many bytes of `input` it consumed; call again with
    /// the rest after sending `out`. With no input it processes a line received earlier.
    #[inline(never)]
    pub fn host_bytes(
        &mut self,
        c: Option<&FoldCorrector>,
        input: &[u8],
        now_ms: u32,
        out: &mut Output,
    ) -> usize {
        out.clear();
        self.st.now_ms = now_ms;
        if !self.st.queue.is_empty() {
            self.st.emit_answers(out);
        }
        if !self.input.is_empty() && self.step_input(c, out) {
            return 0;
        }
        let mut i = 0;
        while i < input.len() {
            let b = input[i];
            if gcs::is_single_char_command(b) {
                if out.to_stage.room() == 0 {
                    break;
                }
                self.host_single(b, out);
                return i + 1;
            }
            // the run of line bytes up to a line end or a single-character command
            let rest = &input[i..];
            let end = gcs::find_run_end(rest);
            let n = match end {
                Some(p) if rest[p] == b'\n' => p + 1,
                Some(p) => p,
                None => rest.len(),
            };
            let run = &rest[..n];
            match self.long {
                LongLine::None
                    if self.input.is_empty()
                        && self.st.held.is_none()
                        && run.last() == Some(&b'\n')
                        && n <= MAX_LINE + 1 =>
                {
                    // a whole line in the link's buffer: processed where it is
                    self.st.fresh_line(c, &run[..n - 1], out);
                    return i + n;
                }
                LongLine::None => {
                    let take = n.min(self.input.room());
                    if take == 0 {
                        break; // full while a line waits: the host link pauses
                    }
                    let _ = self.input.extend(&run[..take]);
                    i += take;
                    if self.step_input(c, out) {
                        return i;
                    }
                }
                LongLine::Stream => {
                    let take = n.min(out.to_stage.room());
                    if take == 0 {
                        break;
                    }
                    let _ = out.to_stage.extend(&run[..take]);
                    if run[take - 1] == b'\n' {
                        self.long = LongLine::None;
                    }
                    i += take;
                }
                LongLine::Discard => {
                    if run[n - 1] == b'\n' {
                        self.long = LongLine::None;
                    }
                    i += n;
                }
            }
        }
        i
    }

    /// Process one line from the input buffer, if one is complete (or overlong) and no line is
    /// held. True when something was processed.
    fn step_input<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) -> bool {
        if self.st.held.is_some() || self.long != LongLine::None {
            return false;
        }
        let bytes = self.input.as_bytes();
        if let Some(lf) = bytes.iter().position(|&b| b == b'\n') {
            if lf > MAX_LINE {
                self.long_line(c, lf, out);
            } else {
                self.st.fresh_line(c, &bytes[..lf], out);
            }
            self.input.consume(lf + 1);
            return true;
        }
        if bytes.len() >= MAX_LINE {
            self.long_line(c, bytes.len(), out);
            self.input.clear();
            return true;
        }
        false
    }

    /// A line longer than [`MAX_LINE`] (its first `len` bytes in the input buffer, followed by
    /// its LF when it has arrived): forwarded as it comes when the proxy passes the command
    /// untouched, else refused and dropped up to its LF.
    fn long_line<C: Corrector>(&mut self, c: Option<&C>, len: usize, out: &mut Output) {
        let _ = c;
        let st = &mut self.st;
        st.counters.host_lines = st.counters.host_lines.wrapping_add(1);
        let bytes = &self.input.as_bytes()[..len];
        let complete = self.input.as_bytes().get(len) == Some(&b'\n');
        let s = gcs::split(bytes);
        let passes = st.bypass || command::action(s.command) == Action::Pass;
        if passes && st.expect_reply(s.command) {
            let _ = out.to_stage.extend(bytes);
            if complete {
                let _ = out.to_stage.push(b'\n');
            } else {
                self.long = LongLine::Stream;
            }
        } else {
            st.refuse(if passes {
                GcsErrorCode::TooManyQueries
            } else {
                GcsErrorCode::LineTooLong
            });
            if !complete {
                self.long = LongLine::Discard;
            }
        }
    }

    /// A single-character command from the host: forwarded at once.
    fn host_single(&mut self, b: u8, out: &mut Output) {
        let st = &mut self.st;
        if !gcs::single_char_has_reply(b) {
            // #24 stops all axes, #27 aborts: targets are wherever the axes stopped, and no
            // line queued before the stop may start a motion after it
            st.forget(None);
            if st.held.take().is_some() {
                st.counters.refused = st.counters.refused.wrapping_add(1);
                st.reseed = Targets::default();
            }
            self.input.clear();
            self.long = LongLine::None;
            let _ = out.to_stage.push(b);
            return;
        }
        let e = if b == 0x03 && !st.bypass && st.ctrl.version != Version::Gcs3 {
            Expect::Map { target: false }
        } else {
            Expect::Relay
        };
        if st.expect(e) {
            let _ = out.to_stage.push(b);
        } else {
            // no reply could be matched: better no reply than a wrong one
            st.counters.refused = st.counters.refused.wrapping_add(1);
        }
    }

    /// Bytes from the controller. Returns how many of `input` it consumed; call again with the
    /// rest after sending `out` (it stops after a complete mapped reply, or when `out` is full).
    #[inline(never)]
    pub fn stage_bytes(
        &mut self,
        c: Option<&FoldCorrector>,
        input: &[u8],
        now_ms: u32,
        out: &mut Output,
    ) -> usize {
        self.st.stage_bytes(c, input, now_ms, out)
    }

    /// Time passes: queries the controller has not answered within [`REPLY_TIMEOUT_MS`] are
    /// given up (their answers are taken as missing), so later replies keep their attribution
    /// and a held line is decided. Call periodically (every few ms to 100 ms).
    #[inline(never)]
    pub fn poll(&mut self, c: Option<&FoldCorrector>, now_ms: u32, out: &mut Output) {
        self.st.poll(c, now_ms, out)
    }

    /// Forget all targets: the next move that needs one asks the controller.
    pub fn forget_targets(&mut self) {
        self.st.forget(None);
    }
}

impl ProxyState {
    /// Forget the hysteresis memory (the play operators' outputs): the next corrected command
    /// primes them at its targets. The rules (see `src/README.md`, *Hysteresis*): reset for a
    /// new model (the firmware calls this when it stages one), and whenever a target is
    /// forgotten (stops, referencing, servo changes, errors on moves, commands in bypass,
    /// reboot) — the stage then went somewhere along a path the proxy did not command. A host
    /// session's end and new settings start a fresh proxy, so they reset it too. A new fold of
    /// the same model (temperatures, λ_KMZ) keeps it: the stage's memory did not change.
    pub fn reset_hysteresis(&mut self) {
        self.hyst.reset();
    }

    /// The hysteresis memory as the commands sent left it.
    pub fn hysteresis(&self) -> &HysteresisState {
        &self.hyst
    }

    /// The error waiting for the host's next `ERR?`.
    pub fn pending_error(&self) -> Option<GcsErrorCode> {
        self.pending_error
    }

    /// Last calibrated targets known to the proxy, µm.
    pub fn targets_um(&self) -> [Option<f64>; MAP_AXES] {
        [0, 1, 2].map(|a| {
            self.targets
                .x(a)
                .map(|t| t as f64 / gcs::MICROS_PER_UNIT as f64)
        })
    }

    /// True when moves are refused because the controller's position unit is not the model's
    /// (µm) or the controller did not tell it.
    pub fn unit_mismatch(&self) -> bool {
        matches!(self.ctrl.units, Units::Mismatch | Units::Unanswered)
    }

    /// True when the controller announced GCS 3.0 (moves refused, replies untouched).
    pub fn gcs3(&self) -> bool {
        self.ctrl.version == Version::Gcs3
    }

    /// Queries in flight (sent, reply not complete).
    pub fn in_flight(&self) -> usize {
        self.queue.len() + usize::from(self.rx.active())
    }

    /// True while a host line waits for the controller's answer to the proxy's own query.
    pub fn holding(&self) -> bool {
        self.held.is_some()
    }

    /// For a query, record that its reply is to be relayed; `false` when the queue is full.
    fn expect_reply(&mut self, command: &[u8]) -> bool {
        !command::is_query(command) || self.expect(Expect::Relay)
    }

    /// Record an expected reply; `false` when too many are in flight.
    fn expect(&mut self, e: Expect) -> bool {
        if self.queue.push(e) {
            self.last_tx_ms = self.now_ms;
            true
        } else {
            false
        }
    }

    fn refuse(&mut self, code: GcsErrorCode) {
        self.pending_error = Some(code);
        self.counters.refused = self.counters.refused.wrapping_add(1);
    }

    /// Forward a line (LF appended).
    fn forward(&mut self, line: &[u8], out: &mut Output) {
        if out.to_stage.extend(line).is_err() || out.to_stage.push(b'\n').is_err() {
            self.refuse(GcsErrorCode::LineTooLong);
        }
    }

    /// One complete command line (LF removed). `fresh` is false when a held line is run again
    /// after the controller answered (then it may not wait again).
    fn process_line<C: Corrector>(
        &mut self,
        c: Option<&C>,
        line: &[u8],
        out: &mut Output,
        fresh: bool,
    ) {
        let s = gcs::split(line);
        if s.command.is_empty() {
            self.forward(line, out);
            return;
        }
        let action = command::action_of_key(s.key);
        if action == Action::ErrorQuery && self.pending_error.is_some() {
            self.answer_error(s.prefix, out);
            return;
        }
        if self.bypass {
            // untouched; targets set in bypass are raw
            if !matches!(action, Action::Pass | Action::ErrorQuery) {
                self.forget(None);
            }
            if self.expect_reply(s.command) {
                self.forward(line, out);
            } else {
                self.refuse(GcsErrorCode::TooManyQueries);
            }
            return;
        }
        let action = match action {
            Action::Macro => command::macro_action(gcs::tokens(s.args).next().unwrap_or(b"")),
            Action::StartStop => start_stop(s.args),
            a => a,
        };
        match action {
            Action::Move(kind) => self.move_line(c, &s, kind, line, out, fresh),
            Action::PositionQuery { target } => {
                let e = if self.ctrl.version == Version::Gcs3 {
                    Expect::Relay
                } else {
                    Expect::Map { target }
                };
                self.query(e, s.command, line, out);
            }
            Action::Forget(affects) => {
                self.forget_affected(affects, s.args);
                self.forward(line, out);
            }
            Action::Refuse(refusal) => {
                if refusal == Refusal::ModelAxes && !self.names_model_axis(&s, c) {
                    self.forward(line, out);
                } else if c.is_none() {
                    self.refuse(GcsErrorCode::NoModel);
                } else {
                    self.refuse(GcsErrorCode::RefusedWhileCompensating);
                }
            }
            Action::SetUnit => {
                self.ctrl.units = Units::Unknown;
                self.forward(line, out);
            }
            Action::UnitQuery => self.query(Expect::Snoop(Info::Units), s.command, line, out),
            Action::VersionQuery => self.query(Expect::Snoop(Info::Version), s.command, line, out),
            Action::ErrorQuery => self.query(Expect::Snoop(Info::Error), s.command, line, out),
            Action::AxesQuery if s.args.is_empty() => {
                self.query(Expect::Snoop(Info::Axes), s.command, line, out)
            }
            Action::Reboot => {
                self.forget(None);
                self.ctrl = ControllerInfo::new();
                self.forward(line, out);
            }
            _ => self.query(Expect::Relay, s.command, line, out),
        }
    }

    /// A move command: corrected and forwarded, refused, or held until the controller answered.
    fn move_line<C: Corrector>(
        &mut self,
        c: Option<&C>,
        s: &Split<'_>,
        kind: command::MoveKind,
        line: &[u8],
        out: &mut Output,
        fresh: bool,
    ) {
        match self.rewrite_move(c, s, kind, out, fresh) {
            Ok(()) => {}
            Err(moves::Stop::Refuse(code)) => {
                out.to_stage.clear();
                self.refuse(code);
            }
            Err(moves::Stop::Hold(needs)) => self.hold(c, line, needs, out),
        }
    }

    /// A whole line straight from the host's buffer. The commonest line, `MOV <axis> <target>`
    /// without address prefix, goes to the move path without the general dispatch.
    fn fresh_line<C: Corrector>(&mut self, c: Option<&C>, line: &[u8], out: &mut Output) {
        self.counters.host_lines = self.counters.host_lines.wrapping_add(1);
        if !self.bypass && line.len() > 4 {
            // "MOV " in any case: one word compare (OR 0x20 folds only these letters' cases)
            let w = u32::from_le_bytes([line[0], line[1], line[2], line[3]]);
            if w | 0x0020_2020 == u32::from_le_bytes(*b"mov ") {
                let mut args = &line[4..];
                while let [rest @ .., b'\r' | b' '] = args {
                    args = rest;
                }
                let s = Split {
                    prefix: &[],
                    command: &line[..3],
                    key: gcs::key(b"MOV"),
                    args,
                };
                self.move_line(c, &s, command::MoveKind::Absolute, line, out, true);
                return;
            }
        }
        self.process_line(c, line, out, true);
    }

    /// Forward a command; for a query, expect its reply as `e`.
    fn query(&mut self, e: Expect, command: &[u8], line: &[u8], out: &mut Output) {
        if command::is_query(command) && !self.expect(e) {
            self.refuse(GcsErrorCode::TooManyQueries);
            return;
        }
        self.forward(line, out);
    }

    /// The proxy's own answer to `ERR?`, after every reply still due.
    fn answer_error(&mut self, prefix: &[u8], out: &mut Output) {
        let Some(code) = self.pending_error.take() else {
            return;
        };
        let a = queue::Answer::new(prefix, code);
        // in turn after the replies still due; at once when none is (or none fits the queue)
        let now = self.queue.is_empty() && !self.rx.active();
        if now || !self.queue.push(Expect::Answer(a)) {
            a.write(&mut out.to_host);
        }
    }

    /// Send the proxy's own answers that are due (nothing in flight before them).
    fn emit_answers(&mut self, out: &mut Output) {
        while !self.rx.active() {
            match self.queue.front() {
                Some(Expect::Answer(a)) if out.to_host.room() >= 24 => {
                    a.write(&mut out.to_host);
                    self.queue.pop();
                }
                _ => break,
            }
        }
    }

    /// Does a command refused on model axes name one (or name no axis, meaning all)?
    fn names_model_axis<C: Corrector>(&self, s: &Split<'_>, c: Option<&C>) -> bool {
        let n = c.map(|c| c.axes()).unwrap_or(MAP_AXES).min(MAP_AXES);
        let mut any = false;
        for t in gcs::tokens(s.args) {
            any = true;
            if self.map.index(t).is_some_and(|a| a < n) {
                return true;
            }
        }
        !any
    }

    /// Forget the targets of the model axes a command affects.
    fn forget_affected(&mut self, affects: Affects, args: &[u8]) {
        match affects {
            Affects::All => self.forget(None),
            Affects::Listed => {
                let mut any = false;
                for t in gcs::tokens(args) {
                    any = true;
                    if let Some(a) = self.map.index(t) {
                        self.forget(Some(a));
                    }
                }
                if !any {
                    self.forget(None);
                }
            }
            Affects::Paired => {
                let mut any = false;
                for (k, t) in gcs::tokens(args).enumerate() {
                    any = true;
                    if k % 2 == 0 {
                        if let Some(a) = self.map.index(t) {
                            self.forget(Some(a));
                        }
                    }
                }
                if !any {
                    self.forget(None);
                }
            }
        }
    }

    /// Forget one model axis' target (`None`: all). The axis stopped short of its target,
    /// was referenced, switched servo, errored, or moved in bypass: the stage went where the
    /// proxy did not send it, so the hysteresis memory is reset too.
    fn forget(&mut self, axis: Option<usize>) {
        match axis {
            Some(a) if a < MAP_AXES => self.targets.known &= !(1 << a),
            _ => self.targets.known = 0,
        }
        self.hyst.reset();
    }

    /// Keep `line` until the controller answered the proxy's own queries for `needs`.
    fn hold<C: Corrector>(
        &mut self,
        c: Option<&C>,
        line: &[u8],
        needs: moves::Needs,
        out: &mut Output,
    ) {
        let Some(c) = c else {
            self.refuse(GcsErrorCode::NoModel);
            return;
        };
        let n = c.axes().min(MAP_AXES);
        let mut held = Held::new();
        if held.extend(line).is_err() {
            self.refuse(GcsErrorCode::LineTooLong);
            return;
        }
        out.to_stage.clear();
        let mut ok = true;
        if needs.units {
            if self.ctrl.version == Version::Unknown
                && self.queue.count_internal(Info::Version) == 0
            {
                ok &= self.internal(Info::Version, b"CSV?", 0, out);
            }
            if self.queue.count_internal(Info::Units) == 0 {
                ok &= self.internal(Info::Units, b"PUN?", n, out);
            }
        }
        if needs.targets && self.queue.count_internal(Info::Targets) == 0 {
            ok &= self.internal(Info::Targets, b"MOV?", n, out);
        }
        if needs.axes && self.queue.count_internal(Info::Axes) == 0 {
            ok &= self.internal(Info::Axes, b"SAI?", 0, out);
        }
        if ok {
            self.held = Some(held);
        } else {
            self.refuse(GcsErrorCode::TooManyQueries);
        }
    }

    /// Send the proxy's own query `word` (with the first `axes` model axis identifiers).
    fn internal(&mut self, info: Info, word: &[u8], axes: usize, out: &mut Output) -> bool {
        if !self.expect(Expect::Internal(info)) {
            return false;
        }
        let _ = out.to_stage.extend(word);
        for a in 0..axes {
            let _ = out.to_stage.push(b' ');
            let _ = out.to_stage.extend(self.map.id(a).unwrap_or(b"?"));
        }
        let _ = out.to_stage.push(b'\n');
        true
    }

    /// Run the held line again once no answer it waits for is outstanding.
    fn try_release<C: Corrector>(&mut self, c: Option<&C>, out: &mut Output) {
        if self.held.is_none() || self.rx.internal() {
            return;
        }
        let waiting = [Info::Version, Info::Units, Info::Targets, Info::Axes]
            .iter()
            .any(|&i| self.queue.count_internal(i) > 0);
        if waiting {
            return;
        }
        if let Some(line) = self.held.take() {
            self.process_line(c, line.as_bytes(), out, false);
            self.reseed = Targets::default();
        }
    }

    fn poll<C: Corrector>(&mut self, c: Option<&C>, now_ms: u32, out: &mut Output) {
        out.clear();
        self.now_ms = now_ms;
        self.emit_answers(out);
        let waiting = !self.queue.is_empty() || self.rx.active();
        let quiet = now_ms.wrapping_sub(self.last_rx_ms) > REPLY_TIMEOUT_MS
            && now_ms.wrapping_sub(self.last_tx_ms) > REPLY_TIMEOUT_MS;
        if !(waiting && quiet) {
            return;
        }
        self.give_up_replies(c, out);
        self.try_release(c, out);
    }
}

/// `WGO`/`JON`/`HIN`/`EGE {id value}`: stopping (every value 0) forgets all targets, starting
/// is refused.
fn start_stop(args: &[u8]) -> Action {
    let mut any = false;
    for (k, t) in gcs::tokens(args).enumerate() {
        any = true;
        if k % 2 == 1 && gcs::parse_micros(t) != Ok(0) {
            return Action::Refuse(Refusal::Always);
        }
    }
    if any {
        Action::Forget(Affects::All)
    } else {
        Action::Refuse(Refusal::Always)
    }
}

impl fmt::Debug for Proxy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let st = &self.st;
        f.debug_struct("Proxy")
            .field("targets", &st.targets)
            .field("pending_error", &st.pending_error)
            .field("bypass", &st.bypass)
            .field("gate", &st.gate)
            .field("in_flight", &st.in_flight())
            .field("holding", &st.holding())
            .finish()
    }
}
