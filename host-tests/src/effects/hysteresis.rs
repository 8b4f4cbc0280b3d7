//! `hysteresis`: a direction-dependent error — the stage stops at a different place when it
//! approaches a pose forward than backward.

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::explain::data::Data;
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

/// The explain candidate: sign of approach × (1, u, u²).
pub struct Candidate;

impl super::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the stage stops at a different place depending on the direction it came from (forward vs backward approach)"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: direction-dependent terms (Term.direction = axis + 1) on u⁰, u¹ and u²"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        d.channels[ch].dir.is_some() && d.channels[ch].u.is_some()
    }
    fn regressors(&self, d: &Data, ch: usize, _theta: Option<f64>) -> Vec<Vec<f64>> {
        let c = &d.channels[ch];
        let (dir, u) = (c.dir.as_ref().unwrap(), c.u.as_ref().unwrap());
        vec![
            dir.clone(),
            dir.iter().zip(u).map(|(a, b)| a * b).collect(),
            // a piezo loop is widest mid-travel: the width's curvature along the travel
            dir.iter().zip(u).map(|(a, b)| a * b * b).collect(),
        ]
    }
    fn params(&self, _d: &Data, _ch: usize, f: &super::Fitted) -> Vec<super::Estimate> {
        vec![
            super::Estimate::new("half_width_nm", f.coeffs[0] * 1e3, f.se[0] * 1e3),
            super::Estimate::new("slope_nm", f.coeffs[1] * 1e3, f.se[1] * 1e3),
            super::Estimate::new("curvature_nm", f.coeffs[2] * 1e3, f.se[2] * 1e3),
        ]
    }
    fn blob_terms(
        &self,
        ctx: &super::BlobContext,
        _theta: Option<f64>,
    ) -> Option<super::BlobTerms> {
        let dir = ctx.output + 1;
        Some(super::BlobTerms {
            lags: Vec::new(),
            terms: vec![
                super::term(ctx.output, [0; 3], nanocal_model::Factor::None, dir),
                super::term(
                    ctx.output,
                    super::powers(ctx.output, 1),
                    nanocal_model::Factor::None,
                    dir,
                ),
                super::term(
                    ctx.output,
                    super::powers(ctx.output, 2),
                    nanocal_model::Factor::None,
                    dir,
                ),
            ],
        })
    }
}
