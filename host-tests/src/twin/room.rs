//! The room a stage stands in: air temperature (daily swing, HVAC cycling, steps, trend),
//! barometric pressure (weather), and the temperature sensors that read it.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::normal;
use crate::effects::lag_series;

/// The air temperature and pressure of a room, as functions of absolute time.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RoomConfig {
    /// Mean air temperature, °C.
    pub mean_c: f64,
    /// Half peak-to-peak of the daily swing, °C.
    pub daily_amplitude_c: f64,
    /// Half peak-to-peak of the HVAC on/off cycling (triangle wave), °C.
    pub hvac_amplitude_c: f64,
    /// Period of the HVAC cycling, s.
    pub hvac_period_s: f64,
    /// Expected number of set-point steps (doors, people, machines) per day.
    pub steps_per_day: f64,
    /// Standard deviation of one step, °C.
    pub step_sigma_c: f64,
    /// Slow linear trend, °C per day (makes a later recording leave the training range).
    pub trend_c_per_day: f64,
    /// Mean barometric pressure, hPa.
    pub pressure_mean_hpa: f64,
    /// Amplitude of weather pressure changes, hPa.
    pub pressure_amplitude_hpa: f64,
    /// Planned changes of the room temperature (e.g. paper 000 Fig. 13: 1.3 °C over the last
    /// two days of validation).
    #[serde(default)]
    pub ramps: Vec<Ramp>,
}

/// A linear change of the room temperature by `delta_c` from `start_s` over `duration_s`
/// (absolute time), held afterwards.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Ramp {
    /// Start, s (absolute time).
    pub start_s: f64,
    /// Duration, s (0: a step).
    pub duration_s: f64,
    /// Change, °C.
    pub delta_c: f64,
}

impl Ramp {
    /// The change at absolute time `t_s`, °C.
    pub fn at(&self, t_s: f64) -> f64 {
        if t_s <= self.start_s {
            0.0
        } else if self.duration_s <= 0.0 || t_s >= self.start_s + self.duration_s {
            self.delta_c
        } else {
            self.delta_c * (t_s - self.start_s) / self.duration_s
        }
    }
}

impl Default for RoomConfig {
    fn default() -> Self {
        Self {
            mean_c: 20.0,
            daily_amplitude_c: 0.12,
            hvac_amplitude_c: 0.02,
            hvac_period_s: 1500.0,
            steps_per_day: 4.0,
            step_sigma_c: 0.04,
            trend_c_per_day: 0.0,
            pressure_mean_hpa: 1013.25,
            pressure_amplitude_hpa: 6.0,
            ramps: Vec::new(),
        }
    }
}

/// One temperature sensor: where it sits (how fast it follows the room air) and how it reads.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SensorConfig {
    /// Column name without the `temp_` prefix.
    pub name: String,
    /// Constant offset of this spot from the room mean, °C.
    pub offset_c: f64,
    /// First-order time constant with which this spot follows the room air, s.
    pub tau_s: f64,
    /// Gain with which this spot sees the room's variation (1 = fully).
    pub gain: f64,
    /// White reading noise, °C (1 σ).
    pub noise_c: f64,
    /// Reading resolution, °C (0 = none).
    pub resolution_c: f64,
    /// Whether a sensor reads this spot (a `temp_` column); an unsensed spot still drives the
    /// stage through its thermal coefficients — a part of the structure no sensor is on.
    #[serde(default = "recorded_by_default")]
    pub recorded: bool,
}

fn recorded_by_default() -> bool {
    true
}

impl SensorConfig {
    /// A sensor with typical noise (2 mK) and resolution (1 mK).
    pub fn new(name: &str, offset_c: f64, tau_s: f64, gain: f64) -> Self {
        Self {
            name: name.into(),
            offset_c,
            tau_s,
            gain,
            noise_c: 0.002,
            resolution_c: 0.001,
            recorded: true,
        }
    }

    /// A spot with the same thermal behaviour that no sensor reads.
    pub fn unsensed(name: &str, offset_c: f64, tau_s: f64, gain: f64) -> Self {
        Self {
            recorded: false,
            ..Self::new(name, offset_c, tau_s, gain)
        }
    }
}

