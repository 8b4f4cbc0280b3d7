//! Moves: `MOV`, `MVR`, `MVE`, `GOH` become the model's corrected commands.
//!
//! This is the path of every move the host sends, so it is written for the microcontroller:
//! targets are integers (micros) in plain arrays with a bit mask of the known ones, arguments
//! are read in one pass, and the forwarded line is printed straight into the output buffer.

use super::{Corrector, Gate, GcsErrorCode, Output, ProxyState, Targets, Units, Version};
use crate::command::MoveKind;
use crate::gcs::{self, GcsError, Split, MAP_AXES};

/// What a move waits for before it can be corrected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Needs {
    /// The controller's position unit (and syntax version).
    pub units: bool,
    /// A target of a model axis the move does not set (re-seeded from `MOV?`).
    pub targets: bool,
    /// The controller's axis identifiers (`GOH` of all axes).
    pub axes: bool,
}

/// Why a move was not forwarded now.
pub(crate) enum Stop {
    /// Refused with this GCS error.
    Refuse(GcsErrorCode),
    /// Waits for the controller's answer to the proxy's own queries.
    Hold(Needs),
}

impl ProxyState {
    /// Correct a move and write it to `out.to_stage`. `fresh`: the line has not waited yet (it
    /// may wait for the controller now).
    pub(super) fn rewrite_move<C: Corrector>(
        &mut self,
        c: Option<&C>,
        s: &Split<'_>,
        kind: MoveKind,
        out: &mut Output,
        fresh: bool,
    ) -> Result<(), Stop> {
        let c = c.ok_or(Stop::Refuse(GcsErrorCode::NoModel))?;
        if self.ctrl.version == Version::Gcs3 {
            return Err(Stop::Refuse(GcsErrorCode::Gcs3));
        }
        if self.gate != Gate::Open {
            return Err(Stop::Refuse(GcsErrorCode::SensorFault));
        }
        let n = c.axes().min(MAP_AXES);
        let all = (1u8 << n) - 1;
        // the arguments, in one pass: new targets `x` (micros) of the model axes in `set`, the
        // model axes `named`, how many arguments name `others`
        // the bases: the targets the proxy knows, else those just re-seeded for this line
        let merged;
        let base = if self.reseed.known == 0 {
            &self.targets
        } else {
            merged = self.targets.merged(&self.reseed);
            &merged
        };
        let mut x = base.x;
        let (mut named, mut set, mut others, mut any) = (0u8, 0u8, 0usize, false);
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
                        return Err(Stop::Refuse(GcsErrorCode::InvalidAxis));
                    }
                    named |= 1 << a;
                    if kind != MoveKind::Relative {
                        x[a] = v;
                        set |= 1 << a;
                    } else if base.known >> a & 1 != 0 {
                        x[a] = x[a].saturating_add(v);
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
        // the axes the command does not set keep their targets (already in `x`)
        let keep = all & !set & base.known;

        let units_ok = match self.ctrl.units {
            Units::Micrometre(k) => k == n,
            Units::Mismatch | Units::Unanswered => {
                return Err(Stop::Refuse(GcsErrorCode::UnitMismatch))
            }
            Units::Unknown => false,
        };
        let needs = Needs {
            units: !units_ok,
            targets: (set | keep) != all,
            axes: home_all && self.ctrl.axes.is_none(),
        };
        if needs.units || needs.targets || needs.axes {
            return Err(if fresh {
                Stop::Hold(needs)
            } else if needs.units {
                Stop::Refuse(GcsErrorCode::UnitMismatch)
            } else {
                Stop::Refuse(GcsErrorCode::TargetUnknown)
            });
        }

        // correct every model axis (a coupled model needs them all)
        let mut xf = [0f32; MAP_AXES];
        let mut dir = self.dir;
        for a in 0..n {
            xf[a] = gcs::micros_to_f32(x[a]);
            if self.targets.known >> a & 1 != 0 {
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
        // the command is the exact target plus δ, in micros; inside the stage travel
        let mut q = x;
        for a in 0..n {
            let (lo, hi) = c.travel_um(a);
            let qa = r.q_um[a];
            if !(qa >= lo && qa <= hi) {
                return Err(Stop::Refuse(GcsErrorCode::PosOutOfLimits));
            }
            // |x| ≤ 10¹⁸ (parse_micros), |d| < 2⁶² (f32_to_micros): no overflow
            let d = gcs::f32_to_micros(r.delta_um[a])
                .ok_or(Stop::Refuse(GcsErrorCode::PosOutOfLimits))?;
            q[a] = x[a] + d;
        }

        let mut written = self.format_move(s.prefix, kind, named, &q, n, out);
        if written.is_ok() && (others > 0 || home_all) {
            written = self.format_other_axes(s, kind, n, home_all, out);
        } else if written.is_ok() {
            written = out.to_stage.push(b'\n');
        }
        written.map_err(|_| Stop::Refuse(GcsErrorCode::LineTooLong))?;
        // the one place a corrected target goes out: its targets and commands are recorded
        // (every model axis; the slots of other axes are never read), and the hysteresis
        // memory follows it
        self.targets = Targets {
            x,
            q,
            known: self.targets.known | all,
        };
        c.sent(&xf, &mut self.hyst);
        self.dir = dir;
        self.counters.moves = self.counters.moves.wrapping_add(1);
        Ok(())
    }

    /// The forwarded line(s): one `MOV` (`MVE`) with every model axis that was named or whose
    /// command changed (coupling, temperature), then (see `format_other_axes`) the untouched
    /// pairs of the other axes; the other axes of an `MVR` keep their relative move in an `MVR`
    /// of their own, those of a `GOH` their `GOH`. This writes the `MOV` without its line end.
    fn format_move(
        &self,
        prefix: &[u8],
        kind: MoveKind,
        named: u8,
        q: &[i64; MAP_AXES],
        n: usize,
        out: &mut Output,
    ) -> Result<(), GcsError> {
        let o = &mut out.to_stage;
        if !prefix.is_empty() {
            o.extend(prefix)?;
        }
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

    /// The other axes' part of a move (rare: a mixed line, or `GOH` of all axes).
    #[cold]
    #[inline(never)]
    fn format_other_axes(
        &self,
        s: &Split<'_>,
        kind: MoveKind,
        n: usize,
        home_all: bool,
        out: &mut Output,
    ) -> Result<(), GcsError> {
        let o = &mut out.to_stage;
        let is_model = |id: &[u8]| self.map.index(id).is_some_and(|a| a < n);
        // the other axes' pairs as they came (every value was parsed before)
        let other_pairs = |o: &mut gcs::LineBuf<{ super::STAGE_OUT }>| -> Result<(), GcsError> {
            for (id, _, text) in gcs::pairs(s.args).flatten().filter(|p| !is_model(p.0)) {
                o.push(b' ')?;
                o.extend(id)?;
                o.push(b' ')?;
                o.extend(text)?;
            }
            Ok(())
        };
        if matches!(kind, MoveKind::Absolute | MoveKind::Vector) {
            other_pairs(o)?;
        }
        o.push(b'\n')?;
        if kind == MoveKind::Relative {
            o.extend(s.prefix)?;
            o.extend(b"MVR")?;
            other_pairs(o)?;
            o.push(b'\n')?;
        }
        if kind == MoveKind::Home {
            // the other axes go home on their own
            let mut list = gcs::LineBuf::<{ gcs::MAX_LINE }>::new();
            for id in gcs::tokens(s.args).filter(|id| !is_model(id)) {
                let _ = list.push(b' ');
                let _ = list.extend(id);
            }
            if home_all {
                if let Some((ids, k)) = &self.ctrl.axes {
                    for id in ids[..*k].iter().flatten() {
                        if !is_model(id.as_bytes()) {
                            let _ = list.push(b' ');
                            let _ = list.extend(id.as_bytes());
                        }
                    }
                }
            }
            if !list.is_empty() {
                o.extend(s.prefix)?;
                o.extend(b"GOH")?;
                o.extend(list.as_bytes())?;
                o.push(b'\n')?;
            }
        }
        Ok(())
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
