//! Fitting recovers a known model: data generated from the published 1-DoF model (raw units).
use nanocal::data::dwell::{dwell_average, DwellOptions};
use nanocal::data::recording::Recording;
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{encode_blob, fit_recording, predict, FitOptions, Selection};
use nanocal::numerics::stepwise::StepwiseOptions;
use nanocal::papers::published::published_1dof_raw;
use nanocal_model::{blob, MAX_TEMPS};

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / ((1u64 << 53) as f64)
    }
}

/// 1 Hz recording, 10 s dwells at 0:30:480 forward/backward, 3 cycles; the stage reaches x and
/// the command is the published model's q(x, T) (+ optional noise on the measurement).
fn recording(noise_um: f64) -> Recording {
    let mut r = Lcg(42);
    let poses: Vec<f64> = (0..=16).map(|k| 30.0 * k as f64).collect();
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); 7];
    let mut t = 0.0;
    for _ in 0..3 {
        for &p in poses.iter().chain(poses.iter().rev()) {
            let temps: [f64; 4] = [
                21.0 + 2.0 * r.next(),
                21.0 + 2.0 * r.next(),
                21.0 + 2.0 * r.next(),
                21.0 + 2.0 * r.next(),
            ];
            let x = p + 0.5 * (r.next() - 0.5);
            let mut tt = [0.0; MAX_TEMPS];
            tt[..4].copy_from_slice(&temps);
            let q = published_1dof_raw(x, &tt);
            for _ in 0..10 {
                cols[0].push(t);
                cols[1].push(q);
                cols[2].push(x + noise_um * (r.next() - 0.5));
                for k in 0..4 {
                    cols[3 + k].push(temps[k]);
                }
                t += 1.0;
            }
        }
    }
    let names = [
        "t", "cmd_x", "meas_x", "temp_a", "temp_b", "temp_c", "temp_d",
    ];
    Recording::from_columns(names.iter().map(|s| s.to_string()).zip(cols).collect()).unwrap()
}

#[test]
fn fixed_static_fit_reproduces_the_published_model() {
    let rec = recording(0.0);
    let opts = FitOptions {
        spec: DesignSpec::published_static(),
        selection: Selection::Fixed,
        ..Default::default()
    };
    let rep = fit_recording(&rec, &opts).unwrap();
    assert_eq!(rep.axes[0].candidates.len(), 7);
    assert!(rep.axes[0].rmse_um < 1e-9, "rmse {}", rep.axes[0].rmse_um);
    // the blob's model evaluates like the published formula across the envelope
    let model = blob::decode(&encode_blob(&rep.model)).unwrap();
    let mut r = Lcg(7);
    for _ in 0..200 {
        let x = 480.0 * r.next();
        let mut temps = [0.0; MAX_TEMPS];
        for t in temps.iter_mut().take(4) {
            *t = 21.0 + 2.0 * r.next();
        }
        let slow = nanocal_model::SlowInputs {
            temps_c: temps,
            ..Default::default()
        };
        let q = model.eval_f64(&[x, 0.0, 0.0], &[1, 0, 0], &slow)[0];
        let want = published_1dof_raw(x, &temps);
        assert!((q - want).abs() < 1e-8, "x {x}: {q} vs {want}");
    }
}

