#![allow(clippy::needless_range_loop)] // index loops over several parallel series read clearer here
//! The digital twin: the one forward physics model of a stage in the project.
//!
//! A stage with 1–3 axes follows a command trajectory; its true position is the command plus a
//! geometric error polynomial, a linear thermal drift from the temperatures of several spots
//! (read by sensors with noise and resolution), a positioning scatter per move, and any number
//! of switchable physical effects from [`crate::effects`]. An interferometer with noise (and
//! optional effects of its own) measures the position. Everything is deterministic from a seed.

pub mod delta;
pub mod drives;
pub mod examples;
pub mod execute;
pub mod room;
pub mod trajectory;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::data::recording::{Recording, RecordingError};
use crate::effects::{EffectSpec, SimContext};
pub use room::{Ramp, Room, RoomConfig, SensorConfig};
pub use trajectory::{Dwell, Trajectory};

/// Axis names used for columns (`cmd_x`, `meas_x`, …).
pub const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// Standard normal draw (Box–Muller).
pub fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.gen_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.gen_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Everything that defines a simulated stage, its room and its instruments.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TwinConfig {
    /// Number of axes (1–3).
    pub axes: usize,
    /// Travel per axis (min, max) in µm; the geometric polynomial uses u = scaled position in [-1, 1].
    pub travel_um: Vec<(f64, f64)>,
    /// Geometric error per axis: coefficients (nm) of u, u², u³, … (order = length).
    pub geometric_nm: Vec<Vec<f64>>,
    /// Thermal drift per axis and sensor, µm/°C (relative to `temp_ref_c`).
    pub thermal_um_per_c: Vec<Vec<f64>>,
    /// Reference temperature of the thermal drift, °C.
    pub temp_ref_c: f64,
    /// The room.
    pub room: RoomConfig,
    /// The spots whose temperature drives the stage, each read by a sensor (one `temp_`
    /// column) unless it is unsensed.
    pub sensors: Vec<SensorConfig>,
    /// Positioning scatter: a fresh random offset per move, nm (1 σ).
    pub positioning_sigma_nm: f64,
    /// Interferometer white noise per sample, nm (1 σ).
    pub interferometer_noise_nm: f64,
    /// Interferometer resolution, nm (0 = none).
    pub interferometer_resolution_nm: f64,
    /// Whether a `pressure` column (hPa) is recorded.
    pub record_pressure: bool,
    /// Pressure sensor noise, hPa (1 σ).
    pub pressure_noise_hpa: f64,
    /// Sample period, s.
    pub sample_period_s: f64,
    /// The switched-on effects with their physical parameters.
    pub effects: Vec<EffectSpec>,
}

impl TwinConfig {
    /// A 1-DoF stage like the published one: cubic geometric error of a few hundred nm over
    /// 0–500 µm, four sensors, thermal coefficients of a few µm/°C (≈1 µm per 0.3 °C), 1 Hz.
    pub fn published_1dof() -> Self {
        Self {
            axes: 1,
            travel_um: vec![(0.0, 500.0)],
            geometric_nm: vec![vec![120.0, -180.0, 150.0]],
            thermal_um_per_c: vec![vec![1.6, 1.2, 0.9, -0.4]],
            temp_ref_c: 20.0,
            room: RoomConfig::default(),
            sensors: vec![
                SensorConfig::new("base", 0.10, 1800.0, 0.9),
                SensorConfig::new("stage", 0.25, 900.0, 1.0),
                SensorConfig::new("air", 0.0, 120.0, 1.0),
                SensorConfig::new("frame", -0.15, 3600.0, 0.8),
            ],
            positioning_sigma_nm: 9.0,
            interferometer_noise_nm: 3.0,
            interferometer_resolution_nm: 0.3,
            record_pressure: false,
            pressure_noise_hpa: 0.02,
            sample_period_s: 1.0,
            effects: Vec::new(),
        }
    }

