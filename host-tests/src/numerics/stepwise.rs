//! Stepwise linear regression with exactly MATLAB `stepwisefit` semantics.
//!
//! - The constant term is always in the model (not a column; reported as `intercept`).
//! - Start from `inmodel` (default: empty). Each step: among the excluded columns that are not
//!   kept, take the smallest p-value; if it is below `penter`, add that column. Otherwise, among
//!   the included columns that are not kept, take the largest p-value; if above `premove`,
//!   remove it. One change per step; stop when nothing changes or after `maxiter` steps.
//! - p-values are two-sided t tests (equal to the partial F test): for an included column in the
//!   current model (`dfe` degrees of freedom), for an excluded one as if it alone were added
//!   (`dfe − 1`). They come from the regularized incomplete beta function and may underflow to
//!   exactly 0; ties go to the lowest column index, as MATLAB's `min`/`max` do. NaN p-values are
//!   ignored by the ranking (as `min` ignores NaN); an included column with a NaN p-value (rank
//!   deficiency, perfect fit) is removed first.
//! - Columns are divided by their standard deviation internally (not centred); coefficients are
//!   reported in original units. Rows with a NaN anywhere are left out.
//!
//! Numerics: QR, never normal equations. The data `[1 X y]` are compressed once by a streaming
//! Householder QR to their `(p+2) × (p+2)` triangular factor `R` ([`crate::numerics::linalg::compress`],
//! O(n p²), multi-threaded). Because `[1 X y] = Q R` with orthonormal `Q`, every regression on a
//! subset of the columns — coefficients, residual norms, added-variable projections, `(XᵀX)⁻¹` —
//! is the same computed on the columns of `R`, so each step is a pivoted Householder QR of a
//! `(p+2) × |in|` matrix, independent of n. The column standard deviations come from `R` too
//! (`‖x_j − x̄_j‖² = Σ_{i≥1} R_ij²` since column 0 is the constant).

#![allow(clippy::needless_range_loop)] // index loops read best in numerical kernels

use crate::numerics::linalg::{compress, Compressed, Mat, PivotedQr};
use crate::numerics::stats::t_pvalue_two_sided;

/// Errors of [`stepwise`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StepwiseError {
    /// An option is out of range.
    #[error("invalid option: {0}")]
    BadOption(String),
    /// Column lengths differ.
    #[error("candidate column {column} has {found} rows, expected {expected} (the response's)")]
    LengthMismatch {
        /// 0-based column.
        column: usize,
        /// Rows of the response.
        expected: usize,
        /// Rows of the column.
        found: usize,
    },
    /// No row without NaN.
    #[error("expected at least 2 rows without NaN, found {0}")]
    TooFewRows(usize),
}

/// Options of [`stepwise`], named as in MATLAB.
#[derive(Debug, Clone, Default)]
pub struct StepwiseOptions {
    /// p-value to enter (default 0.05, or `min(premove, 0.05)` when only premove is given).
    pub penter: Option<f64>,
    /// p-value to remove (default `max(penter, 0.10)`).
    pub premove: Option<f64>,
    /// Maximum number of steps (default: unlimited).
    pub maxiter: Option<usize>,
    /// 0-based columns in the initial model.
    pub inmodel: Vec<usize>,
    /// 0-based columns whose status (in or out) never changes.
    pub keep: Vec<usize>,
    /// Threads for the compression pass (default: available parallelism).
    pub threads: Option<usize>,
}

