//! A stateful fuzz of the compensator's GCS proxy (issue 21): random interleavings of valid,
//! mutated and hostile host lines, control bytes, replies cut anywhere, time passing, host
//! connections dropped and a controller that goes silent, against the simulated PI controller
//! ([`crate::virtual_bench::Controller`]: silent on rejected queries, error codes, refused
//! out-of-range targets, `HLT`/`STP`/`#24` semantics), with the proxy's promises checked after
//! every step by an oracle that knows only GCS and the model ([`oracle`]):
//!
//! 1. every move the controller receives on a model axis is the model's correction of a
//!    target a host line asked for — absolute, or relative to (or keeping) the target the
//!    controller itself held when the move arrived — clamped to the travel within 0.1 µm;
//! 2. no reply reaches the host unmapped or out of order: the host's replies are, in order,
//!    the controller's replies to the host's own queries (position replies mapped back to
//!    calibrated coordinates) or the proxy's answer to an `ERR?`; the proxy's own queries and
//!    their replies never reach the host;
//! 3. nothing the proxy should not forward reaches the controller: every line it receives is
//!    the proxy's own query, a corrected move, or a clean host line, in the host's order;
//!    no open-loop/raw motion of a model axis; no corrected move the controller refuses for
//!    its travel.
//!
//! A controller that stops (a blackout: reboot, power, cable) loses what it was sending and
//! what is sent to it, and stays silent until the proxy has given up the replies it lost — a
//! PI controller answers every query it accepts and is silent for seconds when it stops; the
//! proxy must notice within its reply timeout. Link faults (a stream of their own, see
//! [`run_with`]): bytes lost on the stage link anywhere in what the controller is sending, which
//! the board reports (a UART overrun or framing error, [`Proxy::stage_bytes_lost`]) while the
//! controller keeps running; a host connection dropped in the middle of a line; a controller
//! that stops in the middle of a reply. Bytes lost unnoticed are not among them: a query lost on
//! its way to a controller that answers the next one cannot be told from GCS's bytes (the
//! proxy's stated contract).
//!
//! Following (issue 19, [`follow_setups`]): held targets re-issued when the fold moves their
//! command. Those setups draw a random setting per seed (threshold, interval, step) and, from
//! a stream of their own, change the room's temperatures (a new fold), close and open the move
//! gate (a sensor fault), stage a new model, change the setting, and tick following; the
//! oracle checks every re-issue against the held host target at the current fold
//! (`oracle/follow.rs`). The other setups' runs are unchanged by it.
//!
//! Deterministic: a run is a seed ([`run`]). `tests/proxy_fuzz.rs` runs bounded seeds in CI;
//! its ignored benchmark runs ≥ 10 million steps (BENCHMARKS.md).

mod gen;
mod oracle;

use crate::papers::published::{coupled_2dof, published_1dof};
use crate::virtual_bench::{Config, Controller, IdealPlant, ManualClock};
use nanocal_compensator::proxy::{
    FoldCorrector, FollowConfig, Gate, Output, Proxy, REPLY_TIMEOUT_MS,
};
use nanocal_model::{Input, Model, SlowInputs, MAX_AXES};
use oracle::Oracle;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::fmt;
use std::sync::Arc;

/// Temperatures of the fold.
pub const TEMPS_C: [f64; 4] = [22.0, 22.1, 21.9, 22.3];

/// A model and the controller it runs against.
#[derive(Clone)]
pub struct Setup {
    /// Name in reports.
    pub name: &'static str,
    /// The model the proxy corrects with.
    pub model: Model,
    /// The controller.
    pub controller: Config,
    /// Held targets follow the fold (a random setting per seed; temperatures change).
    pub follow: bool,
}

impl fmt::Debug for Setup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name)
    }
}

