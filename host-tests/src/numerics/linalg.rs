//! Dense linear least squares by Householder QR — never the normal equations.
//!
//! Three layers:
//! - [`Mat`]: a small column-major matrix.
//! - [`compress`]: one streaming pass of Householder QR over tall data `[1 X y]` (row blocks that
//!   fit in cache, one accumulator per thread, merged by a final QR) giving the triangular factor
//!   `R` with `[1 X y] = Q R`. Every least-squares problem on a subset of those columns has the
//!   same solution, residual norm and `(XᵀX)⁻¹` when solved on the columns of `R` instead of the
//!   data (`Q` has orthonormal columns), so later work is O(p³), independent of n.
//! - [`PivotedQr`]: Householder QR with column pivoting (largest remaining column norm, ties to
//!   the lowest index, like LAPACK `dgeqp3`) for rank detection and solving small systems.
//!
//! [`lstsq`] puts them together: intercept handled by the QR itself (centring without
//! subtracting means), columns scaled to unit centred norm, rank detection, coefficients,
//! residuals and the `(RᵀR)⁻¹` diagonal for standard errors.

#![allow(clippy::needless_range_loop)] // index loops read best in numerical kernels

/// Errors of the least-squares routines.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LinalgError {
    /// Column lengths differ.
    #[error("column {column} has {found} rows, expected {expected}")]
    LengthMismatch {
        /// 0-based column.
        column: usize,
        /// Expected number of rows.
        expected: usize,
        /// Found rows.
        found: usize,
    },
    /// Fewer usable (finite) rows than unknowns.
    #[error("expected at least {needed} rows without NaN, found {found}")]
    TooFewRows {
        /// Needed rows.
        needed: usize,
        /// Usable rows.
        found: usize,
    },
}

/// A dense column-major matrix of `f64`.
#[derive(Debug, Clone, PartialEq)]
pub struct Mat {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl Mat {
    /// A zero matrix.
    pub fn zeros(rows: usize, cols: usize) -> Self {
        Mat {
            rows,
            cols,
            data: vec![0.0; rows * cols],
        }
    }
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Number of columns.
    pub fn cols(&self) -> usize {
        self.cols
    }
    /// Element (i, j).
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.data[j * self.rows + i]
    }
    /// Sets element (i, j).
    #[inline]
    pub fn set(&mut self, i: usize, j: usize, v: f64) {
        self.data[j * self.rows + i] = v;
    }
    /// Column j as a slice.
    #[inline]
    pub fn col(&self, j: usize) -> &[f64] {
        &self.data[j * self.rows..(j + 1) * self.rows]
    }
    /// Column j as a mutable slice.
    #[inline]
    pub fn col_mut(&mut self, j: usize) -> &mut [f64] {
        &mut self.data[j * self.rows..(j + 1) * self.rows]
    }
    /// A new matrix with the selected columns, in the given order.
    pub fn select_cols(&self, cols: &[usize]) -> Mat {
        let mut data = Vec::with_capacity(self.rows * cols.len());
        for &c in cols {
            data.extend_from_slice(self.col(c));
        }
        Mat {
            rows: self.rows,
            cols: cols.len(),
            data,
        }
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    // four accumulators so the compiler can vectorise and pipeline
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0f64; 4];
    let chunks = n / 4;
    for k in 0..chunks {
        let i = 4 * k;
        s[0] += a[i] * b[i];
        s[1] += a[i + 1] * b[i + 1];
        s[2] += a[i + 2] * b[i + 2];
        s[3] += a[i + 3] * b[i + 3];
    }
    let mut t = (s[0] + s[2]) + (s[1] + s[3]);
    for i in 4 * chunks..n {
        t += a[i] * b[i];
    }
    t
}

#[inline]
fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// Euclidean norm without overflow for the magnitudes met here (sum of squares).
#[inline]
pub fn norm2(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

/// Streaming Householder QR: accumulates the `k × k` upper-triangular factor of a tall matrix
/// fed in row blocks. Starts from zero rows (`R = 0`).
#[derive(Debug, Clone)]
pub struct RAccumulator {
    k: usize,
    r: Mat,
    rows: usize,
}

impl RAccumulator {
    /// An accumulator for `k` columns.
    pub fn new(k: usize) -> Self {
        RAccumulator {
            k,
            r: Mat::zeros(k, k),
            rows: 0,
        }
    }

    /// Rows absorbed so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Absorbs a block of `b` rows given column-major (`block.len() == b * k`); the block is
    /// overwritten (it holds the Householder vectors afterwards). Computes the QR of `[R; B]`
    /// exploiting that `R` is triangular: reflector j touches `R[j, j..]` and `B[:, j..]` only.
    /// Uses AVX2 + FMA kernels when the CPU has them (detected at run time).
    pub fn push_block(&mut self, block: &mut [f64], b: usize) {
        assert_eq!(
            block.len(),
            b * self.k,
            "RAccumulator::push_block: wrong block size"
        );
        if b == 0 {
            return;
        }
        self.rows += b;
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                unsafe { push_block_avx2(&mut self.r, block, b, self.k) };
                return;
            }
        }
        push_block_kernel::<false>(&mut self.r, block, b, self.k);
    }

    /// Merges another accumulator (QR of the two stacked triangular factors).
    pub fn merge(&mut self, other: &RAccumulator) {
        assert_eq!(self.k, other.k, "RAccumulator::merge: different widths");
        let mut block = other.r.data.clone();
        let rows = self.rows + other.rows;
        self.push_block(&mut block, self.k);
        self.rows = rows;
    }

    /// Consumes the accumulator, returning `R`.
    pub fn into_r(self) -> Mat {
        self.r
    }
}

