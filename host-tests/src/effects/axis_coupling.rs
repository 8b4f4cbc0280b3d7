//! `axis_coupling`: one axis' position depends on where another axis is (crosstalk,
//! non-orthogonality, parasitic motion).

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "axis_coupling";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// The axis whose position causes the error.
    pub from_axis: usize,
    /// The axis that shows the error.
    pub to_axis: usize,
    /// Linear crosstalk, nm per µm of the other axis (from its travel centre).
    pub nm_per_um: f64,
    /// Curvature of the crosstalk: nm at the ends of the other axis' travel (× u²).
    pub quadratic_nm: f64,
}

impl Params {
    /// error_to = c × (x_from − centre) + q × u_from².
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let (lo, hi) = ctx.cfg.travel_um[self.from_axis];
        let c = 0.5 * (lo + hi);
        for k in 0..ctx.t_s.len() {
            let u = ctx.u[self.from_axis][k];
            out[self.to_axis][k] = (self.nm_per_um * (ctx.cmd_um[self.from_axis][k] - c)
                + self.quadratic_nm * u * u)
                * 1e-3;
        }
        out
    }
}
