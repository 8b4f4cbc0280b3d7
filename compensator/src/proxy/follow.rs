//! Held targets follow the model (opt-in, issue 19): while the stage holds the host's last
//! target and the fold (temperatures, λ_KMZ) moves that target's command by more than a
//! threshold, the proxy re-issues the corrected command to the controller, rate-limited as
//! machine-tool controllers slew-limit their thermal offsets. The host keeps its own frame:
//! the proxy records the re-issued command as the one sent for the host's target, so `MOV?`
//! maps back to the host's target exactly, `POS?` through the current fold as always, and
//! `ONT?` is the controller's (on target once the small step has settled).
//!
//! **Holding** means all of: the setting is on; the host's last move went out corrected, with
//! no address prefix, and set every model axis' target (`Targets::known`); no stop since
//! (`HLT`, `STP`, `#24`, `#27`, `SVO`, `FRF`, a non-zero `ERR?`, bypass, a new host session,
//! a new model: anything after which the proxy forgets its targets, or
//! [`Proxy::cancel_follow`](super::Proxy::cancel_follow)); at least the interval since that
//! move (the proxy does not ask `ONT?` itself: a query of its own that the controller refuses
//! would leave an error the host reads as its own; a closed-loop controller retargets a move
//! still under way smoothly anyway); the move gate open (no sensor fault: never chase a bad
//! temperature) and the fold's fast inputs fresh and inside the envelope; nothing in flight
//! or waiting on either link (no host query, no held or queued host line). Any host move
//! re-arms it for the new target, at the next tick (the tick sees the move count change:
//! nothing is added to the `MOV` line's path, whose instruction budget is spent).
//!
//! **A re-issue never races the host.** It takes two steps, each only while nothing else is
//! in flight: first the proxy's own `MOV?` of the model axes — the controller must hold
//! exactly the commands the proxy recorded for the target, or following stops (the base is
//! what the controller did, not what the proxy sent: a host move lost while the controller
//! was silent, with nothing the proxy waited for, is told by nothing else; issue 21's fuzz of
//! following found one "followed" by a 64 µm jump) — and the proxy's own `ERR?`, so that an
//! error the host has not read yet is
//! not lost — a non-zero code is kept for the host's next `ERR?` (answered by the proxy, as
//! its own refusals are) and, as for the host's own `ERR?`, the targets are forgotten and
//! following stops; then, if no host line came meanwhile, `MOV <axes> <commands>` followed
//! by the proxy's own `ERR?`. A non-zero answer to that one is the re-issue's own refusal: it
//! is swallowed (counted in [`Counters::follow_refused`](super::Counters)), the targets are
//! forgotten and following stops until the next host move — the host never reads an error
//! it did not cause. A host `ERR?` that arrives while the first check is in flight, with no
//! other host line since the check went, is answered by the proxy after that check, with the
//! code the check read (or 0); after another host line it is forwarded (that line may have
//! failed at the controller after the check read the register), and a code the check reads
//! is kept for the host's next `ERR?`.
//!
//! **Rate limit**: at most one re-issue per interval, each moving the command by at most the
//! step (the rest follows at the next ones). A command that would leave the stage travel is
//! not chased.

use super::queue::{Entry, Expect, Info};
use super::{Corrector, Gate, Output, ProxyState, MAP_AXES};
use crate::gcs;

/// The setting, as the proxy takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FollowConfig {
    /// Re-issue when the fold moves a held target's command by more than this, nm (0: off).
    pub threshold_nm: u16,
    /// At most one re-issue per this many ms, and the first no sooner after the host's move.
    pub interval_ms: u32,
    /// Largest change of a command per re-issue, nm (0: no limit).
    pub max_step_nm: u16,
}

/// Where a re-issue stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// Nothing asked.
    Idle,
    /// The proxy's `ERR?` before a re-issue is in flight (`lines`: the host lines seen when
    /// it went).
    Checking { lines: u32 },
    /// The controller had no error pending and no host line came since: the re-issue may go.
    Cleared { lines: u32 },
    /// The re-issued `MOV` and its `ERR?` are in flight.
    Sent,
}

/// Following's state in the proxy.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Follow {
    pub cfg: FollowConfig,
    /// A host move set a target that may be followed.
    pub armed: bool,
    /// The host's move or the last re-issue, ms.
    pub since_ms: u32,
    pub phase: Phase,
    /// The host moves ([`Counters::moves`](super::Counters)) seen: a new one arms following
    /// for its target at the next tick (nothing is added to the `MOV` line's path).
    pub seen_moves: u32,
    /// The host moves with an address prefix seen ([`ProxyState::prefixed_moves`]).
    pub seen_prefixed: u32,
    /// The controller's error the proxy's check read, for the host's next `ERR?`.
    pub ctrl_error: Option<i32>,
    /// The check's `MOV?` found the controller holding the recorded commands.
    pub held_ok: bool,
}

