//! The synthetic proof, measured on many seeds: every effect of the library hidden with random
//! parameters (explain is not told which), null controls, and things outside the library — a
//! drift with the square of a temperature, a sensor that freezes, a clock that jumps, a mount
//! that slips. It prints the rates the issue judges by (listed effects named, false alarms,
//! outside-library reported as such, main parameter within 2 stated σ) and asserts them.
//!
//! `EXPLAIN_PROOF_SEEDS=N` runs N seeds per case (default 2, as CI runs it);
//! `EXPLAIN_PROOF_ONLY=label` runs the cases whose label contains it.

mod explain_common;
use explain_common::*;

use nanocal::effects::*;
use nanocal::explain::{FaultKind, Report};
use nanocal::twin::{Columns, Ramp, Trajectory, TwinConfig};

/// What a case must come back as.
enum Expect {
    /// A listed effect: this name, and the truth of its main parameter (name, value) if it has one.
    Listed(&'static str, Option<(&'static str, f64)>),
    /// Nothing hidden: nothing named, no event.
    Nothing,
    /// A data fault of this kind on this column, nothing named.
    Fault(FaultKind, &'static str),
    /// An event (a step) at this row (0-based) within this many rows, nothing named.
    Event(usize, usize),
    /// Structure that no listed form explains (in this coordinate's words), nothing named.
    NotInLibrary(&'static str),
}

struct Case {
    label: &'static str,
    make: fn(u64) -> (Columns, Expect),
}

fn log_draw(r: &mut rand_chacha::ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (draw(r, lo.ln(), hi.ln())).exp()
}

fn col_mut<'a>(cols: &'a mut Columns, name: &str) -> &'a mut Vec<f64> {
    &mut cols.columns.iter_mut().find(|c| c.0 == name).unwrap().1
}

fn thermal_lag_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let tau_s = draw(&mut r, 600.0, 2400.0);
    let mut cfg = lively_fast_sensors();
    cfg.effects = vec![EffectSpec::ThermalLag(thermal_lag::Params::common(tau_s))];
    let cols = simulate(cfg, &Trajectory::published_training_1dof(60.0, 10), seed);
    (cols, Expect::Listed("thermal_lag", Some(("tau_s", tau_s))))
}

/// A lag of more than an hour behind a steady temperature trend (a frame expanding as the
/// room warms all day).
fn slow_thermal_lag_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let tau_s = draw(&mut r, 4000.0, 12000.0);
    let mut cfg = lively_fast_sensors();
    cfg.room.trend_c_per_day = draw(&mut r, 1.5, 3.0);
    cfg.effects = vec![EffectSpec::ThermalLag(thermal_lag::Params::common(tau_s))];
    let cols = simulate(cfg, &Trajectory::published_training_1dof(60.0, 16), seed);
    (cols, Expect::Listed("thermal_lag", Some(("tau_s", tau_s))))
}

fn hysteresis_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let half_width_nm = sign(&mut r) * draw(&mut r, 8.0, 30.0);
    let cols = training_1dof(
        vec![EffectSpec::Hysteresis(hysteresis::Params {
            axis: 0,
            half_width_nm,
            slope_nm: 0.0,
            ..Default::default()
        })],
        6,
        seed,
    );
    (
        cols,
        Expect::Listed("hysteresis", Some(("half_width_nm", half_width_nm.abs()))),
    )
}

/// The truth of explain's `half_width_nm` for a hidden play bank: the half-width of a full
/// loop over the stroke the command covered, which is the stroke explain states
/// (`stroke_um`) and the only one it can know. The random turning points do not reach the
/// ends of the travel: judged against the loop over the whole travel (15 µm amplitude where
/// the command covered 14.03 µm), seed 9003 read 6.7σ off where the loop explain describes
/// is 1.9σ off (9004 2.6 → 0.1σ, the negative stroke's 9005 5.1 → 0.1σ).
fn half_width_at_recorded_stroke_nm(cols: &Columns, thresholds: &[f64], weights: &[f64]) -> f64 {
    let cmd = cols.get("cmd_x").unwrap();
    let lo = cmd.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = cmd.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    1e3 * hysteresis::full_loop_half_width_um(thresholds, weights, 0.5 * (hi - lo))
}

