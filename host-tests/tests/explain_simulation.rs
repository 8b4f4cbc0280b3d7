//! `explain --simulation`: the recording is compared against a given simulation of the same
//! run; what the simulation left out is named.

mod explain_common;
use explain_common::*;

use nanocal::data::recording::Recording;
use nanocal::effects::{hysteresis, EffectSpec};
use nanocal::explain::{explain, Data, Settings};
use nanocal::twin::{Trajectory, Twin, TwinConfig};

#[test]
fn what_the_simulation_left_out_is_named() {
    let traj = Trajectory::published_training_1dof(60.0, 6);
    let mut with = TwinConfig::published_1dof();
    with.effects = vec![EffectSpec::Hysteresis(hysteresis::Params {
        axis: 0,
        half_width_nm: 20.0,
        slope_nm: 0.0,
        ..Default::default()
    })];
    let without = TwinConfig::published_1dof();
    // same room (seed), independent noise (stream)
    let measured = Twin::new(with, 3.0 * 86_400.0, 61).simulate(&traj, 8.0 * 3600.0, 1);
    let simulated = Twin::new(without, 3.0 * 86_400.0, 61).simulate(&traj, 8.0 * 3600.0, 2);
    let rec = Recording::from_columns(measured.columns).unwrap();
    let sim = Recording::from_columns(simulated.columns).unwrap();
    let data = Data::from_recording(&rec, Some(&sim)).unwrap();
    let rep = explain(&data, &Settings::default()).unwrap();
    assert_names(&rep, &["hysteresis"], "simulation without hysteresis");
    let e = effect(&rep, "x", "hysteresis").unwrap();
    assert_close(param(e, "half_width_nm"), 20.0, 0.15, 2.0, "half_width_nm");
    assert!(rep.channels[0].baseline.contains("simulation"));
}

#[test]
fn a_faithful_simulation_leaves_nothing_missing() {
    let traj = Trajectory::published_training_1dof(60.0, 6);
    let cfg = TwinConfig::published_1dof();
    let measured = Twin::new(cfg.clone(), 3.0 * 86_400.0, 62).simulate(&traj, 8.0 * 3600.0, 1);
    let simulated = Twin::new(cfg, 3.0 * 86_400.0, 62).simulate(&traj, 8.0 * 3600.0, 2);
    let rec = Recording::from_columns(measured.columns).unwrap();
    let sim = Recording::from_columns(simulated.columns).unwrap();
    let rep = explain(
        &Data::from_recording(&rec, Some(&sim)).unwrap(),
        &Settings::default(),
    )
    .unwrap();
    assert_names(&rep, &[], "faithful simulation");
}

#[test]
fn a_simulation_of_other_rows_is_refused() {
    let traj = Trajectory::published_training_1dof(60.0, 1);
    let cfg = TwinConfig::published_1dof();
    let twin = Twin::new(cfg, 86_400.0, 63);
    let rec = Recording::from_columns(twin.simulate(&traj, 0.0, 1).columns).unwrap();
    let short = Trajectory::published_training_1dof(30.0, 1);
    let sim = Recording::from_columns(twin.simulate(&short, 0.0, 2).columns).unwrap();
    let err = Data::from_recording(&rec, Some(&sim))
        .unwrap_err()
        .to_string();
    assert!(err.contains("rows"), "{err}");
}
