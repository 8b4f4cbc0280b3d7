//! `hysteresis`: rate-independent hysteresis — where the stage is depends on where it came
//! from, not on how fast. Modelled as a Prandtl–Ishlinskii operator: a weighted sum of play
//! (backlash) operators with thresholds spread over the stroke and weights of one sign
//! (Kuhnen, Eur. J. Control 9, 2003, Eq. 2–3), which reproduces minor loops and changes of
//! amplitude. Every operator is stepped by [`nanocal_model::play::play`], the function the
//! compensator's fast path runs.

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Detail, PlayBank, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::nnls::nnls;
use crate::explain::search::Search;
use crate::explain::units::length_um;

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

/// [`play_deviation`] at `rows` (ascending) only: the operator still steps through every
/// input.
fn play_deviation_at(x: &[f64], r_um: f64, rows: &[usize]) -> Vec<f64> {
    let mut state = x.first().copied().unwrap_or(0.0);
    let mut out = Vec::with_capacity(rows.len());
    let mut next = 0;
    for (k, &v) in x.iter().enumerate() {
        state = nanocal_model::play::play(state, v, r_um);
        while next < rows.len() && rows[next] == k {
            out.push(state - v);
            next += 1;
        }
    }
    out
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

/// The explain candidate: a bank of play operators on the drive, weights of one sign
/// (non-negative least squares for each sign; the better sign is the loop's sense). The drive
/// is the axis' command, or an auxiliary column that carries it (an actuator voltage that
/// follows the measurement closely and reverses); thresholds come from the drive's own stroke,
/// whatever its sign or offset; glitches of the drive are repaired before (see
/// [`crate::explain::faults`]).
pub struct Candidate;

/// The drives the loop may be fed by on channel `ch`: the command (if it reverses), then every
/// auxiliary column that goes with the measurement (|r| ≥ 0.9), reverses at least three times
/// and is not a copy of the command.
pub fn drives(d: &Data, ch: usize) -> Vec<(Option<String>, Vec<f64>)> {
    let c = &d.channels[ch];
    let mut out = Vec::new();
    if let (Some(cmd), Some(_)) = (&c.cmd_um, &c.dir) {
        out.push((None, cmd.clone()));
    }
    for (name, x) in &d.aux {
        if d.pressure_hpa.as_ref().is_some_and(|p| &p.0 == name) || reversals(x) < 3 {
            continue;
        }
        if correlation(x, &c.meas_um).abs() < 0.9 {
            continue;
        }
        if c.cmd_um
            .as_ref()
            .is_some_and(|cmd| correlation(x, cmd).abs() > 0.9999)
        {
            continue;
        }
        out.push((Some(name.clone()), x.clone()));
    }
    out
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    let r = sab / (saa * sbb).sqrt();
    if r.is_finite() {
        r
    } else {
        0.0
    }
}

/// Number of reversals of a series beyond a tenth of its range (noise does not count).
pub fn reversals(x: &[f64]) -> usize {
    let lo = x.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let band = 0.1 * (hi - lo);
    if band.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0;
    }
    let (mut count, mut dir) = (0usize, 0i8);
    let (mut top, mut bottom) = (x[0], x[0]);
    for &v in x {
        if dir >= 0 {
            top = top.max(v);
            if v < top - band {
                count += usize::from(dir > 0);
                dir = -1;
                bottom = v;
            }
        }
        if dir <= 0 {
            bottom = bottom.min(v);
            if v > bottom + band {
                count += usize::from(dir < 0);
                dir = 1;
                top = v;
            }
        }
    }
    count
}

/// A polynomial (degree 3) in an auxiliary drive, scaled to [−1, 1]: its static response.
fn drive_poly(x: &[f64]) -> Vec<Vec<f64>> {
    let lo = x.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let (c, h) = (0.5 * (lo + hi), (0.5 * (hi - lo)).max(f64::MIN_POSITIVE));
    (1..=3)
        .map(|p| x.iter().map(|v| ((v - c) / h).powi(p)).collect())
        .collect()
}

