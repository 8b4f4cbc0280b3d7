//! Moves: `MOV`, `MVR`, `MVE`, `GOH` become the model's corrected commands.
//!
//! This is the path of every move the host sends, so it is written for the microcontroller:
//! targets are integers (micros) in plain arrays with a bit mask of the known ones, arguments
//! are read in one pass, and the forwarded line is printed straight into the output buffer.
//!
//! A target the command does not give — the base of an `MVR`, the other axes of a coupled
//! model — is always read from the controller (`MOV?`, the line waits for the answer): the
//! base is what the controller did, never what the proxy asked for (the controller may have
//! refused that move, or stopped). The proxy's own record stands in for the controller's
//! targets only as a whole (see the module documentation, *Bases*).

use super::controller::NotReady;
use super::travel::{self, Edge, Limit};
use super::{Corrector, Gate, GcsErrorCode, Output, ProxyState, Reseed, Targets};
use crate::command::MoveKind;
use crate::gcs::{self, GcsError, Split, MAP_AXES};

/// What a move waits for before it can be corrected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Needs {
    /// The controller's identity, version, axes, unit and travel.
    pub learn: bool,
    /// The controller's targets of the model axes (`MOV?`): the bases of the move.
    pub targets: bool,
}

/// Why a move was not forwarded now.
pub(crate) enum Stop {
    /// Refused with this GCS error code.
    Refuse(GcsErrorCode),
    /// Waits for the controller's answer to the proxy's own queries.
    Hold(Needs),
}

impl ProxyState {
    /// Correct a move and write it to `out.to_stage`.
    pub(super) fn rewrite_move<C: Corrector>(
        &mut self,
        c: Option<&C>,
        s: &Split<'_>,
        kind: MoveKind,
        out: &mut Output,
    ) -> Result<(), Stop> {
        let c = c.ok_or(Stop::Refuse(GcsErrorCode::NoModel))?;
        if self.gate != Gate::Open {
            return Err(Stop::Refuse(GcsErrorCode::SensorFault));
        }
        let n = c.axes().min(MAP_AXES);
        let all = (1u8 << n) - 1;
        // the arguments, in one pass: absolute targets `x` (micros) of the model axes in `set`,
        // relative distances (in `x` too) of those in `rel`, the model axes `named`, how many
        // arguments name `others` (`x` starts as a copy: cheaper than zeroing it)
        let mut x = self.targets.x;
        let (mut named, mut set, mut rel, mut others, mut any) = (0u8, 0u8, 0u8, 0usize, false);
        let mut toks = gcs::tokens(s.args);
        while let Some(id) = toks.next() {
            any = true;
            let v = if kind == MoveKind::Home {
                0
            } else {
                let text = toks.next().ok_or(Stop::Refuse(GcsErrorCode::ParamSyntax))?;
                match gcs::parse_micros_short(text) {
                    Some(v) => v,
                    None => gcs::parse_micros(text)
                        .map_err(|_| Stop::Refuse(GcsErrorCode::ParamSyntax))?,
                }
            };
            match self.map.index(id).filter(|&a| a < n) {
                Some(a) => {
                    if named >> a & 1 != 0 {
                        return Err(Stop::Refuse(GcsErrorCode::DoubleAxis));
                    }
                    named |= 1 << a;
                    x[a] = v;
                    if kind == MoveKind::Relative {
                        rel |= 1 << a;
                    } else {
                        set |= 1 << a;
                    }
                }
                None => others += 1,
            }
        }
        let home_all = kind == MoveKind::Home && !any;
        if !any && !home_all {
            return Err(Stop::Refuse(GcsErrorCode::ParamSyntax));
        }
        if home_all {
            named = all;
            set = all;
            x = [0; MAP_AXES];
        }
        if named == 0 {
            // no model axis: untouched
            forward_untouched(s, out);
            return Ok(());
        }

        // what the controller must have told first: its facts, and the bases of the axes the
        // command does not set (relative moves, a coupled model's other axes)
        let mut needs = Needs::default();
        match self.controller_ready(n) {
            Ok(()) => {}
            Err(NotReady::Learn) => needs.learn = true,
            Err(NotReady::Refuse(code)) => return Err(Stop::Refuse(code)),
        }
        let need_base = all & !set;
        let mut dir = self.dir;
        if need_base != 0 {
            match self.reseed {
                Reseed::Got(base) => {
                    for a in 0..n {
                        if rel >> a & 1 != 0 {
                            // a relative move goes the way of its distance
                            dir[a] = match x[a] {
                                0 => dir[a],
                                v if v > 0 => 1,
                                _ => -1,
                            };
                            // saturating: an absurd distance stays absurd
                            x[a] = base.x[a].saturating_add(x[a]);
                        } else if need_base >> a & 1 != 0 {
                            x[a] = base.x[a];
                        }
                    }
                }
                Reseed::Failed => return Err(Stop::Refuse(GcsErrorCode::TargetUnknown)),
                Reseed::None | Reseed::Asked => needs.targets = true,
            }
        }
        if needs.learn || needs.targets {
            return Err(Stop::Hold(needs));
        }

        // correct every model axis (a coupled model needs them all)
        let mut xf = [0f32; MAP_AXES];
        for a in 0..n {
            xf[a] = gcs::micros_to_f32(x[a]);
            if rel >> a & 1 == 0 && self.targets.known >> a & 1 != 0 {
                let old = self.targets.x[a];
                if x[a] > old {
                    dir[a] = 1;
                } else if x[a] < old {
                    dir[a] = -1;
                }
            }
        }
        let r = c.correct(&xf, &dir, &self.hyst);
        if r.fast_missing {
            return Err(Stop::Refuse(GcsErrorCode::SensorFault));
        }
        if r.outside_envelope & all != 0 || r.fast_outside {
            return Err(Stop::Refuse(GcsErrorCode::OutsideEnvelope));
        }
        // the command is the exact target plus δ, in micros; inside the stage travel (see
        // `travel`: clamped within 0.1 µm of an end, refused beyond)
        let mut q = x;
        let mut clamped = 0u8;
        for a in 0..n {
            let (lo, hi) = c.travel_um(a);
            let qa = r.q_um[a];
            let (clo, chi) = (self.ctrl.fast_lo[a], self.ctrl.fast_hi[a]);
            // |x| ≤ 10¹⁸ (parse_micros), |d| < 2⁶² (f32_to_micros): no overflow
            let dq = gcs::f32_to_micros(r.delta_um[a])
                .ok_or(Stop::Refuse(GcsErrorCode::PosOutOfLimits))?;
            q[a] = x[a] + dq;
            // (the model's travel is the blob's statement, compared in f32 as the fold holds
            // it; the controller's limits, which it enforces to the last digit, with a margin)
            let inside = qa >= lo && qa <= hi && qa >= clo && qa <= chi;
            if !inside {
                q[a] = self.at_edge(c, a, q[a], &mut clamped)?;
            }
        }
        let x_sent = if clamped != 0 {
            // the stage goes to the clamped command: record where that is in calibrated
            // coordinates
            self.clamped_target(c, &q, &xf, &dir, n)
                .ok_or(Stop::Refuse(GcsErrorCode::OutsideControllerTravel))?
        } else {
            x
        };

        // (the shape of the line's hot path, an unmixed move, as before the mixed lines' checks:
        // the `MOV` line's instruction budget has nothing to spare)
        let mut written = self.format_move(s.prefix, kind, named, &q, n, out);
        if written.is_ok() && (others > 0 || home_all) {
            // (a refusal here clears what was written: nothing goes out)
            self.format_other_axes(s, kind, n, home_all, out)?;
        } else if written.is_ok() {
            written = out.to_stage.push(b'\n');
        }
        written.map_err(|_| Stop::Refuse(GcsErrorCode::LineTooLong))?;
        // the one place a corrected target goes out: its targets and commands are recorded
        // (every model axis; the slots of other axes are never read), and the hysteresis
        // memory follows it
        self.targets = Targets {
            x: x_sent,
            q,
            known: self.targets.known | all,
        };
        if clamped != 0 {
            for a in 0..n {
                xf[a] = gcs::micros_to_f32(x_sent[a]);
            }
        }
        c.sent(&xf, &mut self.hyst);
        self.dir = dir;
        self.counters.moves = self.counters.moves.wrapping_add(1);
        Ok(())
    }

