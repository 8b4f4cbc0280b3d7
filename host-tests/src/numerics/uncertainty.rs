//! What a fit knows about itself: the prediction interval of its output, the collinearity of
//! its sensors, and its accuracy on data it did not see.
//!
//! - **Prediction interval** of a new observation at `x₀` (a row of regressors, intercept
//!   included): `ŷ(x₀) ± t_{1−α/2, dfe} · s · sqrt(1 + x₀ᵀ(XᵀX)⁻¹x₀)` (e.g. Montgomery, Peck &
//!   Vining, *Introduction to Linear Regression Analysis*, 5th ed., Eq. 3.52). `(XᵀX)⁻¹` is never
//!   formed: with `X = Q R`, `x₀ᵀ(XᵀX)⁻¹x₀ = ‖R⁻ᵀx₀‖²`, one forward substitution through the
//!   triangular factor of the design (columns centred and scaled first, so `R` is well
//!   conditioned; the quadratic form is invariant under that change of basis).
//! - **Variance inflation factor** of a column: `VIF_j = 1 / (1 − R_j²)`, `R_j²` of the column
//!   regressed on the others (with intercept). A VIF above 10 is the usual sign that
//!   multicollinearity is unduly influencing the estimates (Kutner, Nachtsheim, Neter & Li,
//!   *Applied Linear Statistical Models*, 5th ed., §10.5; Montgomery, Peck & Vining §9.4.3).
//! - **Held-out accuracy** by blocks of time ([`time_blocks`]): contiguous blocks, not random
//!   rows, because thermal drift is autocorrelated — a randomly held-out dwell has neighbours a
//!   few minutes away in the training set that share its temperature state, so random k-fold
//!   measures interpolation between neighbours and flatters the model; a held-out block is the
//!   closest the data offer to "a later day".

#![allow(clippy::needless_range_loop)] // index loops read best in numerical kernels

use crate::numerics::linalg::{compress, lstsq, Mat, PivotedQr, RAccumulator};
use crate::numerics::stats::t_pvalue_two_sided;

/// Errors of the uncertainty computations.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum UncertaintyError {
    /// Columns of different lengths.
    #[error("column {column} has {found} rows, expected {expected}")]
    LengthMismatch {
        /// 0-based column.
        column: usize,
        /// Rows expected.
        expected: usize,
        /// Rows found.
        found: usize,
    },
    /// No residual degrees of freedom: the interval is undefined.
    #[error(
        "no residual degrees of freedom ({rows} rows, {params} parameters): no prediction interval"
    )]
    NoResidualDof {
        /// Rows used.
        rows: usize,
        /// Parameters (intercept included).
        params: usize,
    },
    /// The design is rank deficient: some column is a combination of the others.
    #[error("the design is rank deficient (column {0} depends on the others)")]
    RankDeficient(usize),
    /// A point has the wrong number of regressors.
    #[error("a point has {found} regressors, the design {expected}")]
    BadPoint {
        /// Regressors of the design.
        expected: usize,
        /// Given.
        found: usize,
    },
    /// Too few rows for the number of blocks.
    #[error("{rows} rows cannot make {blocks} blocks of time (need at least 2 rows per block)")]
    TooFewRowsForBlocks {
        /// Rows.
        rows: usize,
        /// Blocks asked for.
        blocks: usize,
    },
}

