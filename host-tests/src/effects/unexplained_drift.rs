//! `unexplained_drift`: drift from a source no recorded channel sees (e.g. electronics or a
//! motor switching on and off, heating the structure where no sensor is).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::SimContext;
use super::{lag_series, zeros};
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::{Estimate, Theta};
use crate::explain::fit::{cross_validate_score, Design};
use crate::explain::parallel::in_parallel;
use crate::explain::search::Search;

/// The effect's name.
pub const NAME: &str = "unexplained_drift";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Drift when the hidden source has been on long enough, nm.
    pub amplitude_nm: f64,
    /// Time constant with which the structure follows the hidden source, s.
    pub tau_s: f64,
    /// Mean duration of the source's on and off periods, s.
    pub switch_period_s: f64,
}

impl Params {
    /// error = A × lag_τ(on/off source with random switching times).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let mut rng = ChaCha8Rng::seed_from_u64(ctx.seed ^ 0x5EED_D21F);
        let on = telegraph(&ctx.t_abs_s, self.switch_period_s, &mut rng);
        let heat = lag_series(&ctx.t_s, &on, self.tau_s, Some(0.0));
        for (o, h) in out[self.axis].iter_mut().zip(heat) {
            *o = self.amplitude_nm * 1e-3 * h;
        }
        out
    }
}

/// A source switching on (1) and off (0) at random: exponentially distributed on and off
/// periods of mean `mean_period_s`, off at absolute time 0, sampled at `t_abs_s`.
pub fn telegraph(t_abs_s: &[f64], mean_period_s: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let t_end = t_abs_s.last().copied().unwrap_or(0.0);
    let mut switches = Vec::new();
    let mut t = 0.0;
    while t <= t_end {
        t += -mean_period_s * rng.gen_range(f64::MIN_POSITIVE..1.0f64).ln();
        switches.push(t);
    }
    let mut i = 0;
    t_abs_s
        .iter()
        .map(|&ta| {
            while i < switches.len() && switches[i] <= ta {
                i += 1;
            }
            (i % 2) as f64
        })
        .collect()
}

/// The explain candidate: a smooth function of time (cosines up to order K, time scale T/K)
/// that no recorded channel provides — the explanation of last resort. A smooth function of
/// time can absorb anything if a held-out row may be predicted from its neighbours, so it is
/// judged on held-out gaps longer than its own time scale (1.25 × T/K).
pub struct Candidate;

/// The cosine of order `j` over the recording's time, cos(πj(t − t₀)/T) (T its duration).
fn cosine_column(t_s: &[f64], j: usize) -> Vec<f64> {
    let t0 = t_s.first().copied().unwrap_or(0.0);
    let span = (t_s.last().copied().unwrap_or(1.0) - t0).max(1e-9);
    t_s.iter()
        .map(|&t| (std::f64::consts::PI * j as f64 * (t - t0) / span).cos())
        .collect()
}

/// Orders K tried (time scales T/K). The slowest is T/8: with gaps 1.25 time scales long that
/// leaves at least five held-out blocks, so every fold is predicted from data on both sides of
/// it (fewer, longer blocks would test extrapolation of the whole model, not the drift).
const ORDERS: [usize; 7] = [8, 12, 16, 24, 32, 48, 64];
/// Held-out gaps are this many time scales long.
const GAP_PER_SCALE: f64 = 1.25;
/// Most rows the choice of K is made on.
const CHOICE_ROWS: usize = 20_000;

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "a slow drift that no recorded channel explains: a heat source or disturbance without a sensor"
    }
    fn deploy(&self) -> &'static str {
        "not in the blob (no channel sees it): the adaptive KMZ offset (reference pose revisited) follows it; add a sensor where the source is"
    }
    fn applies(&self, d: &Data, _ch: usize) -> bool {
        d.rows() >= 100
    }
    fn time_only(&self) -> bool {
        true
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let d = s.d;
        let span = d.duration_s();
        let rows = &s.basis.rows;
        let stride = rows.len().div_ceil(CHOICE_ROWS).max(1);
        let choice_rows: Vec<usize> = rows.iter().copied().step_by(stride).collect();
        let mut best: Option<(f64, usize, Design)> = None;
        // a time scale the held-out design can test: at least two gaps, each holding rows
        let orders: Vec<usize> = ORDERS
            .iter()
            .copied()
            .filter(|&k| {
                let scale = span / k as f64;
                let blocks = (k as f64 / GAP_PER_SCALE).floor() as usize;
                !(blocks < crate::explain::fit::CV_FOLDS
                    || scale < 10.0 * d.median_dt_s
                    || choice_rows.len() < 10 * blocks
                    || k + s.model.len() + 10 > choice_rows.len() / 4)
            })
            .collect();
        // the cosines of order K are the first K of every higher order: computed once, up to
        // the highest order tried, and shared (the same values as computing each order apart)
        // (and kept with the data for the next naming round and channel)
        let top = orders.iter().copied().max().unwrap_or(0);
        let cosines = d.cosines.first(&d.t_s, top, cosine_column);
        // each order judged on its own held-out design, side by side; taken in order
        let judged = in_parallel(&orders, |&k| -> Result<(f64, Design), ExplainError> {
            let blocks = (k as f64 / GAP_PER_SCALE).floor() as usize;
            let design = Design::blocks(&d.t_s, blocks, crate::explain::fit::CV_FOLDS);
            let mut cols = s.model.clone();
            let cur = cross_validate_score(&cols, s.y, &design, &choice_rows)?;
            cols.extend(cosines[..k].iter().map(|c| c.as_slice()));
            let new = cross_validate_score(&cols, s.y, &design, &choice_rows)?;
            Ok((new.rms_um / cur.rms_um, design))
        });
        for (outcome, &k) in judged.into_iter().zip(&orders) {
            let (ratio, design) = outcome?;
            if ratio.is_finite() && best.as_ref().is_none_or(|b| ratio < b.0) {
                best = Some((ratio, k, design));
            }
        }
        Ok(best.map(|(_, k, design)| {
            let lo = span / ORDERS[ORDERS.len() - 1] as f64;
            Proposal {
                // the kept columns themselves, shared (no copy of up to 64 million-row columns)
                regs: cosines[..k].to_vec(),
                thetas: vec![Theta {
                    name: "time_scale_s".into(),
                    value: span / k as f64,
                    sigma: f64::NAN,
                    lo,
                    hi: span / ORDERS[0] as f64,
                }],
                detail: contract::Detail::None,
                design: Some(design),
                evidence_units: None,
            }
        }))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let gap = f.proposal.design.as_ref().map_or(f64::NAN, |d| d.gap_s);
        vec![
            f.proposal.thetas[0].estimate(),
            Estimate::new("held_out_gap_s", gap, f64::NAN),
        ]
    }
    fn summary(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> String {
        let t = &f.proposal.thetas[0];
        let gap = f.proposal.design.as_ref().map_or(f64::NAN, |d| d.gap_s);
        format!(
            "a smooth function of time with features down to {}, judged on held-out gaps of {} (longer than its time scale, so it is not predicting a row from its neighbours)",
            crate::explain::units::duration(t.value),
            crate::explain::units::duration(gap)
        )
    }
}