impl StepwiseOptions {
    /// Threads for the compression pass: `threads`, else the available parallelism.
    pub fn thread_count(&self) -> usize {
        self.threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |t| t.get()))
    }

    /// The effective `(penter, premove)` with MATLAB's defaults, validated.
    pub fn thresholds(&self) -> Result<(f64, f64), StepwiseError> {
        let (pe, pr) = match (self.penter, self.premove) {
            (None, None) => (0.05, 0.10),
            (None, Some(pr)) => (pr.min(0.05), pr),
            (Some(pe), None) => (pe, pe.max(0.10)),
            (Some(pe), Some(pr)) => (pe, pr),
        };
        for (name, v) in [("penter", pe), ("premove", pr)] {
            if !(v > 0.0 && v < 1.0) {
                return Err(StepwiseError::BadOption(format!(
                    "{name} must lie in (0, 1), found {v}"
                )));
            }
        }
        if pe > pr {
            return Err(StepwiseError::BadOption(format!(
                "penter must be <= premove, found penter {pe} > premove {pr}"
            )));
        }
        Ok((pe, pr))
    }
}

/// One change of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// The 0-based column was added.
    Added(usize),
    /// The 0-based column was removed.
    Removed(usize),
}

/// One step of the history.
#[derive(Debug, Clone)]
pub struct Step {
    /// What changed.
    pub action: Action,
    /// The p-value that triggered it (NaN for a forced removal of a rank-deficient column).
    pub p: f64,
    /// Columns in the model after the step.
    pub inmodel: Vec<bool>,
    /// Coefficients after the step (0 for excluded columns).
    pub b: Vec<f64>,
    /// Root-mean-square error after the step.
    pub rmse: f64,
    /// Model degrees of freedom after the step.
    pub df0: usize,
}

/// Result of [`stepwise`] (MATLAB's `b, se, pval, inmodel, stats, nextstep, history`).
#[derive(Debug, Clone)]
pub struct StepwiseResult {
    /// Coefficient per column: of the final model for included columns, as if added alone for
    /// excluded ones.
    pub b: Vec<f64>,
    /// Standard errors, same convention.
    pub se: Vec<f64>,
    /// p-values, same convention.
    pub pval: Vec<f64>,
    /// t statistics, same convention.
    pub tstat: Vec<f64>,
    /// Final model membership.
    pub inmodel: Vec<bool>,
    /// Intercept of the final model.
    pub intercept: f64,
    /// Root-mean-square error of the final model.
    pub rmse: f64,
    /// Coefficient of determination `1 − SSresid/SStotal`.
    pub r_squared: f64,
    /// Adjusted R² `1 − (SSresid/dfe) / (SStotal/(n − 1))` (MATLAB's `LinearModel`
    /// `Rsquared.Adjusted`; `stepwisefit` itself reports the sums of squares it comes from).
    pub r_squared_adjusted: f64,
    /// Overall F statistic of the final model.
    pub fstat: f64,
    /// p-value of the F statistic.
    pub fpval: f64,
    /// Residual degrees of freedom.
    pub dfe: usize,
    /// Model degrees of freedom (numerical rank − 1).
    pub df0: usize,
    /// Total sum of squares about the mean.
    pub ss_total: f64,
    /// Residual sum of squares.
    pub ss_resid: f64,
    /// The step that would be taken next (0-based column), if maxiter stopped the run.
    pub nextstep: Option<usize>,
    /// Steps taken.
    pub history: Vec<Step>,
    /// Rows used (without NaN).
    pub rows_used: usize,
}

impl StepwiseResult {
    /// The final model's prediction at one row of candidate values (excluded columns ignored).
    pub fn predict(&self, row: &[f64]) -> f64 {
        self.intercept
            + row
                .iter()
                .zip(self.b.iter().zip(&self.inmodel))
                .filter(|(_, (_, &i))| i)
                .map(|(x, (b, _))| x * b)
                .sum::<f64>()
    }
}