/// The `p`-quantile of Student's t with `df` degrees of freedom (`p` in (0.5, 1)), by bisection
/// on the two-sided p-value [`t_pvalue_two_sided`] (monotone in `t`), to 1e-13 relative.
pub fn t_quantile(p: f64, df: f64) -> f64 {
    if !(p > 0.5 && p < 1.0) || df.is_nan() || df <= 0.0 {
        return f64::NAN;
    }
    let tail = 2.0 * (1.0 - p);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while t_pvalue_two_sided(hi, df) > tail {
        hi *= 2.0;
        if hi > 1e12 {
            return f64::INFINITY;
        }
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if t_pvalue_two_sided(mid, df) > tail {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-13 * hi {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// The prediction interval of a linear least-squares fit with intercept (see the module doc).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PredictionBand {
    /// Column means used to centre the regressors.
    pub mean: Vec<f64>,
    /// Column scales (standard deviation; 1 for a constant column).
    pub scale: Vec<f64>,
    /// Upper-triangular factor of `[1 (X − mean)/scale]`, `(p+1) × (p+1)`, row-major.
    pub r: Vec<Vec<f64>>,
    /// Residual standard deviation `s = sqrt(SSresid / dfe)`.
    pub s: f64,
    /// Residual degrees of freedom.
    pub dfe: usize,
}

impl PredictionBand {
    /// The band of the fit of some response on `columns` (the regressors in the model; the
    /// intercept is implied) with residual sum of squares `ss_resid`. Rows with a NaN are left
    /// out, as the fit did.
    pub fn new(columns: &[&[f64]], ss_resid: f64) -> Result<Self, UncertaintyError> {
        let n = columns.first().map_or(0, |c| c.len());
        for (j, c) in columns.iter().enumerate() {
            if c.len() != n {
                return Err(UncertaintyError::LengthMismatch {
                    column: j,
                    expected: n,
                    found: c.len(),
                });
            }
        }
        let ok: Vec<bool> = (0..n)
            .map(|i| columns.iter().all(|c| !c[i].is_nan()))
            .collect();
        let rows = ok.iter().filter(|o| **o).count();
        let p = columns.len();
        if rows <= p + 1 {
            return Err(UncertaintyError::NoResidualDof {
                rows,
                params: p + 1,
            });
        }
        let mut mean = vec![0.0; p];
        let mut scale = vec![1.0; p];
        let mut scaled: Vec<Vec<f64>> = Vec::with_capacity(p);
        for (j, c) in columns.iter().enumerate() {
            let used = c.iter().zip(&ok).filter(|(_, o)| **o).map(|(v, _)| *v);
            let m = used.clone().sum::<f64>() / rows as f64;
            let var = used.map(|v| (v - m).powi(2)).sum::<f64>() / (rows - 1) as f64;
            mean[j] = m;
            scale[j] = if var > 0.0 { var.sqrt() } else { 1.0 };
            scaled.push(c.iter().map(|v| (v - m) / scale[j]).collect());
        }
        let refs: Vec<&[f64]> = scaled.iter().map(|c| c.as_slice()).collect();
        let comp = if p == 0 {
            // intercept only: R = [sqrt(n)]
            let mut r = Mat::zeros(1, 1);
            r.set(0, 0, (rows as f64).sqrt());
            r
        } else {
            compress(&refs, true, 1)
                .map_err(|_| UncertaintyError::LengthMismatch {
                    column: 0,
                    expected: n,
                    found: n,
                })?
                .r
        };
        Self::from_factor(mean, scale, &comp, rows, ss_resid)
    }

    /// The same band as [`Self::new`] (equal to rounding), from the triangle `r` of a
    /// compression of the data with the intercept ([`crate::numerics::linalg::compress`]:
    /// column 0 the constant) instead of another pass over the rows: the regressors are the
    /// columns `cols` of `r`, `constant[t]` says the data of `cols[t]` are all equal, `rows` is the
    /// number of rows compressed.
    ///
    /// Why it is the same: with `[1 X] = Q R`, `1 = Q r₀₀e₀` (`r₀₀² = n`), so column `c`'s mean is
    /// `r₀c / r₀₀`, its centred data are `Q` times column `c` of `R` with row 0 zeroed, and its
    /// sum of squares about the mean is that column's squared norm below row 0. The band's
    /// factor is then the QR of those centred, scaled columns beside `r₀₀e₀` — k rows, not n.
    pub fn from_compressed(
        r: &Mat,
        rows: usize,
        cols: &[usize],
        constant: &[bool],
        ss_resid: f64,
    ) -> Result<Self, UncertaintyError> {
        let p = cols.len();
        if rows <= p + 1 {
            return Err(UncertaintyError::NoResidualDof {
                rows,
                params: p + 1,
            });
        }
        let m = r.rows();
        let r00 = r.get(0, 0);
        let mut mean = vec![0.0; p];
        let mut scale = vec![1.0; p];
        // [r₀₀e₀, centred and scaled columns], m × (p + 1), column-major
        let mut block = vec![0.0; m * (p + 1)];
        block[0] = r00;
        for (t, (&c, &is_const)) in cols.iter().zip(constant).enumerate() {
            mean[t] = r.get(0, c) / r00;
            // an exactly constant column has zero variance; R shows that only up to rounding
            let ss: f64 = if is_const {
                0.0
            } else {
                (1..m).map(|i| r.get(i, c).powi(2)).sum()
            };
            let var = ss / (rows - 1) as f64;
            scale[t] = if var > 0.0 { var.sqrt() } else { 1.0 };
            if !is_const {
                let dst = &mut block[(t + 1) * m..(t + 2) * m];
                for i in 1..m {
                    dst[i] = r.get(i, c) / scale[t];
                }
            }
        }
        let k = p + 1;
        let mut acc = RAccumulator::new(k);
        acc.push_block(&mut block, m);
        let comp = acc.into_r();
        Self::from_factor(mean, scale, &comp, rows, ss_resid)
    }

    /// The band from the factor `comp` of `[1 (X − mean)/scale]` over `rows` rows.
    fn from_factor(
        mean: Vec<f64>,
        scale: Vec<f64>,
        comp: &Mat,
        rows: usize,
        ss_resid: f64,
    ) -> Result<Self, UncertaintyError> {
        let k = mean.len() + 1;
        let r: Vec<Vec<f64>> = (0..k)
            .map(|i| {
                (0..k)
                    .map(|j| if j >= i { comp.get(i, j) } else { 0.0 })
                    .collect()
            })
            .collect();
        // unit-variance columns: |R_ii| = sqrt(n − 1) · sqrt(1 − R²_i|previous), so a tiny ratio
        // to sqrt(n) is a column that the previous ones (nearly) reproduce
        for i in 0..k {
            if r[i][i].abs() <= 1e-10 * (rows as f64).sqrt() {
                return Err(UncertaintyError::RankDeficient(i.saturating_sub(1)));
            }
        }
        let dfe = rows - k;
        Ok(PredictionBand {
            mean,
            scale,
            r,
            s: (ss_resid / dfe as f64).sqrt(),
            dfe,
        })
    }

    /// [`Self::leverage`] at many rows of full-length regressor columns (`columns[t][i]`, the
    /// regressors in the band's order), bit for bit the same numbers, but column by column
    /// over chunks of rows (vectorisable, no allocation per row). Rows must hold no NaN.
    pub fn leverages(
        &self,
        columns: &[&[f64]],
        rows: &[usize],
    ) -> Result<Vec<f64>, UncertaintyError> {
        let mut out = vec![0.0; rows.len()];
        self.leverages_into(columns, rows, &mut out)?;
        Ok(out)
    }

    /// [`Self::leverages`] written into `out` (one value per row of `rows`; its length must
    /// be theirs). Why: threads that each take a part of the rows fill one vector, instead of
    /// a vector each copied into a third.
    pub fn leverages_into(
        &self,
        columns: &[&[f64]],
        rows: &[usize],
        out: &mut [f64],
    ) -> Result<(), UncertaintyError> {
        let p = self.regressors();
        if columns.len() != p {
            return Err(UncertaintyError::BadPoint {
                expected: p,
                found: columns.len(),
            });
        }
        assert_eq!(out.len(), rows.len(), "leverages_into: one value per row");
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2
            unsafe { self.leverages_avx2(columns, rows, out) };
            return Ok(());
        }
        self.leverages_in(columns, rows, out);
        Ok(())
    }

    /// [`Self::leverages_in`] compiled for AVX2: its loops run across rows, four at a time
    /// instead of two, each lane the same operations in the same order (Rust never fuses a
    /// product and a sum), so the same numbers. Why: the leverages were a tenth of `nanocal
    /// stepwise`'s CPU on a 200,000-row file.
    ///
    /// # Safety
    /// The CPU has AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn leverages_avx2(&self, columns: &[&[f64]], rows: &[usize], out: &mut [f64]) {
        self.leverages_in(columns, rows, out)
    }

    /// The body of [`Self::leverages_into`] (`columns` and `out` checked).
    #[inline(always)]
    fn leverages_in(&self, columns: &[&[f64]], rows: &[usize], out: &mut [f64]) {
        let p = self.regressors();
        const CHUNK: usize = 256;
        let k = p + 1;
        let mut z = vec![0.0; k * CHUNK];
        let mut s = [0.0f64; CHUNK];
        for (idx, out) in rows.chunks(CHUNK).zip(out.chunks_mut(CHUNK)) {
            let b = idx.len();
            z[..b].fill(1.0 / self.r[0][0]);
            for i in 1..k {
                let (done, rest) = z.split_at_mut(i * CHUNK);
                let zi = &mut rest[..b];
                let col = columns[i - 1];
                let (m, sc) = (self.mean[i - 1], self.scale[i - 1]);
                for (v, &row) in zi.iter_mut().zip(idx) {
                    *v = (col[row] - m) / sc;
                }
                // the same sums in the same order as `leverage`: Σ_t r_ti z_t from t = 0
                s[..b].fill(-0.0);
                for t in 0..i {
                    let rti = self.r[t][i];
                    for (acc, &zt) in s[..b].iter_mut().zip(&done[t * CHUNK..t * CHUNK + b]) {
                        *acc += rti * zt;
                    }
                }
                let rii = self.r[i][i];
                for (v, acc) in zi.iter_mut().zip(&s[..b]) {
                    *v = (*v - acc) / rii;
                }
            }
            s[..b].fill(-0.0);
            for i in 0..k {
                for (acc, &zi) in s[..b].iter_mut().zip(&z[i * CHUNK..i * CHUNK + b]) {
                    *acc += zi * zi;
                }
            }
            out.copy_from_slice(&s[..b]);
        }
    }

    /// Number of regressors (without the intercept).
    pub fn regressors(&self) -> usize {
        self.mean.len()
    }

    /// `x₀ᵀ(XᵀX)⁻¹x₀` (the leverage of a new point `x₀`, intercept implied), through `R`.
    pub fn leverage(&self, x0: &[f64]) -> Result<f64, UncertaintyError> {
        let p = self.regressors();
        if x0.len() != p {
            return Err(UncertaintyError::BadPoint {
                expected: p,
                found: x0.len(),
            });
        }
        // z = R⁻ᵀ [1, (x0 − mean)/scale]: forward substitution with Rᵀ (lower triangular)
        let k = p + 1;
        let mut z = vec![0.0; k];
        for i in 0..k {
            let v = if i == 0 {
                1.0
            } else {
                (x0[i - 1] - self.mean[i - 1]) / self.scale[i - 1]
            };
            let s: f64 = (0..i).map(|t| self.r[t][i] * z[t]).sum();
            z[i] = (v - s) / self.r[i][i];
        }
        Ok(z.iter().map(|v| v * v).sum())
    }

    /// Half-width of the two-sided prediction interval at confidence `level` (e.g. 0.95) of a
    /// new observation at `x₀`.
    pub fn half_width(&self, x0: &[f64], level: f64) -> Result<f64, UncertaintyError> {
        self.half_width_with(x0, self.t_times_s(level))
    }

    /// `t·s` of the interval at confidence `level`: the half-width is `t·s·√(1 + h)`. The t
    /// quantile is an iterative inverse of the incomplete beta function, dearer than a
    /// leverage: over many points, compute it once and call [`Self::half_width_with`].
    pub fn t_times_s(&self, level: f64) -> f64 {
        t_quantile(0.5 + level / 2.0, self.dfe as f64) * self.s
    }

    /// [`Self::half_width`] with `t_times_s` from [`Self::t_times_s`] (the same number).
    pub fn half_width_with(&self, x0: &[f64], t_times_s: f64) -> Result<f64, UncertaintyError> {
        let h = self.leverage(x0)?;
        Ok(t_times_s * (1.0 + h).sqrt())
    }
}

/// Collinearity of one column with the others.
#[derive(Debug, Clone, PartialEq)]
pub struct Vif {
    /// Column name.
    pub name: String,
    /// Variance inflation factor `1 / (1 − R²)` (∞ for an exact combination, NaN for a
    /// constant column).
    pub vif: f64,
    /// The other column it correlates with most, and the correlation coefficient.
    pub partner: Option<(String, f64)>,
}

/// The usual threshold above which a VIF signals harmful collinearity (Kutner et al. §10.5).
pub const VIF_WARN: f64 = 10.0;

/// VIF of every column against the others (with intercept). With one column there is nothing
/// to be collinear with: VIF 1.
pub fn variance_inflation(names: &[String], columns: &[&[f64]]) -> Vec<Vif> {
    let p = columns.len();
    // each pair's correlation once (it is symmetric, bit for bit)
    let mut corr = vec![f64::NAN; p * p];
    for j in 0..p {
        for i in j + 1..p {
            let r = correlation(columns[i], columns[j]);
            corr[i * p + j] = r;
            corr[j * p + i] = r;
        }
    }
    (0..p)
        .map(|j| {
            let others: Vec<&[f64]> = (0..p).filter(|&i| i != j).map(|i| columns[i]).collect();
            let y = columns[j];
            let ok: Vec<f64> = y.iter().copied().filter(|v| !v.is_nan()).collect();
            let m = ok.iter().sum::<f64>() / ok.len().max(1) as f64;
            let ss_tot: f64 = ok.iter().map(|v| (v - m).powi(2)).sum();
            let vif = if ss_tot == 0.0 {
                f64::NAN
            } else if others.is_empty() {
                1.0
            } else {
                match lstsq(&others, y, true) {
                    Ok(ls) if ls.rss > 1e-14 * ss_tot => ss_tot / ls.rss,
                    Ok(_) => f64::INFINITY,
                    Err(_) => f64::NAN,
                }
            };
            let partner = (0..p)
                .filter(|&i| i != j)
                .map(|i| (i, corr[i * p + j]))
                .filter(|(_, r)| r.is_finite())
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map(|(i, r)| (names[i].clone(), r));
            Vif {
                name: names[j].clone(),
                vif,
                partner,
            }
        })
        .collect()
}

/// [`variance_inflation`] of the columns `cols` of the triangle `r` of a compression of the data
/// with the intercept ([`crate::numerics::linalg::compress`]: column 0 the constant) over `rows`
/// rows, without another pass over the data (equal to rounding). `constant[t]`: the data of
/// `cols[t]` are all equal (its VIF is NaN, as with the data).
///
/// Why it is the same: `[1 X] = Q R` with orthonormal `Q`, and `1 = Q r₀₀e₀`, so the centred
/// data of column `c` are `Q` times column `c` of `R` with row 0 zeroed. Regressing one centred
/// column on the others (the intercept is then implied), sums of squares, residual sums of
/// squares and correlations are the same computed on those k-row columns as on the n rows.
pub fn variance_inflation_compressed(
    names: &[String],
    r: &Mat,
    rows: usize,
    cols: &[usize],
    constant: &[bool],
) -> Vec<Vif> {
    let p = cols.len();
    let m = r.rows();
    // centred columns below row 0 (exactly zero for an exactly constant column)
    let centred: Vec<Vec<f64>> = cols
        .iter()
        .zip(constant)
        .map(|(&c, &is_const)| {
            if is_const {
                vec![0.0; m - 1]
            } else {
                (1..m).map(|i| r.get(i, c)).collect()
            }
        })
        .collect();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let ss: Vec<f64> = centred.iter().map(|c| dot(c, c)).collect();
    let corr = |i: usize, j: usize| dot(&centred[i], &centred[j]) / (ss[i] * ss[j]).sqrt();
    (0..p)
        .map(|j| {
            let ss_tot = ss[j];
            let others: Vec<usize> = (0..p).filter(|&i| i != j).collect();
            let vif = if ss_tot == 0.0 {
                f64::NAN
            } else if others.is_empty() {
                1.0
            } else {
                // as `lstsq`: columns scaled to unit norm, pivoted QR, rank at max(n, q+1)·ε
                let mut a = Mat::zeros(m - 1, others.len());
                for (t, &i) in others.iter().enumerate() {
                    let nrm = ss[i].sqrt();
                    let sc = if nrm > 0.0 { nrm } else { 1.0 };
                    for (dst, v) in a.col_mut(t).iter_mut().zip(&centred[i]) {
                        *dst = v / sc;
                    }
                }
                let qr = PivotedQr::new(a);
                let tol = rows.max(others.len() + 1) as f64 * f64::EPSILON;
                let rank = qr.rank(tol);
                let mut rhs = centred[j].clone();
                qr.apply_qt(&mut rhs);
                let rss: f64 = rhs[rank..].iter().map(|v| v * v).sum();
                if rss > 1e-14 * ss_tot {
                    ss_tot / rss
                } else {
                    f64::INFINITY
                }
            };
            let partner = others
                .iter()
                .map(|&i| (i, corr(i, j)))
                .filter(|(_, r)| r.is_finite())
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map(|(i, r)| (names[i].clone(), r));
            Vif {
                name: names[j].clone(),
                vif,
                partner,
            }
        })
        .collect()
}

/// Pearson correlation over the rows where both are finite.
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    // two passes over the finite pairs, no copy of them (same sums in the same order)
    let pairs = || {
        a.iter()
            .zip(b)
            .filter(|(x, y)| x.is_finite() && y.is_finite())
    };
    let (mut n, mut sa, mut sb) = (0usize, 0.0, 0.0);
    for (x, y) in pairs() {
        n += 1;
        sa += x;
        sb += y;
    }
    let n = n as f64;
    let (ma, mb) = (sa / n, sb / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in pairs() {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt()
}

/// Plain-words warnings for the columns whose VIF exceeds [`VIF_WARN`]; each pair once.
pub fn collinearity_warnings(vifs: &[Vif], what: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut said: Vec<(String, String)> = Vec::new();
    for v in vifs
        .iter()
        .filter(|v| v.vif > VIF_WARN || v.vif.is_infinite())
    {
        match &v.partner {
            Some((other, r)) => {
                let key = if v.name < *other {
                    (v.name.clone(), other.clone())
                } else {
                    (other.clone(), v.name.clone())
                };
                if said.contains(&key) {
                    continue;
                }
                said.push(key);
                out.push(format!(
                    "warning: {what}s {} and {other} carry the same information (correlation {r:.3}, \
                     VIF {:.0} > {VIF_WARN}): the fit cannot tell their effects apart, so the \
                     coefficients on them are unreliable and may swing between fits; keep one, or \
                     record a period in which they move differently",
                    v.name, v.vif
                ));
            }
            None => out.push(format!(
                "warning: {what} {} is almost a combination of the others (VIF {:.0} > {VIF_WARN})",
                v.name, v.vif
            )),
        }
    }
    out
}

/// `k` contiguous blocks of `n` rows in time order, as `(start, end)` ranges of near-equal size.
pub fn time_blocks(n: usize, k: usize) -> Result<Vec<(usize, usize)>, UncertaintyError> {
    if k < 2 || n < 2 * k {
        return Err(UncertaintyError::TooFewRowsForBlocks { rows: n, blocks: k });
    }
    Ok((0..k).map(|b| (b * n / k, (b + 1) * n / k)).collect())
}

/// Held-out accuracy: errors of predictions made by a model that did not see them.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    /// Number of blocks.
    pub blocks: usize,
    /// Held-out predictions made.
    pub n: usize,
    /// RMS of the held-out errors.
    pub rms: f64,
    /// Largest |held-out error|.
    pub max_abs: f64,
    /// RMS per block, in time order.
    pub block_rms: Vec<f64>,
}

impl HeldOut {
    /// Summarises held-out errors given per block.
    pub fn from_block_errors(errors: &[Vec<f64>]) -> Self {
        let mut sum = HeldOutSum::default();
        for block in errors {
            sum.add_block(block.iter().copied());
        }
        sum.finish()
    }
}

/// [`HeldOut`] summed as the errors come, block by block, without keeping them: each sum runs
/// over the finite errors in the order they come, from the first, as a sum over a vector of
/// them would ([`HeldOut::from_block_errors`] is this over the vectors it is given).
///
/// Why: `nanocal stepwise` kept every held-out error of a 200,000-row file in fresh vectors
/// and copied them twice more; their page faults and copies were most of the command's
/// single-threaded tail.
#[derive(Debug, Clone, Default)]
pub struct HeldOutSum {
    n: usize,
    sum_sq: f64,
    max_abs: f64,
    block_rms: Vec<f64>,
}

impl HeldOutSum {
    /// Adds the next block's errors (non-finite ones are left out, as by
    /// [`HeldOut::from_block_errors`]).
    pub fn add_block(&mut self, errors: impl IntoIterator<Item = f64>) {
        let mut block = self.start_block();
        for e in errors {
            block.add(e);
        }
        block.finish();
    }

    /// Starts the next block; its errors go in through [`HeldOutBlock::add`].
    pub fn start_block(&mut self) -> HeldOutBlock<'_> {
        HeldOutBlock {
            sum: self,
            n: 0,
            sum_sq: 0.0,
        }
    }

    /// The summary.
    pub fn finish(self) -> HeldOut {
        HeldOut {
            blocks: self.block_rms.len(),
            n: self.n,
            rms: rms(self.sum_sq, self.n),
            max_abs: self.max_abs,
            block_rms: self.block_rms,
        }
    }
}

