//! The inline compensator's GCS proxy state machine (pure; the firmware only moves bytes).
//!
//! Host → controller: `MOV`/`MVR` targets (every multi-axis form, with or without an address
//! prefix) are replaced by the model's corrected commands (`MVR` becomes an absolute `MOV`);
//! everything else passes untouched. When a move is refused (outside the model's envelope or
//! the stage travel, a failed sensor, no model) nothing is forwarded and the error is kept for
//! the host's next `ERR?`, which the proxy then answers itself (PIPython asks `ERR?` after
//! every command; the controller's own error, if it has one too, stays for the following
//! `ERR?`). Controller → host: replies to `POS?` and `MOV?` are mapped back through the
//! inverse so the host sees calibrated coordinates; all other replies are relayed.
//!
//! The proxy is generic over a [`Corrector`] (the firmware's current thermal fold) so that it is
//! tested natively with the model's own code.

use crate::gcs::{self, AxisMap, Feed, GcsError, LineBuf, MAP_AXES, MAX_LINE};
use core::fmt;
use nanocal_model::{FastInputs, Fold, HysteresisState, Model, SlowInputs, MAX_AXES};

const _: () = assert!(MAP_AXES == MAX_AXES);

/// Output buffer for a forwarded/rewritten line or a complete reply.
pub type Out = LineBuf<OUT_LEN>;
/// Capacity of [`Out`] (bytes).
pub const OUT_LEN: usize = 2 * MAX_LINE;

/// GCS error codes the compensator raises itself (answered on the host's next `ERR?`).
pub mod codes {
    /// PI: illegal parameter / syntax (unparsable number, missing value).
    pub const PARAM_SYNTAX: i32 = 1;
    /// PI: position out of limits — the corrected command is outside the stage travel.
    pub const POS_OUT_OF_LIMITS: i32 = 7;
    /// PI: invalid axis identifier (duplicate axis).
    pub const INVALID_AXIS: i32 = 15;
    /// Compensator: the target lies outside the model's training envelope.
    pub const OUTSIDE_ENVELOPE: i32 = 9001;
    /// Compensator: a temperature sensor the model needs has failed; moves are refused.
    pub const SENSOR_FAULT: i32 = 9002;
    /// Compensator: no valid model is loaded (and compensation is not bypassed).
    pub const NO_MODEL: i32 = 9003;
    /// Compensator: a coupled axis' target is unknown (send one MOV with all model axes first),
    /// or `MVR` on an axis whose target is unknown.
    pub const TARGET_UNKNOWN: i32 = 9004;
    /// Compensator: the line is longer than its buffer.
    pub const LINE_TOO_LONG: i32 = 9005;
}

/// Result of the model's fast path for one target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corrected {
    /// Commands for the controller, µm, per model axis.
    pub q_um: [f32; MAP_AXES],
    /// Bit per axis: the target is outside the training envelope.
    pub outside_envelope: u8,
}

