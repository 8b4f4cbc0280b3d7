//! `thermal_lag`: the structure follows a first-order lag (time constant τ) of the sensed
//! temperatures instead of the readings themselves.

use serde::{Deserialize, Serialize};

use super::{lag_series, zeros};
use crate::explain::data::Data;
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

/// The explain candidate: lagged copies of every temperature, one common τ.
pub struct Candidate;

impl super::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the measured displacement follows the temperatures with a delay: the structure warms and cools more slowly than its sensors (a first-order lag with time constant τ)"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: one lag filter per sensor (LagSpec{sensor, tau_s}) and terms with Factor::Lagged(k); the firmware runs the same LagFilter"
    }
    fn applies(&self, d: &Data, _ch: usize) -> bool {
        !d.temps.is_empty() && d.rows() >= 50
    }
    fn theta_name(&self) -> Option<&'static str> {
        Some("tau_s")
    }
    fn theta_grid(&self, d: &Data, _ch: usize) -> Vec<f64> {
        let dt = d.duration_s() / d.rows().max(2) as f64;
        super::log_grid(
            (3.0 * dt).max(5.0),
            (d.duration_s() / 3.0).max(10.0 * dt),
            16,
        )
    }
    fn continuous(&self) -> bool {
        true
    }
    fn regressors(&self, d: &Data, _ch: usize, theta: Option<f64>) -> Vec<Vec<f64>> {
        let tau = theta.unwrap_or(1.0);
        d.temps
            .iter()
            .map(|(_, x)| super::lag_series(&d.t_s, x, tau, None))
            .collect()
    }
    fn params(&self, _d: &Data, _ch: usize, f: &super::Fitted) -> Vec<super::Estimate> {
        vec![super::Estimate::new(
            "tau_s",
            f.theta.unwrap_or(f64::NAN),
            f.theta_sigma,
        )]
    }
    fn blob_terms(&self, ctx: &super::BlobContext, theta: Option<f64>) -> Option<super::BlobTerms> {
        let tau = theta?;
        let n = ctx.temps.min(nanocal_model::MAX_LAGS as u8);
        Some(super::BlobTerms {
            lags: (0..n).map(|i| (i, tau)).collect(),
            terms: (0..n)
                .map(|k| super::term(ctx.output, [0; 3], nanocal_model::Factor::Lagged(k), 0))
                .collect(),
        })
    }
}
