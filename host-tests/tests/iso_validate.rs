//! Validation on the digital twin's published example: both compensations beat no model by far,
//! KMZ bookkeeping, tests of cycles, and an in-sample model leaves only the regression residual.
use nanocal::data::dwell::{dwell_average, DwellOptions};
use nanocal::data::recording::Recording;
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{adaptive_from_static, fit_dwells, FitOptions, Selection};
use nanocal::validate::{
    roles_from_cycles, validate, Compensation, Role, ValidateError, ValidationData,
    ValidationOptions,
};

fn example() -> (nanocal::data::dwell::Dwells, ValidationData) {
    let (train, val) = nanocal::twin::examples::published_1dof(3);
    let opts = DwellOptions::default();
    let dt = dwell_average(&Recording::from_columns(train.columns).unwrap(), &opts).unwrap();
    let dv = ValidationData::from_recording(&Recording::from_columns(val.columns).unwrap(), &opts)
        .unwrap();
    (dt, dv)
}

/// The example validates one cycle an hour: a test per cycle.
fn hourly() -> ValidationOptions {
    ValidationOptions {
        cycles_per_test: 1,
        ..Default::default()
    }
}

#[test]
fn compensations_beat_no_model_on_the_published_example() {
    let (dt, dv) = example();
    let fixed = |spec| FitOptions {
        spec,
        selection: Selection::Fixed,
        ..Default::default()
    };
    let st = fit_dwells(&dt, &fixed(DesignSpec::published_static())).unwrap();
    let ad = adaptive_from_static(&st.model).unwrap();
    let opts = hourly();
    let none = validate(None, &dv, &Compensation::None, &opts).unwrap();
    let stat = validate(Some(&st.model), &dv, &Compensation::Static, &opts).unwrap();
    let kmz = Compensation::Adaptive {
        reference_um: vec![0.0],
        interval_s: 3600.0,
    };
    let adap = validate(Some(&ad), &dv, &kmz, &opts).unwrap();
    // uncompensated: about a micrometre, as published
    let worst = |r: &nanocal::validate::ValidationReport| r.summary.max_acc_um;
    assert!(
        worst(&none) > 0.5 && worst(&none) < 3.0,
        "no model {}",
        worst(&none)
    );
    assert!(worst(&stat) < 0.5 * worst(&none));
    assert!(worst(&adap) < 0.5 * worst(&none));
    // one KMZ update per hourly cycle; a reference visit is a visit of its test, counted with
    // its drift cancelled (paper 000 Eq. 18)
    assert!(adap.kmz_updates >= 70, "{} KMZ updates", adap.kmz_updates);
    assert_eq!(adap.distribution.n, dv.dwells.len());
    assert!(adap
        .visits
        .iter()
        .filter(|v| v.kmz_reference)
        .all(|v| v.counted() && v.error_um[0].abs() < 0.005));
    assert_eq!(none.tests.len(), adap.tests.len());
    assert!(none.tests.len() >= 72);
    // a test (one cycle, dwells merged where the command stays): 0 (arrived at backward, with
    // the rest), 80…480 forward, 400…80 backward — the return to 0 starts the next cycle
    let t = &none.tests[1];
    assert_eq!(t.poses.len(), 12);
    assert_eq!(t.poses.iter().filter(|p| p.approach == vec![1]).count(), 6);
    assert!(t.poses.iter().all(|p| p.n == 1));
    // R_s and R_t (Eq. 20–21): µm and µm/h over the validation
    assert!(none.r_s_um > stat.r_s_um && none.r_t_um_per_h > adap.r_t_um_per_h);
    let mean_worst: f64 =
        none.tests.iter().map(|t| t.accuracy_um).sum::<f64>() / none.tests.len() as f64;
    assert!((none.r_t_um_per_h - mean_worst / none.time_h).abs() < 1e-12);
    assert!((none.time_h - 72.0).abs() < 1.5, "Time {} h", none.time_h);
}

#[test]
fn tests_are_blocks_of_cycles_and_kmz_visits_are_due_references() {
    let (_, dv) = example();
    let d = &dv.dwells;
    let roles = roles_from_cycles(d, 15, &Compensation::None);
    let last = roles.iter().filter_map(|r| match r {
        Role::Visit(t) => Some(*t),
        _ => None,
    });
    // 73 hourly cycles → tests of 15 cycles: 0..=4
    assert_eq!(last.max(), Some(4));
    let kmz = Compensation::Adaptive {
        reference_um: vec![0.0],
        interval_s: 7200.0,
    };
    let roles = roles_from_cycles(d, 15, &kmz);
    let t_kmz: Vec<f64> = roles
        .iter()
        .zip(&d.t_end_s)
        .filter(|(r, _)| matches!(r, Role::Kmz { counted: true, .. }))
        .map(|(_, t)| *t)
        .collect();
    assert!(t_kmz.len() >= 30);
    assert!(t_kmz.windows(2).all(|w| w[1] - w[0] >= 7200.0 - 1e-9));
}

