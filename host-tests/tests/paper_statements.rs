//! The papers' procedures as they state them (issue 18): each test quotes the section and the
//! words it checks. Paper 000 is Tan, Clévy, Chaillet, "Calibration of Nanopositioning Stages";
//! paper 001 is Lubrano, Bouri, Clavel, "Ultra-high-precision Industrial Robots Calibration".

use nanocal::data::dwell::Dwells;
use nanocal::data::plan::{Phase, Plan, TestKind};
use nanocal::fit::design::{DesignFrame, DesignSpec};
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::numerics::stepwise::StepwiseOptions;
use nanocal::papers::published::{one_dof, published_1dof_raw};
use nanocal::twin::examples::{paper000_1dof_controlled_twin, TRAINING_START_S};
use nanocal::twin::execute::run_plan;
use nanocal::validate::iso9283::pose_stats;
use nanocal::validate::procedure::ProcedureData;
use nanocal_model::{Factor, MAX_TEMPS};

/// A deterministic uniform draw in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / ((1u64 << 53) as f64)
    }
    /// Standard normal (Box–Muller).
    fn normal(&mut self) -> f64 {
        let u1 = self.next().max(1e-300);
        let u2 = self.next();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Paper 000 §4.3.2: "The duration of the training step is about 14 h with 67 cycles of
/// forward and backward motions. Every cycle = 18 poses (forward) + 16 poses (backward)."
///
/// Every visit is labelled by the direction of the motion that reached it; a held pose (the
/// second 480 µm step, the 0 µm that ends one cycle and starts the next) is the same physical
/// approach as the step before it. The paper's 18 + 16 is the cycle split at its turning point:
/// its first 18 steps (0, 30, …, 480 and the held 480) and the 16 of the descent (450, …, 0).
/// By the motion that reached them that is 17 + 17 from the second cycle on: the cycle's first
/// 0 is held after the previous cycle's last, reached backward.
#[test]
fn item1_every_visit_has_the_direction_of_the_motion_that_reached_it() {
    let plan = Plan::paper000_1dof();
    let steps = plan.schedule();
    let cycle = plan.training.cycle_um.len();
    assert_eq!(cycle, 18 + 16);
    // the paper's split of a cycle: the ascent with its held turning point, then the descent
    let c = &plan.training.cycle_um;
    assert!(c[..17].windows(2).all(|w| w[1][0] > w[0][0]) && c[17] == c[16]);
    assert!(c[17..].windows(2).all(|w| w[1][0] < w[0][0]));
    for (k, s) in steps.iter().enumerate().skip(1) {
        let prev = &steps[k - 1];
        let want = if s.target_um == prev.target_um {
            prev.approach[0] // held: the same approach
        } else if s.target_um[0] > prev.target_um[0] {
            1
        } else {
            -1
        };
        assert_eq!(s.approach[0], want, "step {k} at {:?}", s.target_um);
    }
    // the second training cycle: 17 forward (30 … 480, held 480), 17 backward (450 … 0, and
    // the held 0 that starts it)
    let second = &steps[cycle..2 * cycle];
    assert_eq!(second.iter().filter(|s| s.approach == [1]).count(), 17);
    assert_eq!(second[0].approach, vec![-1], "the held 0");
    assert_eq!(second[17].approach, vec![1], "the held 480");
    // in validation, 0 µm is only ever reached backward and 480 µm only forward: each is one
    // pose of a test, visited twice a cycle
    for s in steps.iter().filter(|s| s.phase != Phase::Training) {
        let x = s.target_um[0];
        if x == 0.0 {
            assert_eq!(s.approach, vec![-1]);
        } else if x == 480.0 {
            assert_eq!(s.approach, vec![1]);
        }
    }
}

/// Paper 000 §4.3.1: "The difference between the accuracies of the forward and backward motion
/// is quite small (about 10 nm) which means the hysteresis of the stage has been eliminated
/// well by the closed loop control in actuator layer."
///
/// The twin's stage has ±5 nm of hysteresis (10 nm between the branches). With the held turning
/// points labelled as the same approach, a test has each of 80 … 400 µm both ways and 0 and
/// 480 µm one way each; the mean forward/backward gap over the positions visited both ways is
/// the hysteresis, not diluted by poses that count one approach twice.
#[test]
fn item1_forward_and_backward_differ_by_the_stages_hysteresis() {
    let mut plan = Plan::paper000_1dof().shortened(1, 15, 1);
    plan.validation.order = vec![TestKind::NoModel];
    for seed in 1..=3 {
        let run = run_plan(
            &paper000_1dof_controlled_twin(seed),
            &plan,
            TRAINING_START_S,
            3,
            true,
        );
        let d =
            ProcedureData::new(&run.recording.to_recording().unwrap(), &run.steps, 0.0).unwrap();
        let r = d.validate(TestKind::NoModel, None, None, 1.0).unwrap();
        let t = &r.tests[0];
        assert_eq!(t.poses.len(), 12, "7 positions, 0 and 480 µm one way each");
        let gaps: Vec<f64> = t
            .poses
            .iter()
            .filter(|p| p.approach == [1])
            .filter_map(|f| {
                t.poses
                    .iter()
                    .find(|b| b.target_um == f.target_um && b.approach == [-1])
                    .map(|b| (b.mean_error_um[0] - f.mean_error_um[0]) * 1e3)
            })
            .collect();
        assert_eq!(gaps.len(), 5, "80 … 400 µm both ways");
        let gap = gaps.iter().sum::<f64>() / gaps.len() as f64;
        assert!((gap.abs() - 10.0).abs() < 3.5, "seed {seed}: gap {gap} nm");
    }
}

/// Dwells whose command is the published static model (Table 1) evaluated at the measured
/// position and four temperatures, or `q(x)` given.
fn dwells(q: impl Fn(f64, &[f64; MAX_TEMPS]) -> f64, noise_um: f64, seed: u64) -> Dwells {
    let mut r = Lcg(seed);
    let n = 34 * 8;
    let mut d = Dwells {
        axes: vec!["x".into()],
        t_end_s: Vec::new(),
        t_start_s: Vec::new(),
        cmd_um: vec![Vec::new()],
        meas_um: vec![Vec::new()],
        meas_sd_um: vec![Vec::new()],
        dir: vec![Vec::new()],
        channels: (0..4).map(|i| (format!("temp_{i}"), Vec::new())).collect(),
        rows_averaged: Vec::new(),
    };
    let poses = nanocal::data::plan::up_and_down(&nanocal::data::plan::grid(0.0, 30.0, 480.0));
    for i in 0..n {
        let x = poses[i % poses.len()][0] + 0.05 * (r.next() - 0.5);
        let mut t = [0.0; MAX_TEMPS];
        for v in t.iter_mut().take(4) {
            *v = 21.0 + 2.0 * r.next();
        }
        d.t_start_s.push(22.0 * i as f64);
        d.t_end_s.push(22.0 * i as f64 + 22.0);
        d.cmd_um[0].push(q(x, &t) + noise_um * r.normal());
        d.meas_um[0].push(x);
        d.meas_sd_um[0].push(0.0);
        d.dir[0].push(1);
        for (k, c) in d.channels.iter_mut().enumerate() {
            c.1.push(t[k]);
        }
        d.rows_averaged.push(5);
    }
    d
}

fn stepwise_fit(d: &Dwells) -> nanocal::fit::FitReport {
    fit_dwells(
        d,
        &FitOptions {
            spec: DesignSpec::published_static(),
            selection: Selection::Stepwise(StepwiseOptions::default()),
            ..Default::default()
        },
    )
    .unwrap()
}

/// Paper 000 §3.1, Eq. 8: "q_g = Σ a_i x^(n1−i+1) where … x is the measured position by the
/// external sensor … (here, n1 = 3)", and §3.3, Eq. 12–13: the regressor matrix has the columns
/// "x^n1, x^(n1−1), …, x, t_1, …, t_n2", from which "the stepwise regression … keep[s] the most
/// influential ones by calculating the p-value of F-statistic".
///
/// The candidates are the powers of x itself. A stage whose error has no x² term (q = a_1 x³ +
/// a_3 x) must not get one: with powers of a centred variable u = (x − 240)/240, x³ = 240³(1 +
/// u)³ needs u², and stepwise would keep it — selecting on another set than the paper's.
#[test]
fn item2_stepwise_selects_among_the_powers_of_x_itself() {
    let d = dwells(|x, _| 3e-8 * x * x * x + 1.002 * x + 4.0, 0.002, 5);
    let fit = stepwise_fit(&d);
    let ax = &fit.axes[0];
    let kept: Vec<&str> = ax
        .candidates
        .iter()
        .zip(&ax.selected)
        .filter(|(c, s)| **s && c.name.starts_with('x'))
        .map(|(c, _)| c.name.as_str())
        .collect();
    assert_eq!(kept, ["x", "x^3"], "selected {kept:?}");
    assert!(
        (ax.coeff_um[2] / 3e-8 - 1.0).abs() < 0.02,
        "{}",
        ax.coeff_um[2]
    );
    // converted exactly into the blob's centred, scaled basis: the model evaluates the same
    for i in 0..d.len() {
        let q = nanocal::fit::predict(&fit.model, &fit.frame, &d, i)[0];
        let x = d.meas_um[0][i];
        let mut raw = ax.offset_um + ax.coeff_um[0] * x + ax.coeff_um[2] * x.powi(3);
        for k in 0..4 {
            raw += ax.coeff_um[3 + k] * d.channels[k].1[i];
        }
        assert!((q - raw).abs() < 1e-9, "dwell {i}: {q} vs {raw}");
    }
}

/// Paper 000 §4.3.2, Table 1, "Identified parameters of static model": a_1 = 2.454×10⁻⁸, a_2 =
/// −2.167×10⁻⁵, a_3 = 1.005, b_1 = 2.978, b_2 = −3.142, b_3 = −0.996, b_4 = 0.690, λ = 10.413 µm.
///
/// Data made by Table 1's model itself are fitted back to Table 1's parameters, in the paper's
/// basis (a_i on x^(n1−i+1), b_i on t_i, λ the intercept), by stepwise.
#[test]
fn item2_the_coefficients_are_table_1s() {
    let d = dwells(published_1dof_raw, 0.001, 9);
    let fit = stepwise_fit(&d);
    let ax = &fit.axes[0];
    let names: Vec<&str> = ax.candidates.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names[..3], ["x", "x^2", "x^3"]);
    assert!(ax.selected.iter().all(|s| *s), "all of Eq. 11's terms");
    let want = [
        one_dof::A[2],
        one_dof::A[1],
        one_dof::A[0],
        one_dof::B_UM_PER_C[0],
        one_dof::B_UM_PER_C[1],
        one_dof::B_UM_PER_C[2],
        one_dof::B_UM_PER_C[3],
    ];
    for (j, w) in want.iter().enumerate() {
        let got = ax.coeff_um[j];
        assert!(
            (got - w).abs() < 3.0 * ax.se_um[j] + 1e-3 * w.abs(),
            "{}: {got} vs Table 1's {w} (± {})",
            names[j],
            ax.se_um[j]
        );
    }
    assert!(
        (ax.offset_um - one_dof::LAMBDA_UM).abs() < 0.01,
        "λ {}",
        ax.offset_um
    );
}