fn minor_loop_bank(r: &mut rand_chacha::ChaCha8Rng, stroke_um: f64) -> (Vec<f64>, Vec<f64>) {
    let sense = sign(r);
    let thresholds: Vec<f64> = vec![
        stroke_um * draw(r, 0.01, 0.05),
        stroke_um * draw(r, 0.07, 0.17),
        stroke_um * draw(r, 0.2, 0.37),
    ];
    let weights: Vec<f64> = (0..3).map(|_| sense * draw(r, 0.005, 0.02)).collect();
    (thresholds, weights)
}

fn minor_loop_hysteresis_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let (thresholds, weights) = minor_loop_bank(&mut r, 30.0);
    let cols = continuous_drive(
        vec![EffectSpec::Hysteresis(hysteresis::Params {
            axis: 0,
            play_thresholds_um: thresholds.clone(),
            play_weights: weights.clone(),
            ..Default::default()
        })],
        seed,
    );
    let truth = half_width_at_recorded_stroke_nm(&cols, &thresholds, &weights);
    (
        cols,
        Expect::Listed("hysteresis", Some(("half_width_nm", truth))),
    )
}

/// A piezo loop over negative positions (−19…0 µm) with its drive also logged as a voltage,
/// and 30 glitch rows in the measurement.
fn negative_stroke_piezo_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let (thresholds, weights) = minor_loop_bank(&mut r, 19.0);
    let mut cfg = TwinConfig::published_1dof();
    cfg.travel_um = vec![(-19.0, 0.0)];
    cfg.geometric_nm = vec![vec![30.0, -20.0, 10.0]];
    cfg.sample_period_s = 0.005;
    cfg.positioning_sigma_nm = 0.0;
    cfg.interferometer_noise_nm = 3.0;
    cfg.effects = vec![EffectSpec::Hysteresis(hysteresis::Params {
        axis: 0,
        play_thresholds_um: thresholds.clone(),
        play_weights: weights.clone(),
        ..Default::default()
    })];
    let points = nanocal::twin::drives::random_turning_points(-19.0, 0.0, 60, &mut r);
    let traj = nanocal::twin::drives::through_turning_points(&points, 50, 0.005);
    let mut cols = simulate(cfg, &traj, seed);
    let truth = half_width_at_recorded_stroke_nm(&cols, &thresholds, &weights);
    let volts: Vec<f64> = cols
        .get("cmd_x")
        .unwrap()
        .iter()
        .map(|x| 3.0 + x / 12.5)
        .collect();
    cols.columns.push(("drive_v".into(), volts));
    let n = cols.rows();
    let meas = col_mut(&mut cols, "meas_x");
    for k in 0..30 {
        let i = 200 + (k * 7919 + seed as usize * 31) % (n - 400);
        meas[i] += sign(&mut r) * draw(&mut r, 20.0, 200.0);
    }
    (
        cols,
        Expect::Listed("hysteresis", Some(("half_width_nm", truth))),
    )
}

fn creep_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let gamma = draw(&mut r, 3e-4, 1.2e-3);
    let t0_s = log_draw(&mut r, 0.05, 10.0);
    let cols = training_1dof(
        vec![EffectSpec::Creep(creep::Params {
            axis: 0,
            gamma,
            t0_s,
        })],
        6,
        seed,
    );
    (cols, Expect::Listed("creep", Some(("gamma", gamma))))
}

fn interaction_cfg(alpha_ppm_per_c: f64) -> TwinConfig {
    let mut cfg = TwinConfig::published_1dof();
    cfg.room.daily_amplitude_c = 0.4;
    cfg.room.step_sigma_c = 0.15;
    cfg.effects = vec![EffectSpec::ThermalPositionInteraction(
        thermal_position_interaction::Params {
            axis: 0,
            alpha_ppm_per_c,
        },
    )];
    cfg
}