#[inline(always)]
fn dot_k<const FMA: bool>(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0f64; 8];
    let mut ca = a.chunks_exact(8);
    let mut cb = b.chunks_exact(8);
    for (x, y) in (&mut ca).zip(&mut cb) {
        for i in 0..8 {
            s[i] = if FMA {
                x[i].mul_add(y[i], s[i])
            } else {
                s[i] + x[i] * y[i]
            };
        }
    }
    let mut t = ((s[0] + s[4]) + (s[1] + s[5])) + ((s[2] + s[6]) + (s[3] + s[7]));
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        t += x * y;
    }
    t
}

#[inline(always)]
fn axpy_k<const FMA: bool>(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi = if FMA {
            alpha.mul_add(*xi, *yi)
        } else {
            *yi + alpha * xi
        };
    }
}

/// Makes the Householder reflector of column `j` of `[R; B]` (touching `R[j, j]` and `B[:, j]`):
/// `B[:, j]` becomes its vector below the implicit 1 at `R[j, j]`, `R[j, j]` its β; returns τ
/// (`H = I − τ v vᵀ`; τ = 0 when the column is already triangular: `H = I`).
#[inline(always)]
fn make_reflector<const FMA: bool>(r: &mut Mat, block: &mut [f64], b: usize, j: usize) -> f64 {
    let x = &mut block[j * b..(j + 1) * b];
    let alpha = r.get(j, j);
    let xnorm2 = dot_k::<FMA>(x, x);
    if xnorm2 == 0.0 {
        return 0.0;
    }
    let norm = (alpha * alpha + xnorm2).sqrt();
    let beta = if alpha >= 0.0 { -norm } else { norm };
    let tau = (beta - alpha) / beta;
    let scale = 1.0 / (alpha - beta);
    for v in x.iter_mut() {
        *v *= scale;
    }
    r.set(j, j, beta);
    tau
}

/// Applies reflector `j` (from [`make_reflector`]) to the columns `cols` (all after `j`).
#[inline(always)]
fn apply_reflector<const FMA: bool>(
    r: &mut Mat,
    block: &mut [f64],
    b: usize,
    j: usize,
    tau: f64,
    cols: std::ops::Range<usize>,
) {
    if tau == 0.0 {
        return;
    }
    let (head, tail) = block.split_at_mut((j + 1) * b);
    let x: &[f64] = &head[j * b..];
    for c in cols {
        let col = &mut tail[(c - j - 1) * b..(c - j) * b];
        let w = tau * (r.get(j, c) + dot_k::<FMA>(x, col));
        r.set(j, c, r.get(j, c) - w);
        axpy_k::<FMA>(-w, x, col);
    }
}

/// QR of `[R; B]` (see [`RAccumulator::push_block`]), one reflector at a time over every later
/// column; `FMA` selects fused multiply-add.
#[inline(always)]
fn push_block_kernel<const FMA: bool>(r: &mut Mat, block: &mut [f64], b: usize, k: usize) {
    for j in 0..k {
        let tau = make_reflector::<FMA>(r, block, b, j);
        apply_reflector::<FMA>(r, block, b, j, tau, j + 1..k);
    }
}

/// Reflectors per panel of [`push_block_avx2`].
const PANEL: usize = 4;

/// The AVX2 + FMA QR of `[R; B]`: the same reflectors as [`push_block_kernel`] (equal to
/// rounding), but made [`PANEL`] columns at a time and applied to the later columns together
/// in the compact WY form `I − V Tᵀ Vᵀ` (LAPACK `dlarft`/`dlarfb`, Schreiber & Van Loan 1989),
/// so each later column is read from cache once per panel instead of once per reflector: the
/// column-at-a-time kernel is bound by loads (a dot and an axpy per reflector and column).
/// A reflector's vector is the unit vector of its row of `R` above its column of `B`, so `V`'s
/// part in `R` is the identity and `VᵀV` needs only the `B` part.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn push_block_avx2(r: &mut Mat, block: &mut [f64], b: usize, k: usize) {
    // merges of triangles (b = k) and short blocks: the panel set-up would not pay
    if b < 64 {
        return push_block_kernel::<true>(r, block, b, k);
    }
    let mut j0 = 0;
    while j0 < k {
        let nb = PANEL.min(k - j0);
        let mut tau = [0.0; PANEL];
        for a in 0..nb {
            let j = j0 + a;
            tau[a] = make_reflector::<true>(r, block, b, j);
            apply_reflector::<true>(r, block, b, j, tau[a], j + 1..j0 + nb);
        }
        if nb == PANEL && j0 + PANEL < k {
            // SAFETY: AVX2 and FMA are enabled on this function; the panel and the later
            // columns are disjoint parts of `block`.
            unsafe { apply_panel(r, block, b, k, j0, &tau) };
        }
        j0 += nb;
    }
}