/// Paper 000 §2, Eq. 3: "Rep = (1/n) Σ |x_mi − x̄_m| + 3σ … with σ the standard deviation" —
/// of what, the paper does not say. ISO 9283 (7.2.2) takes S_l, the standard deviation of the
/// distances l_i = |x_mi − x̄_m|; read as the standard deviation of the positions x_mi, Rep is
/// 1.46 times as large for normal scatter (l̄ + 3·S_l = 2.61σ, l̄ + 3σ = 3.80σ). Both are computed.
#[test]
fn item3_both_readings_of_eq3s_sigma() {
    // by hand: positions 1, 2, 3 µm at target 0: l = 1, 0, 1, l̄ = 2/3
    let p = pose_stats(&[0.0], &[vec![1.0], vec![2.0], vec![3.0]]).unwrap();
    let s_l = (1.0f64 / 3.0).sqrt();
    assert!((p.repeatability_um - (2.0 / 3.0 + 3.0 * s_l)).abs() < 1e-12);
    assert!((p.repeatability_position_sigma_um - (2.0 / 3.0 + 3.0 * 1.0)).abs() < 1e-12);
    // normal scatter: the ratio of the two readings
    let mut r = Lcg(11);
    let e: Vec<Vec<f64>> = (0..200_000).map(|_| vec![0.013 * r.normal()]).collect();
    let p = pose_stats(&[0.0], &e).unwrap();
    let ratio = p.repeatability_position_sigma_um / p.repeatability_um;
    let half_normal = (2.0 / std::f64::consts::PI).sqrt();
    let want = (half_normal + 3.0) / (half_normal + 3.0 * (1.0 - half_normal.powi(2)).sqrt());
    assert!(
        (ratio - want).abs() < 0.01,
        "ratio {ratio}, normal theory {want}"
    );
    assert!((want - 1.457).abs() < 0.001);
}

