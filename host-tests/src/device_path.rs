//! The device's slow path replayed on the host: which fold the inline compensator had in force
//! when a command passed through it.
//!
//! The firmware's sensor task (`src/app/sensors.rs`) wakes every sample period, reads every
//! sensor (f32 °C), feeds the readings to the model's [`LagBank`] with the elapsed time, and
//! folds the model (`Model::fold`); a `MOV` is corrected with the fold of the last tick before
//! it. [`DeviceSlowPath`] does the same over a recording's sensor samples: ticks every
//! `fold_period_s` from the first sample, a reading is the latest sample at or before the tick
//! (the sensors are sample-and-hold between the recording's rows), rounded to f32 as the device
//! stores it, and the lag filters run at every tick. The fold itself is a pure function of the
//! slow inputs, so it is computed only when a command needs it.

use nanocal_model::{FastInputs, LagBank, LagSpec, SlowInputs, MAX_AUX, MAX_TEMPS};

use crate::dwell::Dwells;
use crate::recording::Recording;

/// The device's default sample-and-fold period, s: the sensor task folds once a sample period
/// (`src/app/sensors.rs`), whose default is the compensator's
/// `Settings::default().sample_period_ms` (250 ms; a management setting, 50 ms – 60 s). Paper
/// 001 §VI: thermal terms "can be calculated in a non-real-time process each 5-10 seconds".
pub const DEVICE_FOLD_PERIOD_S: f64 = 0.25;

/// The slow channels of a recording as the device's sensors see them: temperatures (model Temp
/// index = order here) and auxiliary channels (model Aux index = order here), sampled at `t_s`.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorStream {
    /// Sample times, s (non-decreasing).
    pub t_s: Vec<f64>,
    /// Temperature channels: (name, °C per sample).
    pub temps: Vec<(String, Vec<f64>)>,
    /// Auxiliary channels: (name, value per sample).
    pub aux: Vec<(String, Vec<f64>)>,
}

fn is_slow_channel(name: &str) -> bool {
    name != "t"
        && !["cmd_", "meas_", "dir_"]
            .iter()
            .any(|p| name.starts_with(p))
}

impl SensorStream {
    /// Every `temp_*` column of `rec` (in file order) and every other non-position column as
    /// aux, sampled at the recording's `t` (row index as seconds without one) — the convention
    /// of [`crate::design`].
    pub fn from_recording(rec: &Recording) -> Self {
        let t_s = match rec.time_s() {
            Some(t) => t.to_vec(),
            None => (0..rec.rows()).map(|i| i as f64).collect(),
        };
        let mut temps = Vec::new();
        let mut aux = Vec::new();
        for name in rec.names().iter().filter(|n| is_slow_channel(n)) {
            let col = rec.column(name).expect("listed").to_vec();
            if name.starts_with("temp_") {
                temps.push((name.clone(), col));
            } else {
                aux.push((name.clone(), col));
            }
        }
        SensorStream { t_s, temps, aux }
    }

    /// The dwell-averaged channels of `d`, each held from the start of its dwell (for per-dwell
    /// data that has no raw recording behind it).
    pub fn from_dwells(d: &Dwells) -> Self {
        let mut temps = Vec::new();
        let mut aux = Vec::new();
        for (name, col) in &d.channels {
            if name.starts_with("temp_") {
                temps.push((name.clone(), col.clone()));
            } else {
                aux.push((name.clone(), col.clone()));
            }
        }
        SensorStream {
            t_s: d.t_start_s.clone(),
            temps,
            aux,
        }
    }

    /// The aux channels as the device reads them with a command sent at `t_s` (the latest
    /// sample at or before it, in f32) — a fast input's value for that command. Channels the
    /// recording lacks are not supplied (NaN).
    pub fn fast_at(&self, t_s: f64) -> FastInputs {
        let mut fast = FastInputs::NONE;
        let i = self.t_s.partition_point(|&t| t <= t_s + 1e-9);
        if i > 0 {
            for (n, (_, col)) in self.aux.iter().enumerate().take(MAX_AUX) {
                fast = fast.with_aux(n, col[i - 1] as f32);
            }
        }
        fast
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }
}

/// The device's slow path over a [`SensorStream`] (see the module doc). Queries must come in
/// non-decreasing time.
#[derive(Debug, Clone)]
pub struct DeviceSlowPath<'a> {
    stream: &'a SensorStream,
    period_s: f64,
    bank: LagBank,
    slow: SlowInputs,
    /// Index of the next tick to run.
    next_tick: u64,
    /// Next stream sample not yet read.
    next_sample: usize,
    ticked: bool,
}