fn interaction_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let alpha = sign(&mut r) * draw(&mut r, 600.0, 1500.0);
    let cols = simulate(
        interaction_cfg(alpha),
        &Trajectory::published_training_1dof(30.0, 30),
        seed,
    );
    (
        cols,
        Expect::Listed(
            "thermal_position_interaction",
            Some(("alpha_ppm_per_c", alpha)),
        ),
    )
}

/// A thermal change of scale that leaves about 1 nm RMS: found only by a targeted test.
fn small_interaction_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let alpha = sign(&mut r) * draw(&mut r, 40.0, 90.0);
    let mut cfg = interaction_cfg(alpha);
    cfg.room.daily_amplitude_c = 0.3;
    cfg.room.step_sigma_c = 0.1;
    let cols = simulate(cfg, &Trajectory::published_training_1dof(30.0, 40), seed);
    (
        cols,
        Expect::Listed(
            "thermal_position_interaction",
            Some(("alpha_ppm_per_c", alpha)),
        ),
    )
}

fn air_refraction_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let dead_path_mm = draw(&mut r, 100.0, 300.0);
    let mut cfg = TwinConfig::published_1dof();
    cfg.record_pressure = true;
    cfg.sample_period_s = 5.0;
    cfg.room.pressure_amplitude_hpa = 8.0;
    cfg.effects = vec![EffectSpec::AirRefraction(air_refraction::Params {
        axis: 0,
        dead_path_mm,
    })];
    let cols = simulate(
        cfg,
        &Trajectory::published_validation_1dof(30.0, 48, 3600.0 - 390.0),
        seed,
    );
    (
        cols,
        Expect::Listed("air_refraction", Some(("dead_path_mm", dead_path_mm))),
    )
}

fn geometric_order_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let coeffs_nm = vec![
        sign(&mut r) * draw(&mut r, 80.0, 150.0),
        sign(&mut r) * draw(&mut r, 50.0, 100.0),
    ];
    let cols = training_1dof(
        vec![EffectSpec::GeometricOrder(geometric_order::Params {
            axis: 0,
            coeffs_nm,
        })],
        6,
        seed,
    );
    (cols, Expect::Listed("geometric_order", None))
}

fn axis_coupling_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let nm_per_um = sign(&mut r) * draw(&mut r, 0.2, 1.0);
    let (from_axis, to_axis) = if seed.is_multiple_of(2) {
        (0, 1)
    } else {
        (1, 0)
    };
    let cols = grid_2dof(
        vec![EffectSpec::AxisCoupling(axis_coupling::Params {
            from_axis,
            to_axis,
            nm_per_um,
            quadratic_nm: draw(&mut r, -15.0, 15.0),
        })],
        seed,
    );
    (
        cols,
        Expect::Listed("axis_coupling", Some(("nm_per_um", nm_per_um))),
    )
}

fn periodic_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let amplitude_nm = draw(&mut r, 5.0, 15.0);
    let mut cfg = lively_fast_sensors();
    cfg.effects = vec![EffectSpec::PeriodicNonlinearity(
        periodic_nonlinearity::Params {
            axis: 0,
            amplitude_nm,
            phase_rad: draw(&mut r, -3.0, 3.0),
            second_harmonic_nm: draw(&mut r, 0.0, 2.0),
        },
    )];
    let cols = simulate(cfg, &Trajectory::published_training_1dof(60.0, 6), seed);
    (
        cols,
        Expect::Listed(
            "periodic_nonlinearity",
            Some(("amplitude_nm", amplitude_nm)),
        ),
    )
}

