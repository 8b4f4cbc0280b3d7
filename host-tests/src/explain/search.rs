//! Searching a candidate's nonlinear parameters against the current model, fast: the current
//! model's columns (and the intercept) are orthonormalised once per round on the rows explain
//! fits ([`Basis`]); the residual sum of squares with extra columns is then the current one
//! minus their projection onto the orthogonal complement — O(rows × columns) per trial instead
//! of a new QR. Gram–Schmidt is applied twice ("twice is enough", Giraud et al., Numer. Math.
//! 101, 2005), which keeps the basis orthonormal to working precision.

use super::estimate::Theta;
use super::parallel::in_parallel;
use crate::explain::data::Data;
use crate::explain::fit::{gather, Design};

/// Orthonormal basis of the current model's columns on the fitted rows, with the residual.
#[derive(Clone, Debug)]
pub struct Basis {
    /// Rows (indices into the recording) the basis lives on.
    pub rows: Vec<usize>,
    q: Vec<Vec<f64>>,
    r: Vec<f64>,
    rss: f64,
}

/// Relative size below which a column is taken as already spanned.
const DEPENDENT: f64 = 1e-9;

/// Dot product with four accumulators (lets the compiler vectorise it).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0f64; 4];
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        for i in 0..4 {
            s[i] += x[i] * y[i];
        }
    }
    let mut t = (s[0] + s[2]) + (s[1] + s[3]);
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        t += x * y;
    }
    t
}

/// y −= c·x.
fn sub_scaled(y: &mut [f64], c: f64, x: &[f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi -= c * xi;
    }
}

impl Basis {
    /// The intercept and `cols` on `rows`, and `y`'s residual after them.
    pub fn new(cols: &[&[f64]], y: &[f64], rows: Vec<usize>) -> Self {
        let mut b = Basis {
            q: Vec::new(),
            r: gather(y, &rows),
            rss: 0.0,
            rows,
        };
        b.rss = dot(&b.r, &b.r);
        b.add(vec![1.0; b.rows.len()]);
        for c in cols {
            let g = gather(c, &b.rows);
            b.add(g);
        }
        b
    }

    /// Columns spanned (intercept included).
    pub fn dim(&self) -> usize {
        self.q.len()
    }

    /// The most recently added basis vector (on the basis rows).
    pub fn last(&self) -> &[f64] {
        self.q.last().map_or(&[], |v| v.as_slice())
    }

    /// Residual sum of squares of the current model on the basis rows.
    pub fn rss(&self) -> f64 {
        self.rss
    }

    /// The current residual on the basis rows.
    pub fn residual(&self) -> &[f64] {
        &self.r
    }

    /// `x` (already on the basis rows) minus its projection onto the basis; None if spanned.
    pub fn orthogonal(&self, mut x: Vec<f64>) -> Option<Vec<f64>> {
        let n0 = dot(&x, &x).sqrt();
        if n0 == 0.0 || !n0.is_finite() {
            return None;
        }
        for _ in 0..2 {
            for q in &self.q {
                let c = dot(q, &x);
                sub_scaled(&mut x, c, q);
            }
        }
        let n1 = dot(&x, &x).sqrt();
        (n1 > DEPENDENT * n0).then(|| {
            for v in x.iter_mut() {
                *v /= n1;
            }
            x
        })
    }

    /// Adds a column (on the basis rows); returns false when it was already spanned.
    pub fn add(&mut self, x: Vec<f64>) -> bool {
        match self.orthogonal(x) {
            Some(e) => {
                let c = dot(&e, &self.r);
                sub_scaled(&mut self.r, c, &e);
                self.rss = dot(&self.r, &self.r);
                self.q.push(e);
                true
            }
            None => false,
        }
    }

    /// Adds a full-length column (gathers it first).
    pub fn add_column(&mut self, x: &[f64]) -> bool {
        let g = gather(x, &self.rows);
        self.add(g)
    }

