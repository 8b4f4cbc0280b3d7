//! `hysteresis`: rate-independent hysteresis — where the stage is depends on where it came
//! from, not on how fast. Modelled as a Prandtl–Ishlinskii operator: a weighted sum of play
//! (backlash) operators with thresholds spread over the stroke and weights of one sign
//! (Kuhnen, Eur. J. Control 9, 2003, Eq. 2–3), which reproduces minor loops and changes of
//! amplitude. Every operator is stepped by [`nanocal_model::play::play`], the function the
//! compensator's fast path runs.

use serde::{Deserialize, Serialize};

use super::{zeros, Detail, PlayBank, Proposal};
use crate::explain::data::Data;
use crate::explain::nnls::nnls;
use crate::explain::search::Search;
use crate::explain::units::length_um;
use crate::explain::ExplainError;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "hysteresis";

/// Twin parameters: a direction-of-approach offset (a backlash seen by a step-and-settle
/// procedure) and/or a Prandtl–Ishlinskii operator on the commanded position.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Half the forward–backward difference at mid travel, nm (error = dir × (this + slope·u)).
    pub half_width_nm: f64,
    /// Change of the half width across the travel (× scaled position u), nm.
    pub slope_nm: f64,
    /// Thresholds of play operators on the commanded position, µm.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub play_thresholds_um: Vec<f64>,
    /// Their weights: error += Σ wᵢ (F_rᵢ[cmd] − cmd) (wᵢ > 0: the response lags the command).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub play_weights: Vec<f64>,
}

/// F_r[x] − x over a sequence (the operator starts at the first input), µm.
pub fn play_deviation(x: &[f64], r_um: f64) -> Vec<f64> {
    let mut state = x.first().copied().unwrap_or(0.0);
    x.iter()
        .map(|&v| {
            state = nanocal_model::play::play(state, v, r_um);
            state - v
        })
        .collect()
}

impl Params {
    /// error = dir × (half_width + slope·u) + Σ wᵢ (F_rᵢ[cmd] − cmd).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            out[a][k] = ctx.dir[a][k] * (self.half_width_nm + self.slope_nm * ctx.u[a][k]) * 1e-3;
        }
        for (r, w) in self.play_thresholds_um.iter().zip(&self.play_weights) {
            for (o, dv) in out[a].iter_mut().zip(play_deviation(&ctx.cmd_um[a], *r)) {
                *o += w * dv;
            }
        }
        out
    }
}

/// Operators in the bank explain fits (the compensator's bank holds 16).
pub const OPERATORS: usize = 12;

/// Thresholds over the stroke: rᵢ = A·(i/m)², i = 1..m, with A half the commanded stroke —
/// dense at small r, where minor loops and the shape near a reversal live.
pub fn thresholds_um(amplitude_um: f64) -> Vec<f64> {
    (1..=OPERATORS)
        .map(|i| amplitude_um * (i as f64 / OPERATORS as f64).powi(2))
        .collect()
}

/// Half the difference between the descending and the ascending branch at mid-stroke of a
/// full-stroke loop (amplitude A) of the operator bank: Σ |wᵢ| min(rᵢ, A − rᵢ), µm.
pub fn full_loop_half_width_um(thresholds_um: &[f64], weights: &[f64], amplitude_um: f64) -> f64 {
    thresholds_um
        .iter()
        .zip(weights)
        .map(|(r, w)| w.abs() * r.min(amplitude_um - r).max(0.0))
        .sum()
}

/// The explain candidate: a bank of play operators on the commanded position, weights of one
/// sign (non-negative least squares for each sign; the better sign is the loop's sense).
pub struct Candidate;

