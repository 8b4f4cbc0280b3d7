//! The digital twin: deterministic, the shared layout, and a published-like 1-DoF stage.

use nanocal::effects::{hysteresis, EffectSpec};
use nanocal::twin::{examples, Trajectory, Twin, TwinConfig};

#[test]
fn same_seed_same_recording_other_seed_differs() {
    let (a, _) = examples::published_1dof(7);
    let (b, _) = examples::published_1dof(7);
    let (c, _) = examples::published_1dof(8);
    assert_eq!(a, b);
    assert_ne!(a.get("meas_x"), c.get("meas_x"));
}

#[test]
fn published_example_has_the_shared_layout_and_plausible_physics() {
    let (train, val) = examples::published_1dof(3);
    let names: Vec<&str> = train.columns.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "t",
            "cmd_x",
            "meas_x",
            "temp_base",
            "temp_stage",
            "temp_air",
            "temp_frame"
        ]
    );
    // Training covers 0:30:480 forward and backward.
    let cmd = train.get("cmd_x").unwrap();
    let mut poses: Vec<i64> = cmd.iter().map(|&c| c as i64).collect();
    poses.dedup();
    assert_eq!(
        &poses[..17],
        &(0..=16).map(|k| 30 * k).collect::<Vec<_>>()[..]
    );
    assert_eq!(poses[17], 450);
    // Validation spans days and leaves the training temperature range.
    let t = val.get("t").unwrap();
    assert!(*t.last().unwrap() > 2.5 * 86_400.0);
    let tmax = |r: &nanocal::twin::Columns| {
        r.get("temp_stage")
            .unwrap()
            .iter()
            .cloned()
            .fold(f64::MIN, f64::max)
    };
    assert!(tmax(&val) > tmax(&train) + 0.1);
}

#[test]
fn drift_is_about_one_micrometre_for_three_tenths_of_a_degree() {
    let cfg = TwinConfig::published_1dof();
    let k: f64 = cfg.thermal_um_per_c[0].iter().sum();
    assert!(
        (2.5..4.5).contains(&k),
        "sum of thermal coefficients {k} µm/°C"
    );
    assert!((0.75..1.35).contains(&(0.3 * k)));
}

#[test]
fn hysteresis_effect_separates_forward_and_backward() {
    let mut cfg = TwinConfig::published_1dof();
    cfg.positioning_sigma_nm = 0.0;
    cfg.interferometer_noise_nm = 0.0;
    cfg.interferometer_resolution_nm = 0.0;
    cfg.effects.push(EffectSpec::Hysteresis(hysteresis::Params {
        axis: 0,
        half_width_nm: 25.0,
        slope_nm: 0.0,
        ..Default::default()
    }));
    let twin = Twin::new(cfg.clone(), 86_400.0, 1);
    let traj = Trajectory::published_training_1dof(10.0, 1);
    let with = twin.simulate(&traj, 0.0, 1);
    cfg.effects.clear();
    let without = Twin::new(cfg, 86_400.0, 1).simulate(&traj, 0.0, 1);
    let d: Vec<f64> = with
        .get("meas_x")
        .unwrap()
        .iter()
        .zip(without.get("meas_x").unwrap())
        .map(|(a, b)| (a - b) * 1e3)
        .collect();
    let cmd = with.get("cmd_x").unwrap();
    // forward at 240 µm (first visit), backward at 240 µm (second visit)
    let i_f = cmd.iter().position(|&c| c == 240.0).unwrap();
    let i_b = cmd.iter().rposition(|&c| c == 240.0).unwrap();
    assert!(
        (d[i_f] - 25.0).abs() < 0.5 && (d[i_b] + 25.0).abs() < 0.5,
        "{} {}",
        d[i_f],
        d[i_b]
    );
}