/// Applies the panel of reflectors `j0..j0 + PANEL` (vectors in `block`'s columns, `tau`) to
/// the columns `j0 + PANEL..k` of `[R; B]` in the compact WY form.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn apply_panel(
    r: &mut Mat,
    block: &mut [f64],
    b: usize,
    k: usize,
    j0: usize,
    tau: &[f64; PANEL],
) {
    use std::arch::x86_64::*;
    let (head, tail) = block.split_at_mut((j0 + PANEL) * b);
    let y: [&[f64]; PANEL] = std::array::from_fn(|a| &head[(j0 + a) * b..(j0 + a + 1) * b]);
    // T (upper triangular): H₀H₁H₂H₃ = I − V T Vᵀ; T[a][c] = −τ_c (T[a][..c] · Vᵀv_c)
    let mut t = [[0.0f64; PANEL]; PANEL];
    for c in 0..PANEL {
        t[c][c] = tau[c];
        let g: [f64; PANEL] = std::array::from_fn(|a| {
            if a < c {
                dot_k::<true>(y[a], y[c])
            } else {
                0.0
            }
        });
        for a in 0..c {
            let s: f64 = (a..c).map(|m| t[a][m] * g[m]).sum();
            t[a][c] = -tau[c] * s;
        }
    }
    let yp: [*const f64; PANEL] = std::array::from_fn(|a| y[a].as_ptr());
    let n4 = b / 4 * 4;
    let ncols = k - j0 - PANEL;
    // W = R[j0.., c] + Yᵀ C[:, c]; W ← Tᵀ W; R[j0.., c] −= W; C[:, c] −= Y W
    let finish = |r: &mut Mat, c: usize, yc: [f64; PANEL]| -> [f64; PANEL] {
        let w: [f64; PANEL] = std::array::from_fn(|a| r.get(j0 + a, c) + yc[a]);
        let wt: [f64; PANEL] = std::array::from_fn(|a| (0..=a).map(|m| t[m][a] * w[m]).sum());
        for a in 0..PANEL {
            r.set(j0 + a, c, r.get(j0 + a, c) - wt[a]);
        }
        wt
    };
    let hsum = |v: __m256d| -> f64 {
        let mut l = [0.0f64; 4];
        _mm256_storeu_pd(l.as_mut_ptr(), v);
        (l[0] + l[2]) + (l[1] + l[3])
    };
    let mut q = 0;
    while q < ncols {
        let two = q + 1 < ncols;
        let c = j0 + PANEL + q;
        let p0 = tail.as_mut_ptr().add(q * b);
        let p1 = if two { p0.add(b) } else { p0 };
        let mut acc0 = [_mm256_setzero_pd(); PANEL];
        let mut acc1 = [_mm256_setzero_pd(); PANEL];
        let mut i = 0;
        while i < n4 {
            let c0 = _mm256_loadu_pd(p0.add(i));
            let c1 = _mm256_loadu_pd(p1.add(i));
            for a in 0..PANEL {
                let ya = _mm256_loadu_pd(yp[a].add(i));
                acc0[a] = _mm256_fmadd_pd(ya, c0, acc0[a]);
                acc1[a] = _mm256_fmadd_pd(ya, c1, acc1[a]);
            }
            i += 4;
        }
        let mut d0: [f64; PANEL] = std::array::from_fn(|a| hsum(acc0[a]));
        let mut d1: [f64; PANEL] = std::array::from_fn(|a| hsum(acc1[a]));
        for i in n4..b {
            for a in 0..PANEL {
                d0[a] = (*yp[a].add(i)).mul_add(*p0.add(i), d0[a]);
                d1[a] = (*yp[a].add(i)).mul_add(*p1.add(i), d1[a]);
            }
        }
        let w0 = finish(r, c, d0);
        let w1 = if two {
            finish(r, c + 1, d1)
        } else {
            [0.0; PANEL]
        };
        let m0: [__m256d; PANEL] = std::array::from_fn(|a| _mm256_set1_pd(-w0[a]));
        let m1: [__m256d; PANEL] = std::array::from_fn(|a| _mm256_set1_pd(-w1[a]));
        let mut i = 0;
        while i < n4 {
            let mut c0 = _mm256_loadu_pd(p0.add(i));
            let mut c1 = _mm256_loadu_pd(p1.add(i));
            for a in 0..PANEL {
                let ya = _mm256_loadu_pd(yp[a].add(i));
                c0 = _mm256_fmadd_pd(ya, m0[a], c0);
                c1 = _mm256_fmadd_pd(ya, m1[a], c1);
            }
            _mm256_storeu_pd(p0.add(i), c0);
            if two {
                _mm256_storeu_pd(p1.add(i), c1);
            }
            i += 4;
        }
        for i in n4..b {
            for a in 0..PANEL {
                *p0.add(i) = (*yp[a].add(i)).mul_add(-w0[a], *p0.add(i));
                if two {
                    *p1.add(i) = (*yp[a].add(i)).mul_add(-w1[a], *p1.add(i));
                }
            }
        }
        q += if two { 2 } else { 1 };
    }
}

