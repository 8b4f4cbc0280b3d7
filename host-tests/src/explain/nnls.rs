//! Non-negative least squares (Lawson & Hanson, "Solving Least Squares Problems", 1974,
//! ch. 23, algorithm NNLS) on a small dense problem: min |b − A w| subject to w ≥ 0. Explain
//! uses it on the m × m reduction of a play-operator bank (see
//! [`crate::explain::search::Basis::reduce`]); each passive-set subproblem is solved by the
//! host's Householder QR.

use crate::numerics::linalg::lstsq;

/// Solves min |b − A w|, w ≥ 0, for A given as columns (each of length `b.len()`).
pub fn nnls(a: &[Vec<f64>], b: &[f64]) -> Vec<f64> {
    let m = a.len();
    let rows = b.len();
    let mut w = vec![0.0; m];
    let mut passive = vec![false; m];
    let scale = a
        .iter()
        .flat_map(|c| c.iter())
        .fold(0.0f64, |s, v| s.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let tol = 1e-12 * scale * b.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
    let residual = |w: &[f64]| -> Vec<f64> {
        (0..rows)
            .map(|i| b[i] - (0..m).map(|j| a[j][i] * w[j]).sum::<f64>())
            .collect()
    };
    for _outer in 0..3 * m + 3 {
        let r = residual(&w);
        let grad: Vec<f64> = (0..m)
            .map(|j| a[j].iter().zip(&r).map(|(x, y)| x * y).sum())
            .collect();
        let Some(j) = (0..m)
            .filter(|&j| !passive[j] && grad[j] > tol)
            .max_by(|&x, &y| grad[x].total_cmp(&grad[y]))
        else {
            break;
        };
        passive[j] = true;
        for _inner in 0..3 * m + 3 {
            let idx: Vec<usize> = (0..m).filter(|&k| passive[k]).collect();
            let cols: Vec<&[f64]> = idx.iter().map(|&k| a[k].as_slice()).collect();
            let z_p = match lstsq(&cols, b, false) {
                Ok(ls) => ls.coeffs,
                Err(_) => break,
            };
            let mut z = vec![0.0; m];
            for (t, &k) in idx.iter().enumerate() {
                z[k] = z_p[t];
            }
            if idx.iter().all(|&k| z[k] > 0.0) {
                w = z;
                break;
            }
            // step from w towards z until the first passive weight reaches zero
            let alpha = idx
                .iter()
                .filter(|&&k| z[k] <= 0.0)
                .map(|&k| w[k] / (w[k] - z[k]))
                .fold(f64::INFINITY, f64::min)
                .clamp(0.0, 1.0);
            for k in 0..m {
                w[k] += alpha * (z[k] - w[k]);
                if passive[k] && w[k] <= 1e-15 * scale.max(1.0) {
                    passive[k] = false;
                    w[k] = 0.0;
                }
            }
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::nnls;

    #[test]
    fn matches_the_unconstrained_solution_when_it_is_positive_and_clips_otherwise() {
        // columns (1,0,0), (0,1,0), (1,1,1)
        let a = vec![
            vec![1.0, 0.0, 0.0],
            vec![0.0, 1.0, 0.0],
            vec![1.0, 1.0, 1.0],
        ];
        let w = nnls(&a, &[3.0, 4.0, 2.0]);
        assert!(
            (w[0] - 1.0).abs() < 1e-12 && (w[1] - 2.0).abs() < 1e-12 && (w[2] - 2.0).abs() < 1e-12
        );
        // the unconstrained solution has a negative weight: it must be zero, the rest refitted
        let w = nnls(&a, &[-1.0, 2.0, 0.5]);
        assert!(w.iter().all(|&v| v >= 0.0), "{w:?}");
        assert_eq!(w[0], 0.0);
        // KKT: the gradient is ≤ 0 where w = 0 and ≈ 0 where w > 0
        let b = [-1.0, 2.0, 0.5];
        let r: Vec<f64> = (0..3)
            .map(|i| b[i] - (0..3).map(|j| a[j][i] * w[j]).sum::<f64>())
            .collect();
        for j in 0..3 {
            let g: f64 = a[j].iter().zip(&r).map(|(x, y)| x * y).sum();
            if w[j] > 0.0 {
                assert!(g.abs() < 1e-9, "{j}: {g}");
            } else {
                assert!(g <= 1e-9, "{j}: {g}");
            }
        }
    }
}
