//! Ready-made simulated stages and recordings.

use super::{Columns, Trajectory, Twin, TwinConfig};
use crate::effects::{thermal_lag, thermal_position_interaction, unexplained_drift, EffectSpec};

/// Absolute time at which the published training starts (08:00 on day 0), s.
pub const TRAINING_START_S: f64 = 8.0 * 3600.0;

/// A simulated 1-DoF stage like the published one, and its (training, validation) recordings.
///
/// Cubic geometric error of a few hundred nm over 0–500 µm, four temperature sensors, thermal
/// coefficients of a few µm/°C (≈ 1 µm drift for 0.3 °C), positioning repeatability ≈ 35 nm
/// (ISO: mean deviation + 3σ), interferometer noise 3 nm.
/// Training: 0:30:480 µm forward then backward, 60 s dwells, 6 cycles (≈ 3.3 h, 1 Hz).
/// Validation: poses 0, 80, …, 480 forward then backward, 30 s dwells, one cycle per hour over
/// three days (5 s sampling), while the room drifts out of the training temperature range.
pub fn published_1dof(seed: u64) -> (Columns, Columns) {
    let twin = published_1dof_twin(seed);
    let training = Trajectory::published_training_1dof(60.0, 6);
    let train = twin.simulate(&training, TRAINING_START_S, 1);
    let val_start = TRAINING_START_S + training.duration_s() + 3600.0;
    let validation = Trajectory::published_validation_1dof(30.0, 72, 3600.0 - 13.0 * 30.0);
    let mut vtwin = twin.clone();
    vtwin.cfg.sample_period_s = 5.0;
    let val = vtwin.simulate(&validation, val_start, 2);
    (train, val)
}

/// The twin behind [`published_1dof`]: its room is realised for four days from `seed`.
pub fn published_1dof_twin(seed: u64) -> Twin {
    let mut cfg = TwinConfig::published_1dof();
    cfg.room.trend_c_per_day = 0.08;
    // What the published models could not see: the structure follows its sensors with a lag, a
    // heat source no sensor reads (electronics, a motor) switches on and off, and the piezo's
    // stroke changes with temperature — a gain error a reference pose at 0 µm cannot measure.
    cfg.effects = vec![
        EffectSpec::ThermalPositionInteraction(thermal_position_interaction::Params {
            axis: 0,
            alpha_ppm_per_c: 600.0,
        }),
        EffectSpec::ThermalLag(thermal_lag::Params::common(1200.0)),
        EffectSpec::UnexplainedDrift(unexplained_drift::Params {
            axis: 0,
            amplitude_nm: 400.0,
            tau_s: 4.0 * 3600.0,
            switch_period_s: 10.0 * 3600.0,
        }),
    ];
    Twin::new(cfg, 5.0 * 86_400.0, seed)
}
