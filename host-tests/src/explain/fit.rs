//! Fitting and scoring model extensions: least squares (the host's Householder QR), blocked
//! cross-validation, an information criterion corrected for autocorrelated residuals.

use crate::linalg::{lstsq, LeastSquares};

use super::ExplainError;

/// Number of contiguous time blocks the recording is cut into for cross-validation.
pub const CV_BLOCKS: usize = 80;
/// Number of folds: block b belongs to fold b mod CV_FOLDS (interleaved, so every fold spans
/// the whole recording and held-out blocks are short against slow structure).
pub const CV_FOLDS: usize = 5;

/// A fitted linear model on named columns (an intercept is always in).
#[derive(Clone, Debug)]
pub struct Fit {
    /// The least-squares solution.
    pub ls: LeastSquares,
    /// Residuals, µm (NaN where a row was left out).
    pub residuals: Vec<f64>,
    /// Residual sum of squares, µm².
    pub rss: f64,
    /// Rows used.
    pub n: usize,
    /// Effective number of independent rows of the residuals (batch means, see [`effective_n`]).
    pub n_eff: f64,
}

/// Least squares of `y` on `cols` plus an intercept.
pub fn fit(cols: &[&[f64]], y: &[f64]) -> Result<Fit, ExplainError> {
    let ls = lstsq(cols, y, true)?;
    let residuals = ls.residuals.clone();
    let n = residuals.iter().filter(|v| v.is_finite()).count();
    let rss = ls.rss;
    let n_eff = effective_n(&residuals);
    Ok(Fit {
        ls,
        residuals,
        rss,
        n,
        n_eff,
    })
}

/// Prediction of a fitted model at row `i`.
pub fn predict(ls: &LeastSquares, cols: &[&[f64]], i: usize) -> f64 {
    ls.intercept
        + cols
            .iter()
            .zip(&ls.coeffs)
            .map(|(c, b)| if *b != 0.0 { b * c[i] } else { 0.0 })
            .sum::<f64>()
}

/// Effective number of independent rows of a residual `r` (NaN skipped): n / τ_int, with the
/// integrated autocorrelation time τ_int from batch means (40 batches), which also sees
/// correlation longer than one sample (a positioning scatter held over a whole dwell).
pub fn effective_n(r: &[f64]) -> f64 {
    let v: Vec<f64> = r.iter().copied().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n < 80 {
        return n as f64;
    }
    let m = v.iter().sum::<f64>() / n as f64;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n as f64;
    if var <= 0.0 {
        return n as f64;
    }
    let batches = 40;
    let b = n / batches;
    let bm: Vec<f64> = (0..batches)
        .map(|k| v[k * b..(k + 1) * b].iter().sum::<f64>() / b as f64)
        .collect();
    let bmm = bm.iter().sum::<f64>() / batches as f64;
    let bvar = bm.iter().map(|x| (x - bmm) * (x - bmm)).sum::<f64>() / (batches - 1) as f64;
    let tau = (b as f64 * bvar / var).max(1.0);
    (n as f64 / tau).clamp(10.0_f64.min(n as f64), n as f64)
}

/// Effective number of independent rows for comparing models in one naming round: from the
/// lag-1 autocorrelation ρ of the current residual after removing its slow part (a centred
/// moving average over 1/80 of the record), n(1−ρ)/(1+ρ), and at most `units` (the number of
/// independent positioning events, e.g. dwells). The same value is used for every candidate of a
/// round, so a candidate cannot win by whitening its own residual.
pub fn round_effective_n(r: &[f64], units: usize) -> f64 {
    let v: Vec<f64> = r.iter().copied().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n < 10 {
        return n as f64;
    }
    let half = (n / 160).max(1);
    let slow = crate::explain::data::centred_mean(&v, half);
    let hp: Vec<f64> = v.iter().zip(&slow).map(|(a, b)| a - b).collect();
    let c0: f64 = hp.iter().map(|x| x * x).sum();
    let c1: f64 = hp.windows(2).map(|w| w[0] * w[1]).sum();
    let rho = if c0 > 0.0 {
        (c1 / c0).clamp(0.0, 0.999)
    } else {
        0.0
    };
    // Smooth real residuals (sensor-limited, ρ → 1) would drive n_eff to a handful; the
    // blocked cross-validation already treats its 2·CV_BLOCKS half-blocks as independent, so
    // that is the floor (never above the number of units).
    let cap = units.max(10).min(n) as f64;
    let floor = ((2 * CV_BLOCKS) as f64).min(cap);
    (n as f64 * (1.0 - rho) / (1.0 + rho)).clamp(floor, cap)
}

