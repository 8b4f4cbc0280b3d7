//! `unexplained_drift`: drift from a source no recorded channel sees (e.g. electronics or a
//! motor switching on and off, heating the structure where no sensor is).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{lag_series, zeros};
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
