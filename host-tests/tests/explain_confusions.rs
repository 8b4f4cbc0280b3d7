//! The confusions a physicist would worry about: creep vs hysteresis (also when only dwell
//! averages are seen), thermal lag vs a missing sensor, axis coupling vs higher-order geometry.

mod explain_common;
use explain_common::*;

use nanocal::effects::*;
use nanocal::twin::{Columns, Trajectory};

/// One row per dwell: the mean of its last `last_s` seconds, as the published procedure does.
fn dwell_averages(cols: &Columns, last_s: f64) -> Columns {
    let t = cols.get("t").unwrap();
    let cmd = cols.get("cmd_x").unwrap();
    let mut ends = Vec::new();
    for i in 1..t.len() {
        if cmd[i] != cmd[i - 1] {
            ends.push(i);
        }
    }
    ends.push(t.len());
    let mut start = 0;
    let mut out: Vec<(String, Vec<f64>)> = cols
        .columns
        .iter()
        .map(|c| (c.0.clone(), Vec::new()))
        .collect();
    for &e in &ends {
        let rows: Vec<usize> = (start..e).filter(|&i| t[i] > t[e - 1] - last_s).collect();
        for (o, c) in out.iter_mut().zip(&cols.columns) {
            let v = if o.0 == "t" {
                t[e - 1]
            } else {
                rows.iter().map(|&i| c.1[i]).sum::<f64>() / rows.len() as f64
            };
            o.1.push(v);
        }
        start = e;
    }
    Columns { columns: out }
}

#[test]
fn hysteresis_is_not_mistaken_for_creep() {
    for seed in [31, 32] {
        let mut r = rng(seed);
        let half_width_nm = sign(&mut r) * draw(&mut r, 10.0, 30.0);
        let rep = explain_columns(training_1dof(
            vec![EffectSpec::Hysteresis(hysteresis::Params {
                axis: 0,
                half_width_nm,
                slope_nm: 0.0,
                ..Default::default()
            })],
            6,
            seed,
        ));
        assert_names(&rep, &["hysteresis"], "hidden hysteresis");
    }
}

#[test]
fn creep_sampled_within_dwells_is_creep_not_hysteresis() {
    for seed in [33, 34] {
        let mut r = rng(seed);
        let gamma = draw(&mut r, 4e-4, 1e-3);
        let rep = explain_columns(training_1dof(
            vec![EffectSpec::Creep(creep::Params {
                axis: 0,
                gamma,
                t0_s: 2.0,
            })],
            6,
            seed,
        ));
        assert_names(&rep, &["creep"], "hidden creep, 1 Hz");
    }
}

/// Seen only through dwell averages, creep's step-history signature is all that separates it
/// from hysteresis: explain must still name creep (from the history of steps), never both.
#[test]
fn creep_seen_only_through_dwell_averages() {
    for seed in [35, 36] {
        let mut r = rng(seed);
        let gamma = draw(&mut r, 4e-4, 1e-3);
        let cols = training_1dof(
            vec![EffectSpec::Creep(creep::Params {
                axis: 0,
                gamma,
                t0_s: 2.0,
            })],
            12,
            seed,
        );
        let rep = explain_columns(dwell_averages(&cols, 10.0));
        assert_names(&rep, &["creep"], "hidden creep, dwell averages");
        let e = effect(&rep, "x", "creep").unwrap();
        assert_close(
            param(e, "gamma"),
            gamma,
            0.3,
            0.0,
            "gamma from dwell averages",
        );
    }
}

#[test]
fn thermal_lag_is_not_reported_as_unexplained_drift() {
    for seed in [37, 38] {
        let mut r = rng(seed);
        let tau_s = draw(&mut r, 900.0, 2400.0);
        let mut cfg = lively_fast_sensors();
        cfg.effects = vec![EffectSpec::ThermalLag(thermal_lag::Params::common(tau_s))];
        let rep = explain_columns(simulate(
            cfg,
            &Trajectory::published_training_1dof(60.0, 10),
            seed,
        ));
        assert_names(&rep, &["thermal_lag"], "hidden thermal lag");
    }
}

/// A missing sensor on a slow spot that follows the room: the structure follows a lag of the
/// sensors that remain — thermal_lag, with τ of the order of the missing spot's lag.
#[test]
fn missing_slow_sensor_is_explained_as_a_lag_of_the_others() {
    for seed in [39, 40] {
        let mut cfg = lively_fast_sensors();
        cfg.sensors
            .push(nanocal::twin::SensorConfig::new("frame", -0.1, 3600.0, 1.0));
        cfg.thermal_um_per_c = vec![vec![0.6, 0.5, 0.4, 2.0]];
        let mut cols = simulate(cfg, &Trajectory::published_training_1dof(60.0, 10), seed);
        cols.columns.retain(|c| c.0 != "temp_frame");
        let rep = explain_columns(cols);
        assert!(
            names(&rep).contains(&"thermal_lag"),
            "expected thermal_lag\n{}",
            rep.to_text()
        );
        let tau = param(effect(&rep, "x", "thermal_lag").unwrap(), "tau_s");
        assert!(
            (1200.0..12_000.0).contains(&tau),
            "τ {tau} s for a spot 3600 s behind the air"
        );
    }
}