/// Bayesian information criterion with an effective sample size: n_eff ln(RSS/n) + k ln n_eff.
pub fn bic(rss: f64, n: usize, k: usize, n_eff: f64) -> f64 {
    n_eff * (rss / n as f64).max(1e-300).ln() + k as f64 * n_eff.max(2.0).ln()
}

/// The fold of each row: interleaved contiguous blocks.
pub fn folds(n: usize) -> Vec<u8> {
    (0..n)
        .map(|i| ((i * CV_BLOCKS / n.max(1)) % CV_FOLDS) as u8)
        .collect()
}

/// Held-out result of blocked cross-validation.
#[derive(Clone, Debug)]
pub struct Cv {
    /// Held-out residual per row, µm (each row predicted by the model fitted without its fold).
    pub residuals: Vec<f64>,
    /// Held-out mean square per fold, µm².
    pub fold_mse: Vec<f64>,
    /// Held-out RMS over all rows, µm.
    pub rms_um: f64,
}

/// Blocked cross-validation of `y` on `cols` plus an intercept.
pub fn cross_validate(cols: &[&[f64]], y: &[f64], fold_of: &[u8]) -> Result<Cv, ExplainError> {
    let n = y.len();
    let mut residuals = vec![f64::NAN; n];
    let mut fold_mse = vec![0.0; CV_FOLDS];
    let mut ym = vec![0.0; n];
    for f in 0..CV_FOLDS as u8 {
        for i in 0..n {
            ym[i] = if fold_of[i] == f { f64::NAN } else { y[i] };
        }
        let ls = lstsq(cols, &ym, true)?;
        let (mut s, mut c) = (0.0, 0usize);
        for i in (0..n).filter(|&i| fold_of[i] == f) {
            let r = y[i] - predict(&ls, cols, i);
            if r.is_finite() {
                residuals[i] = r;
                s += r * r;
                c += 1;
            }
        }
        fold_mse[f as usize] = if c > 0 { s / c as f64 } else { f64::NAN };
    }
    let rms_um = rms(&residuals);
    Ok(Cv {
        residuals,
        fold_mse,
        rms_um,
    })
}

/// RMS of the finite values.
pub fn rms(v: &[f64]) -> f64 {
    let (s, c) = v
        .iter()
        .filter(|x| x.is_finite())
        .fold((0.0, 0usize), |(s, c), x| (s + x * x, c + 1));
    if c == 0 {
        f64::NAN
    } else {
        (s / c as f64).sqrt()
    }
}

/// Noise floor from the data: the high-frequency scatter of `r` (robust: 1.4826·MAD of first
/// differences / √2), µm.
pub fn noise_floor(r: &[f64]) -> f64 {
    let mut d: Vec<f64> = r
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|x| x.is_finite())
        .collect();
    if d.is_empty() {
        return f64::NAN;
    }
    let med = median(&mut d);
    let mut dev: Vec<f64> = d.iter().map(|x| (x - med).abs()).collect();
    1.4826 * median(&mut dev) / std::f64::consts::SQRT_2
}

/// Median (reorders the slice).
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    v.select_nth_unstable_by(m, f64::total_cmp);
    v[m]
}