/// The setups the fuzz runs: the published 1-DoF model on a three-axis controller whose
/// travel is 0…500 µm (the model's correction at 0 is −0.05 µm: the edge is exercised), the
/// coupled 2-DoF model, and the 1-DoF model on a controller that knows fewer commands (no
/// `CSV?`, `ONT?`, `#8`, `#9`, `#11`: more queries go unanswered).
pub fn setups() -> Vec<Setup> {
    let base = |axes: usize| {
        let mut cfg = Config::c867(axes, "µm").ready();
        for c in Config::e727(axes).commands {
            if !cfg.commands.contains(&c) {
                cfg.commands.push(c);
            }
        }
        for c in ["MVE", "WAV", "WTR", "MAC"] {
            if !cfg.commands.contains(&c) {
                cfg.commands.push(c);
            }
        }
        for a in &mut cfg.axes {
            // moves take a little time: a stop can land half-way
            a.velocity = 2_000.0;
            a.min = 0.0;
            a.max = 500.0;
            a.reference = Some(250.0);
            a.start = 250.0;
        }
        cfg
    };
    let m1 = published_1dof().expect("published model");
    let m2 = coupled_2dof().expect("coupled model");
    let mut coupled = base(3);
    // the coupled model's commands for 0…80 µm lie within −10…100 µm
    let q0 = m2.eval_f64(&[40.0, 40.0, 0.0], &[0; MAX_AXES], &slow());
    for (a, ax) in coupled.axes.iter_mut().enumerate() {
        ax.min = -10.0;
        ax.max = 100.0;
        if a < 2 {
            ax.reference = Some(q0[a]);
            ax.start = q0[a];
        } else {
            ax.reference = Some(50.0);
            ax.start = 50.0;
        }
    }
    let mut sparse = base(3);
    sparse
        .commands
        .retain(|c| !["CSV?", "ONT?", "#8", "#9", "#11"].contains(c));
    vec![
        Setup {
            name: "published 1-DoF, travel 0…500 µm",
            model: m1.clone(),
            controller: base(3),
            follow: false,
        },
        Setup {
            name: "coupled 2-DoF",
            model: m2,
            controller: coupled,
            follow: false,
        },
        Setup {
            name: "published 1-DoF, a controller without CSV?, ONT?, #8, #9, #11",
            model: m1,
            controller: sparse,
            follow: false,
        },
    ]
}

/// The setups with held targets following the fold: the published 1-DoF model on the
/// three-axis controller, and the coupled 2-DoF model (both axes re-issued together).
pub fn follow_setups() -> Vec<Setup> {
    let s = setups();
    vec![
        Setup {
            name: "published 1-DoF, following the fold",
            follow: true,
            ..s[0].clone()
        },
        Setup {
            name: "coupled 2-DoF, following the fold",
            follow: true,
            ..s[1].clone()
        },
    ]
}

/// A following setting drawn for a run: threshold 1–40 nm; interval 0–50 ms (re-issues as
/// fast as the proxy allows) or 100–3,000 ms; no step limit, or 1–30 nm.
fn follow_config(rng: &mut ChaCha8Rng) -> FollowConfig {
    FollowConfig {
        threshold_nm: rng.gen_range(1..=40),
        interval_ms: if rng.gen_bool(0.3) {
            rng.gen_range(0..=50)
        } else {
            rng.gen_range(100..=3_000)
        },
        max_step_nm: if rng.gen_bool(0.4) {
            0
        } else {
            rng.gen_range(1..=30)
        },
    }
}

/// The slow inputs at `offset_c` from [`TEMPS_C`] (each sensor its own), kept inside the
/// model's temperature envelope.
fn slow_at(model: &Model, offset_c: &[f64; 4]) -> SlowInputs {
    let mut s = slow();
    for (i, t) in s.temps_c[..TEMPS_C.len()].iter_mut().enumerate() {
        let (lo, hi) = model.envelope(Input::Temp(i as u8));
        *t = TEMPS_C[i] + offset_c[i];
        if lo.is_finite() && hi.is_finite() && lo < hi {
            *t = t.clamp(lo + 0.01, hi - 0.01);
        }
    }
    s
}

/// The slow inputs of the fold.
pub fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[..TEMPS_C.len()].copy_from_slice(&TEMPS_C);
    s
}

/// What a run did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Steps run.
    pub steps: u64,
    /// Host lines and single characters sent.
    pub host_items: u64,
    /// Corrected moves the controller received, each checked against the oracle.
    pub moves_checked: u64,
    /// Host replies checked (mapped or byte for byte).
    pub replies_checked: u64,
    /// Position values in them checked against the f64 inverse.
    pub positions_checked: u64,
    /// Controller lines checked against the host's lines.
    pub lines_checked: u64,
    /// Host connections dropped.
    pub drops: u64,
    /// Controller blackouts (it ignored its input for a while, as while it reboots).
    pub blackouts: u64,
    /// Bytes from the controller lost on the stage link (a UART overrun or framing error,
    /// which the board reports): the proxy was told.
    pub link_losses: u64,
    /// Host connections dropped in the middle of a line.
    pub cut_lines: u64,
    /// Replies cut short by the controller stopping in the middle of them.
    pub cut_replies: u64,
    /// Times the proxy gave up waiting and resynchronised.
    pub resyncs: u64,
    /// Queries the proxy found unanswered.
    pub unanswered: u64,
    /// Host commands the proxy refused.
    pub refused: u64,
    /// The proxy's re-issues of held targets (following) the controller received, each
    /// checked against the held target at the current fold.
    pub reissues_checked: u64,
    /// Re-issues the proxy counted as accepted by the controller.
    pub follow_reissues: u64,
    /// Re-issues the proxy counted as refused by the controller.
    pub follow_refused: u64,
    /// New folds (temperature changes) while following.
    pub folds: u64,
}