/// Stepwise regression of `y` on the candidate columns `x` (see the module doc).
pub fn stepwise(
    x: &[&[f64]],
    y: &[f64],
    opts: &StepwiseOptions,
) -> Result<StepwiseResult, StepwiseError> {
    opts.thresholds()?;
    let p = x.len();
    for (j, c) in x.iter().enumerate() {
        if c.len() != y.len() {
            return Err(StepwiseError::LengthMismatch {
                column: j,
                expected: y.len(),
                found: c.len(),
            });
        }
    }
    for (what, idx) in [("inmodel", &opts.inmodel), ("keep", &opts.keep)] {
        if let Some(&bad) = idx.iter().find(|&&i| i >= p) {
            return Err(StepwiseError::BadOption(format!(
                "{what} column {} out of range: there are {p} candidate columns",
                bad + 1
            )));
        }
    }
    let mut cols: Vec<&[f64]> = x.to_vec();
    cols.push(y);
    let comp = compress(&cols, true, opts.thread_count()).expect("lengths checked");
    stepwise_compressed(comp, opts)
}

/// Stepwise regression on data already compressed: `comp` is [`compress`] (with the intercept)
/// of the candidate columns followed by the response, e.g. [`merge_parts`] of some of the
/// [`compress_parts`] of `[x… y]` — a fit on a subset of row ranges without another pass over
/// the data. Same result as [`stepwise`] on those rows (up to rounding).
///
/// [`merge_parts`]: crate::numerics::linalg::merge_parts
/// [`compress_parts`]: crate::numerics::linalg::compress_parts
pub fn stepwise_compressed(
    comp: Compressed,
    opts: &StepwiseOptions,
) -> Result<StepwiseResult, StepwiseError> {
    let (penter, premove) = opts.thresholds()?;
    let p = comp.constant.len().saturating_sub(1);
    for (what, idx) in [("inmodel", &opts.inmodel), ("keep", &opts.keep)] {
        if let Some(&bad) = idx.iter().find(|&&i| i >= p) {
            return Err(StepwiseError::BadOption(format!(
                "{what} column {} out of range: there are {p} candidate columns",
                bad + 1
            )));
        }
    }
    if comp.rows < 2 {
        return Err(StepwiseError::TooFewRows(comp.rows));
    }
    let mut in_ = vec![false; p];
    for &i in &opts.inmodel {
        in_[i] = true;
    }
    let mut keep = vec![false; p];
    for &i in &opts.keep {
        keep[i] = true;
    }
    Ok(run(
        comp.r,
        &comp.constant,
        comp.rows,
        in_,
        &keep,
        penter,
        premove,
        opts.maxiter.unwrap_or(usize::MAX),
    ))
}

/// Statistics of one model (MATLAB's `stepcalc`).
struct Calc {
    b: Vec<f64>,
    se: Vec<f64>,
    pval: Vec<f64>,
    tstat: Vec<f64>,
    intercept: f64,
    rmse: f64,
    dfe: usize,
    df0: usize,
    ss_total: f64,
    ss_resid: f64,
}