/// Paper 001 §VII.A: "The model used for this robot has 78 parameters (45 geometric and 33
/// thermal)." The count excludes the three offsets; the candidate design `paper001` has the
/// paper's split, 15 geometric and 11 thermal terms per motor, and a fit of all of them has the
/// paper's 78 parameters counted the paper's way.
#[test]
fn item6_the_robot_model_has_the_papers_78_parameters() {
    use nanocal::twin::delta::{DeltaConfig, DeltaTwin};
    let plan = Plan::paper001_robot().shortened(3, 1, 1);
    let twin = DeltaTwin::new(DeltaConfig::paper001(7), 86_400.0, 7);
    let run = run_plan(&twin, &plan, 8.0 * 3600.0, 1, false);
    let d = ProcedureData::new(&run.recording.to_recording().unwrap(), &run.steps, 0.0).unwrap();
    let spec = DesignSpec::parse("paper001").unwrap();
    let frame = DesignFrame::from_dwells(&d.training(), &spec).unwrap();
    let (mut geometric, mut thermal) = (0, 0);
    for o in 0..3 {
        let c = frame.candidates(&spec, o);
        let g = c.iter().filter(|c| c.term.factor == Factor::None).count();
        assert_eq!((g, c.len() - g), (15, 11), "motor {o}");
        geometric += g;
        thermal += c.len() - g;
    }
    assert_eq!((geometric, thermal), (45, 33));
    let fit = fit_dwells(
        &d.training(),
        &FitOptions {
            spec,
            selection: Selection::Fixed,
            ..Default::default()
        },
    )
    .unwrap();
    let params = nanocal::fit::parameter_count(&fit);
    assert_eq!((params.geometric, params.thermal), (45, 33));
    assert_eq!(params.geometric + params.thermal, 78);
}