    /// Residual sum of squares with the full-length columns `xs` added.
    pub fn rss_with(&self, xs: &[&[f64]]) -> f64 {
        let g: Vec<Vec<f64>> = xs.iter().map(|x| gather(x, &self.rows)).collect();
        self.rss_with_gathered(g)
    }

    /// [`Basis::rss_with`] for columns already on the basis rows.
    pub fn rss_with_gathered(&self, xs: Vec<Vec<f64>>) -> f64 {
        let mut b = Basis {
            rows: Vec::new(),
            q: Vec::new(),
            r: self.r.clone(),
            rss: self.rss,
        };
        for g in xs {
            // orthogonal to the model, then (in `add`) to the columns already added
            if let Some(e) = self.orthogonal(g) {
                b.add(e);
            }
        }
        b.rss
    }

    /// `x` (on the basis rows) minus its projection onto the basis, not normalised.
    pub fn project_out(&self, mut x: Vec<f64>) -> Vec<f64> {
        for _ in 0..2 {
            for q in &self.q {
                let c = dot(q, &x);
                sub_scaled(&mut x, c, q);
            }
        }
        x
    }

    /// The least-squares problem "current residual on the full-length columns `xs`, on top of
    /// the model" reduced to m × m by a QR of the columns' parts orthogonal to the model:
    /// returns (R as columns of length m, b, rest) with |r − X w|² = rest + |b − R w|² for
    /// every w — exact, whatever constraint (non-negativity) w is then solved under.
    pub fn reduce(&self, xs: &[&[f64]]) -> (Vec<Vec<f64>>, Vec<f64>, f64) {
        self.reduce_gathered(xs.iter().map(|x| gather(x, &self.rows)).collect())
    }

    /// [`Basis::reduce`] for columns already on the basis rows.
    pub fn reduce_gathered(&self, xs: Vec<Vec<f64>>) -> (Vec<Vec<f64>>, Vec<f64>, f64) {
        let m = xs.len();
        let mut e: Vec<Vec<f64>> = Vec::with_capacity(m);
        let mut r_cols = vec![vec![0.0; m]; m];
        for (j, x) in xs.into_iter().enumerate() {
            let mut v = self.project_out(x);
            let n0 = dot(&v, &v).sqrt();
            for _ in 0..2 {
                for (k, ek) in e.iter().enumerate() {
                    let c = dot(ek, &v);
                    r_cols[j][k] += c;
                    sub_scaled(&mut v, c, ek);
                }
            }
            let nv = dot(&v, &v).sqrt();
            if nv > DEPENDENT * n0.max(f64::MIN_POSITIVE) {
                r_cols[j][j] = nv;
                e.push(v.into_iter().map(|vi| vi / nv).collect());
            } else {
                e.push(vec![0.0; self.rows.len()]);
            }
        }
        let b: Vec<f64> = e.iter().map(|ek| dot(ek, &self.r)).collect();
        let rest = (self.rss - dot(&b, &b)).max(0.0);
        (r_cols, b, rest)
    }
}

/// What a candidate's search can look at: the recording, the channel, the current model (as a
/// basis on the fitted rows), and the round's effective sample size.
pub struct Search<'a> {
    /// The recording.
    pub d: &'a Data,
    /// The channel.
    pub ch: usize,
    /// The response, µm (NaN rows: outliers, left out).
    pub y: &'a [f64],
    /// The current model's columns (without the intercept).
    pub model: Vec<&'a [f64]>,
    /// Orthonormal basis of the current model on the fitted rows.
    pub basis: Basis,
    /// Effective number of independent rows this round (for the BIC).
    pub n_eff: f64,
    /// The standard held-out design.
    pub design: &'a Design,
    /// Whether [`Search::minimise`] works out profile widths (false: the values alone, for the
    /// jackknife's repeated searches, whose spread is the uncertainty).
    pub sigmas: bool,
}

