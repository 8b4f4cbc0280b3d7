//! The published procedures as data: poses, rise, hold, averaging window, cycles, tests, test
//! order and KMZ interval, serialisable (serde/JSON) so that the digital twin, the demo and a
//! campaign on a real or virtual bench execute the same plan.
//!
//! A [`Plan`] has a training [`Procedure`] (cycles through poses, the stage driven without a
//! model) and a [`ValidationPlan`]: tests of a fixed number of cycles, run in a repeating order
//! of compensations (paper 000 §4.3.2: no model, adaptive KMZ, static), with the KMZ
//! re-measured at a reference pose at the start of an adaptive test when its interval has
//! passed. Paper 000 §3.4, Eq. 17: "λ_KMZ is only measured at the first zero position" — when
//! a test's cycle starts at the reference pose, that first visit *is* the KMZ step (measured,
//! and counted as a visit of the test, its drift cancelled by the λ_KMZ it gives: Eq. 18);
//! otherwise a KMZ step at the reference pose comes before the test and is not counted.
//! [`Plan::schedule`] unrolls it into timed [`Step`]s.
//!
//! Every step is a rise followed by a hold at one commanded pose (paper 000 Fig. 9: "the rising
//! time of the input signal is 2 s and the input keeps constant 20 s"); the measurement of a
//! step is the mean over its last `average_last_s` seconds. A step's direction of approach is,
//! per axis, the direction of the motion that reached it: the sign of the last change of that
//! axis' command. A step that repeats the previous pose (a turning point held for a second
//! step, the 0 µm that ends one cycle and starts the next) is the same physical approach as the
//! step before it and keeps its direction; before the first motion every axis counts as forward
//! (+1, as the digital twin and [`crate::data::dwell::dwell_average`] take it).
//!
//! Paper 000's 1-DoF cycle (0, 30, …, 480, 480, 450, …, 0: 34 steps) is then, from the second
//! cycle on, 17 forward (30 … 480 and the held 480) and 17 backward (450 … 0 and the held 0 that
//! starts the next cycle). The paper counts "18 poses (forward) + 16 poses (backward)" (§4.3.2):
//! it splits the cycle at its turning point — the first 18 steps (0, 30, …, 480 and the held
//! 480) forward, the 16 of the descent backward. The held 480 is forward both ways; the only
//! difference is the 0 that starts a cycle, which the stage holds after reaching it backward
//! (forward only in the very first cycle, from rest).

use serde::{Deserialize, Serialize};

/// Cycles through a list of poses, each held as one step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Procedure {
    /// The commanded poses of one cycle, in order, µm (one entry per axis).
    pub cycle_um: Vec<Vec<f64>>,
    /// Rise time at the start of each step, s (the command ramps to the pose).
    pub rise_s: f64,
    /// Hold after the rise, s.
    pub hold_s: f64,
    /// The measurement of a step is the mean of its last this many seconds.
    pub average_last_s: f64,
    /// Number of cycles.
    pub cycles: usize,
}

impl Procedure {
    /// Duration of one step (rise + hold), s.
    pub fn step_s(&self) -> f64 {
        self.rise_s + self.hold_s
    }

    /// Duration of one cycle, s.
    pub fn cycle_s(&self) -> f64 {
        self.cycle_um.len() as f64 * self.step_s()
    }

    /// Duration of all cycles, s.
    pub fn duration_s(&self) -> f64 {
        self.cycles as f64 * self.cycle_s()
    }

    /// Number of axes (0 without poses).
    pub fn axes(&self) -> usize {
        self.cycle_um.first().map_or(0, Vec::len)
    }
}

/// Which model drives the stage during a validation test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TestKind {
    /// No model: command = target (paper 000: "the model equation is q = x").
    NoModel,
    /// The static model (Eq. 11).
    Static,
    /// The adaptive model (Eq. 14): the static model's geometric part + λ_KMZ.
    Adaptive,
}

impl TestKind {
    /// A short name: `no model`, `static`, `adaptive KMZ`.
    pub fn name(self) -> &'static str {
        match self {
            TestKind::NoModel => "no model",
            TestKind::Static => "static",
            TestKind::Adaptive => "adaptive KMZ",
        }
    }
}

