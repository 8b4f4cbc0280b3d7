//! 2-DoF: the published 0:10:80 µm grid for training and the six validation points, on the
//! digital twin; coupled model with cross-axis terms, n-D ISO 9283 (AP = barycentre distance).
use nanocal::data::dwell::{dwell_average, DwellOptions};
use nanocal::data::recording::Recording;
use nanocal::fit::design::DesignSpec;
use nanocal::fit::{fit_dwells, FitOptions, Selection};
use nanocal::numerics::stepwise::StepwiseOptions;
use nanocal::twin::{Trajectory, Twin, TwinConfig};
use nanocal::validate::{validate, Compensation, ValidationData, ValidationOptions};

#[test]
fn coupled_2dof_fit_and_n_d_validation() {
    let twin = Twin::new(TwinConfig::published_2dof(), 3.0 * 86_400.0, 11);
    let train = twin.simulate(&Trajectory::published_grid_2dof(30.0, 2), 8.0 * 3600.0, 1);
    let val = twin.simulate(
        &Trajectory::published_validation_2dof(30.0, 12, 600.0),
        12.0 * 3600.0,
        2,
    );
    let opts = DwellOptions::default();
    let dt = dwell_average(&Recording::from_columns(train.columns).unwrap(), &opts).unwrap();
    let dv = ValidationData::from_recording(&Recording::from_columns(val.columns).unwrap(), &opts)
        .unwrap();
    assert_eq!(dt.axes, vec!["x", "y"]);
    let spec = DesignSpec::parse("poly=3 cross=3 temps").unwrap();
    let fit = fit_dwells(
        &dt,
        &FitOptions {
            spec,
            selection: Selection::Stepwise(StepwiseOptions::default()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(fit.axes.len(), 2);
    // own cubic (3) + terms of degree ≤ 3 involving the other axis (y; xy, y²; x²y, xy², y³) + 4 temps
    assert_eq!(fit.axes[0].candidates.len(), 3 + 6 + 4);
    assert!(fit.axes[0].candidates.iter().any(|c| c.name == "x*y^2"));
    let o = ValidationOptions::default();
    let none = validate(None, &dv, &Compensation::None, &o).unwrap();
    let stat = validate(Some(&fit.model), &dv, &Compensation::Static, &o).unwrap();
    // six points; P0 twice: the very first visit (from rest, "forward") and the later ones
    // (from P5, backward on both axes) are different approaches
    assert_eq!(none.tests[0].poses.len(), 7);
    assert_eq!(none.tests[0].poses[0].target_um.len(), 2);
    assert!(
        stat.summary.max_acc_um < 0.5 * none.summary.max_acc_um,
        "AP static {:?} vs none {:?}",
        stat.summary,
        none.summary
    );
    let kmz = Compensation::Adaptive {
        reference_um: vec![0.0, 0.0],
        interval_s: 1800.0,
    };
    let adap = validate(Some(&fit.model), &dv, &kmz, &o).unwrap();
    // re-measured at the reference whenever at least the interval has passed since the last time
    let t_ref: Vec<f64> = adap
        .visits
        .iter()
        .filter(|v| v.kmz_reference)
        .map(|v| v.t_s)
        .collect();
    assert_eq!(t_ref.len(), adap.kmz_updates);
    assert!(t_ref.len() >= 3, "{} KMZ updates", t_ref.len());
    assert!(t_ref.windows(2).all(|w| w[1] - w[0] >= 1800.0));
    assert!(adap
        .visits
        .iter()
        .all(|v| v.kmz_reference == t_ref.contains(&v.t_s)));
    assert_eq!(adap.inverse_failures, 0);
    // the report plots n-D errors as distances
    let dir = std::env::temp_dir().join(format!("nanocal-2dof-report-{}", std::process::id()));
    let files = nanocal::report::write_report(&dir, &[&none, &stat, &adap]).unwrap();
    // 5 charts + one x–y pose figure per compensation (ISO 9283), each as PNG and SVG
    assert_eq!(files.len(), 16);
    assert!(files.iter().any(|f| f.ends_with("pose_xy_static.svg")));
    assert!(files.iter().all(|f| std::fs::metadata(f)
        .map(|m| m.len() > 1000)
        .unwrap_or(false)));
    std::fs::remove_dir_all(&dir).ok();
}
