//! `hysteresis`: a direction-dependent error — the stage stops at a different place when it
//! approaches a pose forward than backward.

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "hysteresis";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Half the forward–backward difference at mid travel, nm.
    pub half_width_nm: f64,
    /// Change of the half width across the travel (× scaled position u), nm.
    pub slope_nm: f64,
}

impl Params {
    /// error = dir × (half_width + slope·u).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            out[a][k] = ctx.dir[a][k] * (self.half_width_nm + self.slope_nm * ctx.u[a][k]) * 1e-3;
        }
        out
    }
}
