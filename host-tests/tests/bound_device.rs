//! The prediction bound in the blob (format version 3, `nanocal_model::bound`): `fit` writes
//! it, and the f32 half-width the device's code computes from the blob agrees with the host's
//! f64 prediction interval (`nanocal::numerics::uncertainty::PredictionBand`) inside and outside the
//! training envelope.

use std::process::Command;

use nanocal::data::dwell::dwell_average;
use nanocal::data::recording::Recording;
use nanocal::fit::{band_regressors, encode_blob, fit_recording, FitOptions};
use nanocal::numerics::uncertainty::t_quantile;
use nanocal_model::{blob, Input, MAX_AXES};

fn twin_training() -> Recording {
    let (train, _) = nanocal::twin::examples::published_1dof(5);
    Recording::from_columns(train.columns).unwrap()
}

#[test]
fn the_device_bound_from_the_blob_agrees_with_the_host_interval() {
    let rec = twin_training();
    let opts = FitOptions::default();
    let fit = fit_recording(&rec, &opts).unwrap();
    let band = fit.axes[0]
        .band
        .as_ref()
        .expect("the published fit has a band");
    // what the device reads: the blob's bytes, decoded
    let model = blob::decode(&encode_blob(&fit.model)).unwrap();
    let bound = model.bound(0).expect("fit writes the bound of axis 0");
    assert_eq!(bound.regressors(), model.axis_terms(0));
    assert_eq!(bound.regressors(), band.regressors());
    let t95 = t_quantile(0.975, band.dfe as f64);
    assert!((bound.t95() as f64 - t95).abs() < 1e-6 * t95);

    // the training dwells, then the same shifted beyond the envelope (positions to the ends
    // of travel and past them, temperatures up to 3 °C outside)
    let d = dwell_average(&rec, &opts.dwell).unwrap();
    let slow = fit.frame.slow_inputs(&d);
    let (x_lo, x_hi) = model.envelope(Input::Axis(0));
    let (mut checked, mut worst_rel, mut widest_ratio) = (0, 0.0f64, 0.0f64);
    let mut inside_hw = f64::INFINITY;
    for (i, s) in slow.iter().enumerate() {
        for (dx_um, dt_c) in [
            (None, 0.0),
            (Some(x_lo - 5.0), -3.0),
            (Some(x_hi + 5.0), 3.0),
        ] {
            let mut x = [0.0; MAX_AXES];
            let mut dir = [0i8; MAX_AXES];
            x[0] = dx_um.unwrap_or(d.meas_um[0][i]);
            dir[0] = d.dir[0][i];
            let mut s = *s;
            for t in 0..model.temps() {
                s.temps_c[t] += dt_c;
            }
            for l in 0..model.lags().len() {
                s.lagged_c[l] += dt_c;
            }
            let scaled = model.scale(&x, &dir, &s);
            let host = band
                .half_width(&band_regressors(&model, 0, &scaled), 0.95)
                .unwrap();
            let device = model
                .prediction_half_width_um(0, &scaled, bound.t95())
                .unwrap() as f64;
            let rel = (device - host).abs() / host;
            worst_rel = worst_rel.max(rel);
            if dx_um.is_none() {
                inside_hw = inside_hw.min(host);
            } else {
                widest_ratio = widest_ratio.max(host / inside_hw);
            }
            checked += 1;
        }
    }
    eprintln!(
        "{checked} points: device f32 vs host f64 half-width, worst relative difference {worst_rel:.2e}; \
         outside the envelope the interval widens up to {widest_ratio:.1}× the narrowest inside"
    );
    assert!(checked > 100);
    assert!(worst_rel < 1e-3, "f32 bound off by {worst_rel:e}");
    // extrapolation shows: the interval outside the envelope is wider than anywhere inside
    assert!(widest_ratio > 1.5, "{widest_ratio}");
}

#[test]
fn fit_writes_a_version_3_blob_with_a_bound_per_axis() {
    let dir = std::env::temp_dir().join(format!("nanocal-bound-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("training.csv");
    twin_training().write_path(&csv).unwrap();
    let out = dir.join("m.blob");
    let run = Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .arg("fit")
        .arg(&csv)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(&bytes[4..6], &blob::FORMAT_VERSION.to_le_bytes());
    assert_eq!(blob::FORMAT_VERSION, 4);
    let model = blob::decode(&bytes).unwrap();
    for a in 0..model.axes() {
        let b = model
            .bound(a)
            .expect("every axis of the published fit has a bound");
        assert_eq!(b.regressors(), model.axis_terms(a));
        assert!(b.s_um() > 0.0);
    }
    std::fs::remove_dir_all(&dir).ok();
}