/// When and where λ_KMZ is re-measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KmzPlan {
    /// The reference pose ("KiloMeter-Zero"), µm per axis.
    pub reference_um: Vec<f64>,
    /// Re-measured before an adaptive test once this long has passed since the last time, s.
    pub interval_s: f64,
}

/// Validation: tests of a fixed number of cycles, in a repeating order of compensations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationPlan {
    /// One test: `test.cycles` cycles through the validation poses.
    pub test: Procedure,
    /// The repeating order of compensations, one test each.
    pub order: Vec<TestKind>,
    /// How many times the order is run.
    pub rounds: usize,
    /// KMZ re-measurement (adaptive tests only).
    pub kmz: Option<KmzPlan>,
}

/// A published procedure: training, then validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Short name.
    pub name: String,
    /// Where it is published (paper, section, figure).
    pub source: String,
    /// Training (the stage driven without a model).
    pub training: Procedure,
    /// Time between the end of training and the start of validation, s (paper 000 Fig. 12:
    /// "Time 0 = end of training = start of validation").
    pub pause_s: f64,
    /// Validation.
    pub validation: ValidationPlan,
}

/// What a step is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// A training step.
    Training,
    /// The KMZ re-measurement at the reference pose, at the start of validation test `test`.
    Kmz {
        /// The test it belongs to.
        test: usize,
        /// It is the test's first visit (the cycle starts at the reference pose: paper 000
        /// Eq. 17–18 count it, its drift cancelled); else a step of its own before the test,
        /// not counted.
        #[serde(default)]
        visit: bool,
    },
    /// A visit of validation test `test`.
    Test {
        /// Index of the test over the whole validation.
        test: usize,
        /// The compensation driving it.
        kind: TestKind,
    },
}

/// One timed step of a schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// Start of the step (the command is sent), s from the start of the plan.
    pub t_start_s: f64,
    /// Rise, s.
    pub rise_s: f64,
    /// Hold, s.
    pub hold_s: f64,
    /// Averaging window at the end of the step, s.
    pub average_last_s: f64,
    /// Commanded pose, µm.
    pub target_um: Vec<f64>,
    /// Direction of approach per axis (+1 forward, −1 backward).
    pub approach: Vec<i8>,
    /// What the step is for.
    pub phase: Phase,
}

impl Step {
    /// End of the step, s.
    pub fn t_end_s(&self) -> f64 {
        self.t_start_s + self.rise_s + self.hold_s
    }
}

/// `from, from + step, …, to` (inclusive, rounded to the nearest step count).
pub fn grid(from: f64, step: f64, to: f64) -> Vec<f64> {
    let n = ((to - from) / step).round() as usize;
    (0..=n).map(|k| from + step * k as f64).collect()
}

/// 1-DoF up-and-down cycle: `poses` forward then the same backward (the turning point twice).
pub fn up_and_down(poses_um: &[f64]) -> Vec<Vec<f64>> {
    poses_um
        .iter()
        .chain(poses_um.iter().rev())
        .map(|&p| vec![p])
        .collect()
}

/// 2-DoF serpentine over `xs × ys`: rows of increasing y, x alternating direction, starting at
/// (xs[0], ys[0]).
pub fn serpentine(xs: &[f64], ys: &[f64]) -> Vec<Vec<f64>> {
    let mut out = Vec::with_capacity(xs.len() * ys.len());
    for (row, &y) in ys.iter().enumerate() {
        let row_xs: Vec<f64> = if row % 2 == 0 {
            xs.to_vec()
        } else {
            xs.iter().rev().copied().collect()
        };
        out.extend(row_xs.into_iter().map(|x| vec![x, y]));
    }
    out
}

/// Paper 000's 2-DoF validation points P0 … P5 (§5.2.1, Fig. 16), µm.
pub const PAPER000_2DOF_POINTS_UM: [(f64, f64); 6] = [
    (0.0, 0.0),
    (45.0, 45.0),
    (75.0, 15.0),
    (75.0, 75.0),
    (15.0, 75.0),
    (15.0, 15.0),
];

