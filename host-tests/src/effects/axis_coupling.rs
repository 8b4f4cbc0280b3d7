//! `axis_coupling`: one axis' position depends on where another axis is (crosstalk,
//! non-orthogonality, parasitic motion).

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::search::Search;

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
        let (lo, hi) = ctx.travel_um[self.from_axis];
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

/// The explain candidate: the other commanded axes' u, u², and u × own u.
pub struct Candidate;

fn others(d: &Data, ch: usize) -> Vec<usize> {
    (0..d.channels.len())
        .filter(|&b| b != ch && d.channels[b].u.is_some())
        .collect()
}

/// The extension's regressor columns.
fn regressors(d: &Data, ch: usize) -> Vec<Vec<f64>> {
    let ua = d.channels[ch].u.as_ref().unwrap();
    let mut out = Vec::new();
    for b in others(d, ch) {
        let ub = d.channels[b].u.as_ref().unwrap();
        out.push(ub.clone());
        out.push(ub.iter().map(|x| x * x).collect());
        out.push(ub.iter().zip(ua).map(|(x, y)| x * y).collect());
    }
    out
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "this axis' reading depends on where another axis is (crosstalk, non-orthogonality or parasitic motion)"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: cross-axis position monomials (powers on the other axis, Factor::None)"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        d.channels[ch].u.is_some() && !others(d, ch).is_empty()
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        Ok(Some(Proposal::linear(regressors(s.d, s.ch))))
    }
    fn params(&self, d: &Data, ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let b = others(d, ch)[0];
        let h = d.channels[b].half_range_um;
        vec![
            Estimate::new("from_axis", b as f64, 0.0),
            Estimate::new("nm_per_um", f.coeffs[0] / h * 1e3, f.se[0] / h * 1e3),
            Estimate::new("quadratic_nm", f.coeffs[1] * 1e3, f.se[1] * 1e3),
            Estimate::new("cross_nm", f.coeffs[2] * 1e3, f.se[2] * 1e3),
        ]
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        _f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        let mut terms = Vec::new();
        for b in (0..ctx.axes).filter(|&b| b != ctx.output) {
            let mut cross = contract::powers(b, 1);
            cross[ctx.output as usize] = 1;
            terms.push(contract::term(
                ctx.output,
                contract::powers(b, 1),
                nanocal_model::Factor::None,
                0,
            ));
            terms.push(contract::term(
                ctx.output,
                contract::powers(b, 2),
                nanocal_model::Factor::None,
                0,
            ));
            terms.push(contract::term(
                ctx.output,
                cross,
                nanocal_model::Factor::None,
                0,
            ));
        }
        (!terms.is_empty()).then_some(contract::BlobTerms {
            lags: Vec::new(),
            plays: Vec::new(),
            play: Vec::new(),
            terms,
        })
    }
}