#[test]
fn model_fitted_on_validation_itself_leaves_only_noise() {
    let (_, dv) = example();
    let opts = FitOptions {
        spec: DesignSpec::published_static(),
        selection: Selection::Fixed,
        ..Default::default()
    };
    let m = fit_dwells(&dv.dwells, &opts).unwrap();
    // the device folds the dwells' own (averaged) temperatures: in-sample, the compensated RMS
    // is the regression's RMS (same model, f32 path)
    let own = ValidationData::from_dwells(dv.dwells.clone());
    let r = validate(Some(&m.model), &own, &Compensation::Static, &hourly()).unwrap();
    assert!(
        (r.distribution.rms_um - m.axes[0].rmse_um).abs() < 0.2 * m.axes[0].rmse_um + 1e-4,
        "validation RMS {} vs fit RMS {}",
        r.distribution.rms_um,
        m.axes[0].rmse_um
    );
    assert_eq!(r.inverse_failures, 0);
}

#[test]
fn mismatched_inputs_are_reported() {
    let (dt, dv) = example();
    let opts = FitOptions {
        spec: DesignSpec::published_static(),
        selection: Selection::Fixed,
        ..Default::default()
    };
    let m = fit_dwells(&dt, &opts).unwrap();
    let no_temps = ValidationData::from_dwells(nanocal::data::dwell::Dwells {
        channels: Vec::new(),
        ..dv.dwells.clone()
    });
    let o = ValidationOptions::default();
    assert!(matches!(
        validate(Some(&m.model), &no_temps, &Compensation::Static, &o),
        Err(ValidateError::MissingChannels {
            needed: 4,
            found: 0,
            ..
        })
    ));
    let bad_ref = Compensation::Adaptive {
        reference_um: vec![0.0, 0.0],
        interval_s: 1.0,
    };
    assert!(matches!(
        validate(Some(&m.model), &dv, &bad_ref, &o),
        Err(ValidateError::BadReference { .. })
    ));
    assert!(matches!(
        validate(None, &dv, &Compensation::Static, &o),
        Err(ValidateError::NoModel(_))
    ));
    assert!(matches!(
        nanocal::validate::validate_roles(None, &dv, &Compensation::None, &[Role::Skip], &o),
        Err(ValidateError::BadSchedule { .. })
    ));
}

/// A model with a thermal-lag term: validation feeds the model's own lag filters, so data made
/// by that very model (lagged temperature along the dwell sequence) leave no error, while
/// ignoring the lag would leave micrometres.
#[test]
fn lag_filters_of_the_model_are_run_over_the_dwells() {
    use nanocal::data::dwell::Dwells;
    use nanocal_model::{Factor, Input, LagFilter, ModelBuilder, SlowInputs, Term};
    let mut b = ModelBuilder::new(1, 1, 0)
        .unwrap()
        .trained_range(Input::Axis(0), 0.0, 480.0)
        .trained_range(Input::Temp(0), 20.0, 22.0);
    let k = b.lag(0, 900.0).unwrap();
    let lin = Term {
        output: 0,
        powers: [1, 0, 0],
        factor: Factor::None,
        direction: 0,
        coeff: 240.0,
    };
    let lag = Term {
        output: 0,
        powers: [0, 0, 0],
        factor: Factor::Lagged(k),
        direction: 0,
        coeff: 2.0,
    };
    b.add_term(lin).unwrap();
    b.add_term(lag).unwrap();
    let model = b.offset_um(0, 240.0).build().unwrap();
    // dwells every 60 s over 0:80:480, temperature steps from 20 to 22 °C after 10 dwells
    let n = 120;
    let t: Vec<f64> = (0..n).map(|i| 60.0 * (i + 1) as f64).collect();
    let temp: Vec<f64> = (0..n).map(|i| if i < 10 { 20.0 } else { 22.0 }).collect();
    let x: Vec<f64> = (0..n).map(|i| 80.0 * (i % 7) as f64).collect();
    let mut filt = LagFilter::new(900.0);
    let mut cmd = Vec::new();
    for i in 0..n {
        let dt = if i == 0 { 0.0 } else { t[i] - t[i - 1] };
        let mut slow = SlowInputs::default();
        slow.temps_c[0] = temp[i];
        slow.lagged_c[0] = filt.update(temp[i], dt);
        cmd.push(model.eval_f64(&[x[i], 0.0, 0.0], &[1, 0, 0], &slow)[0]);
    }
    let d = ValidationData::from_dwells(Dwells {
        axes: vec!["x".into()],
        t_end_s: t.clone(),
        t_start_s: t.clone(),
        cmd_um: vec![cmd],
        meas_um: vec![x],
        meas_sd_um: vec![vec![0.0; n]],
        dir: vec![vec![1; n]],
        channels: vec![("temp_a".into(), temp)],
        rows_averaged: vec![1; n],
    });
    // the device ticks on the dwells' own 60 s grid: its lag filters see what the model saw
    let opts = ValidationOptions {
        slow: 60.0.into(),
        ..Default::default()
    };
    let r = validate(Some(&model), &d, &Compensation::Static, &opts).unwrap();
    assert!(
        r.distribution.max_um < 1e-4,
        "max error {} µm",
        r.distribution.max_um
    );
    let none = validate(None, &d, &Compensation::None, &opts).unwrap();
    assert!(none.distribution.max_um > 1.0);
}