    /// A 2-DoF stage (x, y) over 0–80 µm with the same room and sensors.
    pub fn published_2dof() -> Self {
        let mut c = Self::published_1dof();
        c.axes = 2;
        c.travel_um = vec![(0.0, 80.0), (0.0, 80.0)];
        c.geometric_nm = vec![vec![40.0, -60.0, 50.0], vec![-30.0, 45.0, 35.0]];
        c.thermal_um_per_c = vec![vec![1.6, 1.2, 0.9, -0.4], vec![-0.8, 1.4, 0.5, 0.7]];
        c
    }

    /// Scaled position u ∈ [-1, 1] of `x_um` on `axis`.
    pub fn scaled(&self, axis: usize, x_um: f64) -> f64 {
        let (lo, hi) = self.travel_um[axis];
        (x_um - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
    }
}

/// A simulated recording as plain named columns in the shared layout.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Columns {
    /// (column name, values) in output order.
    pub columns: Vec<(String, Vec<f64>)>,
}

impl Columns {
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |c| c.1.len())
    }

    /// The values of a column by name.
    pub fn get(&self, name: &str) -> Option<&[f64]> {
        self.columns
            .iter()
            .find(|c| c.0 == name)
            .map(|c| c.1.as_slice())
    }

    /// As a [`Recording`] (the host's type for recordings in the shared layout).
    pub fn to_recording(&self) -> Result<Recording, RecordingError> {
        Recording::from_columns(self.columns.clone())
    }

    /// Write as CSV in the shared layout (through the host's recording writer).
    pub fn write_csv<W: std::io::Write>(&self, w: W) -> std::io::Result<()> {
        self.to_recording().map_err(std::io::Error::other)?.write(w)
    }
}

/// Round to 1 pm (µm columns) / 1 µK (°C): removes binary noise so the CSV stays short.
fn tidy(v: f64) -> f64 {
    let r = (v * 1e6).round() / 1e6;
    if r == 0.0 {
        0.0
    } else {
        r
    }
}

/// The twin: a configuration and a realised room, simulating recordings at any absolute time.
#[derive(Clone, Debug)]
pub struct Twin {
    /// The configuration.
    pub cfg: TwinConfig,
    room: Room,
    seed: u64,
}

impl Twin {
    /// Realise the room's random events for `span_s` seconds of absolute time from `seed`.
    pub fn new(cfg: TwinConfig, span_s: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let room = Room::new(&cfg.room, span_s, &mut rng);
        Self { cfg, room, seed }
    }

    /// The room this twin stands in.
    pub fn room(&self) -> &Room {
        &self.room
    }