/// Result of [`compress`].
#[derive(Debug, Clone)]
pub struct Compressed {
    /// `k × k` upper-triangular factor of `[1 X y]` (column 0 is the intercept column when it was
    /// requested), over the rows without NaN.
    pub r: Mat,
    /// Number of rows used (rows with a NaN anywhere are left out).
    pub rows: usize,
    /// For each input row: true if it held a NaN and was left out.
    pub was_nan: Vec<bool>,
    /// For each input column (not the intercept): true if all its used values are equal
    /// (exactly; a constant column has zero variance, which `R` shows only up to rounding).
    pub constant: Vec<bool>,
}

/// Per-thread constancy tracker: the first value seen per column and whether all equal it.
#[derive(Clone)]
struct Constancy {
    first: Vec<Option<f64>>,
    constant: Vec<bool>,
}

impl Constancy {
    fn new(p: usize) -> Self {
        Constancy {
            first: vec![None; p],
            constant: vec![true; p],
        }
    }
    /// Looks at a column-major block of `b` rows whose columns `off..` are the inputs.
    fn observe(&mut self, blk: &[f64], b: usize, off: usize) {
        if b == 0 {
            return;
        }
        for j in 0..self.first.len() {
            if !self.constant[j] {
                continue;
            }
            let col = &blk[(j + off) * b..(j + off + 1) * b];
            let f = *self.first[j].get_or_insert(col[0]);
            if col.iter().any(|&v| v != f) {
                self.constant[j] = false;
            }
        }
    }
    fn merge(&mut self, other: &Constancy) {
        for j in 0..self.first.len() {
            self.constant[j] = self.constant[j]
                && other.constant[j]
                && match (self.first[j], other.first[j]) {
                    (Some(a), Some(b)) => a == b,
                    _ => true,
                };
            if self.first[j].is_none() {
                self.first[j] = other.first[j];
            }
        }
    }
}

/// Rows per block in [`compress`]: the block (rows × columns × 8 bytes) stays in L2 cache.
fn block_rows(k: usize) -> usize {
    (((192 * 1024) / 8) / k.max(1)).clamp(16, 1024)
}

/// The length all `columns` share (0 for none); a column of another length is an error.
fn common_length(columns: &[&[f64]]) -> Result<usize, LinalgError> {
    let n = columns.first().map_or(0, |c| c.len());
    match columns.iter().position(|c| c.len() != n) {
        Some(j) => Err(LinalgError::LengthMismatch {
            column: j,
            expected: n,
            found: columns[j].len(),
        }),
        None => Ok(n),
    }
}

/// Householder-QR-compresses the columns `[1 (if intercept)] ++ columns` (all the same length)
/// to their triangular factor, in one pass over the data, on up to `threads` threads. Rows with
/// a NaN are left out.
pub fn compress(
    columns: &[&[f64]],
    intercept: bool,
    threads: usize,
) -> Result<Compressed, LinalgError> {
    let n = common_length(columns)?;
    let threads = threads.max(1).min(n / 4096 + 1);
    let chunk = n.div_ceil(threads);
    let parts: Vec<CompressedPart> = if threads == 1 {
        vec![compress_range(columns, intercept, 0, n)]
    } else {
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|t| {
                    let lo = (t * chunk).min(n);
                    let hi = ((t + 1) * chunk).min(n);
                    s.spawn(move || compress_range(columns, intercept, lo, hi))
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("compress worker panicked"))
                .collect()
        })
    };
    let refs: Vec<&CompressedPart> = parts.iter().collect();
    Ok(merge_parts(&refs, n))
}

/// The compression of one contiguous range of rows: mergeable with the compressions of other
/// ranges of the same columns ([`merge_parts`]) into the compression of their union, so a fit
/// that leaves one range out (held-out accuracy) costs a merge of small triangles, not another
/// pass over the data.
#[derive(Clone)]
pub struct CompressedPart {
    acc: RAccumulator,
    /// Input rows (global indices) left out for a NaN.
    nan_rows: Vec<usize>,
    constancy: Constancy,
}

/// Compresses rows `lo..hi` of the columns (one thread).
fn compress_range(columns: &[&[f64]], intercept: bool, lo: usize, hi: usize) -> CompressedPart {
    let k = columns.len() + intercept as usize;
    let mut acc = RAccumulator::new(k);
    let mut constancy = Constancy::new(columns.len());
    let mut nan_rows = Vec::new();
    let br = block_rows(k);
    let mut block = vec![0.0; br * k];
    let mut start = lo;
    while start < hi {
        let b = br.min(hi - start);
        let blk = &mut block[..b * k];
        let off = intercept as usize;
        if intercept {
            blk[..b].fill(1.0);
        }
        for (j, c) in columns.iter().enumerate() {
            blk[(j + off) * b..(j + off + 1) * b].copy_from_slice(&c[start..start + b]);
        }
        prefetch_rows(columns, start + b, br.min(hi - start - b));
        // 64 values at a time without stopping early, so that the compiler tests them several
        // at once: a test of one value at a time was most of this function's time (a sixth
        // of the compression's)
        let any_nan = blk
            .chunks(64)
            .any(|c| c.iter().fold(false, |nan, v| nan | v.is_nan()));
        if any_nan {
            // compact: keep rows without NaN
            let keep: Vec<usize> = (0..b)
                .filter(|&i| (0..k).all(|j| !blk[j * b + i].is_nan()))
                .collect();
            for i in 0..b {
                if !keep.contains(&i) {
                    nan_rows.push(start + i);
                }
            }
            let nb = keep.len();
            let mut small = vec![0.0; nb * k];
            for j in 0..k {
                for (t, &i) in keep.iter().enumerate() {
                    small[j * nb + t] = blk[j * b + i];
                }
            }
            constancy.observe(&small, nb, off);
            acc.push_block(&mut small, nb);
        } else {
            constancy.observe(blk, b, off);
            acc.push_block(blk, b);
        }
        start += b;
    }
    CompressedPart {
        acc,
        nan_rows,
        constancy,
    }
}