impl<'a> DeviceSlowPath<'a> {
    /// A device running a model's lag filters (`lags`, [`nanocal_model::Model::lags`]) over
    /// `stream`, folding every `period_s` seconds (the first tick at the first sample). A
    /// non-positive or non-finite period is taken as [`DEVICE_FOLD_PERIOD_S`].
    pub fn new(lags: &[LagSpec], stream: &'a SensorStream, period_s: f64) -> Self {
        let period_s = if period_s > 0.0 && period_s.is_finite() {
            period_s
        } else {
            DEVICE_FOLD_PERIOD_S
        };
        DeviceSlowPath {
            stream,
            period_s,
            bank: LagBank::new(lags),
            slow: SlowInputs::default(),
            next_tick: 0,
            next_sample: 0,
            ticked: false,
        }
    }

    fn tick_time(&self, k: u64) -> f64 {
        self.stream.t_s.first().copied().unwrap_or(0.0) + k as f64 * self.period_s
    }

    /// The slow inputs of the last fold at or before `t_s` (the readings of the first tick if
    /// `t_s` precedes it).
    pub fn slow_at(&mut self, t_s: f64) -> SlowInputs {
        if self.stream.is_empty() {
            return self.slow;
        }
        while !self.ticked || self.tick_time(self.next_tick) <= t_s + 1e-9 {
            let tick = self.tick_time(self.next_tick);
            while self.next_sample < self.stream.len()
                && self.stream.t_s[self.next_sample] <= tick + 1e-9
            {
                let i = self.next_sample;
                for (n, (_, col)) in self.stream.temps.iter().enumerate().take(MAX_TEMPS) {
                    // the device keeps its readings in f32
                    self.slow.temps_c[n] = f64::from(col[i] as f32);
                }
                for (n, (_, col)) in self.stream.aux.iter().enumerate().take(MAX_AUX) {
                    self.slow.aux[n] = f64::from(col[i] as f32);
                }
                self.next_sample += 1;
            }
            let dt_s = if self.ticked { self.period_s } else { 0.0 };
            let temps_c = self.slow.temps_c;
            self.bank.update(&temps_c, dt_s, &mut self.slow.lagged_c);
            self.ticked = true;
            self.next_tick += 1;
        }
        self.slow
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nanocal_model::{Input, LagFilter, ModelBuilder};

    fn stream() -> SensorStream {
        SensorStream {
            t_s: vec![0.0, 1.0, 2.0, 3.0],
            temps: vec![("temp_a".into(), vec![20.0, 21.0, 22.0, 23.0])],
            aux: vec![("pressure".into(), vec![1000.0, 1001.0, 1002.0, 1003.0])],
        }
    }

    #[test]
    fn the_default_period_is_the_devices_default_setting() {
        let ms = nanocal_interface::settings::Settings::default().sample_period_ms;
        assert_eq!(DEVICE_FOLD_PERIOD_S, f64::from(ms) / 1000.0);
    }

    #[test]
    fn readings_are_sample_and_hold_at_the_last_tick() {
        let m = ModelBuilder::new(1, 1, 1).unwrap().build().unwrap();
        let s = stream();
        let mut dev = DeviceSlowPath::new(m.lags(), &s, 0.25);
        assert_eq!(dev.slow_at(0.0).temps_c[0], 20.0);
        assert_eq!(dev.slow_at(0.9).temps_c[0], 20.0);
        assert_eq!(dev.slow_at(1.1).temps_c[0], 21.0);
        assert_eq!(dev.slow_at(1.1).aux[0], 1001.0);
        // a 5 s fold period sees only the first sample until t = 5 s
        let mut slow = DeviceSlowPath::new(m.lags(), &s, 5.0);
        assert_eq!(slow.slow_at(3.0).temps_c[0], 20.0);
        assert_eq!(slow.slow_at(5.0).temps_c[0], 23.0);
    }

    #[test]
    fn lag_filters_run_at_the_fold_period() {
        let mut b = ModelBuilder::new(1, 1, 0)
            .unwrap()
            .trained_range(Input::Temp(0), 20.0, 23.0);
        b.lag(0, 10.0).unwrap();
        let m = b.build().unwrap();
        let s = stream();
        let mut dev = DeviceSlowPath::new(m.lags(), &s, 0.5);
        let got = dev.slow_at(2.6).lagged_c[0];
        // by hand: ticks at 0, 0.5, …, 2.5 s reading 20, 20, 21, 21, 22, 22
        let mut f = LagFilter::new(10.0);
        let mut want = f.update(20.0, 0.0);
        for x in [20.0, 21.0, 21.0, 22.0, 22.0] {
            want = f.update(x, 0.5);
        }
        assert_eq!(got, want);
    }
}
