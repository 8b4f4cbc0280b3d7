//! Fitting and scoring model extensions: least squares (the host's Householder QR), blocked
//! cross-validation with a held-out design, an information criterion corrected for
//! autocorrelated residuals.

use crate::numerics::linalg::{lstsq, LeastSquares};

use super::error::ExplainError;
use super::parallel::in_parallel;
use super::stats::{centred_mean, median};

/// Number of contiguous time blocks of the default held-out design.
pub const CV_BLOCKS: usize = 80;
/// Number of folds: block b belongs to fold b mod CV_FOLDS (interleaved, so every fold spans
/// the whole recording and held-out blocks are short against slow structure).
pub const CV_FOLDS: usize = 5;

/// A held-out design: contiguous blocks of time, interleaved into folds.
#[derive(Clone, Debug, PartialEq)]
pub struct Design {
    /// Fold of each row.
    pub fold_of: Vec<u8>,
    /// Number of folds.
    pub folds: usize,
    /// Length of one held-out block, s.
    pub gap_s: f64,
}

impl Design {
    /// `blocks` contiguous blocks of equal duration (by time, so irregular sampling and gaps
    /// in the log do not shift them), block b in fold b mod `folds`.
    pub fn blocks(t_s: &[f64], blocks: usize, folds: usize) -> Self {
        let blocks = blocks.max(2);
        let folds = folds.clamp(2, blocks).min(u8::MAX as usize);
        let t0 = t_s.first().copied().unwrap_or(0.0);
        let span = (t_s.last().copied().unwrap_or(0.0) - t0).max(f64::MIN_POSITIVE);
        let fold_of = t_s
            .iter()
            .map(|&t| {
                let b = (((t - t0) / span * blocks as f64) as usize).min(blocks - 1);
                (b % folds) as u8
            })
            .collect();
        Self {
            fold_of,
            folds,
            gap_s: span / blocks as f64,
        }
    }

    /// The default design: [`CV_BLOCKS`] blocks in [`CV_FOLDS`] folds.
    pub fn standard(t_s: &[f64]) -> Self {
        Self::blocks(t_s, CV_BLOCKS.min(t_s.len() / 4).max(CV_FOLDS), CV_FOLDS)
    }

    /// Folds that must improve for a candidate to count: all but one of five (4 of 5), all
    /// but one of fewer.
    pub fn folds_needed(&self, of_five: usize) -> usize {
        if self.folds == CV_FOLDS {
            of_five
        } else {
            (self.folds * of_five).div_ceil(CV_FOLDS).min(self.folds)
        }
    }
}

/// A fitted linear model on named columns (an intercept is always in).
#[derive(Clone, Debug)]
pub struct Fit {
    /// The least-squares solution.
    pub ls: LeastSquares,
    /// Residuals over all rows, µm (NaN where the response is missing: outliers).
    pub residuals: Vec<f64>,
    /// Residual sum of squares over the rows fitted, µm².
    pub rss: f64,
    /// Rows fitted.
    pub n: usize,
}

/// Values of `x` at `rows`.
pub fn gather(x: &[f64], rows: &[usize]) -> Vec<f64> {
    rows.iter().map(|&i| x[i]).collect()
}