/// One block of a [`HeldOutSum`] being added.
pub struct HeldOutBlock<'a> {
    sum: &'a mut HeldOutSum,
    n: usize,
    sum_sq: f64,
}

impl HeldOutBlock<'_> {
    /// Adds one error (left out if not finite).
    #[inline]
    pub fn add(&mut self, e: f64) {
        if e.is_finite() {
            let sq = e * e;
            self.sum_sq += sq;
            self.n += 1;
            self.sum.sum_sq += sq;
            self.sum.n += 1;
            self.sum.max_abs = self.sum.max_abs.max(e.abs());
        }
    }

    /// Closes the block.
    pub fn finish(self) {
        self.sum.block_rms.push(rms(self.sum_sq, self.n));
    }
}

/// √(Σe² / n) as `Iterator::sum` gives it (NaN for no errors).
fn rms(sum_sq: f64, n: usize) -> f64 {
    (sum_sq / n as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_out_summary_is_the_textbook_one_bit_for_bit() {
        // three blocks, one empty, with NaN and ∞ left out, summed as they come
        let blocks: Vec<Vec<f64>> = vec![
            vec![0.1, -0.25, f64::NAN, 1e-9, 3.0],
            vec![],
            vec![-7.5, f64::INFINITY, 0.3333333333333333, -0.0],
        ];
        let h = HeldOut::from_block_errors(&blocks);
        let finite: Vec<f64> = blocks
            .iter()
            .flatten()
            .copied()
            .filter(|e| e.is_finite())
            .collect();
        let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt();
        assert_eq!((h.blocks, h.n), (3, 7));
        assert_eq!(h.rms.to_bits(), rms(&finite).to_bits());
        assert_eq!(h.max_abs, 7.5);
        for (got, b) in h.block_rms.iter().zip(&blocks) {
            let f: Vec<f64> = b.iter().copied().filter(|e| e.is_finite()).collect();
            assert_eq!(got.to_bits(), rms(&f).to_bits(), "{got} for {b:?}");
        }
        assert!(h.block_rms[1].is_nan(), "an empty block has no RMS");
        // the same errors added one at a time give the same summary
        let mut sum = HeldOutSum::default();
        for b in &blocks {
            let mut block = sum.start_block();
            b.iter().for_each(|&e| block.add(e));
            block.finish();
        }
        let one_by_one = sum.finish();
        assert_eq!(one_by_one.rms.to_bits(), h.rms.to_bits());
        assert_eq!(one_by_one.n, h.n);
    }

    #[test]
    fn t_quantiles_match_tables() {
        // Student t table (two-sided 95 %): df 1 → 12.706, 10 → 2.228, 30 → 2.042
        assert!((t_quantile(0.975, 1.0) - 12.7062047).abs() < 1e-6);
        assert!((t_quantile(0.975, 10.0) - 2.2281389).abs() < 1e-6);
        assert!((t_quantile(0.975, 30.0) - 2.0422725).abs() < 1e-6);
        assert!(t_quantile(0.4, 3.0).is_nan());
    }

    #[test]
    fn simple_regression_band_matches_the_textbook_formula() {
        // one regressor: x0ᵀ(XᵀX)⁻¹x0 = 1/n + (x0 − x̄)²/Sxx
        let x: Vec<f64> = (0..12).map(|i| 3.0 + i as f64 * 0.7).collect();
        let band = PredictionBand::new(&[&x], 4.0).unwrap();
        let n = x.len() as f64;
        let xm = x.iter().sum::<f64>() / n;
        let sxx: f64 = x.iter().map(|v| (v - xm).powi(2)).sum();
        for x0 in [3.0, 5.5, 20.0] {
            let want = 1.0 / n + (x0 - xm).powi(2) / sxx;
            let got = band.leverage(&[x0]).unwrap();
            assert!(
                (got - want).abs() < 1e-13 * want.max(1.0),
                "{got} vs {want}"
            );
        }
        assert_eq!(band.dfe, 10);
        let hw = band.half_width(&[xm], 0.95).unwrap();
        let want = t_quantile(0.975, 10.0) * (4.0f64 / 10.0).sqrt() * (1.0 + 1.0 / n).sqrt();
        assert!((hw - want).abs() < 1e-12);
    }

    #[test]
    fn vif_flags_two_columns_that_move_together() {
        let a: Vec<f64> = (0..50).map(|i| (i as f64 * 0.3).sin()).collect();
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.01 * ((i * 7919) % 13) as f64 / 13.0)
            .collect();
        let c: Vec<f64> = (0..50).map(|i| (i as f64 * 1.7).cos()).collect();
        let names: Vec<String> = ["temp_a", "temp_b", "temp_c"].map(String::from).to_vec();
        let v = variance_inflation(&names, &[&a, &b, &c]);
        assert!(v[0].vif > 100.0 && v[1].vif > 100.0, "{v:?}");
        assert!(v[2].vif < 2.0, "{v:?}");
        let w = collinearity_warnings(&v, "temperature");
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("temp_a and temp_b carry the same information"),
            "{w:?}"
        );
    }

    /// Four columns with some collinearity, a constant one and a response, 400 rows.
    fn design() -> Vec<Vec<f64>> {
        let a: Vec<f64> = (0..400).map(|i| 20.0 + (i as f64 * 0.3).sin()).collect();
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| 2.0 * v + 0.05 * ((i * 7919) % 13) as f64)
            .collect();
        let c: Vec<f64> = (0..400).map(|i| 1e3 + (i as f64 * 1.7).cos()).collect();
        let k = vec![4.5; 400];
        let y: Vec<f64> = (0..400)
            .map(|i| a[i] - c[i] + 0.1 * ((i * 31) % 7) as f64)
            .collect();
        vec![a, b, c, k, y]
    }

    #[test]
    fn the_band_from_the_triangle_is_the_band_from_the_rows() {
        let d = design();
        let refs: Vec<&[f64]> = d.iter().map(|c| c.as_slice()).collect();
        let comp = compress(&refs, true, 1).unwrap();
        // regressors a and c (columns 1 and 3 of the triangle)
        let rows_band = PredictionBand::new(&[&d[0], &d[2]], 2.5).unwrap();
        let tri_band =
            PredictionBand::from_compressed(&comp.r, 400, &[1, 3], &[false, false], 2.5).unwrap();
        assert_eq!(rows_band.dfe, tri_band.dfe);
        assert!((rows_band.s - tri_band.s).abs() < 1e-15);
        for t in 0..2 {
            let rel = |a: f64, b: f64| (a - b).abs() / a.abs().max(b.abs());
            assert!(rel(rows_band.mean[t], tri_band.mean[t]) < 1e-13);
            assert!(rel(rows_band.scale[t], tri_band.scale[t]) < 1e-11);
        }
        let all: Vec<usize> = (0..400).collect();
        let h = tri_band.leverages(&[&d[0], &d[2]], &all).unwrap();
        // the build for every x86-64 and the AVX2 one (taken where the CPU has it) alike
        let mut plain = vec![0.0; all.len()];
        tri_band.leverages_in(&[&d[0], &d[2]], &all, &mut plain);
        assert!(h
            .iter()
            .zip(&plain)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        for (i, &hi) in h.iter().enumerate() {
            let x0 = [d[0][i], d[2][i]];
            // the batch is the per-point forward substitution, bit for bit
            assert_eq!(hi.to_bits(), tri_band.leverage(&x0).unwrap().to_bits());
            let want = rows_band.leverage(&x0).unwrap();
            assert!((hi - want).abs() <= 1e-10 * want, "{hi} vs {want}");
        }
        // the constant column: rank deficient both ways
        assert_eq!(
            PredictionBand::from_compressed(&comp.r, 400, &[1, 4], &[false, true], 2.5),
            Err(UncertaintyError::RankDeficient(1))
        );
        assert_eq!(
            PredictionBand::new(&[&d[0], &d[3]], 2.5),
            Err(UncertaintyError::RankDeficient(1))
        );
    }

    #[test]
    fn vif_from_the_triangle_is_vif_from_the_rows() {
        let d = design();
        let refs: Vec<&[f64]> = d.iter().map(|c| c.as_slice()).collect();
        let comp = compress(&refs, true, 1).unwrap();
        let names: Vec<String> = ["a", "b", "c", "k"].map(String::from).to_vec();
        let rows = variance_inflation(&names, &refs[..4]);
        let tri =
            variance_inflation_compressed(&names, &comp.r, 400, &[1, 2, 3, 4], &comp.constant);
        assert!(rows[0].vif > 10.0 && rows[2].vif < 1.01, "{rows:?}");
        for (r, t) in rows.iter().zip(&tri) {
            assert_eq!(r.name, t.name);
            assert_eq!(r.vif.is_nan(), t.vif.is_nan(), "{r:?} {t:?}");
            if r.vif.is_finite() {
                assert!((r.vif - t.vif).abs() <= 1e-9 * r.vif, "{r:?} {t:?}");
            }
            match (&r.partner, &t.partner) {
                (Some(rp), Some(tp)) => {
                    assert_eq!(rp.0, tp.0);
                    assert!((rp.1 - tp.1).abs() < 1e-12, "{r:?} {t:?}");
                }
                // the constant column correlates with nothing
                (None, None) => assert_eq!(r.name, "k"),
                _ => panic!("{r:?} {t:?}"),
            }
        }
        assert!(tri[3].vif.is_nan(), "the constant column: {:?}", tri[3]);
        // an exact combination: infinite both ways
        let e: Vec<f64> = d[0].iter().zip(&d[2]).map(|(a, c)| a - 2.0 * c).collect();
        let cols: Vec<&[f64]> = vec![&d[0], &d[2], &e];
        let comp = compress(&cols, true, 1).unwrap();
        let names: Vec<String> = ["a", "c", "e"].map(String::from).to_vec();
        let tri = variance_inflation_compressed(&names, &comp.r, 400, &[1, 2, 3], &comp.constant);
        let rows = variance_inflation(&names, &cols);
        for (r, t) in rows.iter().zip(&tri) {
            assert!(t.vif.is_infinite() && r.vif.is_infinite(), "{r:?} {t:?}");
        }
    }

    #[test]
    fn blocks_are_contiguous_and_cover_every_row() {
        let b = time_blocks(11, 3).unwrap();
        assert_eq!(b, vec![(0, 3), (3, 7), (7, 11)]);
        assert!(time_blocks(5, 3).is_err());
    }
}