/// Paper 000 §3.4: "The KMZ is reached and the measurement of the sensor is recorded. After a
/// period of time, the KMZ is re-reached again and the new measurement is recorded. The drift
/// in this period is the difference of two measurements of the sensor. The thermal drift is
/// compensated by adding the calculated difference of the two measurements."
///
/// With the KMZ reached by the same command each time, λ_KMZ moves by exactly the difference of
/// the two readings — not by the model's own slope at the reading (Table 1's model has slope
/// 1.005: re-zeroing the model would move λ_KMZ 0.5 % more).
#[test]
fn item4_lambda_kmz_moves_by_the_difference_of_two_readings() {
    use nanocal::data::kmz::KmzDrift;
    use nanocal_model::{HysteresisState, SlowInputs, MAX_AXES};
    let mut m =
        nanocal::fit::adaptive_from_static(&nanocal::papers::published::published_1dof().unwrap())
            .unwrap();
    let slow = SlowInputs::default();
    let h = HysteresisState::new();
    let dir = [-1i8; MAX_AXES];
    let q = [0.0; MAX_AXES];
    let mut kmz = KmzDrift::default();
    let first = kmz.measure(&mut m, &q, &[0.30, 0.0, 0.0], &dir, &slow, &h)[0];
    // the first re-measurement: the model maps the reading to the command
    assert!(m.eval_f64(&[0.30, 0.0, 0.0], &dir, &slow)[0].abs() < 1e-9);
    let second = kmz.measure(&mut m, &q, &[1.30, 0.0, 0.0], &dir, &slow, &h)[0];
    assert!((second - (first - 1.0)).abs() < 1e-12, "{first} → {second}");
    // the model's own slope would have moved it by 1.005 µm
    let mut rezero = m.clone();
    rezero.set_kmz_offset_um(0, first);
    rezero.set_kmz_from_reference(&q, &[1.30, 0.0, 0.0], &dir, &slow);
    assert!((rezero.kmz_offset_um(0) - (first - 1.005)).abs() < 1e-3);
}

