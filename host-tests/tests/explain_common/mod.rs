//! Shared helpers of the explain proof tests: simulate with the twin, explain, look up results.
#![allow(dead_code)]

use nanocal::data::recording::Recording;
use nanocal::effects::EffectSpec;
use nanocal::explain::{explain, ChannelReport, Data, EffectReport, Report, Settings};
use nanocal::twin::{Columns, Trajectory, Twin, TwinConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A seeded generator for the hidden parameters.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed.wrapping_mul(7919).wrapping_add(17))
}

/// Uniform draw in [lo, hi].
pub fn draw(r: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    r.gen_range(lo..=hi)
}

/// Random sign.
pub fn sign(r: &mut ChaCha8Rng) -> f64 {
    if r.gen_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

/// Simulate `traj` on a twin with `cfg` (room realised from `seed`).
pub fn simulate(cfg: TwinConfig, traj: &Trajectory, seed: u64) -> Columns {
    let span = traj.duration_s() + 2.0 * 86_400.0;
    Twin::new(cfg, span, seed).simulate(traj, 8.0 * 3600.0, 1)
}

/// Explain simulated columns.
pub fn explain_columns(cols: Columns) -> Report {
    let rec = Recording::from_columns(cols.columns).expect("twin columns form a recording");
    let data = Data::from_recording(&rec, None).expect("recording is usable");
    explain(&data, &Settings::default()).expect("explain runs")
}

/// Names of all effects found.
pub fn names(rep: &Report) -> Vec<&'static str> {
    rep.effects().map(|e| e.name).collect()
}

/// The effect `name` on channel `ch`, if named.
pub fn effect<'a>(rep: &'a Report, ch: &str, name: &str) -> Option<&'a EffectReport> {
    rep.effects().find(|e| e.name == name && e.channel == ch)
}

/// A parameter value of an effect.
pub fn param(e: &EffectReport, name: &str) -> f64 {
    e.params
        .iter()
        .find(|p| p.name == name)
        .unwrap_or_else(|| panic!("{} has no parameter {name}", e.name))
        .value
}

/// The channel report for `ch`.
pub fn channel<'a>(rep: &'a Report, ch: &str) -> &'a ChannelReport {
    rep.channels
        .iter()
        .find(|c| c.channel == ch)
        .expect("channel exists")
}

/// Standard 1-DoF training recording (published trajectory, 60 s dwells, `cycles` cycles).
pub fn training_1dof(effects: Vec<EffectSpec>, cycles: usize, seed: u64) -> Columns {
    let mut cfg = TwinConfig::published_1dof();
    cfg.record_pressure = true;
    cfg.effects = effects;
    simulate(
        cfg,
        &Trajectory::published_training_1dof(60.0, cycles),
        seed,
    )
}

/// 2-DoF grid recording (20 s dwells, 3 cycles).
pub fn grid_2dof(effects: Vec<EffectSpec>, seed: u64) -> Columns {
    let mut cfg = TwinConfig::published_2dof();
    cfg.effects = effects;
    simulate(cfg, &Trajectory::published_grid_2dof(20.0, 3), seed)
}

/// Assert the report names exactly `expected` (as a set) and print the report on failure.
pub fn assert_names(rep: &Report, expected: &[&str], what: &str) {
    let mut got = names(rep);
    got.sort_unstable();
    got.dedup();
    let mut want = expected.to_vec();
    want.sort_unstable();
    assert_eq!(
        got,
        want,
        "{what}: named {got:?}, expected {want:?}\n{}",
        rep.to_text()
    );
}

/// Assert |found − truth| ≤ rel·|truth| + abs.
pub fn assert_close(found: f64, truth: f64, rel: f64, abs: f64, what: &str) {
    assert!(
        (found - truth).abs() <= rel * truth.abs() + abs,
        "{what}: found {found}, truth {truth} (tolerance {rel}·|truth| + {abs})"
    );
}

/// A lively lab (HVAC ±0.05 °C, daily ±0.3 °C) read by three fast sensors (60–600 s behind the
/// air), so that a slower structure is not already spanned by the sensors themselves.
pub fn lively_fast_sensors() -> TwinConfig {
    use nanocal::twin::SensorConfig;
    let mut cfg = TwinConfig::published_1dof();
    cfg.room.hvac_amplitude_c = 0.05;
    cfg.room.daily_amplitude_c = 0.3;
    cfg.sensors = vec![
        SensorConfig::new("air", 0.0, 60.0, 1.0),
        SensorConfig::new("stage", 0.2, 300.0, 1.0),
        SensorConfig::new("base", 0.1, 600.0, 0.9),
    ];
    cfg.thermal_um_per_c = vec![vec![1.2, 1.0, 0.8]];
    cfg
}

/// A piezo-like stage (0–30 µm, 200 Hz, no geometric error beyond a small cubic) under a
/// continuous drive through random turning points: amplitude changes, minor loops, partly
/// inverted strokes (60 legs, 15 s).
pub fn continuous_drive(effects: Vec<EffectSpec>, seed: u64) -> Columns {
    let mut r = rng(seed ^ 0xD21E);
    let mut cfg = TwinConfig::published_1dof();
    cfg.travel_um = vec![(0.0, 30.0)];
    cfg.geometric_nm = vec![vec![20.0, -15.0, 10.0]];
    cfg.sample_period_s = 0.005;
    cfg.positioning_sigma_nm = 0.0;
    cfg.interferometer_noise_nm = 3.0;
    cfg.effects = effects;
    let points = nanocal::twin::drives::random_turning_points(0.0, 30.0, 60, &mut r);
    let traj = nanocal::twin::drives::through_turning_points(&points, 50, 0.005);
    simulate(cfg, &traj, seed)
}

/// Round a column to a grid of `step` (a coarse encoder, an ADC).
pub fn quantise(cols: &mut Columns, name: &str, step: f64) {
    let c = &mut cols.columns.iter_mut().find(|c| c.0 == name).unwrap().1;
    for v in c.iter_mut() {
        *v = (*v / step).round() * step;
    }
}

/// Add `offset` to `name` at `rows` (a homing error, a mis-trigger).
pub fn add_glitches(cols: &mut Columns, name: &str, rows: &[usize], offset: f64) {
    let c = &mut cols.columns.iter_mut().find(|c| c.0 == name).unwrap().1;
    for &i in rows {
        c[i] += offset;
    }
}

/// Three sensors near their own local heat sources (a motor, electronics, a lamp: each
/// switching on and off at random, independently) in a quiet room — temperatures that vary
/// independently, as on a machine with several heat sources, so that each sensor's own lag can
/// be told apart.
pub fn independent_heat_sources() -> TwinConfig {
    use nanocal::twin::SensorConfig;
    let mut cfg = TwinConfig::published_1dof();
    cfg.room.daily_amplitude_c = 0.05;
    let heater = |name: &str, tau: f64, c: f64, period: f64| {
        let mut s = SensorConfig::new(name, 0.0, tau, 1.0);
        s.local_heater_c = c;
        s.local_heater_period_s = period;
        s
    };
    cfg.sensors = vec![
        heater("motor", 120.0, 0.4, 2400.0),
        heater("drive", 300.0, 0.3, 3600.0),
        heater("lamp", 200.0, 0.5, 3000.0),
    ];
    cfg.thermal_um_per_c = vec![vec![0.8, -0.6, 0.5]];
    cfg
}
