//! `unexplained_drift`: drift from a source no recorded channel sees (e.g. electronics or a
//! motor switching on and off, heating the structure where no sensor is).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{lag_series, zeros};
use crate::explain::data::Data;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "unexplained_drift";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Drift when the hidden source has been on long enough, nm.
    pub amplitude_nm: f64,
    /// Time constant with which the structure follows the hidden source, s.
    pub tau_s: f64,
    /// Mean duration of the source's on and off periods, s.
    pub switch_period_s: f64,
}

impl Params {
    /// error = A × lag_τ(on/off source with random switching times).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let mut rng = ChaCha8Rng::seed_from_u64(ctx.seed ^ 0x5EED_D21F);
        let t_end = ctx.t_abs_s.last().copied().unwrap_or(0.0);
        let mut switches = Vec::new();
        let mut t = 0.0;
        while t <= t_end {
            t += -self.switch_period_s * rng.gen_range(f64::MIN_POSITIVE..1.0f64).ln();
            switches.push(t);
        }
        let mut on = vec![0.0; ctx.t_s.len()];
        let mut i = 0;
        for (k, &ta) in ctx.t_abs_s.iter().enumerate() {
            while i < switches.len() && switches[i] <= ta {
                i += 1;
            }
            on[k] = (i % 2) as f64;
        }
        let heat = lag_series(&ctx.t_s, &on, self.tau_s, Some(0.0));
        for (o, h) in out[self.axis].iter_mut().zip(heat) {
            *o = self.amplitude_nm * 1e-3 * h;
        }
        out
    }
}

/// The explain candidate: a smooth function of time (piecewise linear, K knots) that no
/// recorded channel provides.
pub struct Candidate;

/// Piecewise-linear hat functions over the recording's time with `k` evenly spaced knots.
pub fn hat_basis(t_s: &[f64], k: usize) -> Vec<Vec<f64>> {
    let t0 = t_s.first().copied().unwrap_or(0.0);
    let span = (t_s.last().copied().unwrap_or(1.0) - t0).max(1e-9);
    let h = span / (k - 1) as f64;
    (0..k)
        .map(|j| {
            t_s.iter()
                .map(|&t| (1.0 - ((t - t0) / h - j as f64).abs()).max(0.0))
                .collect()
        })
        .collect()
}

impl super::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "a slow drift that no recorded channel explains: a heat source or disturbance without a sensor"
    }
    fn deploy(&self) -> &'static str {
        "not in the blob (no channel sees it): the adaptive KMZ offset (reference pose revisited) follows it; add a sensor where the source is"
    }
    fn applies(&self, d: &Data, _ch: usize) -> bool {
        d.rows() >= 100
    }
    fn theta_name(&self) -> Option<&'static str> {
        Some("knots")
    }
    fn theta_grid(&self, _d: &Data, _ch: usize) -> Vec<f64> {
        vec![3.0, 5.0, 9.0, 17.0, 33.0]
    }
    fn regressors(&self, d: &Data, _ch: usize, theta: Option<f64>) -> Vec<Vec<f64>> {
        hat_basis(&d.t_s, theta.unwrap_or(5.0) as usize)
    }
    fn params(&self, d: &Data, _ch: usize, f: &super::Fitted) -> Vec<super::Estimate> {
        let k = f.theta.unwrap_or(5.0);
        vec![super::Estimate::new(
            "time_scale_h",
            d.duration_s() / (k - 1.0) / 3600.0,
            f64::NAN,
        )]
    }
}