/// Asks the CPU to bring rows `from..from + len` of every column into its L2 cache while the
/// current block is reduced. Why: the block's copy out of the columns was the compression's
/// only wait on memory (its columns, written by the parse long before, sit in DRAM), and the
/// hardware prefetcher does not follow 40 short streams one after another; the QR of a block
/// takes longer than fetching the next, so the fetch hides behind it.
#[inline]
fn prefetch_rows(columns: &[&[f64]], from: usize, len: usize) {
    #[cfg(target_arch = "x86_64")]
    for c in columns {
        let Some(rows) = c.get(from..from + len) else {
            return;
        };
        // one request per 64-byte line (8 values), the last line too
        for i in (0..len).step_by(8).chain(len.checked_sub(1)) {
            // SAFETY: SSE is part of x86-64; a prefetch never faults, and the address lies in
            // `rows` anyway
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T1 }>(
                    rows.as_ptr().add(i) as *const i8,
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (columns, from, len);
}

/// Compresses the columns (as [`compress`]) separately over the consecutive row ranges
/// `bounds[i]..bounds[i + 1]` (`bounds` ascending, from 0 to the column length), on up to
/// `threads` threads in all: one [`CompressedPart`] per range.
pub fn compress_parts(
    columns: &[&[f64]],
    intercept: bool,
    threads: usize,
    bounds: &[usize],
) -> Result<Vec<CompressedPart>, LinalgError> {
    let n = common_length(columns)?;
    assert!(
        bounds.len() >= 2
            && bounds[0] == 0
            && bounds[bounds.len() - 1] == n
            && bounds.windows(2).all(|w| w[0] <= w[1]),
        "compress_parts: bounds must ascend from 0 to the column length"
    );
    let ranges = bounds.len() - 1;
    // every range in as many pieces as keep the threads busy; pieces merge into their range.
    // Each range in `threads` pieces, so that equal ranges make a multiple of `threads` equal
    // tasks: 5 held-out blocks in one piece each left one of two threads alone with the fifth,
    // a tenth of the whole command's wall time
    let threads = threads.max(1).min(n / 4096 + 1);
    let pieces_per_range = if ranges.is_multiple_of(threads) {
        1
    } else {
        threads
    };
    let tasks: Vec<(usize, usize, usize)> = (0..ranges)
        .flat_map(|r| {
            let (lo, hi) = (bounds[r], bounds[r + 1]);
            let chunk = (hi - lo).div_ceil(pieces_per_range).max(1);
            (0..pieces_per_range)
                .map(move |q| (r, (lo + q * chunk).min(hi), (lo + (q + 1) * chunk).min(hi)))
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let worker = || {
        let mut done = Vec::new();
        loop {
            let t = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let Some(&(r, lo, hi)) = tasks.get(t) else {
                return done;
            };
            done.push((t, r, compress_range(columns, intercept, lo, hi)));
        }
    };
    let mut pieces: Vec<(usize, usize, CompressedPart)> = if threads == 1 {
        worker()
    } else {
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads).map(|_| s.spawn(worker)).collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().expect("compress worker panicked"))
                .collect()
        })
    };
    pieces.sort_by_key(|(t, _, _)| *t);
    let mut out: Vec<CompressedPart> = Vec::with_capacity(ranges);
    let mut last_range = usize::MAX;
    for (_, r, piece) in pieces {
        if r == last_range {
            out.last_mut()
                .expect("a piece of this range")
                .absorb(&piece);
        } else {
            out.push(piece);
            last_range = r;
        }
    }
    Ok(out)
}

impl CompressedPart {
    /// The input rows (global indices) left out for a NaN.
    pub fn left_out(&self) -> &[usize] {
        &self.nan_rows
    }

    fn absorb(&mut self, other: &CompressedPart) {
        self.acc.merge(&other.acc);
        self.constancy.merge(&other.constancy);
        self.nan_rows.extend_from_slice(&other.nan_rows);
    }
}

/// The compression of the union of the parts' rows (`n`: the length of the input columns).
pub fn merge_parts(parts: &[&CompressedPart], n: usize) -> Compressed {
    let mut iter = parts.iter();
    let mut acc = (*iter.next().expect("at least one part")).clone();
    for other in iter {
        acc.absorb(other);
    }
    let mut was_nan = vec![false; n];
    for &i in &acc.nan_rows {
        was_nan[i] = true;
    }
    let rows = acc.acc.rows();
    Compressed {
        r: acc.acc.into_r(),
        rows,
        was_nan,
        constant: acc.constancy.constant,
    }
}

