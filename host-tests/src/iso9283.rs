//! ISO 9283 pose accuracy and repeatability, as the nanopositioning literature adapts them.
//!
//! For one pose reached `n` times at positions `x_j` (1-D or n-D) with target `x_T`:
//! - barycentre `x̄ = mean_j x_j`;
//! - accuracy `AP = ‖x̄ − x_T‖` (1-D: `Acc = |mean(x) − x_T|`);
//! - repeatability `RP = l̄ + 3·S_l` with `l_j = ‖x_j − x̄‖`, `l̄` their mean and `S_l` their
//!   sample standard deviation (1-D: `Rep = mean|x − mean(x)| + 3σ`, σ the deviation of
//!   `|x − mean(x)|`). With one visit `S_l` is 0.
//!
//! Percentiles of the error distance over all visits (the robot literature quotes the 90 %
//! figure, ≈ 1.645σ for a normal error), and two robustness indices over a sequence of tests
//! (e.g. one validation cycle each):
//! - space robustness `R_s = mean_p AP_p / max_p AP_p` (1: the accuracy is the same at every
//!   pose, small: some poses — typically outside the training set — are much worse);
//! - time robustness `R_t = AP_max(first test) / max_k AP_max(test k)` (1: the accuracy holds
//!   over time, small: it degrades, e.g. when temperatures leave the training range).

/// Statistics of one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseStats {
    /// Target position per axis, µm.
    pub target_um: Vec<f64>,
    /// Number of visits.
    pub n: usize,
    /// Barycentre minus target per axis, µm.
    pub mean_error_um: Vec<f64>,
    /// Accuracy AP (1-D: Acc), µm.
    pub accuracy_um: f64,
    /// Repeatability RP (1-D: Rep), µm.
    pub repeatability_um: f64,
}