#[allow(clippy::too_many_arguments)]
fn run(
    mut z: Mat,
    constant: &[bool],
    n: usize,
    mut in_: Vec<bool>,
    keep: &[bool],
    penter: f64,
    premove: f64,
    maxiter: usize,
) -> StepwiseResult {
    let k = z.cols();
    let p = k - 2;
    // standard deviations from R (column 0 is the constant), sx = 0 -> 1. A column whose
    // values are all equal is exactly a multiple of the constant: its R column is zero below
    // the first row (rounding aside), and its standard deviation is exactly 0 as in MATLAB.
    for (j, &c) in constant.iter().enumerate().take(p) {
        if c {
            for i in 1..k {
                z.set(i, j + 1, 0.0);
            }
        }
    }
    let mut sx = vec![1.0; p];
    for j in 0..p {
        let ss: f64 = (1..k).map(|i| z.get(i, j + 1).powi(2)).sum();
        let s = if n > 1 {
            (ss / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        sx[j] = if s == 0.0 { 1.0 } else { s };
        for v in z.col_mut(j + 1) {
            *v /= sx[j];
        }
    }
    let ss_total: f64 = (1..k).map(|i| z.get(i, k - 1).powi(2)).sum();
    let mut history = Vec::new();
    let mut jstep = 0usize;
    loop {
        let mut c = calc(&z, n, &in_, ss_total);
        for j in 0..p {
            c.b[j] /= sx[j];
            c.se[j] /= sx[j];
        }
        if jstep > 0 {
            let last: &mut Step = history.last_mut().expect("a step was recorded");
            last.b = (0..p).map(|j| if in_[j] { c.b[j] } else { 0.0 }).collect();
            last.rmse = c.rmse;
            last.df0 = c.df0;
            last.inmodel = in_.clone();
        }
        let next = stepnext(&in_, &c.pval, &c.b, penter, premove, keep);
        if jstep >= maxiter || next.is_none() {
            let r_squared = 1.0 - c.ss_resid / c.ss_total;
            let r_squared_adjusted =
                1.0 - (c.ss_resid / c.dfe as f64) / (c.ss_total / (n as f64 - 1.0));
            let fstat = ((c.ss_total - c.ss_resid) / c.df0 as f64) / (c.rmse * c.rmse);
            let fpval = crate::numerics::stats::f_pvalue(fstat, c.df0 as f64, c.dfe as f64);
            return StepwiseResult {
                b: c.b,
                se: c.se,
                pval: c.pval,
                tstat: c.tstat,
                inmodel: in_,
                intercept: c.intercept,
                rmse: c.rmse,
                r_squared,
                r_squared_adjusted,
                fstat,
                fpval,
                dfe: c.dfe,
                df0: c.df0,
                ss_total: c.ss_total,
                ss_resid: c.ss_resid,
                nextstep: next.map(|(j, _)| j),
                history,
                rows_used: n,
            };
        }
        let (j, pnext) = next.expect("checked");
        jstep += 1;
        let action = if in_[j] {
            Action::Removed(j)
        } else {
            Action::Added(j)
        };
        in_[j] = !in_[j];
        history.push(Step {
            action,
            p: pnext,
            inmodel: Vec::new(),
            b: Vec::new(),
            rmse: f64::NAN,
            df0: 0,
        });
    }
}

/// MATLAB's `stepnext`: the column to swap and the p-value that triggered it.
fn stepnext(
    in_: &[bool],
    pval: &[f64],
    b: &[f64],
    penter: f64,
    premove: f64,
    keep: &[bool],
) -> Option<(usize, f64)> {
    // smallest p among excluded, NaN ignored, ties to lowest index
    let mut best: Option<(usize, f64)> = None;
    for j in (0..in_.len()).filter(|&j| !in_[j] && !keep[j]) {
        let pj = pval[j];
        if pj.is_nan() {
            continue;
        }
        if best.is_none_or(|(_, pb)| pj < pb) {
            best = Some((j, pj));
        }
    }
    if let Some((j, pmin)) = best {
        if pmin < penter {
            return Some((j, pmin));
        }
    }
    let termsin: Vec<usize> = (0..in_.len()).filter(|&j| in_[j] && !keep[j]).collect();
    if termsin.is_empty() {
        return None;
    }
    let bad: Vec<usize> = termsin
        .iter()
        .copied()
        .filter(|&j| pval[j].is_nan())
        .collect();
    if !bad.is_empty() {
        if let Some(&j) = bad.iter().find(|&&j| b[j].is_nan()) {
            return Some((j, f64::NAN));
        }
        let mut jb = bad[0];
        for &j in &bad[1..] {
            if b[j].abs() < b[jb].abs() {
                jb = j;
            }
        }
        return Some((jb, f64::NAN));
    }
    let mut worst = termsin[0];
    for &j in &termsin[1..] {
        if pval[j] > pval[worst] {
            worst = j;
        }
    }
    if pval[worst] > premove {
        Some((worst, pval[worst]))
    } else {
        None
    }
}

/// MATLAB's `stepcalc`, on the compressed data `z` (columns: constant, scaled x, y).
fn calc(z: &Mat, n: usize, in_: &[bool], ss_total: f64) -> Calc {
    let k = z.cols();
    let m = z.rows();
    let p = k - 2;
    let ycol = z.col(k - 1);
    let in_cols: Vec<usize> = std::iter::once(0)
        .chain((0..p).filter(|&j| in_[j]).map(|j| j + 1))
        .collect();
    let nin = in_cols.len();
    let tol = n.max(p + 1) as f64 * f64::EPSILON;
    let qr = PivotedQr::new(z.select_cols(&in_cols));
    let rank = qr.rank(tol);
    let perm = qr.perm().to_vec();
    // Qb = Q' y, truncated to the rank, small entries zeroed
    let mut qty = ycol.to_vec();
    qr.apply_qt(&mut qty);
    let mut qb = qty[..rank].to_vec();
    let qmax = qb.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    for v in qb.iter_mut() {
        if v.abs() < tol * qmax {
            *v = 0.0;
        }
    }
    let zsol = qr.solve_r(rank, &qb);
    let mut bin = vec![0.0; nin];
    for t in 0..rank {
        bin[perm[t]] = zsol[t];
    }
    // residual in compressed space
    let mut r = ycol.to_vec();
    for (t, &c) in in_cols.iter().enumerate() {
        if bin[t] != 0.0 {
            let col = z.col(c);
            for i in 0..m {
                r[i] -= bin[t] * col[i];
            }
        }
    }
    let dfe = n.saturating_sub(rank);
    let df0 = rank.saturating_sub(1);
    let mut ss_resid: f64 = r.iter().map(|v| v * v).sum();
    if dfe == 0 || ss_resid < tol * ss_total {
        ss_resid = 0.0;
        r.iter_mut().for_each(|v| *v = 0.0);
    }
    let rmse = (ss_resid / dfe as f64).sqrt();
    let rinv = qr.r_inverse(rank);
    let mut se_in = vec![0.0; nin];
    for t in 0..rank {
        let s: f64 = (t..rank).map(|c| rinv.get(t, c).powi(2)).sum();
        se_in[perm[t]] = (rmse * rmse * s).sqrt();
    }
    // added-variable fits for the excluded columns
    let mut b = vec![0.0; p];
    let mut se = vec![0.0; p];
    let mut pval = vec![0.0; p];
    let mut tstat = vec![0.0; p];
    let df2 = dfe.saturating_sub(1);
    let mut xr = vec![0.0; m];
    for j in 0..p {
        if in_[j] {
            continue;
        }
        let x = z.col(j + 1);
        let sumxsq: f64 = x.iter().map(|v| v * v).sum();
        xr.copy_from_slice(x);
        qr.apply_qt(&mut xr);
        xr[..rank].iter_mut().for_each(|v| *v = 0.0);
        qr.apply_q(&mut xr);
        let mut xx: f64 = xr.iter().map(|v| v * v).sum();
        if xx <= tol * sumxsq {
            xr.iter_mut().for_each(|v| *v = 0.0);
            xx = 1.0;
        }
        let b2 = r.iter().zip(&xr).map(|(a, c)| a * c).sum::<f64>() / xx;
        let rss2: f64 = r.iter().zip(&xr).map(|(a, c)| (a - c * b2).powi(2)).sum();
        b[j] = b2;
        se[j] = (rss2 / df2 as f64).sqrt() / xx.sqrt();
    }
    // included: coefficients in order of in_cols[1..]
    for (t, &c) in in_cols.iter().enumerate().skip(1) {
        b[c - 1] = bin[t];
        se[c - 1] = se_in[t];
    }
    for j in 0..p {
        let t = b[j] / se[j];
        if in_[j] {
            tstat[j] = t;
            pval[j] = t_pvalue_two_sided(t, dfe as f64);
        } else if dfe > 1 {
            tstat[j] = t;
            pval[j] = t_pvalue_two_sided(t, (dfe - 1) as f64);
        } else {
            tstat[j] = f64::NAN;
            pval[j] = f64::NAN;
        }
    }
    Calc {
        b,
        se,
        pval,
        tstat,
        intercept: bin[0],
        rmse,
        dfe,
        df0,
        ss_total,
        ss_resid,
    }
}