/// Householder QR with column pivoting, `A P = Q R`, of a small dense matrix.
#[derive(Debug, Clone)]
pub struct PivotedQr {
    /// Householder vectors below the diagonal (implicit 1 on it), R on and above.
    qr: Mat,
    tau: Vec<f64>,
    perm: Vec<usize>,
}

impl PivotedQr {
    /// Factorises `a` (`m × n`). Pivot: the column with the largest remaining norm, recomputed
    /// exactly at each step; ties go to the lowest index.
    pub fn new(mut a: Mat) -> Self {
        let (m, n) = (a.rows, a.cols);
        let steps = m.min(n);
        let mut perm: Vec<usize> = (0..n).collect();
        let mut tau = vec![0.0; steps];
        for j in 0..steps {
            let mut best = j;
            let mut best_norm = -1.0;
            for c in j..n {
                let v = &a.col(c)[j..];
                let nn = dot(v, v);
                if nn > best_norm {
                    best_norm = nn;
                    best = c;
                }
            }
            if best != j {
                perm.swap(j, best);
                for i in 0..m {
                    a.data.swap(j * m + i, best * m + i);
                }
            }
            let alpha = a.get(j, j);
            let x = &a.col(j)[j + 1..];
            let xnorm2 = dot(x, x);
            if xnorm2 == 0.0 {
                tau[j] = 0.0;
                continue;
            }
            let norm = (alpha * alpha + xnorm2).sqrt();
            let beta = if alpha >= 0.0 { -norm } else { norm };
            tau[j] = (beta - alpha) / beta;
            let scale = 1.0 / (alpha - beta);
            for v in a.col_mut(j)[j + 1..].iter_mut() {
                *v *= scale;
            }
            a.set(j, j, beta);
            let (head, tail) = a.data.split_at_mut((j + 1) * m);
            let v = &head[j * m + j + 1..(j + 1) * m];
            for c in (j + 1)..n {
                let col = &mut tail[(c - j - 1) * m..(c - j) * m];
                let w = tau[j] * (col[j] + dot(v, &col[j + 1..]));
                col[j] -= w;
                axpy(-w, v, &mut col[j + 1..]);
            }
        }
        PivotedQr { qr: a, tau, perm }
    }

    /// Column permutation: column `k` of `A P` is column `perm()[k]` of `A`.
    pub fn perm(&self) -> &[usize] {
        &self.perm
    }

    /// Numerical rank: the number of leading `|R[i,i]| > tol · |R[0,0]|`.
    pub fn rank(&self, tol: f64) -> usize {
        let steps = self.tau.len();
        if steps == 0 {
            return 0;
        }
        let r0 = self.qr.get(0, 0).abs();
        (0..steps)
            .filter(|&i| self.qr.get(i, i).abs() > tol * r0)
            .count()
    }

    /// Overwrites `v` (length m) with `Qᵀ v`.
    pub fn apply_qt(&self, v: &mut [f64]) {
        let m = self.qr.rows;
        for (j, &t) in self.tau.iter().enumerate() {
            if t == 0.0 {
                continue;
            }
            let h = &self.qr.col(j)[j + 1..m];
            let w = t * (v[j] + dot(h, &v[j + 1..]));
            v[j] -= w;
            axpy(-w, h, &mut v[j + 1..]);
        }
    }

    /// Overwrites `v` (length m) with `Q v`.
    pub fn apply_q(&self, v: &mut [f64]) {
        let m = self.qr.rows;
        for (j, &t) in self.tau.iter().enumerate().rev() {
            if t == 0.0 {
                continue;
            }
            let h = &self.qr.col(j)[j + 1..m];
            let w = t * (v[j] + dot(h, &v[j + 1..]));
            v[j] -= w;
            axpy(-w, h, &mut v[j + 1..]);
        }
    }

    /// Solves `R[..r, ..r] z = rhs[..r]` by back substitution (pivoted order).
    pub fn solve_r(&self, r: usize, rhs: &[f64]) -> Vec<f64> {
        let mut z = rhs[..r].to_vec();
        for i in (0..r).rev() {
            let mut s = z[i];
            for j in (i + 1)..r {
                s -= self.qr.get(i, j) * z[j];
            }
            z[i] = s / self.qr.get(i, i);
        }
        z
    }

    /// `R[..r, ..r]⁻¹` (upper triangular, r × r, pivoted order).
    pub fn r_inverse(&self, r: usize) -> Mat {
        let mut inv = Mat::zeros(r, r);
        for c in 0..r {
            let mut e = vec![0.0; r];
            e[c] = 1.0;
            let z = self.solve_r(c + 1, &e[..c + 1]);
            for (i, zi) in z.into_iter().enumerate() {
                inv.set(i, c, zi);
            }
        }
        inv
    }
}