/// A realised room: random events drawn once from a seed, evaluated at any absolute time.
#[derive(Clone, Debug)]
pub struct Room {
    cfg: RoomConfig,
    daily_phase: f64,
    hvac_phase: f64,
    steps: Vec<(f64, f64)>,
    weather: Vec<(f64, f64, f64)>,
}

impl Room {
    /// Draw the random parts (phases, steps, weather) for `span_s` seconds of absolute time.
    pub fn new(cfg: &RoomConfig, span_s: f64, rng: &mut ChaCha8Rng) -> Self {
        let daily_phase = rng.gen_range(0.0..std::f64::consts::TAU);
        let hvac_phase = rng.gen_range(0.0..1.0);
        let n_steps = (cfg.steps_per_day * span_s / 86_400.0).round() as usize;
        let steps = (0..n_steps)
            .map(|_| (rng.gen_range(0.0..span_s), cfg.step_sigma_c * normal(rng)))
            .collect();
        let weather = (0..3)
            .map(|k| {
                let period_s = 86_400.0 * (1.5 + 2.0 * k as f64) * rng.gen_range(0.8..1.2);
                (
                    period_s,
                    rng.gen_range(0.0..std::f64::consts::TAU),
                    cfg.pressure_amplitude_hpa / (k + 1) as f64,
                )
            })
            .collect();
        Self {
            cfg: cfg.clone(),
            daily_phase,
            hvac_phase,
            steps,
            weather,
        }
    }

    /// Air temperature at absolute time `t_s`, °C.
    pub fn air_c(&self, t_s: f64) -> f64 {
        let c = &self.cfg;
        let daily =
            c.daily_amplitude_c * (std::f64::consts::TAU * t_s / 86_400.0 + self.daily_phase).sin();
        let ph = (t_s / c.hvac_period_s + self.hvac_phase).fract();
        let tri = if ph < 0.5 {
            4.0 * ph - 1.0
        } else {
            3.0 - 4.0 * ph
        };
        let hvac = c.hvac_amplitude_c * tri;
        let steps: f64 = self.steps.iter().filter(|s| s.0 <= t_s).map(|s| s.1).sum();
        let ramps: f64 = c.ramps.iter().map(|r| r.at(t_s)).sum();
        c.mean_c + daily + hvac + steps + ramps + c.trend_c_per_day * t_s / 86_400.0
    }

    /// True temperature of each spot at the samples `t_s` (absolute times `t_abs_s`, starting at
    /// `start_s`), °C: each follows the room air through its own first-order lag, settled over
    /// the 5 τ before the start, seen with its gain around the room mean plus its offset.
    pub fn spots(
        &self,
        cfg: &RoomConfig,
        sensors: &[SensorConfig],
        t_s: &[f64],
        t_abs_s: &[f64],
        start_s: f64,
    ) -> Vec<Vec<f64>> {
        let air: Vec<f64> = t_abs_s.iter().map(|&t| self.air_c(t)).collect();
        let warm_start = |s: &SensorConfig| {
            // settle the lag over the preceding 5 τ (coarse steps) so a recording starts settled
            let t0 = start_s - 5.0 * s.tau_s;
            let m = 200;
            let mut y = self.air_c(t0);
            for i in 1..=m {
                let t = t0 + (start_s - t0) * i as f64 / m as f64;
                let a = 1.0 - (-(5.0 * s.tau_s / m as f64) / s.tau_s).exp();
                y += a * (self.air_c(t) - y);
            }
            y
        };
        sensors
            .iter()
            .map(|s| {
                let y0 = warm_start(s);
                let lagged = lag_series(t_s, &air, s.tau_s, Some(y0));
                lagged
                    .iter()
                    .map(|&v| cfg.mean_c + s.offset_c + s.gain * (v - cfg.mean_c))
                    .collect()
            })
            .collect()
    }

    /// Barometric pressure at absolute time `t_s`, hPa.
    pub fn pressure_hpa(&self, t_s: f64) -> f64 {
        let w: f64 = self
            .weather
            .iter()
            .map(|(p, ph, a)| a * (std::f64::consts::TAU * t_s / p + ph).sin())
            .sum();
        self.cfg.pressure_mean_hpa + w
    }
}

/// Round `x` to a multiple of `resolution` (no rounding when `resolution` is 0).
pub fn quantize(x: f64, resolution: f64) -> f64 {
    if resolution > 0.0 {
        (x / resolution).round() * resolution
    } else {
        x
    }
}