#[test]
fn stepwise_fit_selects_the_true_terms_and_predictions_match_regression() {
    let rec = recording(0.002);
    let spec = DesignSpec::parse("poly=5 temps temp_x_pos direction").unwrap();
    let opts = FitOptions {
        spec,
        selection: Selection::Stepwise(StepwiseOptions::default()),
        ..Default::default()
    };
    let rep = fit_recording(&rec, &opts).unwrap();
    let ax = &rep.axes[0];
    let names: Vec<&str> = ax
        .candidates
        .iter()
        .zip(&ax.selected)
        .filter(|(_, s)| **s)
        .map(|(c, _)| c.name.as_str())
        .collect();
    for must in ["x", "x^2", "x^3", "temp_a", "temp_b", "temp_c", "temp_d"] {
        assert!(names.contains(&must), "{must} not selected: {names:?}");
    }
    assert!(ax.rmse_um < 0.01, "rmse {}", ax.rmse_um);
    // the fitted value of each dwell IS the model's evaluation (coefficients not rewritten)
    let d = dwell_average(&rec, &DwellOptions::default()).unwrap();
    let st = ax.stepwise.as_ref().unwrap();
    let x: Vec<Vec<f64>> =
        nanocal::fit::design::regressors(&ax.candidates, &rep.frame.raw_inputs(&d));
    for i in 0..d.len() {
        let mut yhat = st.intercept;
        for (j, col) in x.iter().enumerate() {
            if st.inmodel[j] {
                yhat += st.b[j] * col[i];
            }
        }
        let q = predict(&rep.model, &rep.frame, &d, i)[0];
        assert!(
            (q - yhat).abs() < 1e-9,
            "dwell {i}: model {q} vs regression {yhat}"
        );
    }
}

/// Thermal lag: the stage follows a lagged copy (τ = 900 s) of the sensed temperature. With
/// `lag=900` among the candidates, stepwise picks the lagged term over the direct one, the blob
/// declares the lag filter, and validation (which runs the model's own lag filters) of the
/// fitted model on its training dwells leaves only the noise.
#[test]
fn lagged_temperature_term_is_selected_and_deployed() {
    use nanocal::data::dwell::Dwells;
    use nanocal::validate::{validate, Compensation, ValidationData, ValidationOptions};
    use nanocal_model::LagFilter;
    let n = 400;
    let mut r = Lcg(9);
    let t: Vec<f64> = (0..n).map(|i| 60.0 * (i + 1) as f64).collect();
    // temperature: slow steps and ramps between 20 and 22 °C
    let temp: Vec<f64> = (0..n)
        .map(|i| 21.0 + ((i / 40) % 3) as f64 * 0.5 - 0.5 + 0.002 * (i % 40) as f64)
        .collect();
    let x: Vec<f64> = (0..n).map(|i| 30.0 * (i % 17) as f64).collect();
    let mut filt = LagFilter::new(900.0);
    let cmd: Vec<f64> = (0..n)
        .map(|i| {
            let dt = if i == 0 { 0.0 } else { t[i] - t[i - 1] };
            let lagged = filt.update(temp[i], dt);
            1.003 * x[i] - 1.5 * (lagged - 21.0) + 0.001 * (r.next() - 0.5)
        })
        .collect();
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
    let spec = DesignSpec::parse("poly=1 temps lag=900").unwrap();
    let opts = FitOptions {
        spec,
        selection: Selection::Stepwise(StepwiseOptions::default()),
        ..Default::default()
    };
    let rep = nanocal::fit::fit_dwells(&d, &opts).unwrap();
    let ax = &rep.axes[0];
    let chosen: Vec<&str> = ax
        .candidates
        .iter()
        .zip(&ax.selected)
        .filter(|(_, s)| **s)
        .map(|(c, _)| c.name.as_str())
        .collect();
    assert!(chosen.contains(&"lag(temp_a, 900 s)"), "{chosen:?}");
    assert!(ax.rmse_um < 0.002, "rmse {}", ax.rmse_um);
    assert_eq!(rep.model.lags().len(), 1);
    assert_eq!(rep.model.lags()[0].tau_s, 900.0);
    let model = blob::decode(&encode_blob(&rep.model)).unwrap();
    // the device ticks on the dwells' 60 s grid, its lag filter seeing what the fit saw
    let opts = ValidationOptions {
        slow: 60.0.into(),
        ..Default::default()
    };
    let v = validate(
        Some(&model),
        &ValidationData::from_dwells(d),
        &Compensation::Static,
        &opts,
    )
    .unwrap();
    assert!(
        v.distribution.max_um < 0.01,
        "max error {} µm",
        v.distribution.max_um
    );
}
