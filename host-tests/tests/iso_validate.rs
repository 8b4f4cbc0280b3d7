//! Validation on the digital twin's published example: both compensations beat no model by far,
//! KMZ bookkeeping, and an in-sample model leaves only the regression residual.
use nanocal::design::DesignSpec;
use nanocal::dwell::{dwell_average, DwellOptions};
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::recording::Recording;
use nanocal::validate::{validate, Compensation, ValidateError};

fn example() -> (nanocal::dwell::Dwells, nanocal::dwell::Dwells) {
    let (train, val) = nanocal::twin::examples::published_1dof(3);
    let opts = DwellOptions::default();
    let dt = dwell_average(&Recording::from_columns(train.columns).unwrap(), &opts).unwrap();
    let dv = dwell_average(&Recording::from_columns(val.columns).unwrap(), &opts).unwrap();
    (dt, dv)
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
    let ad = fit_dwells(&dt, &fixed(DesignSpec::published_adaptive())).unwrap();
    let none = validate(None, &dv, &Compensation::None).unwrap();
    let stat = validate(Some(&st.model), &dv, &Compensation::Static).unwrap();
    let kmz = Compensation::Adaptive {
        reference_um: vec![0.0],
        interval_s: 3600.0,
    };
    let adap = validate(Some(&ad.model), &dv, &kmz).unwrap();
    // uncompensated: about a micrometre, as published
    assert!(
        none.max_um.0 > 0.5 && none.max_um.0 < 3.0,
        "no model {:?}",
        none.max_um
    );
    assert!(
        stat.max_um.0 < 0.5 * none.max_um.0,
        "static {:?} vs none {:?}",
        stat.max_um,
        none.max_um
    );
    assert!(
        adap.max_um.0 < 0.5 * none.max_um.0,
        "adaptive {:?} vs none {:?}",
        adap.max_um,
        none.max_um
    );
    // one KMZ update per hourly cycle, reference visits excluded from the statistics
    assert!(adap.kmz_updates >= 70, "{} KMZ updates", adap.kmz_updates);
    assert_eq!(adap.distribution.n, dv.len() - adap.kmz_updates);
    assert_eq!(none.poses.len(), 7);
    assert_eq!(none.tests, adap.tests);
    assert!(none.forward.len() == 7 && none.backward.len() >= 6);
    assert!(stat.r_s > 0.0 && stat.r_s <= 1.0 && stat.r_t > 0.0 && stat.r_t <= 1.0);
}

#[test]
fn model_fitted_on_validation_itself_leaves_only_noise() {
    let (_, dv) = example();
    let opts = FitOptions {
        spec: DesignSpec::published_static(),
        selection: Selection::Fixed,
        ..Default::default()
    };
    let m = fit_dwells(&dv, &opts).unwrap();
    let r = validate(Some(&m.model), &dv, &Compensation::Static).unwrap();
    // the in-sample RMS of the compensated error equals the regression's RMS (same model, f32 path)
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
    let no_temps = nanocal::dwell::Dwells {
        channels: Vec::new(),
        ..dv.clone()
    };
    assert!(matches!(
        validate(Some(&m.model), &no_temps, &Compensation::Static),
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
        validate(Some(&m.model), &dv, &bad_ref),
        Err(ValidateError::BadReference { .. })
    ));
}

/// A model with a thermal-lag term: validation feeds the model's own lag filters, so data made
/// by that very model (lagged temperature along the dwell sequence) leave no error, while
/// ignoring the lag would leave micrometres.
#[test]
fn lag_filters_of_the_model_are_run_over_the_dwells() {
    use nanocal::dwell::Dwells;
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
    let d = Dwells {
        axes: vec!["x".into()],
        t_end_s: t.clone(),
        t_start_s: t.iter().map(|v| v - 30.0).collect(),
        cmd_um: vec![cmd],
        meas_um: vec![x],
        meas_sd_um: vec![vec![0.0; n]],
        dir: vec![vec![1; n]],
        channels: vec![("temp_a".into(), temp)],
        rows_averaged: vec![1; n],
    };
    let r = validate(Some(&model), &d, &Compensation::Static).unwrap();
    assert!(
        r.distribution.max_um < 1e-4,
        "max error {} µm",
        r.distribution.max_um
    );
    let none = validate(None, &d, &Compensation::None).unwrap();
    assert!(none.distribution.max_um > 1.0);
}
