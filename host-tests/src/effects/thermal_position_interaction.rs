//! `thermal_position_interaction`: the moving part expands (or the actuator gain changes) with
//! temperature, so the thermal error grows with position: error ∝ x × ΔT.

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "thermal_position_interaction";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Relative change of scale per °C of the mean spot temperature, ppm/°C.
    pub alpha_ppm_per_c: f64,
}

impl Params {
    /// error = α × (x − x_min) × (mean spot temperature − reference).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        let lo = ctx.cfg.travel_um[a].0;
        let ns = ctx.spot_c.len().max(1) as f64;
        for k in 0..ctx.t_s.len() {
            let dt: f64 = ctx.spot_c.iter().map(|s| s[k]).sum::<f64>() / ns - ctx.cfg.temp_ref_c;
            out[a][k] = self.alpha_ppm_per_c * 1e-6 * (ctx.cmd_um[a][k] - lo) * dt;
        }
        out
    }
}