/// A cyclic error of 3–15 nm under 5–20 nm of noise on a dense set of targets.
fn small_periodic_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let amplitude_nm = draw(&mut r, 3.0, 15.0);
    let mut cfg = TwinConfig::published_1dof();
    cfg.room.daily_amplitude_c = 0.005;
    cfg.room.hvac_amplitude_c = 0.002;
    cfg.room.steps_per_day = 0.0;
    cfg.positioning_sigma_nm = 3.0;
    cfg.interferometer_noise_nm = draw(&mut r, 5.0, 20.0);
    cfg.effects = vec![EffectSpec::PeriodicNonlinearity(
        periodic_nonlinearity::Params {
            axis: 0,
            amplitude_nm,
            phase_rad: draw(&mut r, -3.0, 3.0),
            second_harmonic_nm: 0.0,
        },
    )];
    let start = draw(&mut r, 0.0, 0.05);
    let poses: Vec<f64> = (0..600).map(|k| start + 0.0437 * k as f64).collect();
    let cols = simulate(
        cfg,
        &Trajectory::forward_backward(&poses, 4.0, 2, 0.0),
        seed,
    );
    (
        cols,
        Expect::Listed(
            "periodic_nonlinearity",
            Some(("amplitude_nm", amplitude_nm)),
        ),
    )
}

fn unexplained_drift_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let cols = training_1dof(
        vec![EffectSpec::UnexplainedDrift(unexplained_drift::Params {
            axis: 0,
            amplitude_nm: draw(&mut r, 60.0, 150.0),
            tau_s: draw(&mut r, 600.0, 1800.0),
            switch_period_s: draw(&mut r, 4000.0, 8000.0),
        })],
        12,
        seed,
    );
    (cols, Expect::Listed("unexplained_drift", None))
}

fn null_training(seed: u64) -> (Columns, Expect) {
    (training_1dof(Vec::new(), 6, seed), Expect::Nothing)
}

fn null_validation(seed: u64) -> (Columns, Expect) {
    let mut cfg = TwinConfig::published_1dof();
    cfg.record_pressure = true;
    cfg.sample_period_s = 5.0;
    cfg.room.trend_c_per_day = 0.1;
    let cols = simulate(
        cfg,
        &Trajectory::published_validation_1dof(30.0, 48, 3600.0 - 390.0),
        seed,
    );
    (cols, Expect::Nothing)
}

fn null_grid(seed: u64) -> (Columns, Expect) {
    (grid_2dof(Vec::new(), seed), Expect::Nothing)
}

fn null_lively_training(seed: u64) -> (Columns, Expect) {
    let cols = simulate(
        lively_fast_sensors(),
        &Trajectory::published_training_1dof(60.0, 10),
        seed,
    );
    (cols, Expect::Nothing)
}

fn null_drive(seed: u64) -> (Columns, Expect) {
    (continuous_drive(Vec::new(), seed), Expect::Nothing)
}

/// A drift with the square of one temperature while the room warms by 1–2 °C: physics
/// outside the library.
fn temperature_squared_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let mut cfg = lively_fast_sensors();
    cfg.room.ramps = vec![Ramp {
        start_s: 8.0 * 3600.0 + draw(&mut r, 0.5, 2.0) * 3600.0,
        duration_s: draw(&mut r, 1.5, 3.0) * 3600.0,
        delta_c: sign(&mut r) * draw(&mut r, 1.0, 2.0),
    }];
    let mut cols = simulate(cfg, &Trajectory::published_training_1dof(60.0, 10), seed);
    let k_um_per_c2 = sign(&mut r) * draw(&mut r, 0.15, 0.4);
    let temp = cols.get("temp_stage").unwrap().to_vec();
    let t0 = temp[0];
    for (m, t) in col_mut(&mut cols, "meas_x").iter_mut().zip(&temp) {
        *m += k_um_per_c2 * (t - t0).powi(2);
    }
    (cols, Expect::NotInLibrary("temp_stage"))
}