impl Stats {
    /// Count what one oracle check saw.
    fn count(&mut self, c: oracle::Checked) {
        self.moves_checked += c.moves;
        self.replies_checked += c.replies;
        self.positions_checked += c.positions;
        self.lines_checked += c.lines;
        self.reissues_checked += c.reissues;
    }
}

impl std::ops::AddAssign for Stats {
    fn add_assign(&mut self, o: Stats) {
        self.steps += o.steps;
        self.host_items += o.host_items;
        self.moves_checked += o.moves_checked;
        self.replies_checked += o.replies_checked;
        self.positions_checked += o.positions_checked;
        self.lines_checked += o.lines_checked;
        self.drops += o.drops;
        self.blackouts += o.blackouts;
        self.link_losses += o.link_losses;
        self.cut_lines += o.cut_lines;
        self.cut_replies += o.cut_replies;
        self.resyncs += o.resyncs;
        self.unanswered += o.unanswered;
        self.refused += o.refused;
        self.reissues_checked += o.reissues_checked;
        self.follow_reissues += o.follow_reissues;
        self.follow_refused += o.follow_refused;
        self.folds += o.folds;
    }
}

/// An invariant that did not hold.
#[derive(Debug, Clone)]
pub struct Violation {
    /// The setup.
    pub setup: &'static str,
    /// The seed of the run.
    pub seed: u64,
    /// The step at which it was seen.
    pub step: u64,
    /// What was wrong.
    pub what: String,
    /// The last actions before it.
    pub trace: Vec<String>,
}