/// Duration of one validation test of paper 000's 1-DoF procedure, s ("Every test of
/// validation takes 1.25 h for 15 cycles", §4.2).
pub const PAPER000_TEST_S: f64 = 1.25 * 3600.0;

/// The published 2 s rise + 20 s hold, mean of the last 5 s (paper 000 §4.2, Fig. 9).
fn published_step(cycle_um: Vec<Vec<f64>>, cycles: usize) -> Procedure {
    Procedure {
        cycle_um,
        rise_s: 2.0,
        hold_s: 20.0,
        average_last_s: 5.0,
        cycles,
    }
}

impl Plan {
    /// Paper 000's 1-DoF procedure (§4.2, §4.3.2).
    ///
    /// Training: 0:30:480 µm forward then backward, 34 steps a cycle ("18 poses (forward) + 16
    /// poses (backward)" in the paper; 17 + 17 by the motion that reached each, see the module
    /// doc for how the two counts map onto the cycle), 2 s rise +
    /// 20 s hold, mean of the last 5 s. The paper gives both "about 12 h for 24 cycles" (§4.2)
    /// and "about 14 h with 67 cycles" (§4.3.2); only the second agrees with its own step:
    /// 67 × 34 × 22 s = 13.9 h, while 24 cycles take 5.0 h (12 h would need 53 s a step). So:
    /// 67 cycles.
    ///
    /// Validation: poses 0, 80, …, 480 forward then backward (14 steps a cycle), tests of 15
    /// cycles taking 1.25 h ("Every test of validation takes 1.25 h for 15 cycles", §4.2 and
    /// §4.3.2), so a step is 1.25 h / 210 = 21.43 s: the 2 s rise and 19.43 s of hold, the last
    /// 5 s averaged (the paper states the 22 s step for training; 22 s would make a test 1.28 h
    /// and the KMZ spacing 3.85 h). In the repeating order no model, adaptive KMZ, static,
    /// 31 rounds = 93 tests = 116.25 h (Fig. 12: five days). The KMZ at 0 µm ("Here the KMZ is
    /// measured every 3.75 h") is the first visit of each adaptive test, 3 tests = 3.75 h apart.
    pub fn paper000_1dof() -> Plan {
        Plan {
            name: "paper000-1dof".into(),
            source: "Tan, Clévy, Chaillet, Calibration of nanopositioning stages, §4.2, §4.3.2, Fig. 9, 11-12"
                .into(),
            training: published_step(up_and_down(&grid(0.0, 30.0, 480.0)), 67),
            pause_s: 0.0,
            validation: ValidationPlan {
                test: Procedure {
                    hold_s: PAPER000_TEST_S / (15.0 * 14.0) - 2.0,
                    ..published_step(up_and_down(&grid(0.0, 80.0, 480.0)), 15)
                },
                order: vec![TestKind::NoModel, TestKind::Adaptive, TestKind::Static],
                rounds: 31,
                kmz: Some(KmzPlan {
                    reference_um: vec![0.0],
                    interval_s: 3.75 * 3600.0,
                }),
            },
        }
    }

    /// Paper 000's 2-DoF procedure (§5.2.1).
    ///
    /// Training: the 0:10:80 µm grid on x and y (81 poses a cycle, serpentine from (0, 0) to
    /// (80, 80), then back to the start for the next cycle), 12 cycles; with the 1-DoF step
    /// (2 s + 20 s) that is 12 × 81 × 22 s = 5.9 h, the paper's "6 h".
    ///
    /// Validation: P0 … P5 = (0,0), (45,45), (75,15), (75,75), (15,75), (15,15) µm in turn, then
    /// back to P0 for a new cycle. Not published for 2-DoF, taken from the 1-DoF procedure: 22 s
    /// steps, tests of 15 cycles (33 min); no model and static alternate, 21 rounds = 23 h ("in
    /// nearly one day"); no KMZ.
    pub fn paper000_2dof() -> Plan {
        let g = grid(0.0, 10.0, 80.0);
        let points = PAPER000_2DOF_POINTS_UM;
        Plan {
            name: "paper000-2dof".into(),
            source: "Tan, Clévy, Chaillet, Calibration of nanopositioning stages, §5.2, Fig. 15-17"
                .into(),
            training: published_step(serpentine(&g, &g), 12),
            pause_s: 0.0,
            validation: ValidationPlan {
                test: published_step(points.iter().map(|&(x, y)| vec![x, y]).collect(), 15),
                order: vec![TestKind::NoModel, TestKind::Static],
                rounds: 21,
                kmz: None,
            },
        }
    }

