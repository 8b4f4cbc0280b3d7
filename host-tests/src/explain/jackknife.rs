//! Honest uncertainties for what a named effect's model is nonlinear in: a delete-one-block
//! jackknife over time.
//!
//! The profile of the residual sum of squares gives a θ (a time constant, a creep t0, the
//! thresholds of a play bank) a 1σ that is right only when the residual is white and the
//! model's form is right; with slow, autocorrelated residuals, and with linear coefficients
//! that trade off against θ (creep's γ against t0), it comes out several times too small.
//! Deleting one contiguous time block at a time, searching the candidate's parameters again on
//! what is left and reading its parameters off the refit measures the spread the data really
//! allow: autocorrelation within a block is kept whole, and the linear coefficients move with
//! the nonlinear ones.

use super::contract::{Candidate, Detail, Fitted, Proposal};
use super::estimate::Estimate;

use super::fit::{fit_rows, Design};
use super::search::{Basis, Search};
use super::{in_parallel, Data, ExplainError};

/// Contiguous time blocks deleted one at a time.
pub const BLOCKS: usize = 8;

/// Largest recording (rows × (temperatures + 1), the cost of a thermal-lag search) the
/// jackknife is run on: each block searches the candidate's parameters again, so it costs
/// [`BLOCKS`] more searches of the named effect. Beyond it the profile's σ is stated alone.
pub const MAX_COST: usize = 1_500_000;

/// Whether the model is nonlinear in something of `p` (searched parameters, lag terms, play
/// thresholds): what the jackknife is for.
pub fn nonlinear(p: &Proposal) -> bool {
    !p.thetas.is_empty() || matches!(p.detail, Detail::Lags(_) | Detail::Play(_))
}

/// Whether the jackknife is cheap enough on `d` (see [`MAX_COST`]).
pub fn affordable(d: &Data) -> bool {
    d.rows().saturating_mul(d.temps.len() + 1) <= MAX_COST
}

/// The jackknife 1σ of each of `full` (the parameters on all rows) that has a stated σ, by
/// name; None where a block's search found nothing, the name did not come back from every
/// block, or a value is not finite.
///
/// Block b of [`BLOCKS`] is the b-th contiguous share of `rows` (ascending in time); on the
/// rows outside it, `cand` searches its parameters again on top of `model` (the model it was
/// named on), the extension is refitted, and its parameters are read as on all rows
/// (`full_fit`: under the names that fit gave them, see [`Candidate::replicate_params`]). The
/// jackknife variance is (B − 1)/B Σ (θ_b − θ̄)².
#[allow(clippy::too_many_arguments)]
pub fn sigmas(
    d: &Data,
    ch: usize,
    model: &[&[f64]],
    y: &[f64],
    rows: &[usize],
    design: &Design,
    n_eff: f64,
    cand: &dyn Candidate,
    full_fit: &Fitted,
    full: &[Estimate],
) -> Result<Vec<Option<f64>>, ExplainError> {
    let n = rows.len();
    if n < 10 * BLOCKS {
        return Ok(vec![None; full.len()]);
    }
    let blocks: Vec<usize> = (0..BLOCKS).collect();
    let replicates = in_parallel(
        &blocks,
        |&b| -> Result<Option<Vec<Estimate>>, ExplainError> {
            let (a, e) = (b * n / BLOCKS, (b + 1) * n / BLOCKS);
            let kept: Vec<usize> = rows[..a].iter().chain(&rows[e..]).copied().collect();
            let s = Search {
                d,
                ch,
                y,
                model: model.to_vec(),
                basis: Basis::new(model, y, kept.clone()),
                n_eff,
                design,
                sigmas: false,
            };
            let Some(p) = cand.propose(&s)? else {
                return Ok(None);
            };
            let cols: Vec<&[f64]> = model
                .iter()
                .copied()
                .chain(p.regs.iter().map(|c| c.as_slice()))
                .collect();
            let f = fit_rows(&cols, y, &kept)?;
            let m = model.len();
            let se = f.ls.std_errors();
            let fitted = Fitted {
                proposal: &p,
                coeffs: &f.ls.coeffs[m..],
                se: &se[m..],
                noise_sigma_um: f.ls.rmse(),
            };
            Ok(Some(cand.replicate_params(d, ch, full_fit, &fitted)))
        },
    );
    let mut reps: Vec<Vec<Estimate>> = Vec::with_capacity(BLOCKS);
    for r in replicates {
        match r? {
            Some(p) => reps.push(p),
            None => return Ok(vec![None; full.len()]),
        }
    }
    Ok(full
        .iter()
        .map(|est| {
            if !(est.sigma.is_finite() && est.sigma > 0.0) {
                return None;
            }
            let vals: Vec<f64> = reps
                .iter()
                .filter_map(|r| r.iter().find(|e| e.name == est.name).map(|e| e.value))
                .filter(|v| v.is_finite())
                .collect();
            if vals.len() != BLOCKS {
                return None;
            }
            let b = BLOCKS as f64;
            let mean = vals.iter().sum::<f64>() / b;
            let ss: f64 = vals.iter().map(|v| (v - mean) * (v - mean)).sum();
            Some(((b - 1.0) / b * ss).sqrt())
        })
        .collect())
}