/// A temperature sensor that freezes mid-record while the room keeps moving.
fn frozen_sensor_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let mut cols = simulate(
        lively_fast_sensors(),
        &Trajectory::published_training_1dof(60.0, 10),
        seed,
    );
    let n = cols.rows();
    let from = (draw(&mut r, 0.3, 0.7) * n as f64) as usize;
    let to = if r.gen_bool(0.5) {
        n
    } else {
        (from + n / 5).min(n)
    };
    let name = ["temp_stage", "temp_base"][seed as usize % 2];
    let t = col_mut(&mut cols, name);
    let v = t[from];
    for x in t[from..to].iter_mut() {
        *x = v;
    }
    (cols, Expect::Fault(FaultKind::Frozen, name))
}

/// The logger's clock jumps ahead (or back) mid-record; the machine carries on.
fn clock_jump_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let mut cols = simulate(
        lively_fast_sensors(),
        &Trajectory::published_training_1dof(60.0, 10),
        seed,
    );
    let n = cols.rows();
    let from = (draw(&mut r, 0.2, 0.8) * n as f64) as usize;
    let jump = if r.gen_bool(0.7) {
        draw(&mut r, 1800.0, 7200.0)
    } else {
        -draw(&mut r, 600.0, 3600.0)
    };
    for v in col_mut(&mut cols, "t")[from..].iter_mut() {
        *v += jump;
    }
    let kind = if jump > 0.0 {
        FaultKind::ClockJump
    } else {
        FaultKind::TimeBackwards
    };
    (cols, Expect::Fault(kind, "t"))
}

/// A mount that slips once: the measurement steps by 100–400 nm at a random row and stays.
fn mount_slip_case(seed: u64) -> (Columns, Expect) {
    let mut r = rng(seed);
    let mut cols = simulate(
        lively_fast_sensors(),
        &Trajectory::published_training_1dof(60.0, 10),
        seed,
    );
    let n = cols.rows();
    let row = (draw(&mut r, 0.2, 0.8) * n as f64) as usize;
    let size_um = sign(&mut r) * draw(&mut r, 0.1, 0.4);
    for v in col_mut(&mut cols, "meas_x")[row..].iter_mut() {
        *v += size_um;
    }
    (cols, Expect::Event(row, 3))
}

use rand::Rng;

const CASES: &[Case] = &[
    Case {
        label: "thermal_lag",
        make: thermal_lag_case,
    },
    Case {
        label: "thermal_lag, slow (τ > 1 h) behind a trend",
        make: slow_thermal_lag_case,
    },
    Case {
        label: "hysteresis, step and settle",
        make: hysteresis_case,
    },
    Case {
        label: "hysteresis, minor loops",
        make: minor_loop_hysteresis_case,
    },
    Case {
        label: "hysteresis, negative stroke, drive as a voltage, glitches",
        make: negative_stroke_piezo_case,
    },
    Case {
        label: "creep",
        make: creep_case,
    },
    Case {
        label: "thermal_position_interaction",
        make: interaction_case,
    },
    Case {
        label: "thermal_position_interaction, ≈1 nm",
        make: small_interaction_case,
    },
    Case {
        label: "air_refraction",
        make: air_refraction_case,
    },
    Case {
        label: "geometric_order",
        make: geometric_order_case,
    },
    Case {
        label: "axis_coupling",
        make: axis_coupling_case,
    },
    Case {
        label: "periodic_nonlinearity, drift through fringes",
        make: periodic_case,
    },
    Case {
        label: "periodic_nonlinearity, 3–15 nm under 5–20 nm noise",
        make: small_periodic_case,
    },
    Case {
        label: "unexplained_drift",
        make: unexplained_drift_case,
    },
    Case {
        label: "control: 1-DoF training",
        make: null_training,
    },
    Case {
        label: "control: two days of validation with pressure",
        make: null_validation,
    },
    Case {
        label: "control: 2-DoF grid",
        make: null_grid,
    },
    Case {
        label: "control: lively room, fast sensors",
        make: null_lively_training,
    },
    Case {
        label: "control: continuous drive",
        make: null_drive,
    },
    Case {
        label: "outside: drift with temperature²",
        make: temperature_squared_case,
    },
    Case {
        label: "outside: frozen sensor",
        make: frozen_sensor_case,
    },
    Case {
        label: "outside: clock jump",
        make: clock_jump_case,
    },
    Case {
        label: "outside: mount slip",
        make: mount_slip_case,
    },
];

