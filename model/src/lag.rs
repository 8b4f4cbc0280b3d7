//! First-order lag filters: the structure follows its sensors with a time constant τ.

use crate::limits::{MAX_LAGS, MAX_TEMPS};

/// A declared lag filter: which temperature sensor it follows, and its time constant.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LagSpec {
    /// Index of the temperature sensor filtered.
    pub sensor: u8,
    /// Time constant τ, s (> 0).
    pub tau_s: f64,
}

/// First-order lag `dy/dt = (x − y)/τ`, discretised exactly for a held input over each step.
/// The first sample initialises the state (no start-up transient) unless a start was given.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LagFilter {
    tau_s: f64,
    state: f64,
    primed: bool,
    /// Step of the last update and its smoothing factor: sampling is usually regular, so the
    /// exponential is computed once per step size, not once per sample.
    last_dt_s: f64,
    alpha: f64,
}

impl LagFilter {
    /// A filter with time constant `tau_s` (τ ≤ 0 passes the input through).
    pub fn new(tau_s: f64) -> Self {
        LagFilter {
            tau_s,
            state: 0.0,
            primed: false,
            last_dt_s: f64::NAN,
            alpha: 1.0,
        }
    }

    /// A filter whose output starts at `y0` instead of at the first sample.
    pub fn starting_at(tau_s: f64, y0: f64) -> Self {
        LagFilter {
            state: y0,
            primed: true,
            ..LagFilter::new(tau_s)
        }
    }

    /// Feeds sample `x` taken `dt_s` after the previous one; returns the filtered value.
    pub fn update(&mut self, x: f64, dt_s: f64) -> f64 {
        if !self.primed || self.tau_s <= 0.0 || !dt_s.is_finite() {
            self.state = x;
            self.primed = true;
        } else if dt_s > 0.0 {
            if dt_s != self.last_dt_s {
                self.alpha = 1.0 - libm::exp(-dt_s / self.tau_s);
                self.last_dt_s = dt_s;
            }
            self.state += self.alpha * (x - self.state);
        }
        self.state
    }

    /// Current output.
    pub fn value(&self) -> f64 {
        self.state
    }
}

/// The lag filters a model declares, run together over a stream of temperature samples.
#[derive(Clone, Copy, Debug)]
pub struct LagBank {
    /// The sensor each filter follows (its τ is the filter's own).
    sensors: [u8; MAX_LAGS],
    filters: [LagFilter; MAX_LAGS],
    len: usize,
}

impl LagBank {
    /// A bank for the given specs (at most [`MAX_LAGS`] are used).
    pub fn new(specs: &[LagSpec]) -> Self {
        let mut bank = LagBank {
            sensors: [0; MAX_LAGS],
            filters: [LagFilter::new(0.0); MAX_LAGS],
            len: specs.len().min(MAX_LAGS),
        };
        for (k, spec) in specs.iter().take(MAX_LAGS).enumerate() {
            bank.sensors[k] = spec.sensor;
            bank.filters[k] = LagFilter::new(spec.tau_s);
        }
        bank
    }

    /// Feeds one set of temperatures taken `dt_s` after the previous; writes each filter's output
    /// into `lagged_c` by lag index.
    pub fn update(
        &mut self,
        temps_c: &[f64; MAX_TEMPS],
        dt_s: f64,
        lagged_c: &mut [f64; MAX_LAGS],
    ) {
        for k in 0..self.len {
            let sensor = (self.sensors[k] as usize).min(MAX_TEMPS - 1);
            lagged_c[k] = self.filters[k].update(temps_c[sensor], dt_s);
        }
    }
}
