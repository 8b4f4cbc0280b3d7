//! `air_refraction`: the interferometer assumes a fixed refractive index of air; when the
//! barometric pressure changes, the reading changes ∝ (dead path + x) × Δp (Edlén).

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "air_refraction";

/// Edlén sensitivity of the refractive index of standard air to pressure, per hPa
/// (∂n/∂p ≈ 2.68 × 10⁻⁷ /hPa at 20 °C, 633 nm).
pub const DN_DP_PER_HPA: f64 = 2.68e-7;

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Dead path (optical path outside the measured travel), mm.
    pub dead_path_mm: f64,
}

impl Params {
    /// error = (L + x) × ∂n/∂p × (p − p_mean).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        let p0 = ctx.cfg.room.pressure_mean_hpa;
        for k in 0..ctx.t_s.len() {
            let path_um = self.dead_path_mm * 1e3 + ctx.pos_um[a][k];
            out[a][k] = path_um * DN_DP_PER_HPA * (ctx.pressure_hpa[k] - p0);
        }
        out
    }
}
