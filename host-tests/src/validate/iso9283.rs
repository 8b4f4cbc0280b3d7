//! ISO 9283:1998 pose accuracy and repeatability, and the robustness indices of
//! Tan, Clévy, Chaillet, "Calibration of Nanopositioning Stages" (paper 000 in `shared/seeds`).
//!
//! For one pose reached `n` times at positions `x_j` (1-D or n-D) with commanded pose `x_c`:
//! - barycentre `x̄ = mean_j x_j`;
//! - pose accuracy (ISO 9283 clause 7.2.1) `AP = ‖x̄ − x_c‖`; in 1-D this is paper 000's Eq. 2,
//!   `Acc = |mean(x_m) − x_T|`;
//! - pose repeatability (ISO 9283 clause 7.2.2) `RP = l̄ + 3·S_l` with `l_j = ‖x_j − x̄‖`,
//!   `l̄ = mean_j l_j` and `S_l = sqrt(Σ_j (l_j − l̄)² / (n − 1))`. Paper 000's Eq. 3 writes
//!   `Rep = (1/n) Σ |x_mi − x̄| + 3σ` "with σ the standard deviation" without saying of what.
//!   Rep is ISO's RP with σ = `S_l`, the sample standard deviation of the distances `l_j` (in
//!   1-D, of `|x_mi − x̄|`), which is what every `repeatability_um` here is. Read as the
//!   standard deviation of the positions themselves, `σ_x = sqrt(Σ_j ‖x_j − x̄‖² / (n − 1))`
//!   (in 1-D the sample standard deviation of `x_mi`), Rep is larger: for normal scatter
//!   `l̄ + 3·S_l ≈ 2.61 σ_x` while `l̄ + 3·σ_x ≈ 3.80 σ_x`, 1.46 times as much. Both are kept
//!   ([`PoseStats::repeatability_position_sigma_um`]) and printed where paper 000 quotes Rep.
//!   With one visit `S_l = σ_x = 0`.
//!
//! Forward and backward approaches of the same position are separate poses (paper 000,
//! Fig. 10–11: "forward and backward motions"): [`per_pose`] groups visits by commanded pose
//! *and* direction of approach.
//!
//! A **test** is one block of cycles (paper 000 §4.2: 15 cycles, 1.25 h). Its accuracy and
//! repeatability are the maxima over its M poses (Eq. 6–7): [`TestStats`]. Over n tests:
//! - space robustness (Eq. 20) `R_s = (1/n) Σ_i [max(Acc_i) − min(Acc_i)]`, µm: the mean spread
//!   of the accuracy over the workspace within a test ([`space_robustness_um`]);
//! - time robustness (Eq. 21) `R_t = ((1/n) Σ_i max(Acc_i)) / Time`, µm/h, with `Time` the
//!   duration of the validation in hours ([`time_robustness_um_per_h`]).
//!
//! Both are smaller-is-better. Paper 000's Table 2 (R_s 0.3476 / 0.0577 / 0.0493, R_t 0.0058 /
//! 0.0029 / 0.0005 for no model / static / adaptive) reads in µm and µm/h: with `Time` = the five
//! days of Fig. 12 (120 h), R_t gives mean worst accuracies of 0.70, 0.35 and 0.06 µm, which is
//! what the paper's text says of Fig. 12 (no model 0.4–1 µm, static < 0.4 µm for 70 h then
//! worse, adaptive < 0.1 µm).
//!
//! Paper 001 (Lubrano, Bouri, Clavel) quotes accuracy as "±70 nm in the 90 % of the set,
//! equivalent to 1.645σ", per coordinate: [`ninety_percent_per_axis`].

/// Statistics of one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseStats {
    /// Commanded pose per axis, µm.
    pub target_um: Vec<f64>,
    /// Direction of approach per axis (+1 forward, −1 backward); empty when the visits were
    /// grouped by position only.
    pub approach: Vec<i8>,
    /// Number of visits.
    pub n: usize,
    /// Barycentre minus commanded pose per axis, µm.
    pub mean_error_um: Vec<f64>,
    /// Pose accuracy AP (1-D: Acc, Eq. 2), µm.
    pub accuracy_um: f64,
    /// Pose repeatability RP = l̄ + 3·S_l (1-D: Rep, Eq. 3 with σ = S_l), µm.
    pub repeatability_um: f64,
    /// Eq. 3 with σ read as the standard deviation of the positions, `l̄ + 3·σ_x` (see the
    /// module doc), µm.
    pub repeatability_position_sigma_um: f64,
}