/// Accuracy and repeatability of one pose from its errors `x_j − x_T` (one `Vec` per visit,
/// one entry per axis). Returns `None` without visits.
pub fn pose_stats(target_um: &[f64], errors_um: &[Vec<f64>]) -> Option<PoseStats> {
    let n = errors_um.len();
    if n == 0 {
        return None;
    }
    let k = target_um.len();
    let mean: Vec<f64> = (0..k)
        .map(|a| errors_um.iter().map(|e| e[a]).sum::<f64>() / n as f64)
        .collect();
    let accuracy = mean.iter().map(|m| m * m).sum::<f64>().sqrt();
    let l: Vec<f64> = errors_um
        .iter()
        .map(|e| (0..k).map(|a| (e[a] - mean[a]).powi(2)).sum::<f64>().sqrt())
        .collect();
    let lbar = l.iter().sum::<f64>() / n as f64;
    let sl = if n > 1 {
        (l.iter().map(|v| (v - lbar).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    Some(PoseStats {
        target_um: target_um.to_vec(),
        n,
        mean_error_um: mean,
        accuracy_um: accuracy,
        repeatability_um: lbar + 3.0 * sl,
    })
}

/// Groups visits by target (exact equality of the commanded pose) and computes [`pose_stats`]
/// for each, in order of first appearance.
pub fn per_pose(targets_um: &[Vec<f64>], errors_um: &[Vec<f64>]) -> Vec<PoseStats> {
    let mut keys: Vec<Vec<f64>> = Vec::new();
    let mut groups: Vec<Vec<Vec<f64>>> = Vec::new();
    for (t, e) in targets_um.iter().zip(errors_um) {
        match keys.iter().position(|k| k == t) {
            Some(i) => groups[i].push(e.clone()),
            None => {
                keys.push(t.clone());
                groups.push(vec![e.clone()]);
            }
        }
    }
    keys.iter()
        .zip(&groups)
        .filter_map(|(k, g)| pose_stats(k, g))
        .collect()
}

/// The worst pose: (max accuracy, max repeatability) over poses, µm; (NaN, NaN) if empty.
pub fn max_over_poses(poses: &[PoseStats]) -> (f64, f64) {
    if poses.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    (
        poses.iter().map(|p| p.accuracy_um).fold(0.0, f64::max),
        poses.iter().map(|p| p.repeatability_um).fold(0.0, f64::max),
    )
}

/// The `q`-th percentile (0–100) of `values` by linear interpolation between order statistics
/// (NaN values ignored; NaN if none).
pub fn percentile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.partial_cmp(b).expect("no NaN"));
    let pos = (q / 100.0).clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// Distribution of the error distance over all visits.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorDistribution {
    /// Visits.
    pub n: usize,
    /// Root mean square of the error distance, µm.
    pub rms_um: f64,
    /// Median error distance, µm.
    pub p50_um: f64,
    /// 90th percentile of the error distance, µm.
    pub p90_um: f64,
    /// 95th percentile, µm.
    pub p95_um: f64,
    /// Largest error distance, µm.
    pub max_um: f64,
    /// The normal-theory 90 % figure for 1-D errors, `|mean| + 1.645·σ`, µm (for n-D, of the
    /// distance).
    pub normal90_um: f64,
}

/// Error distribution of the visits (one error vector per visit).
pub fn distribution(errors_um: &[Vec<f64>]) -> ErrorDistribution {
    let d: Vec<f64> = errors_um
        .iter()
        .map(|e| e.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    let n = d.len();
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt();
    let signed: Vec<f64> = if errors_um.first().is_some_and(|e| e.len() == 1) {
        errors_um.iter().map(|e| e[0]).collect()
    } else {
        d.clone()
    };
    let m = signed.iter().sum::<f64>() / n.max(1) as f64;
    let sd = if n > 1 {
        (signed.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    ErrorDistribution {
        n,
        rms_um: if n > 0 { rms } else { f64::NAN },
        p50_um: percentile(&d, 50.0),
        p90_um: percentile(&d, 90.0),
        p95_um: percentile(&d, 95.0),
        max_um: d.iter().copied().fold(f64::NAN, f64::max),
        normal90_um: if n > 0 {
            m.abs() + 1.645 * sd
        } else {
            f64::NAN
        },
    }
}

/// Space robustness `R_s = mean_p AP_p / max_p AP_p` (see the module doc).
pub fn space_robustness(poses: &[PoseStats]) -> f64 {
    let (max, _) = max_over_poses(poses);
    if poses.is_empty() || max == 0.0 {
        return 1.0;
    }
    poses.iter().map(|p| p.accuracy_um).sum::<f64>() / poses.len() as f64 / max
}

/// Time robustness `R_t = AP_max(first test) / max_k AP_max(test k)` over a sequence of tests,
/// each given as its per-pose statistics (see the module doc).
pub fn time_robustness(tests: &[Vec<PoseStats>]) -> f64 {
    let worst: Vec<f64> = tests
        .iter()
        .filter(|t| !t.is_empty())
        .map(|t| max_over_poses(t).0)
        .collect();
    match worst.first() {
        None => 1.0,
        Some(&first) => {
            let max = worst.iter().copied().fold(0.0, f64::max);
            if max == 0.0 {
                1.0
            } else {
                first / max
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_d_definitions() {
        // errors 1, 2, 3 at target 10: mean 2 → Acc 2; |dev| = 1, 0, 1 → mean 2/3, sd 0.57735
        let p = pose_stats(&[10.0], &[vec![1.0], vec![2.0], vec![3.0]]).unwrap();
        assert!((p.accuracy_um - 2.0).abs() < 1e-15);
        let sd = (((1.0f64 - 2.0 / 3.0).powi(2) * 2.0 + (2.0f64 / 3.0).powi(2)) / 2.0).sqrt();
        assert!((p.repeatability_um - (2.0 / 3.0 + 3.0 * sd)).abs() < 1e-12);
    }

    #[test]
    fn n_d_accuracy_is_barycentre_distance() {
        let p = pose_stats(&[0.0, 0.0], &[vec![3.0, 4.0], vec![3.0, 4.0]]).unwrap();
        assert!((p.accuracy_um - 5.0).abs() < 1e-15);
        assert_eq!(p.repeatability_um, 0.0);
    }

    #[test]
    fn grouping_percentiles_and_robustness() {
        let targets = vec![vec![0.0], vec![80.0], vec![0.0], vec![80.0]];
        let errors = vec![vec![0.1], vec![0.4], vec![0.1], vec![0.4]];
        let poses = per_pose(&targets, &errors);
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[1].n, 2);
        assert!((max_over_poses(&poses).0 - 0.4).abs() < 1e-15);
        assert!((space_robustness(&poses) - 0.25 / 0.4).abs() < 1e-12);
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0, 5.0], 90.0), 4.6);
        let early = per_pose(&targets[..2], &errors[..2]);
        let late = per_pose(&targets[..2], &[vec![0.2], vec![0.8]]);
        assert!((time_robustness(&[early, late]) - 0.5).abs() < 1e-12);
        let d = distribution(&errors);
        assert_eq!(d.n, 4);
        assert!((d.max_um - 0.4).abs() < 1e-15);
    }
}