impl Follow {
    pub const fn new() -> Self {
        Self {
            cfg: FollowConfig {
                threshold_nm: 0,
                interval_ms: 0,
                max_step_nm: 0,
            },
            armed: false,
            since_ms: 0,
            phase: Phase::Idle,
            seen_moves: 0,
            seen_prefixed: 0,
            ctrl_error: None,
            held_ok: false,
        }
    }
}

/// Micros (10⁻⁶ µm) per nm.
const MICROS_PER_NM: i64 = 1_000;

impl ProxyState {
    /// Host moves went out corrected since the last tick: follow the last one's targets
    /// (not when one of them had an address prefix, which following does not repeat).
    fn follow_arm(&mut self) {
        let prefixed = self.prefixed_moves != self.follow.seen_prefixed;
        let f = &mut self.follow;
        f.seen_moves = self.counters.moves;
        f.seen_prefixed = self.prefixed_moves;
        f.armed = !prefixed && f.cfg.threshold_nm != 0;
        f.since_ms = self.now_ms;
        // (a check or re-issue in flight is read when its reply comes; a cleared check is
        // void: a host line came after it)
        if let Phase::Cleared { .. } = f.phase {
            f.phase = Phase::Idle;
        }
    }

    /// The commands the fold now gives for the held targets, when one differs from the
    /// command the controller holds by more than the threshold: the next commands to send,
    /// each at most the step from the one held. `None` when nothing is to be re-issued (or it
    /// must not be: inputs missing or outside the envelope, the command outside the travel).
    fn follow_step<C: Corrector>(&self, c: &C) -> Option<[i64; MAP_AXES]> {
        let n = c.axes().min(MAP_AXES);
        let all = (1u8 << n) - 1;
        if self.targets.known & all != all {
            return None;
        }
        let mut xf = [0f32; MAP_AXES];
        for a in 0..n {
            xf[a] = gcs::micros_to_f32(self.targets.x[a]);
        }
        let r = c.correct(&xf, &self.dir, &self.hyst);
        if r.fast_missing || r.fast_outside || r.outside_envelope & all != 0 {
            return None;
        }
        let thr = i64::from(self.follow.cfg.threshold_nm) * MICROS_PER_NM;
        let step = i64::from(self.follow.cfg.max_step_nm) * MICROS_PER_NM;
        let mut q = self.targets.q;
        let mut beyond = false;
        for a in 0..n {
            let (lo, hi) = c.travel_um(a);
            let qa = r.q_um[a];
            let (clo, chi) = (self.ctrl.fast_lo[a], self.ctrl.fast_hi[a]);
            if !(qa >= lo && qa <= hi && qa >= clo && qa <= chi) {
                return None;
            }
            let want = self.targets.x[a] + gcs::f32_to_micros(r.delta_um[a])?;
            let diff = want - self.targets.q[a];
            beyond |= diff.abs() > thr;
            q[a] = if step > 0 {
                self.targets.q[a] + diff.clamp(-step, step)
            } else {
                want
            };
        }
        beyond.then_some(q)
    }

    /// Time passes for following (see the module docs). `waiting`: host lines are queued in
    /// the proxy's input.
    pub(super) fn follow_tick<C: Corrector>(
        &mut self,
        c: Option<&C>,
        now_ms: u32,
        waiting: bool,
        out: &mut Output,
    ) {
        out.clear();
        self.now_ms = now_ms;
        if self.counters.moves != self.follow.seen_moves {
            self.follow_arm();
        }
        if !self.follow.armed {
            return;
        }
        let Some(c) = c else {
            self.follow_cancel();
            return;
        };
        let n = c.axes().min(MAP_AXES);
        let all = (1u8 << n) - 1;
        if self.bypass
            || self.gate != Gate::Open
            || self.link_lost
            || self.targets.known & all != all
        {
            self.follow_cancel();
            return;
        }
        let quiet = self.queue.is_empty()
            && !self.rx.active()
            && !self.resyncing
            && self.held.is_none()
            && !waiting;
        match self.follow.phase {
            Phase::Checking { .. } | Phase::Sent => {
                if self.queue.is_empty() && !self.rx.active() {
                    // its reply was given up (the controller went silent): what a re-issue
                    // did is not known
                    self.follow_cancel();
                }
            }
            Phase::Cleared { lines } => {
                self.follow.phase = Phase::Idle;
                if lines != self.counters.host_lines || !quiet {
                    return;
                }
                if let Some(q) = self.follow_step(c) {
                    self.follow_send(&q, n, out);
                }
            }
            Phase::Idle => {
                if !quiet || now_ms.wrapping_sub(self.follow.since_ms) < self.follow.cfg.interval_ms
                {
                    return;
                }
                // the model axes all the controller's: the `MOV?` is certain, else a marker
                let maybe = match self.ctrl.axes.known() {
                    Some(axes) => (0..n).any(|a| axes.find(self.map.id(a).unwrap_or(b"")).is_err()),
                    None => true,
                };
                let room = if maybe { 4 } else { 2 };
                if self.follow_step(c).is_some() && self.queue.room() >= room {
                    self.follow.held_ok = false;
                    let g = self.counters.moves as u8;
                    if !self.ask(Info::FollowHeld(g), b"MOV?", n, maybe, out) {
                        return;
                    }
                    let _ = out.to_stage.extend(b"ERR?\n");
                    self.expect(Entry::new(
                        Expect::Internal(Info::FollowCheck(self.counters.moves as u8)),
                        false,
                        false,
                    ));
                    self.follow.phase = Phase::Checking {
                        lines: self.counters.host_lines,
                    };
                }
            }
        }
    }