/// Rows the selection fits on: those with a finite response, every k-th of them when there are
/// more than `max_rows` (a 1 kHz log over-samples everything explain looks at).
pub fn eval_rows(y: &[f64], max_rows: usize) -> Vec<usize> {
    let finite: Vec<usize> = (0..y.len()).filter(|&i| y[i].is_finite()).collect();
    let k = finite.len().div_ceil(max_rows.max(1)).max(1);
    finite.into_iter().step_by(k).collect()
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

/// Rows per block of [`predict_block`]: its sums stay in the L1 cache.
const PREDICT_BLOCK: usize = 1024;
/// Blocks per span of rows [`fit_rows`] hands a core at a time.
const PREDICT_BLOCKS_PER_SPAN: usize = 64;

/// Predictions of `ls` at rows `a..a + out.len()` into `out`, every row summed exactly as
/// [`predict`] sums it (the same terms in the same order, from the same neutral element), but
/// a column at a time over a block of rows: contiguous loads instead of one load per column
/// and row.
fn predict_block(ls: &LeastSquares, cols: &[&[f64]], a: usize, out: &mut [f64]) {
    let b = a + out.len();
    // the neutral element `Sum` starts from (-0.0 today), so every zero keeps its sign
    let zero: f64 = std::iter::empty::<f64>().sum();
    out.fill(zero);
    for (c, &coeff) in cols.iter().zip(&ls.coeffs) {
        if coeff != 0.0 {
            for (o, v) in out.iter_mut().zip(&c[a..b]) {
                *o += coeff * v;
            }
        } else {
            // `predict` adds a literal 0 for a dropped column
            for o in out.iter_mut() {
                *o += 0.0;
            }
        }
    }
    // intercept + sum, as `predict` (IEEE addition commutes exactly)
    for o in out.iter_mut() {
        *o += ls.intercept;
    }
}

/// Least squares of `y` on `cols` plus an intercept, fitted on `rows`; residuals for every row
/// with a finite response.
pub fn fit_rows(cols: &[&[f64]], y: &[f64], rows: &[usize]) -> Result<Fit, ExplainError> {
    let all = rows.len() == y.len();
    let ls = if all {
        lstsq(cols, y, true)?
    } else {
        let g: Vec<Vec<f64>> = cols.iter().map(|c| gather(c, rows)).collect();
        let refs: Vec<&[f64]> = g.iter().map(|c| c.as_slice()).collect();
        lstsq(&refs, &gather(y, rows), true)?
    };
    let mut residuals = vec![f64::NAN; y.len()];
    // each row's residual is its own: spans of rows side by side where a core is idle
    let span = PREDICT_BLOCK * PREDICT_BLOCKS_PER_SPAN;
    let spans: Vec<(usize, std::sync::Mutex<&mut [f64]>)> = residuals
        .chunks_mut(span)
        .enumerate()
        .map(|(k, r)| (k * span, std::sync::Mutex::new(r)))
        .collect();
    in_parallel(&spans, |(start, out)| {
        let mut out = out.lock().unwrap_or_else(|e| e.into_inner());
        let mut buf = [0.0; PREDICT_BLOCK];
        for (k, res) in out.chunks_mut(PREDICT_BLOCK).enumerate() {
            let a = start + k * PREDICT_BLOCK;
            let b = a + res.len();
            let pred = &mut buf[..b - a];
            predict_block(&ls, cols, a, pred);
            for ((r, &yi), &p) in res.iter_mut().zip(&y[a..b]).zip(pred.iter()) {
                if yi.is_finite() {
                    *r = yi - p;
                }
            }
        }
    });
    drop(spans);
    let rss = ls.rss;
    let n = rows.len();
    Ok(Fit {
        ls,
        residuals,
        rss,
        n,
    })
}

/// Least squares on every row (the response's NaN rows are left out).
pub fn fit(cols: &[&[f64]], y: &[f64]) -> Result<Fit, ExplainError> {
    let rows: Vec<usize> = (0..y.len()).filter(|&i| y[i].is_finite()).collect();
    fit_rows(cols, y, &rows)
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
    let slow = centred_mean(&v, half);
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

/// Autocorrelation of `x` (mean removed) at lag `k` rows.
fn autocorrelation(x: &[f64], var: f64, k: usize) -> f64 {
    if k >= x.len() || var <= 0.0 {
        return 0.0;
    }
    let s: f64 = x[..x.len() - k]
        .iter()
        .zip(&x[k..])
        .map(|(a, b)| a * b)
        .sum();
    s / (x.len() as f64 * var)
}

fn centred(x: &[f64]) -> (Vec<f64>, f64) {
    let n = x.len().max(1);
    let m = x.iter().sum::<f64>() / n as f64;
    let c: Vec<f64> = x.iter().map(|v| v - m).collect();
    let var = c.iter().map(|v| v * v).sum::<f64>() / n as f64;
    (c, var)
}

/// 1 + 2 Σ_{k≥1} p(k) for a correlation sequence p with p(0) = 1: the sum runs while p stays
/// positive (the initial positive sequence), evaluated on a geometric ladder of lags (each
/// 1.5× the last) and integrated by the trapezoid rule up to the zero crossing.
fn correlation_time(n: usize, p: impl Fn(usize) -> f64) -> f64 {
    let mut sum = 0.0;
    let (mut prev_k, mut prev_p) = (0usize, 1.0f64);
    let mut k = 1usize;
    while k < n / 2 {
        let pk = p(k);
        if pk <= 0.0 {
            let zero = prev_k as f64 + (k - prev_k) as f64 * prev_p / (prev_p - pk);
            sum += 0.5 * prev_p * (zero - prev_k as f64);
            break;
        }
        sum += 0.5 * (prev_p + pk) * (k - prev_k) as f64;
        prev_k = k;
        prev_p = pk;
        k = (k + 1).max((k as f64 * 1.5) as usize);
    }
    // the trapezoid from lag 0 counted half of p(0) = 1 into the first step
    (1.0 + 2.0 * (sum - 0.5).max(0.0)).max(1.0)
}

/// Effective number of independent rows behind the association of two series (Bartlett 1935;
/// Bretherton et al., J. Climate 12, 1999, Eq. 31): n / (1 + 2 Σₖ ρₐ(k) ρ_b(k)) (see
/// [`correlation_time`]). Two smooth series (a slow drift and a long lag of a temperature)
/// share few independent values however finely they are sampled — the reason a smooth
/// regressor must explain much of a smooth residual before it counts; a fast one (a direction
/// pattern, a fringe) keeps almost every row.
pub fn bartlett_n_eff(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n < 10 {
        return n as f64;
    }
    let (ca, va) = centred(&a[..n]);
    let (cb, vb) = centred(&b[..n]);
    let tau = correlation_time(n, |k| {
        autocorrelation(&ca, va, k) * autocorrelation(&cb, vb, k)
    });
    (n as f64 / tau).clamp(2.0, n as f64)
}

/// Bayesian information criterion with an effective sample size: n_eff ln(RSS/n) + k ln n_eff.
pub fn bic(rss: f64, n: usize, k: usize, n_eff: f64) -> f64 {
    n_eff * (rss / n as f64).max(1e-300).ln() + k as f64 * n_eff.max(2.0).ln()
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

impl Cv {
    /// Folds in which `self` predicts better than `other`.
    pub fn folds_better_than(&self, other: &Cv) -> usize {
        self.fold_mse
            .iter()
            .zip(&other.fold_mse)
            .filter(|(a, b)| a < b)
            .count()
    }
}

/// Blocked cross-validation of `y` on `cols` plus an intercept: for each fold, fitted on the
/// `rows` outside it, predicting every row inside it.
pub fn cross_validate(
    cols: &[&[f64]],
    y: &[f64],
    design: &Design,
    rows: &[usize],
) -> Result<Cv, ExplainError> {
    let mut residuals = vec![f64::NAN; y.len()];
    let score = held_out(cols, y, design, rows, Some(&mut residuals))?;
    Ok(Cv {
        residuals,
        fold_mse: score.fold_mse,
        rms_um: score.rms_um,
    })
}

/// The held-out scores of [`cross_validate`] without its residual per row: the same numbers,
/// bit for bit, for a caller that compares models only (on a million-row log the residuals
/// are an 8 MB vector written and dropped per call).
#[derive(Clone, Debug)]
pub struct CvScore {
    /// Held-out mean square per fold, µm².
    pub fold_mse: Vec<f64>,
    /// Held-out RMS over all rows, µm.
    pub rms_um: f64,
}

/// [`cross_validate`]'s scores alone (see [`CvScore`]).
pub fn cross_validate_score(
    cols: &[&[f64]],
    y: &[f64],
    design: &Design,
    rows: &[usize],
) -> Result<CvScore, ExplainError> {
    held_out(cols, y, design, rows, None)
}

/// Blocked cross-validation (see [`cross_validate`]), writing each row's held-out residual
/// into `residuals` when given (left as it is where the residual is not finite).
fn held_out(
    cols: &[&[f64]],
    y: &[f64],
    design: &Design,
    rows: &[usize],
    mut residuals: Option<&mut Vec<f64>>,
) -> Result<CvScore, ExplainError> {
    let n = y.len();
    // the columns on `rows` once (scattered reads), each fold's training rows from those
    let on_rows: Vec<Vec<f64>> = cols.iter().map(|c| gather(c, rows)).collect();
    let y_rows = gather(y, rows);
    let mut fits = Vec::with_capacity(design.folds);
    for f in 0..design.folds {
        let train: Vec<usize> = (0..rows.len())
            .filter(|&k| design.fold_of[rows[k]] as usize != f)
            .collect();
        let g: Vec<Vec<f64>> = on_rows.iter().map(|c| gather(c, &train)).collect();
        let refs: Vec<&[f64]> = g.iter().map(|c| c.as_slice()).collect();
        fits.push(lstsq(&refs, &gather(&y_rows, &train), true)?);
    }
    drop(on_rows);
    // one pass over the rows, each predicted by its fold's fit (runs of one fold, in blocks);
    // every fold's sum grows in row order, as fold by fold, and so does the sum over all rows
    // (as [`rms`] sums the residuals: from 0.0, in row order, the finite ones)
    let mut sums = vec![(0.0f64, 0usize); design.folds];
    let (mut total, mut count) = (0.0f64, 0usize);
    let mut buf = [0.0; PREDICT_BLOCK];
    let mut a = 0;
    while a < n {
        let f = design.fold_of[a] as usize;
        let mut b = a + 1;
        while b < n && b - a < PREDICT_BLOCK && design.fold_of[b] as usize == f {
            b += 1;
        }
        let pred = &mut buf[..b - a];
        predict_block(&fits[f], cols, a, pred);
        let (s, c) = &mut sums[f];
        for (k, (&yi, &p)) in y[a..b].iter().zip(pred.iter()).enumerate() {
            let r = yi - p;
            if r.is_finite() {
                if let Some(res) = residuals.as_deref_mut() {
                    res[a + k] = r;
                }
                *s += r * r;
                *c += 1;
                total += r * r;
                count += 1;
            }
        }
        a = b;
    }
    let fold_mse: Vec<f64> = sums
        .iter()
        .map(|&(s, c)| if c > 0 { s / c as f64 } else { f64::NAN })
        .collect();
    let rms_um = if count == 0 {
        f64::NAN
    } else {
        (total / count as f64).sqrt()
    };
    Ok(CvScore { fold_mse, rms_um })
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

/// Robust scale of the sample-to-sample scatter of `r` (1.4826·MAD of first differences / √2),
/// µm; rows where `changed` is false (a held reading repeated) are skipped.
pub fn noise_floor(r: &[f64], changed: Option<&[bool]>) -> f64 {
    let mut d: Vec<f64> = (1..r.len())
        .filter(|&i| changed.is_none_or(|c| c[i]))
        .map(|i| r[i] - r[i - 1])
        .filter(|x| x.is_finite())
        .collect();
    if d.is_empty() {
        return f64::NAN;
    }
    let med = median(&mut d);
    let mut dev: Vec<f64> = d.iter().map(|x| (x - med).abs()).collect();
    1.4826 * median(&mut dev) / std::f64::consts::SQRT_2
}
