//! `creep`: after each step the position keeps moving in the direction of the step,
//! ∝ step × log(1 + t/t0).

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "creep";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Creep per unit of log(1 + t/t0), as a fraction of the step (e.g. 0.001 = 1 nm per µm).
    pub gamma: f64,
    /// Time scale of the logarithm, s.
    pub t0_s: f64,
}

/// Σ over past steps of step_um × log(1 + (t − t_step)/t0), µm per unit γ.
pub fn creep_basis(t_s: &[f64], steps: &[(usize, f64)], t0_s: f64) -> Vec<f64> {
    let mut out = vec![0.0; t_s.len()];
    for &(k0, dq) in steps {
        // The move happens between samples k0-1 and k0: take the midpoint as the step time.
        let ts = if k0 > 0 {
            0.5 * (t_s[k0 - 1] + t_s[k0])
        } else {
            t_s[0]
        };
        for k in k0..t_s.len() {
            out[k] += dq * (1.0 + (t_s[k] - ts) / t0_s).ln();
        }
    }
    out
}

impl Params {
    /// error = γ Σ Δq log(1 + (t − t_k)/t0).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let b = creep_basis(&ctx.t_s, &ctx.steps[self.axis], self.t0_s);
        for (o, v) in out[self.axis].iter_mut().zip(b) {
            *o = self.gamma * v;
        }
        out
    }
}