/// Accuracy and repeatability of one pose from its errors `x_j − x_c` (one `Vec` per visit,
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
    let (sl, sx) = if n > 1 {
        (
            (l.iter().map(|v| (v - lbar).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt(),
            (l.iter().map(|v| v * v).sum::<f64>() / (n - 1) as f64).sqrt(),
        )
    } else {
        (0.0, 0.0)
    };
    Some(PoseStats {
        target_um: target_um.to_vec(),
        approach: Vec::new(),
        n,
        mean_error_um: mean,
        accuracy_um: accuracy,
        repeatability_um: lbar + 3.0 * sl,
        repeatability_position_sigma_um: lbar + 3.0 * sx,
    })
}

/// Groups visits by commanded pose (exact equality) and computes [`pose_stats`] for each, in
/// order of first appearance; both directions of approach together.
pub fn per_pose(targets_um: &[Vec<f64>], errors_um: &[Vec<f64>]) -> Vec<PoseStats> {
    let none: Vec<Vec<i8>> = vec![Vec::new(); targets_um.len()];
    per_pose_approach(targets_um, &none, errors_um)
}

/// Groups visits by commanded pose *and* direction of approach (forward and backward are
/// separate poses, paper 000 Fig. 10–11) and computes [`pose_stats`] for each, in order of
/// first appearance.
pub fn per_pose_approach(
    targets_um: &[Vec<f64>],
    approach: &[Vec<i8>],
    errors_um: &[Vec<f64>],
) -> Vec<PoseStats> {
    let mut keys: Vec<(&[f64], &[i8])> = Vec::new();
    let mut groups: Vec<Vec<Vec<f64>>> = Vec::new();
    for ((t, d), e) in targets_um.iter().zip(approach).zip(errors_um) {
        let key = (t.as_slice(), d.as_slice());
        match keys.iter().position(|k| *k == key) {
            Some(i) => groups[i].push(e.clone()),
            None => {
                keys.push(key);
                groups.push(vec![e.clone()]);
            }
        }
    }
    keys.iter()
        .zip(&groups)
        .filter_map(|((t, d), g)| {
            pose_stats(t, g).map(|mut p| {
                p.approach = d.to_vec();
                p
            })
        })
        .collect()
}

/// The worst pose: (max accuracy, max repeatability) over poses, µm (Eq. 6–7); (NaN, NaN) if
/// empty.
pub fn max_over_poses(poses: &[PoseStats]) -> (f64, f64) {
    if poses.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    (
        poses.iter().map(|p| p.accuracy_um).fold(0.0, f64::max),
        poses.iter().map(|p| p.repeatability_um).fold(0.0, f64::max),
    )
}

/// One validation test: a block of cycles through the test poses (paper 000 §4.2).
#[derive(Debug, Clone, PartialEq)]
pub struct TestStats {
    /// Index of the test in the validation (0-based, over all compensations).
    pub index: usize,
    /// Start of the test's first visit, s.
    pub t_start_s: f64,
    /// End of the test's last visit, s.
    pub t_end_s: f64,
    /// Per pose (commanded pose and direction of approach).
    pub poses: Vec<PoseStats>,
    /// Acc of the test = max over its poses (Eq. 6), µm.
    pub accuracy_um: f64,
    /// Rep of the test = max over its poses (Eq. 7), µm.
    pub repeatability_um: f64,
    /// Rep with Eq. 3's σ read as the positions' standard deviation, max over the poses, µm.
    pub repeatability_position_sigma_um: f64,
}

impl TestStats {
    /// A test from its per-pose statistics.
    pub fn new(index: usize, t_start_s: f64, t_end_s: f64, poses: Vec<PoseStats>) -> Self {
        let (accuracy_um, repeatability_um) = max_over_poses(&poses);
        let repeatability_position_sigma_um = poses
            .iter()
            .map(|p| p.repeatability_position_sigma_um)
            .fold(f64::NAN, f64::max);
        TestStats {
            index,
            t_start_s,
            t_end_s,
            poses,
            accuracy_um,
            repeatability_um,
            repeatability_position_sigma_um,
        }
    }

    /// The smallest pose accuracy of the test, µm (NaN without poses).
    pub fn min_accuracy_um(&self) -> f64 {
        self.poses
            .iter()
            .map(|p| p.accuracy_um)
            .fold(f64::NAN, f64::min)
    }
}

/// Space robustness, paper 000 Eq. 20: `R_s = (1/n) Σ_i [max(Acc_i) − min(Acc_i)]` over the
/// n tests, `Acc_i` the pose accuracies of test i; µm, smaller is better. NaN without tests.
pub fn space_robustness_um(tests: &[TestStats]) -> f64 {
    let spreads: Vec<f64> = tests
        .iter()
        .filter(|t| !t.poses.is_empty())
        .map(|t| t.accuracy_um - t.min_accuracy_um())
        .collect();
    mean(&spreads)
}

/// Time robustness, paper 000 Eq. 21: `R_t = ((1/n) Σ_i max(Acc_i)) / Time` over the n tests,
/// with `Time` the duration of the validation in hours; µm/h, smaller is better. NaN without
/// tests or with a non-positive `Time`.
pub fn time_robustness_um_per_h(tests: &[TestStats], time_h: f64) -> f64 {
    let worst: Vec<f64> = tests
        .iter()
        .filter(|t| !t.poses.is_empty())
        .map(|t| t.accuracy_um)
        .collect();
    if time_h > 0.0 {
        mean(&worst) / time_h
    } else {
        f64::NAN
    }
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
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
    let (m, sd) = mean_sd(&signed);
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

/// Mean and sample standard deviation (0 for one value; NaN for none).
fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len();
    let m = mean(v);
    let sd = if n > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else if n == 1 {
        0.0
    } else {
        f64::NAN
    };
    (m, sd)
}

/// Paper 001's accuracy figure for one coordinate: "±70 nm in the 90 % of the set, equivalent
/// to 1.645σ" (§VII.A). Both readings are given: the normal-theory `1.645·σ` and the empirical
/// half-width of the zero-centred interval holding 90 % of the errors.
#[derive(Debug, Clone, PartialEq)]
pub struct NinetyPercent {
    /// Number of errors.
    pub n: usize,
    /// Mean error, µm.
    pub mean_um: f64,
    /// Sample standard deviation σ of the errors, µm.
    pub sigma_um: f64,
    /// `1.645·σ`, µm (the ± bound a zero-mean normal error keeps 90 % of the time).
    pub normal90_um: f64,
    /// 90th percentile of |error|, µm: ±this holds 90 % of the set.
    pub empirical90_um: f64,
}

/// [`NinetyPercent`] of each coordinate of `errors_um` (one `Vec` per sample, one entry per
/// coordinate); non-finite errors are left out.
pub fn ninety_percent_per_axis(errors_um: &[Vec<f64>]) -> Vec<NinetyPercent> {
    let k = errors_um.first().map_or(0, Vec::len);
    (0..k)
        .map(|a| {
            let e: Vec<f64> = errors_um
                .iter()
                .map(|v| v[a])
                .filter(|v| v.is_finite())
                .collect();
            let (m, sd) = mean_sd(&e);
            let abs: Vec<f64> = e.iter().map(|v| v.abs()).collect();
            NinetyPercent {
                n: e.len(),
                mean_um: m,
                sigma_um: sd,
                normal90_um: 1.645 * sd,
                empirical90_um: percentile(&abs, 90.0),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_d_definitions_by_hand() {
        // Eq. 2–3 with σ = ISO's S_l: errors 1, 2, 3 µm at target 10 µm.
        // x̄ − x_T = 2 → Acc = 2; l = |e − 2| = 1, 0, 1 → l̄ = 2/3;
        // S_l = sqrt(((1 − 2/3)² + (0 − 2/3)² + (1 − 2/3)²) / 2) = sqrt((1/9 + 4/9 + 1/9)/2)
        //     = sqrt(1/3) = 0.577 350 → Rep = 2/3 + 3·0.577 350 = 2.398 717.
        let p = pose_stats(&[10.0], &[vec![1.0], vec![2.0], vec![3.0]]).unwrap();
        assert!((p.accuracy_um - 2.0).abs() < 1e-15);
        assert!((p.repeatability_um - 2.398_717_474).abs() < 1e-9);
        // σ read as the positions' standard deviation: sd(1, 2, 3) = 1 → 2/3 + 3 = 3.666 667
        assert!((p.repeatability_position_sigma_um - 11.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn n_d_accuracy_is_barycentre_distance_and_rp_uses_distances() {
        // ISO 9283 7.2.1/7.2.2 in 2-D: errors (3,4) and (3,4) → AP = 5, RP = 0.
        let p = pose_stats(&[0.0, 0.0], &[vec![3.0, 4.0], vec![3.0, 4.0]]).unwrap();
        assert!((p.accuracy_um - 5.0).abs() < 1e-15);
        assert_eq!(p.repeatability_um, 0.0);
        // errors (0,0), (6,8): x̄ = (3,4) → AP 5; l = 5, 5 → l̄ = 5, S_l = 0 → RP 5.
        let p = pose_stats(&[0.0, 0.0], &[vec![0.0, 0.0], vec![6.0, 8.0]]).unwrap();
        assert!((p.accuracy_um - 5.0).abs() < 1e-15);
        assert!((p.repeatability_um - 5.0).abs() < 1e-15);
    }

    #[test]
    fn forward_and_backward_are_separate_poses() {
        let targets = vec![vec![80.0]; 4];
        let dirs = vec![vec![1], vec![-1], vec![1], vec![-1]];
        let errors = vec![vec![0.10], vec![-0.02], vec![0.12], vec![-0.04]];
        let poses = per_pose_approach(&targets, &dirs, &errors);
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[0].approach, vec![1]);
        assert!((poses[0].accuracy_um - 0.11).abs() < 1e-12);
        assert!((poses[1].accuracy_um - 0.03).abs() < 1e-12);
        // by position alone they merge: mean 0.04
        let merged = per_pose(&targets, &errors);
        assert_eq!(merged.len(), 1);
        assert!((merged[0].accuracy_um - 0.04).abs() < 1e-12);
    }

    fn test_with(index: usize, acc_um: &[f64]) -> TestStats {
        let poses = acc_um
            .iter()
            .enumerate()
            .map(|(i, &a)| pose_stats(&[80.0 * i as f64], &[vec![a]]).unwrap())
            .collect();
        TestStats::new(index, 0.0, 4500.0, poses)
    }

    #[test]
    fn robustness_indices_by_hand() {
        // Eq. 20–21 on two tests: Acc_1 = {0.10, 0.30, 0.20}, Acc_2 = {0.40, 0.10} µm, Time 10 h.
        // R_s = ((0.30 − 0.10) + (0.40 − 0.10)) / 2 = 0.25 µm;
        // R_t = ((0.30 + 0.40) / 2) / 10 h = 0.035 µm/h.
        let tests = [
            test_with(0, &[0.10, 0.30, 0.20]),
            test_with(1, &[0.40, 0.10]),
        ];
        assert!((space_robustness_um(&tests) - 0.25).abs() < 1e-12);
        assert!((time_robustness_um_per_h(&tests, 10.0) - 0.035).abs() < 1e-12);
        assert!(space_robustness_um(&[]).is_nan());
        assert!(time_robustness_um_per_h(&tests, 0.0).is_nan());
    }

    #[test]
    fn paper_figure_11_first_tests_by_hand() {
        // Paper 000 §4.3.2 (Fig. 11): T1 (no model) max 650, min 350 nm → its R_s term 0.300 µm,
        // beside Table 2's five-day mean 0.3476; T2 (adaptive) max ≈ 43 nm, spread ≈ 35 nm;
        // T3 (static) max ≈ 95 nm, spread ≈ 40 nm.
        let t1 = test_with(0, &[0.650, 0.500, 0.350]);
        let t2 = test_with(1, &[0.043, 0.020, 0.008]);
        let t3 = test_with(2, &[0.095, 0.070, 0.055]);
        assert!((space_robustness_um(std::slice::from_ref(&t1)) - 0.300).abs() < 1e-12);
        assert!((space_robustness_um(std::slice::from_ref(&t2)) - 0.035).abs() < 1e-12);
        assert!((space_robustness_um(std::slice::from_ref(&t3)) - 0.040).abs() < 1e-12);
        // Table 2's R_t in µm/h over the five days of Fig. 12 (Time = 120 h) means worst
        // accuracies of 0.70 (no model), 0.35 (static) and 0.06 µm (adaptive): inside the
        // ranges the text gives (0.4–1 µm; < 0.4 µm for 70 h; < 0.1 µm).
        let mean_worst = |r_t: f64| r_t * 120.0;
        assert!((0.4..1.0).contains(&mean_worst(0.0058)));
        assert!(mean_worst(0.0029) < 0.4);
        assert!(mean_worst(0.0005) < 0.1);
    }

    #[test]
    fn percentiles_and_distribution() {
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0, 5.0], 90.0), 4.6);
        let errors = vec![vec![0.1], vec![0.4], vec![0.1], vec![0.4]];
        let d = distribution(&errors);
        assert_eq!(d.n, 4);
        assert!((d.max_um - 0.4).abs() < 1e-15);
    }

    #[test]
    fn ninety_percent_per_coordinate_by_hand() {
        // coordinate 0: −0.03, −0.01, 0.01, 0.03 → mean 0, σ = sqrt((9+1+1+9)e-4/3) = 0.025 820,
        // 1.645σ = 0.042 474; |e| = .03 .01 .01 .03 → P90 = 0.03.
        // coordinate 1: constant 0.05 → σ 0, P90 0.05.
        let e = vec![
            vec![-0.03, 0.05],
            vec![-0.01, 0.05],
            vec![0.01, 0.05],
            vec![0.03, 0.05],
        ];
        let n = ninety_percent_per_axis(&e);
        assert_eq!(n.len(), 2);
        assert!(n[0].mean_um.abs() < 1e-15);
        assert!((n[0].sigma_um - 0.025_819_889).abs() < 1e-9);
        assert!((n[0].normal90_um - 1.645 * 0.025_819_889).abs() < 1e-9);
        assert!((n[0].empirical90_um - 0.03).abs() < 1e-12);
        assert_eq!(n[1].sigma_um, 0.0);
        assert!((n[1].empirical90_um - 0.05).abs() < 1e-12);
    }
}
