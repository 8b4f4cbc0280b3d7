//! Negative controls: with nothing hidden, explain names nothing and finds nothing unexplained.

mod explain_common;
use explain_common::*;

use nanocal::twin::{Trajectory, TwinConfig};

fn assert_nothing(rep: &nanocal::explain::Report, what: &str) {
    assert_names(rep, &[], what);
    for c in &rep.channels {
        assert!(
            c.unexplained.is_empty(),
            "{what}: unexplained {:?}\n{}",
            c.unexplained,
            rep.to_text()
        );
        // held-out RMS is the positioning scatter plus noise, not more
        assert!(
            c.baseline_rms_nm < 15.0,
            "{what}: baseline RMS {} nm",
            c.baseline_rms_nm
        );
    }
}

#[test]
fn published_training_with_nothing_hidden_reports_nothing() {
    for seed in [21, 22, 23] {
        assert_nothing(
            &explain_columns(training_1dof(Vec::new(), 6, seed)),
            "1-DoF training",
        );
    }
}

#[test]
fn days_of_validation_with_pressure_and_nothing_hidden_report_nothing() {
    for seed in [24, 25] {
        let mut cfg = TwinConfig::published_1dof();
        cfg.record_pressure = true;
        cfg.sample_period_s = 5.0;
        cfg.room.trend_c_per_day = 0.1;
        let cols = simulate(
            cfg,
            &Trajectory::published_validation_1dof(30.0, 48, 3600.0 - 390.0),
            seed,
        );
        assert_nothing(&explain_columns(cols), "1-DoF validation, two days");
    }
}

#[test]
fn two_axis_grid_with_nothing_hidden_reports_nothing() {
    for seed in [26, 27] {
        assert_nothing(&explain_columns(grid_2dof(Vec::new(), seed)), "2-DoF grid");
    }
}

#[test]
fn thermal_only_standstill_with_nothing_hidden_reports_nothing() {
    for seed in [28, 29] {
        let mut cfg = TwinConfig::published_1dof();
        cfg.room.hvac_amplitude_c = 0.05;
        cfg.room.daily_amplitude_c = 0.3;
        let mut cols = simulate(
            cfg,
            &Trajectory::standstill(vec![100.0], 14.0 * 3600.0),
            seed,
        );
        cols.columns.retain(|c| c.0 != "cmd_x");
        assert_nothing(&explain_columns(cols), "thermal-only standstill");
    }
}