/// What the proxy needs from a model: the fast path, its inverse and the stage travel.
pub trait Corrector {
    /// Number of model axes (1..=3).
    fn axes(&self) -> usize;
    /// Fast path: commands for calibrated targets `x_um` approached in direction `dir`.
    fn correct(&self, x_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Corrected;
    /// Inverse: calibrated position for controller positions `q_um`; `None` if it fails.
    fn inverse(&self, q_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Option<[f32; MAP_AXES]>;
    /// Stage travel of a model axis in command space (min, max), µm.
    fn travel_um(&self, axis: usize) -> (f32, f32);
}

/// The model's fast path as the proxy uses it: a thermal fold and the stage travel.
#[derive(Debug, Clone, Copy)]
pub struct FoldCorrector {
    /// The current thermal fold.
    pub fold: Fold,
    /// Stage travel per axis in command space, µm.
    pub travel_um: [(f32, f32); MAX_AXES],
}

impl FoldCorrector {
    /// Fold `model` at `slow` (the slow path).
    pub fn new(model: &Model, slow: &SlowInputs) -> Self {
        let mut travel_um = [(0.0, 0.0); MAX_AXES];
        for (a, t) in travel_um.iter_mut().enumerate().take(model.axes()) {
            let (lo, hi) = model.travel_um(a);
            *t = (lo as f32, hi as f32);
        }
        Self {
            fold: model.fold(slow),
            travel_um,
        }
    }
}

impl Corrector for FoldCorrector {
    fn axes(&self) -> usize {
        self.fold.axes()
    }
    fn correct(&self, x_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Corrected {
        // Fast inputs and hysteresis state are not supplied by the device yet: a model that
        // uses a fast input yields NaN commands (refused as out of travel), and play operators
        // start fresh on every command.
        let c = self
            .fold
            .correct(x_um, dir, &FastInputs::NONE, &mut HysteresisState::new());
        Corrected {
            q_um: c.q_um,
            outside_envelope: c.outside_envelope,
        }
    }
    fn inverse(&self, q_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Option<[f32; MAP_AXES]> {
        self.fold
            .inverse(q_um, dir, &FastInputs::NONE, &HysteresisState::new())
            .ok()
    }
    fn travel_um(&self, axis: usize) -> (f32, f32) {
        self.travel_um.get(axis).copied().unwrap_or((0.0, 0.0))
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

/// Where the bytes the proxy produced go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    /// Nothing to send.
    None,
    /// Send the output to the stage controller.
    Stage,
    /// Send the output back to the host (the proxy answered itself).
    Host,
}

/// What the controller's next reply belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    /// Relay as is.
    Pass,
    /// `POS?`/`MOV?`: map axis values back through the inverse.
    Map,
}

/// Counters for the status report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Host lines seen.
    pub host_lines: u32,
    /// Moves corrected and forwarded.
    pub moves: u32,
    /// Moves refused with an error.
    pub refused: u32,
    /// Replies mapped through the inverse.
    pub mapped_replies: u32,
    /// Inverse failures (reply relayed unmapped... never: replaced by the raw value).
    pub inverse_failures: u32,
}

/// The proxy's state.
pub struct Proxy {
    map: AxisMap,
    /// Last calibrated target per model axis (what the host asked for).
    target_um: [Option<f64>; MAP_AXES],
    /// Last command per model axis (what the controller was told / reported).
    q_um: [Option<f32>; MAP_AXES],
    dir: [i8; MAP_AXES],
    /// Last error the compensator raised, for the next `ERR?` (0 = none).
    pending_error: i32,
    /// What the controller's next reply answers. GCS is request/response, and a query the
    /// controller does not answer at all (an invalid one only sets its error) must not shift
    /// the attribution of later replies: so a reply belongs to the most recent query.
    pending: Option<Pending>,
    reply: LineBuf<OUT_LEN>,
    /// Forward everything untouched.
    pub bypass: bool,
    /// Refuse all moves when not open.
    pub gate: Gate,
    /// Counters.
    pub counters: Counters,
    /// Decimals of forwarded commands and mapped replies.
    pub decimals: u32,
}

impl Default for Proxy {
    fn default() -> Self {
        Self::new(AxisMap::default())
    }
}

impl Proxy {
    /// A proxy with no targets known.
    pub fn new(map: AxisMap) -> Self {
        Self {
            map,
            target_um: [None; MAP_AXES],
            q_um: [None; MAP_AXES],
            dir: [0; MAP_AXES],
            pending_error: 0,
            pending: None,
            reply: LineBuf::new(),
            bypass: false,
            gate: Gate::Open,
            counters: Counters::default(),
            decimals: 6,
        }
    }

    /// The error waiting for the host's next `ERR?` (0 = none).
    pub fn pending_error(&self) -> i32 {
        self.pending_error
    }

    /// Last calibrated targets known to the proxy.
    pub fn targets_um(&self) -> [Option<f64>; MAP_AXES] {
        self.target_um
    }

    /// Forget targets (after a model change the old commands mean something else).
    pub fn forget_targets(&mut self) {
        self.target_um = [None; MAP_AXES];
    }

    fn raise(&mut self, code: i32) {
        self.pending_error = code;
        self.counters.refused += 1;
    }

    fn push_pending(&mut self, p: Pending) {
        if self.pending != Some(p) {
            // a new query while a multi-line reply was being collected: drop the partial reply
            self.reply.clear();
        }
        self.pending = Some(p);
    }

    fn front_pending(&self) -> Pending {
        self.pending.unwrap_or(Pending::Pass)
    }

    fn pop_pending(&mut self) {
        self.pending = None;
    }

    /// A single-character command from the host: forwarded as is (its reply is relayed).
    pub fn host_single(&mut self, b: u8, out: &mut Out) -> Route {
        out.clear();
        if gcs::single_char_has_reply(b) {
            self.push_pending(Pending::Pass);
        }
        if out.push(b).is_ok() {
            Route::Stage
        } else {
            Route::None
        }
    }

    /// Feed what a [`gcs::LineAssembler`] produced for the host stream.
    pub fn host_feed<C: Corrector>(
        &mut self,
        c: Option<&C>,
        feed: Feed,
        line: &[u8],
        out: &mut Out,
    ) -> Route {
        match feed {
            Feed::Pending => Route::None,
            Feed::Single(b) => self.host_single(b, out),
            Feed::Line => self.host_line(c, line, out),
            Feed::Overflow => {
                out.clear();
                self.raise(codes::LINE_TOO_LONG);
                Route::None
            }
        }
    }

    /// One complete host line (LF removed). The output line ends with LF.
    pub fn host_line<C: Corrector>(&mut self, c: Option<&C>, line: &[u8], out: &mut Out) -> Route {
        out.clear();
        self.counters.host_lines += 1;
        let s = gcs::split(line);
        match s.command {
            b"ERR?" if self.pending_error != 0 => {
                let code = self.pending_error;
                self.pending_error = 0;
                let ok = out.extend(s.prefix).is_ok()
                    && out.push_int(i64::from(code)).is_ok()
                    && out.push(b'\n').is_ok();
                if ok {
                    Route::Host
                } else {
                    Route::None
                }
            }
            b"MOV" | b"MVR" if !self.bypass => {
                let relative = s.command == b"MVR";
                match self.rewrite_move(c, s.prefix, s.args, relative, out) {
                    Ok(()) => {
                        self.counters.moves += 1;
                        Route::Stage
                    }
                    Err(code) => {
                        out.clear();
                        self.raise(code);
                        Route::None
                    }
                }
            }
            cmd => {
                if !self.bypass && (cmd == b"POS?" || cmd == b"MOV?") {
                    self.push_pending(Pending::Map);
                } else if cmd.last() == Some(&b'?') {
                    self.push_pending(Pending::Pass);
                }
                if out.extend(line).is_ok() && out.push(b'\n').is_ok() {
                    Route::Stage
                } else {
                    out.clear();
                    self.raise(codes::LINE_TOO_LONG);
                    Route::None
                }
            }
        }
    }

    #[allow(clippy::needless_range_loop)]
    fn rewrite_move<C: Corrector>(
        &mut self,
        c: Option<&C>,
        prefix: &[u8],
        args: &[u8],
        relative: bool,
        out: &mut Out,
    ) -> Result<(), i32> {
        let c = c.ok_or(codes::NO_MODEL)?;
        if self.gate != Gate::Open {
            return Err(codes::SENSOR_FAULT);
        }
        let pairs = gcs::parse_pairs(args).map_err(|e| match e {
            GcsError::DuplicateAxis => codes::INVALID_AXIS,
            _ => codes::PARAM_SYNTAX,
        })?;
        if pairs.n == 0 {
            return Err(codes::PARAM_SYNTAX);
        }
        let axes = c.axes().min(MAP_AXES);
        let mut x = self.target_um;
        let mut mentioned = [false; MAP_AXES];
        for &(id, v) in pairs.as_slice() {
            if let Some(a) = self.map.index(id).filter(|&a| a < axes) {
                mentioned[a] = true;
                x[a] = if relative {
                    Some(self.target_um[a].ok_or(codes::TARGET_UNKNOWN)? + v)
                } else {
                    Some(v)
                };
            }
        }
        let mut xf = [0f32; MAP_AXES];
        let mut dir = self.dir;
        for a in 0..axes {
            let xa = x[a].ok_or(codes::TARGET_UNKNOWN)?;
            xf[a] = xa as f32;
            if let Some(old) = self.target_um[a] {
                if xa > old {
                    dir[a] = 1;
                } else if xa < old {
                    dir[a] = -1;
                }
            }
        }
        let r = c.correct(&xf, &dir);
        if r.outside_envelope & ((1u8 << axes) - 1) != 0 {
            return Err(codes::OUTSIDE_ENVELOPE);
        }
        for a in 0..axes {
            let (lo, hi) = c.travel_um(a);
            let q = r.q_um[a];
            if !(q >= lo && q <= hi) {
                return Err(codes::POS_OUT_OF_LIMITS);
            }
        }
        // forward: every model axis that was mentioned or whose command changed because of a
        // coupled axis, then the untouched pairs of axes the model does not cover
        let fmt = |out: &mut Out| -> Result<(), GcsError> {
            out.extend(prefix)?;
            out.extend(b"MOV")?;
            for a in 0..axes {
                let changed = self.q_um[a].map(|q| q != r.q_um[a]).unwrap_or(true);
                if mentioned[a] || changed {
                    out.push(b' ')?;
                    out.extend(self.map.id(a).unwrap_or(b"?"))?;
                    out.push(b' ')?;
                    out.push_fixed(f64::from(r.q_um[a]), self.decimals)?;
                }
            }
            for &(id, v) in pairs.as_slice() {
                if self.map.index(id).filter(|&a| a < axes).is_none() {
                    out.push(b' ')?;
                    out.extend(id)?;
                    out.push(b' ')?;
                    if relative {
                        // an axis the model does not cover keeps its relative move: it cannot be
                        // made absolute without knowing its target — forward it in its own MVR
                        return Err(GcsError::MissingValue);
                    }
                    out.push_fixed(v, self.decimals)?;
                }
            }
            out.push(b'\n')
        };
        fmt(out).map_err(|_| codes::PARAM_SYNTAX)?;
        for a in 0..axes {
            self.target_um[a] = x[a];
            self.q_um[a] = Some(r.q_um[a]);
        }
        self.dir = dir;
        Ok(())
    }

    /// One complete line from the controller (LF removed). Returns the bytes for the host
    /// (LF-terminated; a mapped multi-line reply is returned whole with its final line).
    pub fn stage_line<C: Corrector>(&mut self, c: Option<&C>, line: &[u8], out: &mut Out) -> Route {
        out.clear();
        let continued = gcs::is_continued(line);
        match self.front_pending() {
            Pending::Pass => {
                if !continued {
                    self.pop_pending();
                }
                if out.extend(line).is_ok() && out.push(b'\n').is_ok() {
                    Route::Host
                } else {
                    Route::None
                }
            }
            Pending::Map => {
                if self.reply.extend(line).is_err() || self.reply.push(b'\n').is_err() {
                    // too long to map: relay what we have, unmapped
                    let _ = out.extend(self.reply.as_bytes());
                    let _ = out.extend(line);
                    let _ = out.push(b'\n');
                    self.reply.clear();
                    if !continued {
                        self.pop_pending();
                    }
                    return Route::Host;
                }
                if continued {
                    return Route::None;
                }
                self.pop_pending();
                let mut reply = LineBuf::<OUT_LEN>::new();
                let _ = reply.extend(self.reply.as_bytes());
                self.reply.clear();
                self.map_reply(c, reply.as_bytes(), out);
                Route::Host
            }
        }
    }

    #[allow(clippy::needless_range_loop)]
    fn map_reply<C: Corrector>(&mut self, c: Option<&C>, reply: &[u8], out: &mut Out) {
        let Some(c) = c else {
            let _ = out.extend(reply);
            return;
        };
        let axes = c.axes().min(MAP_AXES);
        // gather the controller's values of the model axes
        let mut q = [0f32; MAP_AXES];
        let mut have = [false; MAP_AXES];
        for l in lines(reply) {
            if let Some(av) = gcs::parse_axis_value(l) {
                if let Some(a) = self.map.index(av.axis).filter(|&a| a < axes) {
                    q[a] = av.value as f32;
                    have[a] = true;
                }
            }
        }
        for a in 0..axes {
            if !have[a] {
                q[a] = match self.q_um[a] {
                    Some(v) => v,
                    // unknown other axis: assume it is at its travel centre
                    None => {
                        let (lo, hi) = c.travel_um(a);
                        0.5 * (lo + hi)
                    }
                };
            }
        }
        let x = c.inverse(&q, &self.dir);
        if x.is_some() {
            self.counters.mapped_replies += 1;
        } else {
            self.counters.inverse_failures += 1;
        }
        for l in lines(reply) {
            let av = gcs::parse_axis_value(l);
            let mapped = match (av, x) {
                (Some(av), Some(x)) => self
                    .map
                    .index(av.axis)
                    .filter(|&a| a < axes)
                    .map(|a| (av, x[a])),
                _ => None,
            };
            let ok = match mapped {
                Some((av, xa)) => (|| -> Result<(), GcsError> {
                    out.extend(av.prefix)?;
                    out.extend(av.axis)?;
                    out.push(b'=')?;
                    out.push_fixed(f64::from(xa), self.decimals)?;
                    if av.continued {
                        out.push(b' ')?;
                    }
                    out.push(b'\n')
                })(),
                None => out.extend(l).and_then(|_| out.push(b'\n')),
            };
            if ok.is_err() {
                break;
            }
        }
    }
}

fn lines(reply: &[u8]) -> impl Iterator<Item = &[u8]> {
    reply.split(|&b| b == b'\n').filter(|l| !l.is_empty())
}

impl fmt::Debug for Proxy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Proxy")
            .field("target_um", &self.target_um)
            .field("pending_error", &self.pending_error)
            .field("bypass", &self.bypass)
            .field("gate", &self.gate)
            .finish()
    }
}