impl super::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "rate-independent hysteresis: where the stage ends up depends on where it came from (the history of reversals), not on how fast — a Prandtl–Ishlinskii sum of play operators"
    }
    fn deploy(&self) -> &'static str {
        "in the blob (v2): a play-operator bank on the axis, fed by its target (declared thresholds r_i in µm, terms with Factor::Play(k)); the fit sets the correction's weights, the fast path steps the operators with the same play function"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        d.channels[ch].dir.is_some() && d.channels[ch].u.is_some()
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let c = &s.d.channels[s.ch];
        let Some(cmd) = &c.cmd_um else {
            return Ok(None);
        };
        let amplitude_um = c.half_range_um;
        let rs = thresholds_um(amplitude_um);
        let cols: Vec<Vec<f64>> = rs.iter().map(|&r| play_deviation(cmd, r)).collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let (r_mat, b, rest) = s.basis.reduce(&refs);
        let neg: Vec<Vec<f64>> = r_mat
            .iter()
            .map(|col| col.iter().map(|v| -v).collect())
            .collect();
        let misfit = |a: &[Vec<f64>], w: &[f64]| -> f64 {
            (0..b.len())
                .map(|i| {
                    let e = b[i] - a.iter().zip(w).map(|(col, wj)| col[i] * wj).sum::<f64>();
                    e * e
                })
                .sum::<f64>()
                + rest
        };
        let w_pos = nnls(&r_mat, &b);
        let w_neg = nnls(&neg, &b);
        let (w, sense) = if misfit(&r_mat, &w_pos) <= misfit(&neg, &w_neg) {
            (w_pos, 1.0)
        } else {
            (w_neg, -1.0)
        };
        let active: Vec<usize> = (0..w.len()).filter(|&j| w[j] > 0.0).collect();
        if active.is_empty() {
            return Ok(None);
        }
        // σ of the half-width per unit noise: solve Rᵀg = c on the active operators' reduction
        let act: Vec<&[f64]> = active.iter().map(|&j| cols[j].as_slice()).collect();
        let (ra, _, _) = s.basis.reduce(&act);
        let c: Vec<f64> = active
            .iter()
            .map(|&j| sense * rs[j].min(amplitude_um - rs[j]).max(0.0))
            .collect();
        let mut g = vec![0.0; c.len()];
        for i in 0..c.len() {
            let acc: f64 = (0..i).map(|k| ra[i][k] * g[k]).sum();
            g[i] = if ra[i][i] > 0.0 {
                (c[i] - acc) / ra[i][i]
            } else {
                0.0
            };
        }
        let half_width_per_noise = g.iter().map(|v| v * v).sum::<f64>().sqrt();
        Ok(Some(Proposal {
            regs: active.iter().map(|&j| cols[j].clone()).collect(),
            thetas: Vec::new(),
            detail: Detail::Play(PlayBank {
                axis: s.ch,
                thresholds_um: active.iter().map(|&j| rs[j]).collect(),
                sense,
                amplitude_um,
                half_width_per_noise,
            }),
            design: None,
        }))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &super::Fitted) -> Vec<super::Estimate> {
        let Detail::Play(bank) = &f.proposal.detail else {
            return Vec::new();
        };
        let a = bank.amplitude_um;
        let hw = full_loop_half_width_um(&bank.thresholds_um, f.coeffs, a);
        let hw_sigma = f.noise_sigma_um * bank.half_width_per_noise;
        vec![
            super::Estimate::new("half_width_nm", hw * 1e3, hw_sigma * 1e3),
            super::Estimate::new("loop_sense", bank.sense, 0.0),
            super::Estimate::new("operators", bank.thresholds_um.len() as f64, 0.0),
            super::Estimate::new("stroke_um", 2.0 * a, 0.0),
        ]
    }
    fn summary(&self, _d: &Data, _ch: usize, f: &super::Fitted) -> String {
        let Detail::Play(bank) = &f.proposal.detail else {
            return String::new();
        };
        let hw = full_loop_half_width_um(&bank.thresholds_um, f.coeffs, bank.amplitude_um);
        let sense = if bank.sense > 0.0 {
            "counter-clockwise loop (measured vs commanded): the response lags the command — on the way up the stage stays below where it is on the way down, as a piezo's does"
        } else {
            "clockwise loop (measured vs commanded): the response leads the command — on the way up the stage is above where it is on the way down"
        };
        let ops: Vec<String> = bank
            .thresholds_um
            .iter()
            .zip(f.coeffs)
            .map(|(r, w)| format!("{:.3} µm × {:.4}", r, w))
            .collect();
        format!(
            "{sense}; full-stroke loop half-width {} at mid-stroke; {} play operators (threshold × weight): {}",
            length_um(hw),
            ops.len(),
            ops.join(", ")
        )
    }
    fn blob_terms(&self, ctx: &super::BlobContext, f: &super::Fitted) -> Option<super::BlobTerms> {
        let Detail::Play(bank) = &f.proposal.detail else {
            return None;
        };
        let plays: Vec<(u8, f64)> = bank
            .thresholds_um
            .iter()
            .map(|&r| (ctx.output, r))
            .collect();
        Some(super::BlobTerms {
            lags: Vec::new(),
            terms: (0..plays.len() as u8)
                .map(|k| super::term(ctx.output, [0; 3], nanocal_model::Factor::Play(k), 0))
                .collect(),
            plays,
            play: bank
                .thresholds_um
                .iter()
                .zip(f.coeffs)
                .map(|(&threshold_um, &weight)| super::PlayOperator {
                    axis: ctx.output,
                    threshold_um,
                    weight,
                })
                .collect(),
        })
    }
}