/// The bank fitted on one drive: (misfit, sense, weights per threshold, thresholds, columns).
struct BankFit {
    misfit: f64,
    sense: f64,
    weights: Vec<f64>,
    thresholds: Vec<f64>,
    cols: Vec<Vec<f64>>,
    amplitude: f64,
}

/// Non-negative fit of the operators with thresholds `rs` on `basis` (each sign; the better);
/// with `keep_cols` false, the operators' columns are formed on the basis rows only (and not
/// returned).
fn fit_bank(
    basis: &crate::explain::search::Basis,
    x: &[f64],
    rs: Vec<f64>,
    amplitude: f64,
    keep_cols: bool,
) -> BankFit {
    let (cols, (r_mat, b, rest)) = if keep_cols {
        let cols: Vec<Vec<f64>> = rs.iter().map(|&r| play_deviation(x, r)).collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let reduced = basis.reduce(&refs);
        (cols, reduced)
    } else {
        let on_rows = rs
            .iter()
            .map(|&r| play_deviation_at(x, r, &basis.rows))
            .collect();
        (Vec::new(), basis.reduce_gathered(on_rows))
    };
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
    let (mp, mn) = (misfit(&r_mat, &w_pos), misfit(&neg, &w_neg));
    let (weights, sense, m) = if mp <= mn {
        (w_pos, 1.0, mp)
    } else {
        (w_neg, -1.0, mn)
    };
    BankFit {
        misfit: m,
        sense,
        weights: weights.iter().map(|w| w * sense).collect(),
        thresholds: rs,
        cols,
        amplitude,
    }
}

/// The thresholds of alternative grids (r = A(i/m)^p for other m and p): the half-width's
/// spread over them is the part of its uncertainty the choice of grid brings.
fn alternative_grids(amplitude: f64) -> Vec<Vec<f64>> {
    [(9usize, 2.0f64), (16, 2.0), (12, 1.5), (12, 2.5)]
        .iter()
        .map(|&(m, p)| {
            (1..=m)
                .map(|i| amplitude * (i as f64 / m as f64).powf(p))
                .collect()
        })
        .collect()
}

/// The best bank so far: its fit, the auxiliary drive's name (None for the command), the
/// drive's own static columns and the search basis with them.
type BestDrive = (
    BankFit,
    Option<String>,
    Vec<Vec<f64>>,
    crate::explain::search::Basis,
);