    /// A command near or outside an end of the travel: its exact check (see `travel`). The
    /// command to send, or the refusal.
    #[cold]
    #[inline(never)]
    fn at_edge<C: Corrector>(
        &self,
        c: &C,
        a: usize,
        q: i64,
        clamped: &mut u8,
    ) -> Result<i64, Stop> {
        let (lo, hi) = c.travel_um(a);
        let model = travel::model_travel_micros(lo, hi);
        match travel::edge(q, model, self.controller_travel(a)) {
            Edge::Inside => Ok(q),
            Edge::Clamped(limit) => {
                *clamped |= 1 << a;
                Ok(limit)
            }
            Edge::Outside(Limit::Model) => Err(Stop::Refuse(GcsErrorCode::PosOutOfLimits)),
            Edge::Outside(Limit::Controller) => {
                Err(Stop::Refuse(GcsErrorCode::OutsideControllerTravel))
            }
        }
    }

    /// The calibrated position of commands `q` (one or more clamped to the travel), started
    /// at the targets asked for `x`.
    #[cold]
    #[inline(never)]
    fn clamped_target<C: Corrector>(
        &self,
        c: &C,
        q: &[i64; MAP_AXES],
        x: &[f32; MAP_AXES],
        dir: &[i8; MAP_AXES],
        n: usize,
    ) -> Option<[i64; MAP_AXES]> {
        let mut qf = [0f32; MAP_AXES];
        for a in 0..n {
            qf[a] = gcs::micros_to_f32(q[a]);
        }
        let (_, delta) = c.inverse(&qf, dir, &self.hyst, Some(x))?;
        let mut xs = [0i64; MAP_AXES];
        for a in 0..n {
            xs[a] = q[a].saturating_sub(gcs::f32_to_micros(delta[a])?);
        }
        Some(xs)
    }

