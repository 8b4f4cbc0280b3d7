//! Paper 000's published procedures executed on the digital twin (shortened to keep the suite
//! fast): the stage's repeatability by ISO 9283, the plan's steps in the recording, the static
//! and adaptive (Eq. 14) models, tests of the plan's compensation, R_s and R_t, and the 2-DoF
//! model of Eq. 22.

use nanocal::data::plan::{Phase, Plan, TestKind};
use nanocal::device::device_path::SlowPeriods;
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{adaptive_from_static, fit_dwells, FitOptions, Selection};
use nanocal::numerics::stepwise::StepwiseOptions;
use nanocal::twin::examples::{
    paper000_1dof_controlled_twin, paper000_1dof_twin, paper000_2dof_twin, TRAINING_START_S,
};
use nanocal::twin::execute::run_plan;
use nanocal::validate::procedure::ProcedureData;
use nanocal_model::Factor;

fn data(twin: &nanocal::twin::Twin, plan: &Plan) -> ProcedureData {
    let run = run_plan(twin, plan, TRAINING_START_S, 1, true);
    ProcedureData::new(&run.recording.to_recording().unwrap(), &run.steps, 0.0).unwrap()
}

/// §4.3.1: at stable temperature the stage's repeatability is "about 35 nm" — Rep of one test of
/// 15 cycles after a cycle of the training trajectory (Eq. 7: max over its 12 poses of ISO 9283
/// RP = l̄ + 3·S_l; 80 … 400 µm both ways, 0 µm only reached backward and 480 µm forward).
#[test]
fn the_twin_repeats_to_about_35_nm_by_iso_9283() {
    let mut plan = Plan::paper000_1dof().shortened(1, 15, 1);
    plan.validation.order = vec![TestKind::NoModel];
    for seed in 1..=3 {
        let d = data(&paper000_1dof_controlled_twin(seed), &plan);
        let r = d
            .validate(TestKind::NoModel, None, None, SlowPeriods::DEVICE)
            .unwrap();
        assert_eq!(r.tests.len(), 1);
        let t = &r.tests[0];
        assert_eq!(t.poses.len(), 12);
        for p in &t.poses {
            let turning = p.target_um[0] == 0.0 || p.target_um[0] == 480.0;
            assert_eq!(p.n, if turning { 30 } else { 15 }, "{:?}", p.target_um);
        }
        let rep_nm = t.repeatability_um * 1e3;
        assert!(
            (25.0..45.0).contains(&rep_nm),
            "seed {seed}: Rep {rep_nm} nm"
        );
        // intrinsic accuracy of a stage with ≈ 400 nm geometric error (paper: ≈ 350 nm)
        let acc_nm = t.accuracy_um * 1e3;
        assert!(
            (300.0..500.0).contains(&acc_nm),
            "seed {seed}: Acc {acc_nm} nm"
        );
    }
}

