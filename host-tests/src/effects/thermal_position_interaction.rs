//! `thermal_position_interaction`: the moving part expands (or the actuator gain changes) with
//! temperature, so the thermal error grows with position: error ∝ x × ΔT.

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::search::Search;

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
        let lo = ctx.travel_um[a].0;
        let ns = ctx.spot_c.len().max(1) as f64;
        for k in 0..ctx.t_s.len() {
            let dt: f64 = ctx.spot_c.iter().map(|s| s[k]).sum::<f64>() / ns - ctx.temp_ref_c;
            out[a][k] = self.alpha_ppm_per_c * 1e-6 * (ctx.cmd_um[a][k] - lo) * dt;
        }
        out
    }
}

/// The explain candidate: u × mean temperature, and u × each sensor's deviation from the mean.
pub struct Candidate;

fn mean_temp(d: &Data) -> Vec<f64> {
    let m = d.temps.len() as f64;
    (0..d.rows())
        .map(|k| d.temps.iter().map(|(_, x)| x[k]).sum::<f64>() / m)
        .collect()
}

/// The extension's regressor columns.
fn regressors(d: &Data, ch: usize) -> Vec<Vec<f64>> {
    let u = d.channels[ch].u.as_ref().unwrap();
    let tm = mean_temp(d);
    let t0 = tm.iter().sum::<f64>() / tm.len() as f64;
    let mut out = vec![u
        .iter()
        .zip(&tm)
        .map(|(u, t)| u * (t - t0))
        .collect::<Vec<f64>>()];
    for (_, x) in d.temps.iter().take(d.temps.len().saturating_sub(1)) {
        out.push((0..d.rows()).map(|k| u[k] * (x[k] - tm[k])).collect());
    }
    out
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the thermal error grows with position: the moving part expands (or the actuator's gain changes) with temperature, ∝ x × ΔT"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: position × temperature terms (powers u¹ with Factor::Temp(i))"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        d.channels[ch].u.is_some() && !d.temps.is_empty()
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        Ok(Some(Proposal::linear(regressors(s.d, s.ch))))
    }
    fn params(&self, d: &Data, ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let h = d.channels[ch].half_range_um;
        vec![Estimate::new(
            "alpha_ppm_per_c",
            f.coeffs[0] / h * 1e6,
            f.se[0] / h * 1e6,
        )]
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        _f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        Some(contract::BlobTerms {
            lags: Vec::new(),
            plays: Vec::new(),
            play: Vec::new(),
            terms: (0..ctx.temps)
                .map(|i| {
                    contract::term(
                        ctx.output,
                        contract::powers(ctx.output, 1),
                        nanocal_model::Factor::Temp(i),
                        0,
                    )
                })
                .collect(),
        })
    }
}