/// A least-squares fit `y ≈ b0 + Σ b_j x_j` from [`lstsq`].
#[derive(Debug, Clone)]
pub struct LeastSquares {
    /// Coefficients per column (0 for columns dropped as linearly dependent).
    pub coeffs: Vec<f64>,
    /// Intercept (0 when no intercept was fitted).
    pub intercept: f64,
    /// Numerical rank of the design (without the intercept).
    pub rank: usize,
    /// For each column: false if it was dropped as linearly dependent.
    pub used: Vec<bool>,
    /// Residuals `y − ŷ` per row (NaN for rows left out because of a NaN).
    pub residuals: Vec<f64>,
    /// Residual sum of squares.
    pub rss: f64,
    /// Residual degrees of freedom: rows − rank − (1 if intercept).
    pub dof: usize,
    /// Diagonal of `(XᵀX)⁻¹` per column (of the centred columns when an intercept is fitted;
    /// 0 for dropped columns): `se_j = sqrt(rss/dof · diag_j)`.
    pub xtx_inv_diag: Vec<f64>,
    /// The same for the intercept (0 without intercept).
    pub intercept_xtx_inv: f64,
}

impl LeastSquares {
    /// Root-mean-square error `sqrt(rss / dof)` (NaN when dof = 0).
    pub fn rmse(&self) -> f64 {
        (self.rss / self.dof as f64).sqrt()
    }
    /// Standard errors of the coefficients.
    pub fn std_errors(&self) -> Vec<f64> {
        let s2 = self.rss / self.dof as f64;
        self.xtx_inv_diag.iter().map(|d| (s2 * d).sqrt()).collect()
    }
}