#[test]
fn the_1dof_procedure_runs_as_planned() {
    let plan = Plan::paper000_1dof().shortened(6, 3, 2);
    let d = data(&paper000_1dof_twin(2), &plan);
    let training = d.training();
    assert_eq!(training.len(), 6 * 34);
    // the turning points are two steps each, the second held: the same approach
    assert_eq!(training.cmd_um[0][16], 480.0);
    assert_eq!(training.cmd_um[0][17], 480.0);
    assert_eq!((training.dir[0][16], training.dir[0][17]), (1, 1));
    assert_eq!((training.dir[0][33], training.dir[0][34]), (-1, -1));
    // the mean of the last 5 s of a 22 s step at 1 Hz: 5 rows
    assert!(training.rows_averaged.iter().all(|&n| n == 5));
    let fit = |spec| {
        fit_dwells(
            &training,
            &FitOptions {
                spec,
                selection: Selection::Stepwise(StepwiseOptions::default()),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let st = fit(DesignSpec::published_static());
    let ad = adaptive_from_static(&st.model).unwrap();
    assert!(ad.terms().iter().all(|t| t.factor == Factor::None));
    assert_eq!(
        ad.terms().len(),
        st.model
            .terms()
            .iter()
            .filter(|t| t.factor == Factor::None)
            .count()
    );
    let kmz = plan.validation.kmz.as_ref();
    let p = SlowPeriods::DEVICE;
    let none = d.validate(TestKind::NoModel, None, kmz, p).unwrap();
    let adap = d.validate(TestKind::Adaptive, Some(&ad), kmz, p).unwrap();
    let stat = d
        .validate(TestKind::Static, Some(&st.model), kmz, p)
        .unwrap();
    // tests in the order no model (0, 3), adaptive (1, 4), static (2, 5)
    let ids = |r: &nanocal::validate::ValidationReport| -> Vec<usize> {
        r.tests.iter().map(|t| t.index).collect()
    };
    assert_eq!(ids(&none), [0, 3]);
    assert_eq!(ids(&adap), [1, 4]);
    assert_eq!(ids(&stat), [2, 5]);
    // the KMZ is re-measured once (tests of 3 cycles are 0.25 h apart; 3.75 h interval), at
    // the first visit of the first adaptive test, and counted (Eq. 18)
    assert_eq!(adap.kmz_updates, 1);
    let first_kmz = d
        .steps
        .iter()
        .position(|s| {
            matches!(
                s.phase,
                Phase::Kmz {
                    test: 1,
                    visit: true
                }
            )
        })
        .unwrap();
    assert!(adap.visits.iter().any(|v| v.kmz_reference
        && v.counted()
        && v.t_move_s == d.data.dwells.t_start_s[first_kmz]));
    for r in [&none, &adap, &stat] {
        assert_eq!(r.refused, 0);
        // 80 … 400 µm both ways, 0 µm reached backward and 480 µm forward, each twice a cycle
        assert!(r.tests.iter().all(|t| t.poses.len() == 12));
        for p in r.tests.iter().flat_map(|t| &t.poses) {
            let turning = p.target_um[0] == 0.0 || p.target_um[0] == 480.0;
            assert_eq!(p.n, if turning { 6 } else { 3 }, "{:?}", p.target_um);
        }
        // Eq. 20–21 over this compensation's tests; Time = the whole validation
        let spread: f64 = r
            .tests
            .iter()
            .map(|t| t.accuracy_um - t.min_accuracy_um())
            .sum::<f64>()
            / 2.0;
        let worst: f64 = r.tests.iter().map(|t| t.accuracy_um).sum::<f64>() / 2.0;
        assert!((r.r_s_um - spread).abs() < 1e-12);
        assert!((r.r_t_um_per_h - worst / d.validation_h()).abs() < 1e-12);
    }
    // six tests of 3 of the 15 cycles a 1.25 h test has
    assert!((d.validation_h() - 6.0 * 1.25 * 3.0 / 15.0).abs() < 1e-9);
    // both models beat no model
    assert!(stat.summary.max_acc_um < 0.5 * none.summary.max_acc_um);
    assert!(adap.summary.max_acc_um < 0.5 * none.summary.max_acc_um);
}

#[test]
fn the_2dof_procedure_with_eq22() {
    let plan = Plan::paper000_2dof().shortened(3, 3, 2);
    let d = data(&paper000_2dof_twin(3), &plan);
    let training = d.training();
    assert_eq!(training.len(), 3 * 81);
    let fit = fit_dwells(
        &training,
        &FitOptions {
            spec: DesignSpec::published_2dof(),
            selection: Selection::Fixed,
            ..Default::default()
        },
    )
    .unwrap();
    // Eq. 22: per output 3 own powers, 3 powers of the other axis, 4 temperatures; no products
    assert_eq!(fit.model.terms().len(), 2 * (3 + 3 + 4));
    assert!(fit
        .model
        .terms()
        .iter()
        .all(|t| t.powers.iter().filter(|&&p| p > 0).count() <= 1));
    let none = d
        .validate(TestKind::NoModel, None, None, SlowPeriods::DEVICE)
        .unwrap();
    let stat = d
        .validate(
            TestKind::Static,
            Some(&fit.model),
            None,
            SlowPeriods::DEVICE,
        )
        .unwrap();
    assert_eq!(none.tests.len(), 2);
    assert!(
        none.summary.min_acc_um > 0.5,
        "uncompensated 2-D accuracy {} µm",
        none.summary.min_acc_um
    );
    assert!(stat.summary.max_acc_um < 0.25 * none.summary.min_acc_um);
}