/// How one run came out.
#[derive(Default)]
struct Outcome {
    /// The expectation was met (listed: named; control: nothing; outside: reported as such).
    right: bool,
    /// Names that should not be there.
    false_names: Vec<&'static str>,
    /// For a listed effect with a truth: whether the main parameter is within 2 stated σ.
    within_2_sigma: Option<bool>,
    /// What was found, for the printout.
    found: String,
}

fn judge(rep: &Report, expect: &Expect) -> Outcome {
    let named: Vec<&'static str> = names(rep);
    let events: usize = rep.channels.iter().map(|c| c.events.len()).sum();
    let mut found = format!("named {named:?}");
    if events > 0 {
        found.push_str(&format!(", {events} event(s)"));
    }
    let faults: Vec<String> = rep
        .data_faults
        .iter()
        .filter(|f| f.kind.needs_check())
        .map(|f| format!("{} in {}", f.kind, f.column))
        .collect();
    if !faults.is_empty() {
        found.push_str(&format!(", faults {faults:?}"));
    }
    let mut out = Outcome::default();
    match expect {
        Expect::Listed(name, truth) => {
            out.right = named.contains(name);
            out.false_names = named.iter().copied().filter(|n| n != name).collect();
            if let (Some((p, value)), true) = (truth, out.right) {
                let e = rep.effects().find(|e| e.name == *name).unwrap();
                let est = e.param(p);
                let ok = est.is_some_and(|est| {
                    est.sigma.is_finite()
                        && est.sigma > 0.0
                        && (est.value - value).abs() <= 2.0 * est.sigma
                });
                if let Some(est) = est {
                    found.push_str(&format!(
                        "; {p} = {:.4e} ± {:.2e} vs {value:.4e}",
                        est.value, est.sigma
                    ));
                }
                out.within_2_sigma = Some(ok);
            }
        }
        Expect::Nothing => {
            out.false_names = named.clone();
            out.right = named.is_empty() && events == 0;
        }
        Expect::Fault(kind, column) => {
            out.false_names = named.clone();
            out.right = named.is_empty()
                && rep
                    .data_faults
                    .iter()
                    .any(|f| f.kind == *kind && f.column == *column);
        }
        Expect::Event(row, within) => {
            out.false_names = named.clone();
            let hit = rep.channels.iter().flat_map(|c| &c.events).any(|e| {
                e.row.abs_diff(*row) <= *within || (e.row_range.0 <= *row && *row <= e.row_range.1)
            });
            out.right = named.is_empty() && hit;
        }
        Expect::NotInLibrary(coordinate) => {
            out.false_names = named.clone();
            let said = rep.channels.iter().any(|c| {
                c.not_in_library
                    .iter()
                    .any(|m| m.coordinate.contains(coordinate))
            });
            out.right = named.is_empty() && said;
        }
    }
    out.found = found;
    out
}