    /// The forwarded line: one `MOV` (`MVE`) with every model axis that was named or whose
    /// command changed (coupling, temperature), then (see `format_other_axes`) the other axes
    /// the host named, in the same line. This writes the `MOV` without its line end.
    fn format_move(
        &mut self,
        prefix: &[u8],
        kind: MoveKind,
        named: u8,
        q: &[i64; MAP_AXES],
        n: usize,
        out: &mut Output,
    ) -> Result<(), GcsError> {
        if !prefix.is_empty() {
            // (counted here, off the unaddressed line's path: following does not repeat an
            // address, so it leaves such a target alone)
            self.prefixed_moves = self.prefixed_moves.wrapping_add(1);
            out.to_stage.extend(prefix)?;
        }
        let o = &mut out.to_stage;
        o.extend(if kind == MoveKind::Vector {
            b"MVE"
        } else {
            b"MOV"
        })?;
        for a in 0..n {
            if named >> a & 1 != 0 || self.targets.q(a) != Some(q[a]) {
                o.push_pair(self.map.id(a).unwrap_or(b"?"), q[a])?;
            }
        }
        Ok(())
    }

    /// The other axes' part of a move (rare: a mixed line, or `GOH` of all axes), and its line
    /// end. Everything the host asked goes out as one line, so the controller accepts or
    /// refuses it as a whole, as it would the host's: the other axes' pairs of a `MOV` (`MVE`)
    /// as they came, those of a `GOH` as target 0 ("equivalent to moving the axes to
    /// positions 0 using MOV", PI) — the axes named, or for `GOH` of all axes every axis of
    /// the controller's (`SAI?`) the model does not cover. Refused: a line that names an axis
    /// twice ([`GcsErrorCode::DoubleAxis`], as the controller refuses it), and what cannot go
    /// out as one line ([`GcsErrorCode::SplitMove`]): an `MVR`'s other axes (the model axes'
    /// part is a corrected absolute target, theirs is relative to targets the proxy does not
    /// know), `GOH` of all axes while the controller's axes are unknown. Split into two lines,
    /// the controller could refuse one part (an axis named twice, not one of its axes, beyond
    /// its travel, servo off) and execute the other: the host's line would have moved nothing,
    /// and the model axes would have moved (issue 21's fuzz of following, seed 1044: `MVR 3
    /// 7.668 1 9.56 3 -15.8` moved axis 1 by 9.6 µm).
    #[cold]
    #[inline(never)]
    fn format_other_axes(
        &self,
        s: &Split<'_>,
        kind: MoveKind,
        n: usize,
        home_all: bool,
        out: &mut Output,
    ) -> Result<(), Stop> {
        let is_model = |id: &[u8]| self.map.index(id).is_some_and(|a| a < n);
        // the other axes' identifiers as named (every value was parsed before; a model axis
        // named twice was refused then)
        let step = if kind == MoveKind::Home { 1 } else { 2 };
        let ids = || gcs::tokens(s.args).step_by(step).filter(|id| !is_model(id));
        for (i, id) in ids().enumerate() {
            if ids().skip(i + 1).any(|other| gcs::same_axis(id, other)) {
                return Err(Stop::Refuse(GcsErrorCode::DoubleAxis));
            }
        }
        if kind == MoveKind::Relative {
            return Err(Stop::Refuse(GcsErrorCode::SplitMove));
        }
        let axes = self.ctrl.axes.known();
        if home_all && axes.is_none_or(|a| a.truncated) {
            // which other axes `GOH` means is unknown: a `MOV` of the model axes alone would
            // leave them where they are
            return Err(Stop::Refuse(GcsErrorCode::SplitMove));
        }
        let too_long = |_| Stop::Refuse(GcsErrorCode::LineTooLong);
        let o = &mut out.to_stage;
        let mut pair = |id: &[u8], value: &[u8]| -> Result<(), GcsError> {
            o.push(b' ')?;
            o.extend(id)?;
            o.push(b' ')?;
            o.extend(value)
        };
        if kind == MoveKind::Home {
            for id in ids() {
                pair(id, b"0").map_err(too_long)?;
            }
            if let (true, Some(axes)) = (home_all, axes) {
                for id in axes.ids[..axes.k].iter().flatten() {
                    if !is_model(id.as_bytes()) {
                        pair(id.as_bytes(), b"0").map_err(too_long)?;
                    }
                }
            }
        } else {
            for (id, _, text) in gcs::pairs(s.args).flatten().filter(|p| !is_model(p.0)) {
                pair(id, text).map_err(too_long)?;
            }
        }
        o.push(b'\n').map_err(too_long)
    }
}

/// A move that names no model axis goes out as it came (spacing normalised).
fn forward_untouched(s: &Split<'_>, out: &mut Output) {
    let o = &mut out.to_stage;
    let _ = o.extend(s.prefix);
    let _ = o.extend(s.command);
    if !s.args.is_empty() {
        let _ = o.push(b' ');
        let _ = o.extend(s.args);
    }
    let _ = o.push(b'\n');
}