/// A heat source with no sensor at all is not forced into a lag of the sensors.
#[test]
fn unseen_heat_source_is_not_a_thermal_lag() {
    for seed in [41, 42] {
        let rep = explain_columns(training_1dof(
            vec![EffectSpec::UnexplainedDrift(unexplained_drift::Params {
                axis: 0,
                amplitude_nm: 100.0,
                tau_s: 1200.0,
                switch_period_s: 5000.0,
            })],
            12,
            seed,
        ));
        assert!(
            !names(&rep).contains(&"thermal_lag"),
            "unseen source named thermal_lag\n{}",
            rep.to_text()
        );
        assert!(
            names(&rep).contains(&"unexplained_drift"),
            "{}",
            rep.to_text()
        );
    }
}

#[test]
fn coupling_is_not_mistaken_for_higher_order_geometry() {
    for seed in [43, 44] {
        let mut r = rng(seed);
        let nm_per_um = sign(&mut r) * draw(&mut r, 0.3, 1.0);
        let rep = explain_columns(grid_2dof(
            vec![EffectSpec::AxisCoupling(axis_coupling::Params {
                from_axis: 1,
                to_axis: 0,
                nm_per_um,
                quadratic_nm: 0.0,
            })],
            seed,
        ));
        assert_names(&rep, &["axis_coupling"], "hidden coupling");
    }
}

#[test]
fn higher_order_geometry_is_not_mistaken_for_coupling() {
    for seed in [45, 46] {
        let mut r = rng(seed);
        let coeffs_nm = vec![
            sign(&mut r) * draw(&mut r, 40.0, 80.0),
            sign(&mut r) * draw(&mut r, 30.0, 60.0),
        ];
        let rep = explain_columns(grid_2dof(
            vec![EffectSpec::GeometricOrder(geometric_order::Params {
                axis: 0,
                coeffs_nm,
            })],
            seed,
        ));
        assert_names(&rep, &["geometric_order"], "hidden geometry");
        assert!(effect(&rep, "x", "geometric_order").is_some());
    }
}

/// A periodic error the stage never drifted through (quiet room: the same phase at every
/// visit of a pose) is indistinguishable from geometry and must not be named periodic.
#[test]
fn periodic_error_without_fringe_crossing_is_not_claimed() {
    for seed in [47, 48] {
        let mut cfg = nanocal::twin::TwinConfig::published_1dof();
        cfg.room.daily_amplitude_c = 0.005;
        cfg.room.hvac_amplitude_c = 0.002;
        cfg.room.steps_per_day = 0.0;
        cfg.effects = vec![EffectSpec::PeriodicNonlinearity(
            periodic_nonlinearity::Params {
                axis: 0,
                amplitude_nm: 10.0,
                phase_rad: 0.5,
                second_harmonic_nm: 0.0,
            },
        )];
        let rep = explain_columns(simulate(
            cfg,
            &Trajectory::published_training_1dof(60.0, 6),
            seed,
        ));
        assert!(
            !names(&rep).contains(&"periodic_nonlinearity"),
            "{}",
            rep.to_text()
        );
    }
}

/// A fine scan (poses 50 nm apart) samples the fringe at many phases without any drift: there
/// the periodic error is identifiable, and found.
#[test]
fn periodic_error_in_a_fine_scan_is_found() {
    let poses: Vec<f64> = (0..400).map(|k| 0.05 * k as f64).collect();
    for seed in [49, 50] {
        let mut r = rng(seed);
        let amplitude_nm = draw(&mut r, 4.0, 10.0);
        let mut cfg = nanocal::twin::TwinConfig::published_1dof();
        cfg.room.daily_amplitude_c = 0.005;
        cfg.room.hvac_amplitude_c = 0.002;
        cfg.room.steps_per_day = 0.0;
        cfg.positioning_sigma_nm = 3.0;
        cfg.effects = vec![EffectSpec::PeriodicNonlinearity(
            periodic_nonlinearity::Params {
                axis: 0,
                amplitude_nm,
                phase_rad: draw(&mut r, -3.0, 3.0),
                second_harmonic_nm: 0.0,
            },
        )];
        let traj = Trajectory::forward_backward(&poses, 5.0, 3, 0.0);
        let rep = explain_columns(simulate(cfg, &traj, seed));
        assert_names(&rep, &["periodic_nonlinearity"], "fine scan");
        let e = effect(&rep, "x", "periodic_nonlinearity").unwrap();
        assert_close(
            param(e, "amplitude_nm"),
            amplitude_nm,
            0.25,
            1.0,
            "amplitude_nm",
        );
    }
}