impl contract::Candidate for Candidate {
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
        !drives(d, ch).is_empty()
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let mut best: Option<BestDrive> = None;
        for (drive, x) in drives(s.d, s.ch) {
            let lo = x.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let amplitude = 0.5 * (hi - lo);
            if amplitude.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                continue;
            }
            // an auxiliary drive brings its own static response (the baseline's polynomial is
            // in the command)
            let poly = if drive.is_some() {
                drive_poly(&x)
            } else {
                Vec::new()
            };
            let mut basis = s.basis.clone();
            for c in &poly {
                basis.add_column(c);
            }
            let fit = fit_bank(&basis, &x, thresholds_um(amplitude), amplitude, true);
            if best.as_ref().is_none_or(|b| fit.misfit < b.0.misfit) {
                best = Some((fit, drive, poly, basis));
            }
        }
        let Some((fit, drive, poly, basis)) = best else {
            return Ok(None);
        };
        let active: Vec<usize> = (0..fit.weights.len())
            .filter(|&j| fit.weights[j] != 0.0)
            .collect();
        if active.is_empty() {
            return Ok(None);
        }
        let amplitude_um = fit.amplitude;
        let sense = fit.sense;
        let rs = &fit.thresholds;
        // σ of the half-width per unit noise: solve Rᵀg = c on the active operators' reduction
        let act: Vec<&[f64]> = active.iter().map(|&j| fit.cols[j].as_slice()).collect();
        let (ra, _, _) = basis.reduce(&act);
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
        // the grid's share of the uncertainty: the half-width over other threshold grids
        let x: Vec<f64> = match &drive {
            None => s.d.channels[s.ch].cmd_um.clone().unwrap_or_default(),
            Some(name) => {
                s.d.aux
                    .iter()
                    .find(|a| &a.0 == name)
                    .map(|a| a.1.clone())
                    .unwrap_or_default()
            }
        };
        let own = full_loop_half_width_um(rs, &fit.weights, amplitude_um);
        let others: Vec<f64> = alternative_grids(amplitude_um)
            .into_iter()
            .map(|grid| {
                let f = fit_bank(&basis, &x, grid, amplitude_um, false);
                full_loop_half_width_um(&f.thresholds, &f.weights, amplitude_um)
            })
            .collect();
        let grid_spread_um = (others.iter().map(|h| (h - own).powi(2)).sum::<f64>()
            / others.len().max(1) as f64)
            .sqrt();
        let mut regs = poly.clone();
        regs.extend(active.iter().map(|&j| fit.cols[j].clone()));
        Ok(Some(Proposal {
            regs: regs.into_iter().map(std::sync::Arc::new).collect(),
            thetas: Vec::new(),
            detail: Detail::Play(PlayBank {
                axis: s.ch,
                drive,
                leading_poly: poly.len(),
                thresholds_um: active.iter().map(|&j| rs[j]).collect(),
                sense,
                amplitude_um,
                half_width_per_noise,
                grid_spread_um,
            }),
            design: None,
            evidence_units: Some(reversals(&x) as f64),
        }))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let Detail::Play(bank) = &f.proposal.detail else {
            return Vec::new();
        };
        let a = bank.amplitude_um;
        let w = &f.coeffs[bank.leading_poly..];
        let hw = full_loop_half_width_um(&bank.thresholds_um, w, a);
        let hw_sigma = (f.noise_sigma_um * bank.half_width_per_noise).hypot(bank.grid_spread_um);
        vec![
            Estimate::new("half_width_nm", hw * 1e3, hw_sigma * 1e3),
            Estimate::new("loop_sense", bank.sense, f64::NAN),
            Estimate::new("operators", bank.thresholds_um.len() as f64, f64::NAN),
            Estimate::new(
                if bank.drive.is_some() {
                    "drive_stroke"
                } else {
                    "stroke_um"
                },
                2.0 * a,
                f64::NAN,
            ),
        ]
    }
    fn summary(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> String {
        let Detail::Play(bank) = &f.proposal.detail else {
            return String::new();
        };
        let w = &f.coeffs[bank.leading_poly..];
        let hw = full_loop_half_width_um(&bank.thresholds_um, w, bank.amplitude_um);
        let sense = if bank.sense > 0.0 {
            "counter-clockwise loop (measured vs commanded): the response lags the command — on the way up the stage stays below where it is on the way down, as a piezo's does"
        } else {
            "clockwise loop (measured vs commanded): the response leads the command — on the way up the stage is above where it is on the way down"
        };
        let ops: Vec<String> = bank
            .thresholds_um
            .iter()
            .zip(w)
            .map(|(r, w)| format!("{:.3} × {:.4}", r, w))
            .collect();
        let fed = match &bank.drive {
            None => "fed by the command (thresholds in µm)".to_string(),
            Some(name) => format!(
                "fed by `{name}`, which carries the drive (thresholds in its unit; the loop against the command is not what the stage does) — the compensator can run it only once it reads that channel"
            ),
        };
        format!(
            "{sense}; full-stroke loop half-width {} at mid-stroke; {} play operators {fed} (threshold × weight): {}",
            length_um(hw),
            ops.len(),
            ops.join(", ")
        )
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        let Detail::Play(bank) = &f.proposal.detail else {
            return None;
        };
        // the compensator's bank is fed by the axis' target: only a loop on the command deploys
        if bank.drive.is_some() {
            return None;
        }
        let plays: Vec<(u8, f64)> = bank
            .thresholds_um
            .iter()
            .map(|&r| (ctx.output, r))
            .collect();
        Some(contract::BlobTerms {
            lags: Vec::new(),
            terms: (0..plays.len() as u8)
                .map(|k| contract::term(ctx.output, [0; 3], nanocal_model::Factor::Play(k), 0))
                .collect(),
            plays,
            play: bank
                .thresholds_um
                .iter()
                .zip(f.coeffs)
                .map(|(&threshold_um, &weight)| contract::PlayOperator {
                    axis: ctx.output,
                    threshold_um,
                    weight,
                })
                .collect(),
        })
    }
}