impl Search<'_> {
    /// Minimise `rss(θ)` over a log-spaced grid on [lo, hi], refined by golden-section search
    /// on log θ between the best point's neighbours; with `sigma`, θ's 1σ from the profile
    /// (where n_eff·ln(RSS/RSS_min) rises by 1), else NaN. Returns the θ estimate and its RSS.
    pub fn minimise(
        &self,
        name: &str,
        range: (f64, f64),
        points: usize,
        sigma: bool,
        rss: impl Fn(f64) -> f64 + Sync,
    ) -> (Theta, f64) {
        self.minimise_ahead(name, range, points, sigma, rss, |_| {})
    }

    /// [`Search::minimise`], telling `ahead` the θ values it is about to ask `rss` for before
    /// it asks: the point it needs now with both points it may need next (golden section,
    /// bisection), or the first steps of the profile's ladder. Only a hint — a candidate whose
    /// columns are cheaper made several at a time (lag filters side by side) makes them
    /// together; the search and its result are those of [`Search::minimise`].
    pub fn minimise_ahead(
        &self,
        name: &str,
        (lo, hi): (f64, f64),
        points: usize,
        sigma: bool,
        rss: impl Fn(f64) -> f64 + Sync,
        ahead: impl Fn(&[f64]),
    ) -> (Theta, f64) {
        let grid = log_grid(lo, hi, points);
        // the grid's points are independent: side by side where a core is idle
        let vals: Vec<f64> = in_parallel(&grid, |&t| rss(t));
        let bi = (0..grid.len())
            .min_by(|&a, &b| vals[a].total_cmp(&vals[b]))
            .unwrap_or(0);
        let (mut best_t, mut best_rss) = (grid[bi], vals[bi]);
        if grid.len() >= 3 {
            let g = 0.618_033_988_75;
            let (mut a, mut b) = (
                grid[bi.saturating_sub(1)].ln(),
                grid[(bi + 1).min(grid.len() - 1)].ln(),
            );
            let mut x1 = b - g * (b - a);
            let mut x2 = a + g * (b - a);
            ahead(&[x1.exp(), x2.exp()]);
            let mut f1 = rss(x1.exp());
            let mut f2 = rss(x2.exp());
            // one step: the bracket kept (the lower side when `lower`) and the new point
            let step = |(a, b, x1, x2): (f64, f64, f64, f64), lower: bool| {
                if lower {
                    let b = x2;
                    let x1n = b - g * (b - a);
                    ((a, b, x1n, x1), x1n)
                } else {
                    let a = x1;
                    let x2n = a + g * (b - a);
                    ((a, b, x2, x2n), x2n)
                }
            };
            const STEPS: usize = 8;
            for i in 0..STEPS {
                let lower = f1 < f2;
                let (next, x) = step((a, b, x1, x2), lower);
                if i % 2 == 0 && i + 1 < STEPS {
                    // this step's point and both the next step may take
                    let (_, lo_next) = step(next, true);
                    let (_, hi_next) = step(next, false);
                    ahead(&[x.exp(), lo_next.exp(), hi_next.exp()]);
                }
                let fx = rss(x.exp());
                (a, b, x1, x2) = next;
                if lower {
                    f2 = f1;
                    f1 = fx;
                } else {
                    f1 = f2;
                    f2 = fx;
                }
            }
            let (xm, fm) = if f1 < f2 { (x1, f1) } else { (x2, f2) };
            if fm < best_rss {
                best_rss = fm;
                best_t = xm.exp();
            }
        }
        let sigma = if sigma && self.sigmas {
            profile_sigma(
                best_t,
                best_rss,
                self.n_eff,
                lo,
                hi,
                &mut |t| rss(t),
                &ahead,
            )
        } else {
            f64::NAN
        };
        (
            Theta {
                name: name.to_string(),
                value: best_t,
                sigma,
                lo,
                hi,
            },
            best_rss,
        )
    }
}