/// Paper 000 §3.4, Eq. 17–18: "λ_KMZ is only measured at the first zero position, so λ_KMZ =
/// −D₁(t), when q_T = 0. Then the accuracy becomes Acc_A = |(1/n) Σ_{i=1}^{n} P_i(q_T) +
/// (1/n) Σ_{i=2}^{n} [λ_KMZ + D_i(t)]|" — the first visit at 0 is the KMZ, counted among the n
/// visits with its drift term cancelled; §4.3.2: "Here the KMZ is measured every 3.75 h" with
/// "Every validation test takes 1.25 h for 15 cycles" (§4.2) in the order no model, adaptive,
/// static: every adaptive test, 3 × 1.25 h apart.
#[test]
fn item4_the_kmz_is_the_first_visit_every_3_75_h() {
    let plan = Plan::paper000_1dof();
    let steps = plan.schedule();
    let tests: Vec<(usize, f64)> = steps
        .iter()
        .filter_map(|s| match s.phase {
            Phase::Test { test, .. } | Phase::Kmz { test, .. } => Some((test, s.t_start_s)),
            _ => None,
        })
        .collect();
    let start = |n: usize| tests.iter().find(|t| t.0 == n).unwrap().1;
    assert!(
        (start(1) - start(0) - 1.25 * 3600.0).abs() < 1e-6,
        "a test takes 1.25 h"
    );
    let kmz: Vec<&nanocal::data::plan::Step> = steps
        .iter()
        .filter(|s| matches!(s.phase, Phase::Kmz { .. }))
        .collect();
    assert_eq!(kmz.len(), 31, "one per adaptive test");
    for (k, s) in kmz.iter().enumerate() {
        let Phase::Kmz { test, visit } = s.phase else {
            unreachable!()
        };
        assert!(visit && s.target_um == [0.0]);
        assert!(
            (s.t_start_s - start(test)).abs() < 1e-9,
            "the test's first visit"
        );
        if k > 0 {
            assert!((s.t_start_s - kmz[k - 1].t_start_s - 3.75 * 3600.0).abs() < 1e-6);
        }
    }
    // on the twin: the KMZ visits count, their drift cancelled
    let mut plan = Plan::paper000_1dof().shortened(3, 1, 6);
    plan.validation.kmz.as_mut().unwrap().interval_s = 1800.0;
    let run = run_plan(
        &nanocal::twin::examples::paper000_1dof_twin(4),
        &plan,
        TRAINING_START_S,
        1,
        true,
    );
    let d = ProcedureData::new(&run.recording.to_recording().unwrap(), &run.steps, 0.0).unwrap();
    let st = stepwise_fit(&d.training());
    let ad = nanocal::fit::adaptive_from_static(&st.model).unwrap();
    let kmz = plan.validation.kmz.as_ref();
    let r = d.validate(TestKind::Adaptive, Some(&ad), kmz, 1.0).unwrap();
    assert_eq!(r.kmz_updates, 3);
    let at_kmz: Vec<_> = r.visits.iter().filter(|v| v.kmz_reference).collect();
    assert_eq!(at_kmz.len(), 3);
    for v in at_kmz {
        assert!(v.counted());
        assert!(v.error_um[0].abs() < 0.005, "{} nm", v.error_um[0] * 1e3);
    }
    // each test's 0 µm pose has its 2 visits a cycle, the KMZ among them
    for t in &r.tests {
        let zero = t.poses.iter().find(|p| p.target_um == [0.0]).unwrap();
        assert_eq!(zero.n, 2);
    }
}

/// Paper 001 §VI: "To fast its calculation, it is possible to detach the thermal coefficient by
/// the others. Thermal variations are very slow, so they can be calculated in a non-real-time
/// process each 5-10 seconds."
///
/// Through the QEMU firmware on the virtual bench, paper 000's static model (Table 1), four type
/// K thermocouples on MAX31856 chips (16 mK a reading) in a constant room: folded once a reading
/// (as the firmware did, each 250 ms reading), a command scatters by ‖b‖·16 mK ≈ 71 nm; with the
/// readings of a 5 s fold period averaged (20 readings at 250 ms) by √20 less.
#[test]
fn item5_the_thermal_part_every_5_s_with_averaged_readings() {
    use nanocal::virtual_bench::jitter::{measure, Periods};
    if !nanocal::virtual_bench::have_qemu() {
        assert!(
            std::env::var_os("CI").is_none(),
            "qemu-system-arm is missing in CI"
        );
        eprintln!("item5: SKIPPED — qemu-system-arm ≥ 10 not found (bash .ci/firmware.sh)");
        return;
    }
    let once = Periods {
        sample_ms: 1000,
        fold_ms: 1000,
    };
    let averaged = Periods {
        sample_ms: 250,
        fold_ms: 5000,
    };
    let j = measure(&[once, averaged], 40, 11.0, 2).unwrap();
    for m in &j {
        assert_eq!(m.moves, 40);
        assert!(
            (m.sigma_nm / m.expected_nm - 1.0).abs() < 0.35,
            "{:?}: {} nm, expected {} nm",
            m.periods,
            m.sigma_nm,
            m.expected_nm
        );
    }
    assert!((j[0].expected_nm - 71.0).abs() < 2.0);
    assert!(j[1].sigma_nm < 0.35 * j[0].sigma_nm, "{j:?}");
}