/// Least squares of `y` on the columns `x` (plus an intercept if asked), by Householder QR:
/// the data are compressed to a triangular factor in one pass; the columns of that factor are
/// scaled to unit (centred) norm and factorised again with column pivoting for rank detection
/// (tolerance `max(n, p+1)·ε·|R₀₀|`). Rows with a NaN are left out.
pub fn lstsq(x: &[&[f64]], y: &[f64], intercept: bool) -> Result<LeastSquares, LinalgError> {
    let p = x.len();
    let n = y.len();
    let mut cols: Vec<&[f64]> = x.to_vec();
    cols.push(y);
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    let comp = compress(&cols, intercept, threads)?;
    let off = intercept as usize;
    let needed = p + off;
    if comp.rows < needed.max(1) {
        return Err(LinalgError::TooFewRows {
            needed: needed.max(1),
            found: comp.rows,
        });
    }
    let r = &comp.r;
    let k = r.cols();
    // sub-problem on rows off..k (centred part when intercept), columns off..off+p, rhs column k-1
    let m = k - off;
    let mut a = Mat::zeros(m, p);
    let mut scale = vec![1.0; p];
    for j in 0..p {
        let c: Vec<f64> = (off..k).map(|i| r.get(i, j + off)).collect();
        let nrm = norm2(&c);
        scale[j] = if nrm > 0.0 { nrm } else { 1.0 };
        for (i, v) in c.iter().enumerate() {
            a.set(i, j, v / scale[j]);
        }
    }
    let mut rhs: Vec<f64> = (off..k).map(|i| r.get(i, k - 1)).collect();
    let qr = PivotedQr::new(a);
    let tol = (comp.rows.max(p + 1)) as f64 * f64::EPSILON;
    let rank = if p == 0 { 0 } else { qr.rank(tol) };
    qr.apply_qt(&mut rhs);
    let z = qr.solve_r(rank, &rhs);
    let mut coeffs = vec![0.0; p];
    let mut used = vec![false; p];
    let perm = qr.perm();
    for (t, &zt) in z.iter().enumerate() {
        coeffs[perm[t]] = zt / scale[perm[t]];
        used[perm[t]] = true;
    }
    // (XᵀX)⁻¹ diagonal in original units: C = Rinv Rinv^T (pivoted, scaled)
    let rinv = qr.r_inverse(rank);
    let mut xtx_inv_diag = vec![0.0; p];
    for t in 0..rank {
        let s: f64 = (t..rank).map(|c| rinv.get(t, c).powi(2)).sum();
        xtx_inv_diag[perm[t]] = s / (scale[perm[t]] * scale[perm[t]]);
    }
    // intercept from row 0: r00 b0 + Σ r0j bj = r0y
    let (b0, intercept_xtx_inv) = if intercept {
        let r00 = r.get(0, 0);
        let mut s = r.get(0, k - 1);
        for j in 0..p {
            s -= r.get(0, j + 1) * coeffs[j];
        }
        // var(b0)/σ² = 1/r00² + gᵀ C g with g_j = r0j / r00 (original units)
        let g: Vec<f64> = (0..rank)
            .map(|t| r.get(0, perm[t] + 1) / r00 / scale[perm[t]])
            .collect();
        // C (scaled, pivoted) = Rinv Rinv^T  →  gᵀ C g = ||Rinvᵀ g||²
        let mut q = 0.0;
        for c in 0..rank {
            let v: f64 = (0..=c).map(|t| rinv.get(t, c) * g[t]).sum();
            q += v * v;
        }
        (s / r00, 1.0 / (r00 * r00) + q)
    } else {
        (0.0, 0.0)
    };
    let mut residuals = vec![f64::NAN; n];
    let mut rss = 0.0;
    for i in 0..n {
        if comp.was_nan[i] {
            continue;
        }
        let mut yh = b0;
        for j in 0..p {
            yh += coeffs[j] * x[j][i];
        }
        let e = y[i] - yh;
        residuals[i] = e;
        rss += e * e;
    }
    Ok(LeastSquares {
        coeffs,
        intercept: b0,
        rank,
        used,
        residuals,
        rss,
        dof: comp.rows.saturating_sub(rank + off),
        xtx_inv_diag,
        intercept_xtx_inv,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
    }

    #[test]
    fn exact_polynomial_is_recovered() {
        let x: Vec<f64> = (0..50).map(|i| i as f64 * 10.0).collect();
        let x2: Vec<f64> = x.iter().map(|v| v * v).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 - 0.5 * v + 2e-4 * v * v).collect();
        let fit = lstsq(&[&x, &x2], &y, true).unwrap();
        assert!((fit.intercept - 3.0).abs() < 1e-9);
        assert!((fit.coeffs[0] + 0.5).abs() < 1e-12);
        assert!((fit.coeffs[1] - 2e-4).abs() < 1e-15);
        assert!(fit.rss < 1e-15);
        assert_eq!(fit.rank, 2);
    }

    #[test]
    fn dependent_column_is_dropped() {
        let mut s = 7;
        let a: Vec<f64> = (0..40).map(|_| lcg(&mut s)).collect();
        let b: Vec<f64> = (0..40).map(|_| lcg(&mut s)).collect();
        let c: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 2.0 * x - y).collect();
        let y: Vec<f64> = a
            .iter()
            .zip(&b)
            .map(|(x, y)| 1.0 + x + y + 0.01 * lcg(&mut 3))
            .collect();
        let fit = lstsq(&[&a, &b, &c], &y, true).unwrap();
        assert_eq!(fit.rank, 2);
        assert_eq!(fit.used.iter().filter(|u| !**u).count(), 1);
    }

    #[test]
    fn compress_matches_direct_qr_invariants() {
        // RᵀR = AᵀA for a tall random matrix, across threads and block boundaries
        let mut s = 11;
        let n = 5000;
        let cols: Vec<Vec<f64>> = (0..3)
            .map(|_| (0..n).map(|_| lcg(&mut s) + 5.0).collect())
            .collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        for threads in [1, 2, 3] {
            let c = compress(&refs, true, threads).unwrap();
            assert_eq!(c.rows, n);
            let k = 4;
            for i in 0..k {
                for j in 0..k {
                    let rtr: f64 = (0..k).map(|t| c.r.get(t, i) * c.r.get(t, j)).sum();
                    let ci = |r: usize| if i == 0 { 1.0 } else { cols[i - 1][r] };
                    let cj = |r: usize| if j == 0 { 1.0 } else { cols[j - 1][r] };
                    let ata: f64 = (0..n).map(|r| ci(r) * cj(r)).sum();
                    assert!(
                        (rtr - ata).abs() <= 1e-10 * ata.abs().max(1.0),
                        "{i},{j}: {rtr} vs {ata}"
                    );
                }
            }
        }
    }

    #[test]
    fn panels_give_the_column_kernels_triangle() {
        // the AVX2 path applies reflectors four at a time (compact WY); the portable kernel one
        // at a time: the same factor up to rounding, for widths with a partial last panel,
        // blocks with a tail of rows not a multiple of four, and on top of an earlier block
        let mut s = 17;
        for (k, rows) in [(11, 203), (8, 64), (13, 1000), (42, 585)] {
            let mut blocks: Vec<Vec<f64>> = (0..2)
                .map(|_| {
                    (0..rows * k)
                        .map(|i| lcg(&mut s) + if i < rows { 3.0 } else { 0.0 })
                        .collect()
                })
                .collect();
            let mut fast = RAccumulator::new(k);
            let mut plain = Mat::zeros(k, k);
            for blk in blocks.iter_mut() {
                let mut copy = blk.clone();
                fast.push_block(blk, rows);
                push_block_kernel::<false>(&mut plain, &mut copy, rows, k);
            }
            let fast = fast.into_r();
            let scale = (0..k).map(|j| plain.get(j, j).abs()).fold(0.0, f64::max);
            for i in 0..k {
                for j in i..k {
                    let (a, b) = (fast.get(i, j), plain.get(i, j));
                    assert!(
                        (a - b).abs() <= 1e-12 * scale,
                        "k {k}, rows {rows}, R[{i},{j}]: {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn standard_errors_match_textbook_simple_regression() {
        let x: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let mut s = 5;
        let y: Vec<f64> = x.iter().map(|v| 1.0 + 2.0 * v + lcg(&mut s)).collect();
        let fit = lstsq(&[&x], &y, true).unwrap();
        let n = x.len() as f64;
        let xm = x.iter().sum::<f64>() / n;
        let sxx: f64 = x.iter().map(|v| (v - xm).powi(2)).sum();
        assert!((fit.xtx_inv_diag[0] - 1.0 / sxx).abs() < 1e-14);
        assert!((fit.intercept_xtx_inv - (1.0 / n + xm * xm / sxx)).abs() < 1e-12);
        assert_eq!(fit.dof, 18);
    }
}