/// 1σ of a log-scale parameter θ from the RSS profile: the distance (on log θ, converted back)
/// at which n_eff·ln(RSS/RSS_min) rises by 1, averaged over both sides; one-sided when the
/// other side leaves the searched range; infinite when the profile is flat.
pub fn profile_sigma(
    theta: f64,
    rss_min: f64,
    n_eff: f64,
    lo: f64,
    hi: f64,
    rss: &mut impl FnMut(f64) -> f64,
    ahead: &impl Fn(&[f64]),
) -> f64 {
    let l0 = theta.ln();
    let mut g = |lt: f64| n_eff * (rss(lt.exp()) / rss_min).max(1e-300).ln() - 1.0;
    let mut bounds = [f64::NAN; 2];
    for (s, sign) in [1.0f64, -1.0].into_iter().enumerate() {
        let room = if sign > 0.0 {
            (hi.ln() - l0).max(0.0) + 0.7
        } else {
            (l0 - lo.ln()).max(0.0) + 0.7
        };
        let mut inner = 0.0;
        let mut outer = f64::NAN;
        const LADDER: [f64; 7] = [0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6];
        // the ladder's first steps are asked for together (most profiles rise within them)
        let first: Vec<f64> = LADDER[..4]
            .iter()
            .filter(|&&step| step <= room)
            .map(|&step| (l0 + sign * step).exp())
            .collect();
        ahead(&first);
        for step in LADDER {
            if step > room {
                break;
            }
            if g(l0 + sign * step) > 0.0 {
                outer = step;
                break;
            }
            inner = step;
        }
        if outer.is_nan() {
            continue;
        }
        for i in 0..5 {
            let mid = 0.5 * (inner + outer);
            if i % 2 == 0 && i + 1 < 5 {
                // this step's point and both the next step may take
                ahead(&[
                    (l0 + sign * mid).exp(),
                    (l0 + sign * (0.5 * (inner + mid))).exp(),
                    (l0 + sign * (0.5 * (mid + outer))).exp(),
                ]);
            }
            if g(l0 + sign * mid) > 0.0 {
                outer = mid;
            } else {
                inner = mid;
            }
        }
        bounds[s] = 0.5 * (inner + outer);
    }
    let width = match (bounds[0].is_finite(), bounds[1].is_finite()) {
        (true, true) => 0.5 * (bounds[0] + bounds[1]),
        (true, false) => bounds[0],
        (false, true) => bounds[1],
        _ => return f64::INFINITY,
    };
    theta * width
}

/// Log-spaced grid of `k` values from `lo` to `hi`.
pub fn log_grid(lo: f64, hi: f64, k: usize) -> Vec<f64> {
    if !(hi > lo && lo > 0.0) || k < 2 {
        return vec![lo.max(hi)];
    }
    (0..k)
        .map(|i| lo * (hi / lo).powf(i as f64 / (k - 1) as f64))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projected_rss_matches_a_full_least_squares_fit() {
        let n = 400;
        let x1: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin()).collect();
        let x2: Vec<f64> = (0..n).map(|i| (i as f64 * 0.037).cos()).collect();
        let x3: Vec<f64> = (0..n).map(|i| (i as f64 / n as f64).powi(2)).collect();
        let y: Vec<f64> = (0..n)
            .map(|i| 2.0 + x1[i] - 0.5 * x2[i] + 3.0 * x3[i] + 0.01 * ((i * 7919) % 13) as f64)
            .collect();
        let rows: Vec<usize> = (0..n).collect();
        let b = Basis::new(&[&x1], &y, rows);
        let with = b.rss_with(&[&x2, &x3]);
        let ls = crate::numerics::linalg::lstsq(&[&x1, &x2, &x3], &y, true).unwrap();
        assert!(
            (with - ls.rss).abs() < 1e-9 * ls.rss.max(1e-12),
            "{with} vs {}",
            ls.rss
        );
        let base = crate::numerics::linalg::lstsq(&[&x1], &y, true).unwrap();
        assert!((b.rss() - base.rss).abs() < 1e-9 * base.rss);
        // a spanned column changes nothing
        let dup: Vec<f64> = x1.iter().map(|v| 3.0 * v + 1.0).collect();
        assert!((b.rss_with(&[&dup]) - b.rss()).abs() < 1e-9 * b.rss());
    }
}