/// A violation seen at `step` of run (`setup`, `seed`), with the last steps' notes.
fn violation(
    setup: &'static str,
    seed: u64,
    step: u64,
    what: String,
    trace: &VecDeque<String>,
) -> Box<Violation> {
    Box::new(Violation {
        setup,
        seed,
        step,
        what,
        trace: trace.iter().cloned().collect(),
    })
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} (seed {}, step {}): {}",
            self.setup, self.seed, self.step, self.what
        )?;
        writeln!(f, "last actions:")?;
        for t in &self.trace {
            writeln!(f, "  {t}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Violation {}

/// The proxy between a host and the simulated controller, on a hand-driven clock.
struct Rig {
    proxy: Proxy,
    comp: FoldCorrector,
    ctl: Controller,
    clock: ManualClock,
    now_ms: u32,
    out: Output,
    /// Host bytes written, not yet taken by the proxy.
    host_tx: VecDeque<u8>,
    /// Controller bytes not yet given to the proxy, and when the oldest was sent.
    stage_rx: VecDeque<u8>,
    stage_since_ms: u32,
    /// The controller is not running: it ignores its input and answers nothing.
    blackout: Option<Blackout>,
    /// Bytes the host received.
    host_rx: Vec<u8>,
    /// Bytes sent to the controller while it was not running.
    lost: Vec<u8>,
    /// Where the proxy gave up what was in flight (see [`GiveUp`]), since the last check.
    give_ups: Vec<GiveUp>,
    /// The proxy's resync count when the last give-up was recorded.
    resyncs_seen: u32,
    /// Following is on: time passing ticks it.
    follow: bool,
}

/// The proxy gave up the replies in flight: how many commands the controller had processed
/// and how many bytes the host had received then. No reply to a query in flight at a give-up
/// reaches the host after it (the proxy drops them, or they are lost): the oracle pairs the
/// host's bytes before it with the queries before it, then retires those queries — a later
/// reply of the same text is never taken for one of them.
#[derive(Debug, Clone, Copy)]
pub(super) struct GiveUp {
    /// Commands the controller had processed ([`Controller::peek_processed`]).
    pub processed: usize,
    /// Bytes the host had received (`Rig::host_rx`).
    pub host_rx: usize,
}

impl Rig {
    fn new(setup: &Setup) -> Self {
        let clock = ManualClock::new();
        let start: Vec<f64> = setup.controller.axes.iter().map(|a| a.start).collect();
        let mut ctl = Controller::new(
            setup.controller.clone(),
            Box::new(IdealPlant::new(&start)),
            Arc::new(clock.clone()),
        );
        ctl.record();
        Self {
            proxy: Proxy::default(),
            comp: FoldCorrector::new(&setup.model, &slow()),
            ctl,
            clock,
            now_ms: 1,
            out: Output::new(),
            host_tx: VecDeque::new(),
            stage_rx: VecDeque::new(),
            stage_since_ms: 0,
            blackout: None,
            host_rx: Vec::new(),
            lost: Vec::new(),
            give_ups: Vec::new(),
            resyncs_seen: 0,
            follow: setup.follow,
        }
    }

    /// Following's periodic tick (the firmware's stage link runs it while it is due).
    fn follow_tick(&mut self) {
        self.proxy
            .follow_tick(Some(&self.comp), self.now_ms, &mut self.out);
        self.route();
        self.resume();
    }

    /// What the proxy produced goes its way (the controller answers at once, unless it is
    /// blacked out).
    fn route(&mut self) {
        self.host_rx.extend_from_slice(self.out.to_host.as_bytes());
        if self.proxy.counters.resyncs != self.resyncs_seen {
            // (what this call sends the controller comes after the give-up)
            self.resyncs_seen = self.proxy.counters.resyncs;
            self.give_ups.push(GiveUp {
                processed: self.ctl.peek_processed().len(),
                host_rx: self.host_rx.len(),
            });
        }
        let sending = !self.out.to_stage.is_empty();
        if sending && self.silent() {
            self.lost.extend_from_slice(self.out.to_stage.as_bytes());
            if self.proxy.in_flight() > 0 {
                // (a query among them, or replies due before them: lost either way)
                self.lose_replies();
            }
        } else if sending {
            let reply = self.ctl.input(self.out.to_stage.as_bytes());
            if self.stage_rx.is_empty() {
                self.stage_since_ms = self.now_ms;
            }
            self.stage_rx.extend(reply);
        }
        self.out.clear();
    }

    /// Hand the proxy up to `n` host bytes; then whatever it can do with bytes it holds.
    fn feed_host(&mut self, n: usize) {
        let mut budget = n;
        while budget > 0 && !self.host_tx.is_empty() {
            let chunk: Vec<u8> = self.host_tx.iter().take(budget).copied().collect();
            let used = self
                .proxy
                .host_bytes(Some(&self.comp), &chunk, self.now_ms, &mut self.out);
            let produced = !self.out.is_empty();
            self.route();
            self.host_tx.drain(..used);
            budget -= used.min(budget);
            if used == 0 && !produced {
                break; // the proxy waits (a held line fills its input)
            }
        }
        self.resume();
    }

    /// Lines the proxy received earlier that it can process now, and its own answers due.
    fn resume(&mut self) {
        for _ in 0..1_000 {
            if !self.proxy.has_work() {
                return;
            }
            self.proxy
                .host_bytes(Some(&self.comp), &[], self.now_ms, &mut self.out);
            self.route();
        }
        panic!("the proxy had work that never ended");
    }

    /// Give the proxy up to `n` controller bytes.
    fn deliver(&mut self, n: usize) {
        let mut budget = n;
        while budget > 0 && !self.stage_rx.is_empty() {
            let chunk: Vec<u8> = self.stage_rx.iter().take(budget).copied().collect();
            let used = self
                .proxy
                .stage_bytes(Some(&self.comp), &chunk, self.now_ms, &mut self.out);
            let produced = !self.out.is_empty();
            self.stage_rx.drain(..used);
            self.stage_since_ms = self.now_ms;
            budget -= used.min(budget);
            self.route();
            self.resume();
            if used == 0 && !produced {
                // (none taken but something sent — a resynchronising marker: the firmware's
                // stage link offers the bytes again, `src/app/links.rs`'s `feed`)
                break;
            }
        }
    }

    /// Let `ms` pass (the stage moves, the proxy polls).
    fn wait(&mut self, ms: u32) {
        self.now_ms = self.now_ms.wrapping_add(ms);
        self.clock.advance(f64::from(ms) * 1e-3);
        self.proxy
            .poll(Some(&self.comp), self.now_ms, &mut self.out);
        self.route();
        self.resume();
        if self.follow {
            self.follow_tick();
        }
    }

    /// The controller stops for `ms` (a reboot, its power or cable out): what it was sending
    /// is lost, and so is everything sent to it until it runs again.
    fn black_out(&mut self, ms: u32) {
        self.blackout = Some(Blackout {
            start_ms: self.now_ms,
            len_ms: ms,
            lost: None,
        });
        self.stage_rx.clear();
        if self.proxy.in_flight() > 0 {
            self.lose_replies();
        }
    }

    /// The stage link loses `len` bytes `at` bytes into what the controller is sending (all of
    /// them when fewer are on their way; none: noise on an idle line), and the board tells the
    /// proxy — a UART overrun or framing error — after the bytes before them arrived. The
    /// controller keeps running: what it sends after them still comes.
    fn lose_stage_bytes(&mut self, at: usize, len: usize) {
        self.deliver(at);
        let n = len.min(self.stage_rx.len());
        self.stage_rx.drain(..n);
        self.proxy.stage_bytes_lost(self.now_ms);
    }

    /// Replies the proxy counts as due will never come.
    fn lose_replies(&mut self) {
        let resyncs = self.proxy.counters.resyncs;
        if let Some(b) = &mut self.blackout {
            if b.lost.is_none_or(|(r, _)| r != resyncs) {
                b.lost = Some((resyncs, self.now_ms));
            }
        }
    }

    /// Is the controller still not running? A blackout lasts its length and, when it cost
    /// replies, until the proxy gave them up: a PI controller answers every query it
    /// receives, and one that stops is silent for longer than the proxy's reply timeout
    /// (PI's controllers take seconds to boot) — a shorter loss of input to a running
    /// controller is a link fault no proxy can see in GCS's bytes (the proxy's contract).
    fn silent(&mut self) -> bool {
        let resyncs = self.proxy.counters.resyncs;
        let Some(b) = &mut self.blackout else {
            return false;
        };
        if b.lost.is_some_and(|(r, _)| r != resyncs) {
            // the proxy gave up what was lost
            b.lost = None;
        }
        if self.now_ms.wrapping_sub(b.start_ms) >= b.len_ms && b.lost.is_none() {
            self.blackout = None;
            return false;
        }
        true
    }

    /// Replies lost to a blackout the proxy still waits for, since `since_ms`, for longer
    /// than its reply timeout (it polled since): it did not notice the silence.
    fn unnoticed_silence(&mut self) -> Option<u32> {
        self.silent();
        let resyncs = self.proxy.counters.resyncs;
        let (r, since) = self.blackout.as_ref()?.lost?;
        let waited = self.now_ms.wrapping_sub(since);
        (r == resyncs && waited > REPLY_TIMEOUT_MS + 100).then_some(waited)
    }

    /// Nothing in flight anywhere: every host line taken and processed, every reply given.
    fn quiet(&self) -> bool {
        self.host_tx.is_empty()
            && self.stage_rx.is_empty()
            && self.proxy.in_flight() == 0
            && !self.proxy.holding()
            && !self.proxy.has_work()
    }
}

/// A controller that is not running.
struct Blackout {
    start_ms: u32,
    len_ms: u32,
    /// Replies due were lost: the proxy's resync count then, and since when.
    lost: Option<(u32, u32)>,
}

/// The host drops its connection (DTR falls) and opens it again, after the controller sent
/// the proxy up to `n` more bytes: what happened before is checked first.
fn drop_connection(
    rig: &mut Rig,
    oracle: &mut Oracle,
    gen: &mut gen::Gen,
    n: usize,
) -> Result<oracle::Checked, String> {
    rig.deliver(n);
    oracle.lost(&std::mem::take(&mut rig.lost));
    let give_ups = std::mem::take(&mut rig.give_ups);
    let k = oracle.check(&mut rig.ctl, &mut rig.host_rx, &give_ups, false)?;
    rig.host_tx.clear();
    rig.proxy.new_session();
    oracle.new_session();
    gen.new_session();
    rig.host_rx.clear();
    Ok(k)
}

/// Run `steps` steps of seed `seed` on `setup`, link faults included; the first violation
/// stops it.
pub fn run(setup: &Setup, seed: u64, steps: u64) -> Result<Stats, Box<Violation>> {
    run_with(setup, seed, steps, true)
}

/// Run `steps` steps of seed `seed` on `setup`; the first violation stops it. Without
/// `link_faults` the run is the one the fuzz made before it had them (bytes lost on the stage
/// link, host lines cut by a dropped connection, replies cut by a controller that stops, each
/// drawn from a stream of their own): the replays of earlier findings stay replays.
pub fn run_with(
    setup: &Setup,
    seed: u64,
    steps: u64,
    link_faults: bool,
) -> Result<Stats, Box<Violation>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut faults = ChaCha8Rng::seed_from_u64(seed ^ 0x6c69_6e6b_2d66_6175);
    let mut rig = Rig::new(setup);
    let mut oracle = Oracle::new(setup);
    let mut gen = gen::Gen::new(setup.model.axes());
    let mut stats = Stats::default();
    let mut trace: VecDeque<String> = VecDeque::new();
    // following's own stream: the other setups' runs stay what they were
    let mut fol = ChaCha8Rng::seed_from_u64(seed ^ 0x666f_6c6c_6f77_2d31);
    let mut offset_c = [0.0f64; 4];
    // steps left of a hold: the host quiet while time passes and the room drifts
    let mut hold = 0u32;
    if setup.follow {
        let cfg = follow_config(&mut fol);
        rig.proxy.set_follow(cfg);
        oracle.follow.cfg = cfg;
    }
    for step in 0..steps {
        oracle.follow.step_start_ms = rig.now_ms;
        if setup.follow && (hold > 0 || fol.gen_range(0..1000u32) < 60) {
            let note = if hold > 0 {
                hold -= 1;
                hold_step(&mut rig, &mut oracle, &mut fol, &mut offset_c, setup)
            } else if fol.gen_bool(0.3) {
                hold = fol.gen_range(2..30);
                // as PIPython does: a move and its `ERR?`, then the stage holds
                let n = setup.model.axes();
                let span = if n == 1 { 480.0 } else { 80.0 };
                let mut line = "MOV".to_string();
                for a in 0..n {
                    line += &format!(" {} {:.3}", a + 1, fol.gen_range(0.05..0.95) * span);
                }
                line += "\nERR?\n";
                let item = oracle.prepare(line.into_bytes());
                stats.host_items += 1;
                oracle.host_sent(&item);
                let shown = item.escape_ascii().to_string();
                rig.host_tx.extend(item);
                rig.feed_host(usize::MAX);
                format!("host {shown:?}, then holds for {hold} steps")
            } else {
                follow_event(&mut rig, &mut oracle, &mut fol, &mut offset_c, setup)
            };
            stats.folds += u64::from(note.starts_with("fold"));
            if std::env::var_os("NANOCAL_FUZZ_TRACE").is_some() {
                eprintln!(
                    "{step}: {note} | resyncs {} following {} | {:?} | processed {:?}",
                    rig.proxy.counters.resyncs,
                    rig.proxy.following(),
                    rig.proxy,
                    rig.ctl
                        .peek_processed()
                        .iter()
                        .map(|p| p.line.clone())
                        .collect::<Vec<_>>()
                );
            }
            end_step(&mut rig, &mut oracle, &mut stats, &mut trace, note)
                .map_err(|what| violation(setup.name, seed, step, what, &trace))?;
            continue;
        }
        let fault = if link_faults {
            faults.gen_range(0..1000u32)
        } else {
            1000
        };
        let action = if fault < 12 {
            1000
        } else {
            rng.gen_range(0..1000u32)
        };
        let note = match action {
            1000 => match fault {
                0..=4 => {
                    // bytes lost on the stage link, anywhere in what is on its way
                    let at = faults.gen_range(0..=rig.stage_rx.len());
                    let len = faults.gen_range(1..24);
                    rig.lose_stage_bytes(at, len);
                    stats.link_losses += 1;
                    format!("stage link lost {len} bytes after {at}")
                }
                5..=8 => {
                    // the host's connection drops in the middle of a line: the proxy took
                    // the beginning of it (single characters in it acted at once)
                    let item = oracle.prepare(gen.item(&mut faults));
                    let cut = faults.gen_range(0..item.len().max(1));
                    let part = item[..cut].to_vec();
                    stats.host_items += 1;
                    oracle.host_sent(&part);
                    rig.host_tx.extend(&part);
                    rig.feed_host(usize::MAX);
                    let n = faults.gen_range(0..16);
                    drop_connection(&mut rig, &mut oracle, &mut gen, n)
                        .map_err(|what| violation(setup.name, seed, step, what, &trace))
                        .map(|k| stats.count(k))?;
                    stats.cut_lines += 1;
                    format!(
                        "host {:?}, connection dropped",
                        part.escape_ascii().to_string()
                    )
                }
                _ => {
                    // the controller stops in the middle of what it is sending
                    let at = faults.gen_range(0..=rig.stage_rx.len());
                    rig.deliver(at);
                    let ms = faults.gen_range(100..3_000);
                    rig.black_out(ms);
                    stats.blackouts += 1;
                    stats.cut_replies += 1;
                    format!("controller silent for {ms} ms after {at} bytes")
                }
            },
            0..=399 => {
                if oracle.host_queries_pending() >= 12 {
                    // room for every query's reply in the proxy (16 host queries in flight)
                    let n = rng.gen_range(1..64);
                    rig.feed_host(n);
                    format!("feed {n}")
                } else {
                    let item = oracle.prepare(gen.item(&mut rng));
                    stats.host_items += 1;
                    oracle.host_sent(&item);
                    let shown = format!("host {:?}", item.escape_ascii().to_string());
                    rig.host_tx.extend(item);
                    let n = rng.gen_range(0..96);
                    rig.feed_host(n);
                    shown
                }
            }
            400..=599 => {
                let n = rng.gen_range(1..64);
                rig.feed_host(n);
                format!("feed {n}")
            }
            600..=849 => {
                let n = rng.gen_range(1..48);
                rig.deliver(n);
                format!("deliver {n}")
            }
            850..=989 => {
                let ms = if rng.gen_bool(0.03) {
                    REPLY_TIMEOUT_MS + rng.gen_range(1..300)
                } else {
                    rng.gen_range(1..60)
                };
                // the controller's replies are never late by more than a link's buffering,
                // unless it is silent (a blackout): they arrive before a silence as long as
                // the proxy's reply timeout (a controller silent that long has stopped
                // answering: what it still owes is lost, the proxy's contract)
                if rig.now_ms.wrapping_sub(rig.stage_since_ms) > 500
                    || ms >= REPLY_TIMEOUT_MS
                    || rng.gen_bool(0.8)
                {
                    rig.deliver(usize::MAX);
                }
                rig.wait(ms);
                format!("wait {ms} ms")
            }
            990..=994 => {
                // the host closes the port (DTR falls) and opens it again
                let n = rng.gen_range(0..16);
                drop_connection(&mut rig, &mut oracle, &mut gen, n)
                    .map_err(|what| violation(setup.name, seed, step, what, &trace))
                    .map(|k| stats.count(k))?;
                stats.drops += 1;
                "connection dropped".to_string()
            }
            _ => {
                // the controller goes silent for a while (it reboots, a cable is pulled)
                let ms = rng.gen_range(100..3_000);
                rig.black_out(ms);
                stats.blackouts += 1;
                format!("controller silent for {ms} ms")
            }
        };
        if std::env::var_os("NANOCAL_FUZZ_TRACE").is_some() {
            eprintln!("{step}: oracle {}", oracle.pending());
            eprintln!(
                "{step}: {note} | resyncs {} stage_rx {:?} | {:?} | host_rx {:?} | processed {:?}",
                rig.proxy.counters.resyncs,
                String::from_utf8_lossy(&rig.stage_rx.iter().copied().collect::<Vec<u8>>()),
                rig.proxy,
                String::from_utf8_lossy(&rig.host_rx),
                rig.ctl
                    .peek_processed()
                    .iter()
                    .map(|p| (
                        p.line.clone(),
                        String::from_utf8_lossy(&p.reply).into_owned()
                    ))
                    .collect::<Vec<_>>()
            );
        }
        end_step(&mut rig, &mut oracle, &mut stats, &mut trace, note)
            .map_err(|what| violation(setup.name, seed, step, what, &trace))?;
    }
    stats.follow_reissues = u64::from(rig.proxy.counters.follow_reissues);
    stats.follow_refused = u64::from(rig.proxy.counters.follow_refused);
    stats.resyncs = u64::from(rig.proxy.counters.resyncs);
    stats.unanswered = u64::from(rig.proxy.counters.unanswered);
    stats.refused = u64::from(rig.proxy.counters.refused);
    Ok(stats)
}

/// The end of every step, whatever it did: `note` joins the trace (the last 40 steps), the
/// oracle learns the lines the link lost, and checks what the controller and the host got.
/// `Err`: the violation, described.
fn end_step(
    rig: &mut Rig,
    oracle: &mut Oracle,
    stats: &mut Stats,
    trace: &mut VecDeque<String>,
    note: String,
) -> Result<(), String> {
    trace.push_back(note);
    if trace.len() > 40 {
        trace.pop_front();
    }
    oracle.lost(&std::mem::take(&mut rig.lost));
    if let Some(ms) = rig.unnoticed_silence() {
        return Err(format!(
            "the controller has been silent for {ms} ms with replies due; the proxy still waits"
        ));
    }
    oracle.follow.now_ms = rig.now_ms;
    let quiet = rig.quiet();
    let give_ups = std::mem::take(&mut rig.give_ups);
    let checked = oracle.check(&mut rig.ctl, &mut rig.host_rx, &give_ups, quiet)?;
    stats.count(checked);
    stats.steps += 1;
    Ok(())
}

/// A new fold at `offset_c` (°C from [`TEMPS_C`]) after the room drifted by up to
/// `drift_c`, and following's tick (the firmware ticks it whenever the fold changed).
fn refold(
    rig: &mut Rig,
    oracle: &mut Oracle,
    fol: &mut ChaCha8Rng,
    offset_c: &mut [f64; 4],
    setup: &Setup,
    drift_c: f64,
) -> String {
    // a random walk of the room (sensors a little apart), within ±0.6 °C
    let common = fol.gen_range(-drift_c..drift_c);
    for o in offset_c.iter_mut() {
        *o = (*o + common + fol.gen_range(-0.01..0.01)).clamp(-0.6, 0.6);
    }
    let s = slow_at(&setup.model, offset_c);
    rig.comp = FoldCorrector::new(&setup.model, &s);
    oracle.set_slow(s);
    rig.follow_tick();
    format!("fold at {:+.3} °C", offset_c[0])
}

/// A step of a hold: the controller's replies arrive, the room drifts now and then, time
/// passes (the proxy polls, following ticks).
fn hold_step(
    rig: &mut Rig,
    oracle: &mut Oracle,
    fol: &mut ChaCha8Rng,
    offset_c: &mut [f64; 4],
    setup: &Setup,
) -> String {
    // (the new fold first: the oracle checks the step's mapped replies with it)
    let mut note = String::new();
    if fol.gen_bool(0.4) {
        note = refold(rig, oracle, fol, offset_c, setup, 0.05) + ", ";
    }
    rig.deliver(usize::MAX);
    if fol.gen_bool(0.03) {
        // the controller's servo goes off while the target is held: the next re-issue is
        // refused (the proxy swallows it and stops following)
        let a = fol.gen_range(0..setup.model.axes());
        rig.ctl.servo_fault(a);
        note += &format!("servo {} off at the controller, ", a + 1);
    }
    let ms = fol.gen_range(20..1_500);
    rig.wait(ms);
    note + &format!("held {ms} ms")
}

/// One of following's events (drawn from its own stream): the room's temperatures change (a
/// new fold, the usual event), following ticks between other steps, the move gate closes for
/// a sensor fault or opens again, a new model is staged, the setting changes.
fn follow_event(
    rig: &mut Rig,
    oracle: &mut Oracle,
    fol: &mut ChaCha8Rng,
    offset_c: &mut [f64; 4],
    setup: &Setup,
) -> String {
    match fol.gen_range(0..100u32) {
        0..=54 => refold(rig, oracle, fol, offset_c, setup, 0.08),
        55..=89 => {
            rig.follow_tick();
            "follow tick".to_string()
        }
        90..=91 => {
            // the controller refuses moves behind the proxy's back (a re-issue is refused
            // until the host switches the servo on again)
            let a = fol.gen_range(0..setup.model.axes());
            rig.ctl.servo_fault(a);
            format!("servo {} off at the controller", a + 1)
        }
        92..=94 => {
            if rig.proxy.gate == Gate::Open {
                // a sensor fails: moves refused, following cancelled at the tick
                rig.proxy.gate = Gate::SensorFault;
                rig.follow_tick();
                oracle.follow.cancel();
                "sensor fault".to_string()
            } else {
                rig.proxy.gate = Gate::Open;
                "sensor recovered".to_string()
            }
        }
        95..=96 => {
            // a new model staged (the same one again: the firmware resets the play operators
            // and cancels following)
            rig.proxy.reset_hysteresis();
            rig.proxy.cancel_follow();
            oracle.follow.cancel();
            "new model".to_string()
        }
        _ => {
            let cfg = if fol.gen_bool(0.2) {
                FollowConfig::default()
            } else {
                follow_config(fol)
            };
            rig.proxy.set_follow(cfg);
            oracle.follow.cfg = cfg;
            if cfg.threshold_nm == 0 {
                oracle.follow.cancel();
            }
            format!("follow setting {cfg:?}")
        }
    }
}