    /// Send the re-issue: the commands `q` and the proxy's `ERR?` after them.
    fn follow_send(&mut self, q: &[i64; MAP_AXES], n: usize, out: &mut Output) {
        if self.queue.room() < 2 {
            return;
        }
        let o = &mut out.to_stage;
        let mut ok = o.extend(b"MOV").is_ok();
        for (a, &qa) in q.iter().enumerate().take(n) {
            ok &= o.push_pair(self.map.id(a).unwrap_or(b"?"), qa).is_ok();
        }
        ok &= o.extend(b"\nERR?\n").is_ok();
        if !ok {
            o.clear();
            return;
        }
        self.expect(Entry::new(
            Expect::Internal(Info::FollowDone(self.counters.moves as u8)),
            false,
            false,
        ));
        // the command the controller now holds for the host's (unchanged) target: `MOV?`
        // maps back to that target exactly; the play operators stay where the target is
        self.targets.q[..n].copy_from_slice(&q[..n]);
        self.follow.phase = Phase::Sent;
        self.follow.since_ms = self.now_ms;
    }

    /// Following stops until the next host move.
    pub(super) fn follow_cancel(&mut self) {
        self.follow.armed = false;
        // the moves before the cancel are done with: only a later one arms it again
        self.follow.seen_moves = self.counters.moves;
        self.follow.seen_prefixed = self.prefixed_moves;
        // a check or re-issue in flight is still read when its reply comes (an error it reads
        // is the host's, or the re-issue's own); one given up is not waited for
        let in_flight = matches!(self.follow.phase, Phase::Checking { .. } | Phase::Sent);
        if !in_flight || (self.queue.is_empty() && !self.rx.active()) {
            self.follow.phase = Phase::Idle;
        }
    }

    /// The controller's answer to the proxy's own `ERR?` (`Info::FollowCheck` or
    /// `Info::FollowDone`).
    pub(super) fn follow_reply(&mut self, info: Info, lines: &[u8]) {
        let code = super::controller::error_code(lines);
        match info {
            Info::FollowHeld(g) => {
                // the commands the controller holds, every model axis
                let n = self.facts_n.min(MAP_AXES);
                let mut q: [Option<i64>; MAP_AXES] = [None; MAP_AXES];
                for l in super::controller::lines_of(lines) {
                    if let Some(av) = gcs::parse_axis_value(l) {
                        if let Some(a) = self.map.index(av.axis).filter(|&a| a < n) {
                            // exactly the command sent, not a target that rounds to it
                            // (`gcs::is_whole_micros`)
                            q[a] = gcs::parse_micros(av.value)
                                .ok()
                                .filter(|_| gcs::is_whole_micros(av.value));
                        }
                    }
                }
                let held = n > 0 && (0..n).all(|a| q[a].is_some() && self.targets.q(a) == q[a]);
                if g == self.counters.moves as u8 && held {
                    self.follow.held_ok = true;
                } else if g == self.counters.moves as u8 {
                    // the controller holds something else: what the proxy recorded did not
                    // happen (lost, refused, stopped); nothing to follow
                    self.follow_cancel();
                }
            }
            Info::FollowCheck(g) => {
                let was = self.follow.phase;
                self.follow.phase = Phase::Idle;
                let held = core::mem::replace(&mut self.follow.held_ok, false);
                match code {
                    Some(0) if g == self.counters.moves as u8 && self.follow.armed && held => {
                        if let Phase::Checking { lines } = was {
                            self.follow.phase = Phase::Cleared { lines };
                        }
                    }
                    Some(0) => {}
                    Some(code) => {
                        // the host's own error, not read yet: kept for its next `ERR?`; the
                        // controller may have refused a move the proxy sent (as for the
                        // host's `ERR?`)
                        self.follow.ctrl_error = Some(code);
                        self.forget(None);
                    }
                    None => self.follow_cancel(),
                }
            }
            Info::FollowDone(g) => {
                self.follow.phase = Phase::Idle;
                if code == Some(0) {
                    self.counters.follow_reissues = self.counters.follow_reissues.wrapping_add(1);
                } else {
                    // the re-issue's own refusal: swallowed, the target forgotten
                    self.counters.follow_refused = self.counters.follow_refused.wrapping_add(1);
                    if g == self.counters.moves as u8 {
                        self.forget(None);
                    }
                    self.follow_cancel();
                }
            }
            _ => {}
        }
    }
}
