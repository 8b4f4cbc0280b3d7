//! The twin executes a [`Plan`]: every step of its schedule becomes a dwell of the command
//! trajectory, and the whole plan — training and validation — is one continuous recording, so
//! the room, the thermal lags and every effect carry on from training into validation as they
//! would on a bench.
//!
//! The stage is driven open loop (command = target); the validation is evaluated afterwards as
//! the compensator would have applied each test's model ([`crate::validate`]: the target for
//! which the device sends the recorded command is `fold.inverse(cmd)`, exactly). The step's
//! 2 s rise is part of the dwell: the twin's command switches at the start of the step and the
//! stage responds at once (plus any creep effect); the measurement is the mean of the step's
//! last seconds, long after the rise.

use super::delta::DeltaTwin;
use super::{Columns, Dwell, Trajectory, Twin};
use crate::data::plan::{Phase, Plan, Step};

/// Something that turns a command trajectory into a recording in the shared layout.
pub trait Simulator {
    /// Simulates `traj` from absolute time `start_s`; `stream` separates the noise of runs.
    fn simulate(&self, traj: &Trajectory, start_s: f64, stream: u64) -> Columns;
}

impl Simulator for Twin {
    fn simulate(&self, traj: &Trajectory, start_s: f64, stream: u64) -> Columns {
        Twin::simulate(self, traj, start_s, stream)
    }
}

impl Simulator for DeltaTwin {
    fn simulate(&self, traj: &Trajectory, start_s: f64, stream: u64) -> Columns {
        DeltaTwin::simulate(self, traj, start_s, stream)
    }
}

/// A plan run on the twin: its schedule and the recording.
#[derive(Debug, Clone)]
pub struct PlanRun {
    /// The plan's steps (times from the start of the plan = the recording's `t`).
    pub steps: Vec<Step>,
    /// The recording from the start of training to the end of validation.
    pub recording: Columns,
    /// Absolute (room) time of the start of the plan, s.
    pub start_s: f64,
}

/// The command trajectory of a schedule: one dwell per step (repeated poses are not merged).
pub fn trajectory(steps: &[Step]) -> Trajectory {
    Trajectory {
        dwells: steps
            .iter()
            .map(|s| Dwell {
                cmd_um: s.target_um.clone(),
                dwell_s: s.rise_s + s.hold_s,
            })
            .collect(),
    }
}

/// Runs `plan` on `twin` from absolute time `start_s` (`stream` separates the noise of runs
/// of the same twin). With `zero_at_start`, every interferometer reading is taken relative to
/// the first one (paper 000 §4.1: "the interferometer defines the global frame … by setting the
/// initial reading at the beginning of training phase as zero").
pub fn run_plan(
    twin: &impl Simulator,
    plan: &Plan,
    start_s: f64,
    stream: u64,
    zero_at_start: bool,
) -> PlanRun {
    let steps = plan.schedule();
    let mut recording = twin.simulate(&trajectory(&steps), start_s, stream);
    if zero_at_start {
        zero_interferometer(&mut recording);
    }
    PlanRun {
        steps,
        recording,
        start_s,
    }
}

/// Makes every `meas_*` column relative to its first value.
pub fn zero_interferometer(rec: &mut Columns) {
    for (name, col) in rec.columns.iter_mut() {
        if name.starts_with("meas_") {
            if let Some(&first) = col.first() {
                for v in col.iter_mut() {
                    *v -= first;
                }
            }
        }
    }
}

impl PlanRun {
    /// Recording time of the end of the training (the start of the first validation step).
    pub fn training_end_s(&self) -> f64 {
        self.steps
            .iter()
            .find(|s| s.phase != Phase::Training)
            .map_or_else(
                || self.steps.last().map_or(0.0, Step::t_end_s),
                |s| s.t_start_s,
            )
    }

    /// The recording split at the end of training: (training, validation); both keep the plan's
    /// time axis.
    pub fn split(&self) -> (Columns, Columns) {
        let t_split = self.training_end_s();
        let t = self.recording.get("t").unwrap_or(&[]);
        let n = t.partition_point(|&v| v < t_split - 1e-9);
        let part = |r: std::ops::Range<usize>| Columns {
            columns: self
                .recording
                .columns
                .iter()
                .map(|(name, c)| (name.clone(), c[r.clone()].to_vec()))
                .collect(),
        };
        (part(0..n), part(n..t.len()))
    }
}
