//! Command trajectories: a list of poses, each held for a dwell, sampled at a fixed period.
//! The published ones: training 0:30:480 µm forward then backward, validation poses
//! 0, 80, …, 480, and the 2-DoF 0:10:80 µm grid.

use serde::{Deserialize, Serialize};

/// One pose held for `dwell_s` seconds.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Dwell {
    /// Commanded position per axis, µm.
    pub cmd_um: Vec<f64>,
    /// How long the pose is held, s.
    pub dwell_s: f64,
}

/// A sequence of dwells; moves between poses are instantaneous at the sample scale.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Trajectory {
    /// The dwells in order.
    pub dwells: Vec<Dwell>,
}

impl Trajectory {
    /// Number of axes (0 for an empty trajectory).
    pub fn axes(&self) -> usize {
        self.dwells.first().map_or(0, |d| d.cmd_um.len())
    }

    /// Total duration, s.
    pub fn duration_s(&self) -> f64 {
        self.dwells.iter().map(|d| d.dwell_s).sum()
    }

    /// Sample the trajectory every `period_s`: (time since start, command per axis).
    pub fn sample(&self, period_s: f64) -> (Vec<f64>, Vec<Vec<f64>>) {
        let axes = self.axes();
        let mut t = Vec::new();
        let mut cmd = vec![Vec::new(); axes];
        let mut start = 0.0;
        let mut k = 0usize;
        for d in &self.dwells {
            let end = start + d.dwell_s;
            loop {
                let tk = k as f64 * period_s;
                if tk >= end - 1e-9 {
                    break;
                }
                t.push(tk);
                for (a, c) in cmd.iter_mut().enumerate() {
                    c.push(d.cmd_um[a]);
                }
                k += 1;
            }
            start = end;
        }
        (t, cmd)
    }

    /// Append another trajectory.
    pub fn then(mut self, other: Trajectory) -> Self {
        self.dwells.extend(other.dwells);
        self
    }

    /// Merge consecutive dwells at the same pose.
    fn merged(dwells: Vec<Dwell>) -> Self {
        let mut out: Vec<Dwell> = Vec::with_capacity(dwells.len());
        for d in dwells {
            match out.last_mut() {
                Some(last) if last.cmd_um == d.cmd_um => last.dwell_s += d.dwell_s,
                _ => out.push(d),
            }
        }
        Self { dwells: out }
    }

    /// 1-DoF: `poses` forward, then back in reverse order, `cycles` times, each held `dwell_s`;
    /// after each cycle the stage rests at the first pose for `rest_s`.
    pub fn forward_backward(poses_um: &[f64], dwell_s: f64, cycles: usize, rest_s: f64) -> Self {
        let mut dwells = Vec::new();
        for _ in 0..cycles {
            for &p in poses_um.iter().chain(poses_um.iter().rev()) {
                dwells.push(Dwell {
                    cmd_um: vec![p],
                    dwell_s,
                });
            }
            if rest_s > 0.0 {
                dwells.push(Dwell {
                    cmd_um: vec![poses_um[0]],
                    dwell_s: rest_s,
                });
            }
        }
        Self::merged(dwells)
    }

    /// Published 1-DoF training: 0:30:480 µm forward then backward.
    pub fn published_training_1dof(dwell_s: f64, cycles: usize) -> Self {
        let poses: Vec<f64> = (0..=16).map(|k| 30.0 * k as f64).collect();
        Self::forward_backward(&poses, dwell_s, cycles, 0.0)
    }

    /// Published 1-DoF validation poses 0, 80, …, 480 forward then backward; `rest_s` at 0 between cycles.
    pub fn published_validation_1dof(dwell_s: f64, cycles: usize, rest_s: f64) -> Self {
        let poses: Vec<f64> = (0..=6).map(|k| 80.0 * k as f64).collect();
        Self::forward_backward(&poses, dwell_s, cycles, rest_s)
    }

    /// Published 2-DoF training grid 0:10:80 µm on both axes (serpentine), `cycles` times.
    pub fn published_grid_2dof(dwell_s: f64, cycles: usize) -> Self {
        let mut dwells = Vec::new();
        for c in 0..cycles {
            for iy in 0..=8 {
                for k in 0..=8 {
                    let ix = if (iy + c) % 2 == 0 { k } else { 8 - k };
                    dwells.push(Dwell {
                        cmd_um: vec![10.0 * ix as f64, 10.0 * iy as f64],
                        dwell_s,
                    });
                }
            }
        }
        Self::merged(dwells)
    }

    /// Published 2-DoF validation points (0,0), (45,45), (75,15), (75,75), (15,75), (15,15).
    pub fn published_validation_2dof(dwell_s: f64, cycles: usize, rest_s: f64) -> Self {
        let pts = crate::data::plan::PAPER000_2DOF_POINTS_UM;
        let mut dwells = Vec::new();
        for _ in 0..cycles {
            for &(x, y) in &pts {
                dwells.push(Dwell {
                    cmd_um: vec![x, y],
                    dwell_s,
                });
            }
            if rest_s > 0.0 {
                dwells.push(Dwell {
                    cmd_um: vec![0.0, 0.0],
                    dwell_s: rest_s,
                });
            }
        }
        Self::merged(dwells)
    }

    /// A stage that stands still at `cmd_um` for `duration_s` (thermal-only recordings).
    pub fn standstill(cmd_um: Vec<f64>, duration_s: f64) -> Self {
        Self {
            dwells: vec![Dwell {
                cmd_um,
                dwell_s: duration_s,
            }],
        }
    }
}