fn seeds() -> Vec<u64> {
    let k: u64 = std::env::var("EXPLAIN_PROOF_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2);
    (0..k).map(|i| 9000 + i).collect()
}

#[test]
fn the_library_the_controls_and_what_is_outside_on_many_seeds() {
    let only = std::env::var("EXPLAIN_PROOF_ONLY").unwrap_or_default();
    let seeds = seeds();
    let (mut listed, mut listed_right) = (0, 0);
    let (mut controls, mut control_alarms) = (0, 0);
    let (mut outside, mut outside_right) = (0, 0);
    let (mut params, mut params_in) = (0, 0);
    let mut false_names_in_listed = 0;
    let mut failures: Vec<String> = Vec::new();
    println!("case | seed | right | found");
    for case in CASES.iter().filter(|c| c.label.contains(&only)) {
        for &seed in &seeds {
            let (cols, expect) = (case.make)(seed);
            let rep = explain_columns(cols);
            let o = judge(&rep, &expect);
            if std::env::var("EXPLAIN_PROOF_VERBOSE").is_ok() {
                println!("{}", rep.to_text());
            }
            println!(
                "{} | {seed} | {} | {}",
                case.label,
                if o.right { "yes" } else { "NO" },
                o.found
            );
            match expect {
                Expect::Listed(..) => {
                    listed += 1;
                    listed_right += usize::from(o.right);
                    false_names_in_listed += usize::from(!o.false_names.is_empty());
                }
                Expect::Nothing => {
                    controls += 1;
                    control_alarms += usize::from(!o.right);
                }
                _ => {
                    outside += 1;
                    outside_right += usize::from(o.right);
                }
            }
            if let Some(ok) = o.within_2_sigma {
                params += 1;
                params_in += usize::from(ok);
            }
            if !o.right {
                failures.push(format!("{} (seed {seed}): {}", case.label, o.found));
            }
        }
    }
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    println!(
        "\nseeds per case: {}\nlisted effects named: {listed_right}/{listed} ({:.0} %), with a further wrong name: {false_names_in_listed}\ncontrols with a false alarm: {control_alarms}/{controls}\noutside the library reported as such: {outside_right}/{outside} ({:.0} %)\nmain parameter within 2 stated σ: {params_in}/{params} ({:.0} %)",
        seeds.len(),
        pct(listed_right, listed),
        pct(outside_right, outside),
        pct(params_in, params)
    );
    if only.is_empty() {
        assert!(
            pct(listed_right, listed) >= 90.0,
            "listed effects named {listed_right}/{listed}\n{}",
            failures.join("\n")
        );
        assert_eq!(control_alarms, 0, "{}", failures.join("\n"));
        assert_eq!(outside_right, outside, "{}", failures.join("\n"));
        assert!(
            pct(params_in, params) >= 90.0,
            "parameters within 2σ {params_in}/{params}"
        );
    }
}

/// The targeted position × temperature test's false-alarm rate on the 1-DoF training control,
/// measured over many rooms: the family of one test claims `FAMILY_FALSE_ALARM` (0.1 %), the
/// issue allows 1 % per record. Ignored (≈ 2 s a seed);
/// `EXPLAIN_NULL_SEEDS=N` sets the number of seeds (default 60), from `host-tests/`:
/// `cargo test --release --test explain_proof -- --ignored --nocapture null_rate`.
#[test]
#[ignore]
fn null_rate_of_the_targeted_interaction_test() {
    let n: u64 = std::env::var("EXPLAIN_NULL_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60);
    let (mut below_1pc, mut below_5pc, mut alarms) = (0, 0, 0);
    for seed in 9000..9000 + n {
        let rep = explain_columns(training_1dof(Vec::new(), 6, seed));
        let t = rep
            .channels
            .iter()
            .flat_map(|c| &c.targeted)
            .find(|t| t.effect == "thermal_position_interaction")
            .expect("the interaction test applies to a 1-DoF recording with temperatures");
        println!(
            "seed {seed}: p = {:.2e}, z = {:.2}, significant {}",
            t.p_value, t.z, t.significant
        );
        below_1pc += usize::from(t.p_value < 0.01);
        below_5pc += usize::from(t.p_value < 0.05);
        alarms += usize::from(t.significant);
    }
    println!("{n} null seeds: p < 0.01 on {below_1pc}, p < 0.05 on {below_5pc}, named on {alarms}");
    // at a true 1 %, 4 or more alarms in 60 seeds happen with probability 0.3 %
    let allowed = 1 + (0.035 * n as f64).floor() as usize;
    assert!(
        alarms <= allowed,
        "false alarms {alarms}/{n} against a claimed 1 % (allowed {allowed})"
    );
}
