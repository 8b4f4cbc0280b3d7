//! `air_refraction`: the interferometer assumes a fixed refractive index of air; when the
//! barometric pressure changes, the reading changes ∝ (dead path + x) × Δp (Edlén).

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::search::Search;

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
        let p0 = ctx.pressure_mean_hpa;
        for k in 0..ctx.t_s.len() {
            let path_um = self.dead_path_mm * 1e3 + ctx.pos_um[a][k];
            out[a][k] = path_um * DN_DP_PER_HPA * (ctx.pressure_hpa[k] - p0);
        }
        out
    }
}

/// The explain candidate: Δp and u × Δp; dead path from the Edlén sensitivity.
pub struct Candidate;

/// The extension's regressor columns.
fn regressors(d: &Data, ch: usize) -> Vec<Vec<f64>> {
    let p = &d.pressure_hpa.as_ref().unwrap().1;
    let m = p.iter().sum::<f64>() / p.len() as f64;
    let dp: Vec<f64> = p.iter().map(|v| v - m).collect();
    let mut out = vec![dp.clone()];
    if let Some(u) = &d.channels[ch].u {
        out.push(u.iter().zip(&dp).map(|(u, p)| u * p).collect());
    }
    out
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the interferometer reading changes with barometric pressure (refractive index of air, Edlén), ∝ (dead path + x) × Δp"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: a pressure term (Factor::Aux(pressure)) and position × pressure (u¹ with Factor::Aux)"
    }
    fn applies(&self, d: &Data, _ch: usize) -> bool {
        d.pressure_hpa.as_ref().is_some_and(|(_, p)| {
            let lo = p.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = p.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            hi - lo > 0.2
        })
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        Ok(Some(Proposal::linear(regressors(s.d, s.ch))))
    }
    fn params(&self, d: &Data, ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let c = &d.channels[ch];
        let centre = c.cmd_um.as_ref().map_or(0.0, |cmd| {
            let lo = cmd.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = cmd.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            0.5 * (lo + hi)
        });
        let l_mm = (f.coeffs[0] / DN_DP_PER_HPA - centre) * 1e-3;
        vec![
            Estimate::new("sensitivity_nm_per_hpa", f.coeffs[0] * 1e3, f.se[0] * 1e3),
            Estimate::new("dead_path_mm", l_mm, f.se[0] / DN_DP_PER_HPA * 1e-3),
        ]
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        _f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        let p = nanocal_model::Factor::Aux(ctx.pressure_aux?);
        Some(contract::BlobTerms {
            lags: Vec::new(),
            plays: Vec::new(),
            play: Vec::new(),
            terms: vec![
                contract::term(ctx.output, [0; 3], p, 0),
                contract::term(ctx.output, contract::powers(ctx.output, 1), p, 0),
            ],
        })
    }
}