    /// Simulate `traj` starting at absolute time `start_s`; `stream` separates the noise of
    /// recordings made from the same twin.
    pub fn simulate(&self, traj: &Trajectory, start_s: f64, stream: u64) -> Columns {
        let cfg = &self.cfg;
        assert_eq!(traj.axes(), cfg.axes, "trajectory axes must match the twin");
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let (t_s, cmd_um) = traj.sample(cfg.sample_period_s);
        let n = t_s.len();
        let t_abs_s: Vec<f64> = t_s.iter().map(|t| t + start_s).collect();
        let u: Vec<Vec<f64>> = (0..cfg.axes)
            .map(|a| cmd_um[a].iter().map(|&x| cfg.scaled(a, x)).collect())
            .collect();
        let mut dir = vec![vec![1.0; n]; cfg.axes];
        let mut steps = vec![Vec::new(); cfg.axes];
        for a in 0..cfg.axes {
            let mut d = 1.0;
            for k in 0..n {
                if k > 0 {
                    let dq = cmd_um[a][k] - cmd_um[a][k - 1];
                    if dq != 0.0 {
                        d = dq.signum();
                        steps[a].push((k, dq));
                    }
                }
                dir[a][k] = d;
            }
        }
        let spot_c = self
            .room
            .spots(&cfg.room, &cfg.sensors, &t_s, &t_abs_s, start_s);
        let pressure_hpa: Vec<f64> = t_abs_s.iter().map(|&t| self.room.pressure_hpa(t)).collect();

        // Stage position: command + geometry + thermal drift + positioning scatter.
        let mut pos_um = vec![vec![0.0; n]; cfg.axes];
        for a in 0..cfg.axes {
            let mut scatter = cfg.positioning_sigma_nm * 1e-3 * normal(&mut rng);
            for k in 0..n {
                if k > 0 && cmd_um[a][k] != cmd_um[a][k - 1] {
                    scatter = cfg.positioning_sigma_nm * 1e-3 * normal(&mut rng);
                }
                let mut geo = 0.0;
                let mut p = 1.0;
                for c in &cfg.geometric_nm[a] {
                    p *= u[a][k];
                    geo += c * p;
                }
                let thermal: f64 = cfg.thermal_um_per_c[a]
                    .iter()
                    .zip(&spot_c)
                    .map(|(kc, s)| kc * (s[k] - cfg.temp_ref_c))
                    .sum();
                pos_um[a][k] = cmd_um[a][k] + geo * 1e-3 + thermal + scatter;
            }
        }
        let mut ctx = SimContext {
            axes: cfg.axes,
            travel_um: &cfg.travel_um,
            thermal_um_per_c: &cfg.thermal_um_per_c,
            temp_ref_c: cfg.temp_ref_c,
            pressure_mean_hpa: cfg.room.pressure_mean_hpa,
            t_s: t_s.clone(),
            t_abs_s,
            cmd_um: cmd_um.clone(),
            u,
            dir,
            steps,
            spot_c,
            pressure_hpa,
            pos_um: Vec::new(),
            seed: self.seed,
        };
        for e in cfg.effects.iter().filter(|e| !e.is_interferometer()) {
            let add = e.produce(&ctx);
            for a in 0..cfg.axes {
                for k in 0..n {
                    pos_um[a][k] += add[a][k];
                }
            }
        }
        ctx.pos_um = pos_um;
        let mut meas_um = ctx.pos_um.clone();
        for e in cfg.effects.iter().filter(|e| e.is_interferometer()) {
            let add = e.produce(&ctx);
            for a in 0..cfg.axes {
                for k in 0..n {
                    meas_um[a][k] += add[a][k];
                }
            }
        }
        let res_um = cfg.interferometer_resolution_nm * 1e-3;
        for m in meas_um.iter_mut() {
            for v in m.iter_mut() {
                *v = room::quantize(
                    *v + cfg.interferometer_noise_nm * 1e-3 * normal(&mut rng),
                    res_um,
                );
            }
        }

        let mut columns = vec![("t".to_string(), t_s)];
        for (a, c) in cmd_um.into_iter().enumerate() {
            columns.push((format!("cmd_{}", AXIS_NAMES[a]), c));
        }
        for (a, m) in meas_um.into_iter().enumerate() {
            columns.push((format!("meas_{}", AXIS_NAMES[a]), m));
        }
        for (s, spot) in cfg.sensors.iter().zip(&ctx.spot_c) {
            if !s.recorded {
                continue;
            }
            let read = spot
                .iter()
                .map(|&v| room::quantize(v + s.noise_c * normal(&mut rng), s.resolution_c))
                .collect();
            columns.push((format!("temp_{}", s.name), read));
        }
        if cfg.record_pressure {
            let read = ctx
                .pressure_hpa
                .iter()
                .map(|&p| room::quantize(p + cfg.pressure_noise_hpa * normal(&mut rng), 0.01))
                .collect();
            columns.push(("pressure".to_string(), read));
        }
        for c in columns.iter_mut() {
            for v in c.1.iter_mut() {
                *v = tidy(*v);
            }
        }
        Columns { columns }
    }
}