    /// Paper 001's procedure for the delta robot (§IV.C), which publishes no durations: "measure
    /// the pose of the end-effector in all the workspace, doing a regular trajectory" while the
    /// temperatures vary over their range of use, and "collect some separate measurement … to
    /// validate". Here: training over a 5 × 5 × 5 grid of effector poses over ±5 mm (a 1 cm³
    /// cube), commanded in motor coordinates by the nominal inverse geometric model, 72 cycles
    /// of 125 steps of 2 s + 8 s (mean of the last 5 s) = 25 h, a full day of the room's swing;
    /// validation at 40 other poses drawn at random inside ±4.5 mm, in tests of 3 cycles
    /// alternating no model and the model, 18 rounds = 12 h.
    pub fn paper001_robot() -> Plan {
        use crate::twin::delta::{grid_poses_mm, motor_poses_um, random_poses_mm};
        let step = |cycle_um, cycles| Procedure {
            cycle_um,
            rise_s: 2.0,
            hold_s: 8.0,
            average_last_s: 5.0,
            cycles,
        };
        Plan {
            name: "paper001-robot".into(),
            source: "Lubrano, Bouri, Clavel, Ultra-high-precision industrial robots calibration, §IV.C, §VII.A"
                .into(),
            training: step(motor_poses_um(&grid_poses_mm(5, 5.0)), 72),
            pause_s: 0.0,
            validation: ValidationPlan {
                test: step(motor_poses_um(&random_poses_mm(40, 4.5, 2011)), 3),
                order: vec![TestKind::NoModel, TestKind::Static],
                rounds: 18,
                kmz: None,
            },
        }
    }

    /// The same plan with fewer cycles and rounds (for tests): at most `training_cycles`,
    /// `test_cycles` per test and `rounds`.
    pub fn shortened(mut self, training_cycles: usize, test_cycles: usize, rounds: usize) -> Plan {
        self.training.cycles = self.training.cycles.min(training_cycles);
        self.validation.test.cycles = self.validation.test.cycles.min(test_cycles);
        self.validation.rounds = self.validation.rounds.min(rounds);
        self
    }

    /// Number of validation tests.
    pub fn tests(&self) -> usize {
        self.validation.order.len() * self.validation.rounds
    }

    /// Whether a KMZ re-measurement is the first visit of its test (the test's cycle starts
    /// at the reference pose), rather than a step of its own before the test.
    pub fn kmz_is_first_visit(&self) -> bool {
        let v = &self.validation;
        v.kmz
            .as_ref()
            .is_some_and(|k| v.test.cycle_um.first() == Some(&k.reference_um))
    }

    /// The schedule ([`Plan::schedule`]) followed by `blocks` validation blocks of the
    /// validate-and-return loop (paper 001 §II step 5), each `tests` tests of the plan's test
    /// procedure with the static model (refitted for the block), one after the other; test
    /// indices continue the plan's.
    pub fn schedule_with_blocks(&self, blocks: usize, tests: usize) -> Vec<Step> {
        let mut steps = self.schedule();
        let mut t = steps.last().map_or(0.0, Step::t_end_s);
        let v = &self.validation.test;
        for n in 0..blocks * tests {
            let phase = Phase::Test {
                test: self.tests() + n,
                kind: TestKind::Static,
            };
            for _ in 0..v.cycles {
                for pose in &v.cycle_um {
                    steps.push(Step {
                        t_start_s: t,
                        rise_s: v.rise_s,
                        hold_s: v.hold_s,
                        average_last_s: v.average_last_s,
                        target_um: pose.clone(),
                        approach: Vec::new(),
                        phase,
                    });
                    t += v.step_s();
                }
            }
        }
        label_approach(&mut steps);
        steps
    }

