//! `thermal_lag`: the structure follows a first-order lag (time constant τ) of the sensed
//! temperatures instead of the readings themselves.

use serde::{Deserialize, Serialize};

use super::{lag_series, zeros};
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "thermal_lag";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Time constant of the structure behind the sensed spots, s.
    pub tau_s: f64,
}

impl Params {
    /// Replaces the drift Σ kᵢ·Tᵢ with Σ kᵢ·lag_τ(Tᵢ) on every axis.
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        for (i, spot) in ctx.spot_c.iter().enumerate() {
            let lagged = lag_series(&ctx.t_s, spot, self.tau_s, None);
            for (a, o) in out.iter_mut().enumerate() {
                let k = ctx.cfg.thermal_um_per_c[a][i];
                for (j, v) in o.iter_mut().enumerate() {
                    *v += k * (lagged[j] - spot[j]);
                }
            }
        }
        out
    }
}
