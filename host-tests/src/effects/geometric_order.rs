//! `geometric_order`: the geometric error has terms of higher order in position than the
//! model's polynomial.

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "geometric_order";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Coefficients (nm) of u⁴, u⁵, … of the scaled position.
    pub coeffs_nm: Vec<f64>,
}

impl Params {
    /// error = Σ c_j u^(4+j).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            let u = ctx.u[a][k];
            out[a][k] = self
                .coeffs_nm
                .iter()
                .enumerate()
                .map(|(j, c)| c * u.powi(4 + j as i32))
                .sum::<f64>()
                * 1e-3;
        }
        out
    }
}