    /// Unrolls the plan into timed steps: training, the pause, then the validation tests in
    /// order; at the start of each adaptive test whose KMZ interval has passed (and of the
    /// first), the KMZ step — the test's first visit when its cycle starts at the reference
    /// pose, else a step of its own before it.
    pub fn schedule(&self) -> Vec<Step> {
        let mut steps = Vec::new();
        let mut t = 0.0;
        let push = |steps: &mut Vec<Step>, t: &mut f64, p: &Procedure, pose: &[f64], phase| {
            steps.push(Step {
                t_start_s: *t,
                rise_s: p.rise_s,
                hold_s: p.hold_s,
                average_last_s: p.average_last_s,
                target_um: pose.to_vec(),
                approach: Vec::new(),
                phase,
            });
            *t += p.step_s();
        };
        let tr = &self.training;
        for _ in 0..tr.cycles {
            for pose in &tr.cycle_um {
                push(&mut steps, &mut t, tr, pose, Phase::Training);
            }
        }
        t += self.pause_s;
        let v = &self.validation;
        let first_visit = self.kmz_is_first_visit();
        let mut last_kmz: Option<f64> = None;
        for test in 0..self.tests() {
            let kind = v.order[test % v.order.len()];
            let mut kmz_now = false;
            if let (TestKind::Adaptive, Some(kmz)) = (kind, &v.kmz) {
                if last_kmz.is_none_or(|t0| t - t0 >= kmz.interval_s - 1e-6) {
                    last_kmz = Some(t);
                    kmz_now = true;
                    if !first_visit {
                        let phase = Phase::Kmz { test, visit: false };
                        push(&mut steps, &mut t, &v.test, &kmz.reference_um, phase);
                    }
                }
            }
            for c in 0..v.test.cycles {
                for (i, pose) in v.test.cycle_um.iter().enumerate() {
                    let phase = if kmz_now && first_visit && c == 0 && i == 0 {
                        Phase::Kmz { test, visit: true }
                    } else {
                        Phase::Test { test, kind }
                    };
                    push(&mut steps, &mut t, &v.test, pose, phase);
                }
            }
        }
        label_approach(&mut steps);
        steps
    }
}

/// Direction of approach of every step (see the module doc): per axis, the sign of the last
/// change of its command; a held pose keeps it; +1 before the first motion.
fn label_approach(steps: &mut [Step]) {
    let k = steps.first().map_or(0, |s| s.target_um.len());
    let mut dir = vec![1i8; k];
    let mut prev: Option<Vec<f64>> = None;
    for step in steps.iter_mut() {
        if let Some(p) = &prev {
            for a in 0..k {
                if step.target_um[a] != p[a] {
                    dir[a] = if step.target_um[a] > p[a] { 1 } else { -1 };
                }
            }
        }
        step.approach = dir.clone();
        prev = Some(step.target_um.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_1dof_durations_are_self_consistent() {
        let p = Plan::paper000_1dof();
        assert_eq!(p.training.cycle_um.len(), 34);
        assert_eq!(p.training.step_s(), 22.0);
        // 67 cycles of 34 × 22 s: 13.9 h ("about 14 h"); 24 cycles would be 5.0 h, not 12 h
        assert!((p.training.duration_s() / 3600.0 - 13.92).abs() < 0.01);
        assert!((24.0 * p.training.cycle_s() / 3600.0 - 4.99).abs() < 0.01);
        // a test: 15 cycles of 14 steps, 1.25 h ("1.25 h for 15 cycles"): 21.43 s a step
        assert_eq!(p.validation.test.cycle_um.len(), 14);
        assert!((p.validation.test.duration_s() - 4500.0).abs() < 1e-9);
        assert!((p.validation.test.step_s() - 21.4286).abs() < 1e-4);
        assert_eq!(p.tests(), 93);
        assert!(p.kmz_is_first_visit());
    }

    #[test]
    fn published_2dof_grid_and_points() {
        let p = Plan::paper000_2dof();
        assert_eq!(p.training.cycle_um.len(), 81);
        assert_eq!(p.training.cycle_um[0], vec![0.0, 0.0]);
        assert_eq!(p.training.cycle_um[80], vec![80.0, 80.0]);
        // 12 cycles of 81 × 22 s = 5.9 h ("12 cycles … during 6 h")
        assert!((p.training.duration_s() / 3600.0 - 5.94).abs() < 0.01);
        assert_eq!(p.validation.test.cycle_um[2], vec![75.0, 15.0]);
    }

    #[test]
    fn schedule_orders_tests_kmz_and_approach() {
        let p = Plan::paper000_1dof().shortened(2, 2, 3);
        let s = p.schedule();
        let training = s.iter().filter(|x| x.phase == Phase::Training).count();
        assert_eq!(training, 68);
        // the first cycle from rest: 0 (forward by convention), 30 … 480, the held 480 forward
        let fwd = s[..34].iter().filter(|x| x.approach == vec![1]).count();
        assert_eq!(fwd, 18);
        assert_eq!(s[16].target_um, vec![480.0]);
        assert_eq!((s[16].approach[0], s[17].approach[0]), (1, 1), "held 480");
        assert_eq!(s[18].approach, vec![-1]);
        assert_eq!(s[33].approach, vec![-1]);
        assert_eq!(
            s[34].approach,
            vec![-1],
            "the held 0 starting the next cycle"
        );
        // every later cycle: 17 forward, 17 backward
        let fwd = s[34..68].iter().filter(|x| x.approach == vec![1]).count();
        assert_eq!(fwd, 17);
        // tests: none, adaptive, static, …
        let kinds: Vec<(usize, TestKind)> = s
            .iter()
            .filter_map(|x| match x.phase {
                Phase::Test { test, kind } => Some((test, kind)),
                _ => None,
            })
            .collect();
        // the first adaptive test's first visit is the KMZ
        assert_eq!(kinds.len(), 9 * 2 * 14 - 1);
        assert_eq!(kinds[0].1, TestKind::NoModel);
        assert_eq!(kinds[27].1, TestKind::NoModel);
        assert_eq!(kinds[28].1, TestKind::Adaptive);
        let kmz_steps = |s: &[Step]| -> Vec<Step> {
            s.iter()
                .filter(|x| matches!(x.phase, Phase::Kmz { .. }))
                .cloned()
                .collect()
        };
        // 2-cycle tests (600 s): adaptive tests start 1800 s apart, under 3.75 h: one KMZ
        let kmz = kmz_steps(&s);
        assert_eq!(kmz.len(), 1);
        assert_eq!(
            kmz[0].phase,
            Phase::Kmz {
                test: 1,
                visit: true
            }
        );
        assert_eq!(kmz[0].target_um, vec![0.0]);
        // every 30 min: at every adaptive test (1800 s apart)
        let mut q = p.clone();
        q.validation.kmz.as_mut().unwrap().interval_s = 1800.0;
        let kmz = kmz_steps(&q.schedule());
        assert_eq!(kmz.len(), 3);
        assert!((kmz[1].t_start_s - kmz[0].t_start_s - 1800.0).abs() < 1e-6);
        // a reference pose the cycle does not start at: a step of its own, before the test
        q.validation.kmz.as_mut().unwrap().reference_um = vec![240.0];
        let s2 = q.schedule();
        let kmz = kmz_steps(&s2);
        assert_eq!(kmz.len(), 3);
        assert_eq!(
            kmz[0].phase,
            Phase::Kmz {
                test: 1,
                visit: false
            }
        );
        assert_eq!(s2.len(), s.len() + 3);
        // contiguous in time
        assert!(s
            .windows(2)
            .all(|w| (w[1].t_start_s - w[0].t_end_s()).abs() < 1e-9));
    }

    #[test]
    fn plans_round_trip_through_json() {
        for p in [
            Plan::paper000_1dof(),
            Plan::paper000_2dof(),
            Plan::paper001_robot(),
        ] {
            let text = serde_json::to_string(&p).unwrap();
            let back: Plan = serde_json::from_str(&text).unwrap();
            assert_eq!(back, p);
        }
    }
}
