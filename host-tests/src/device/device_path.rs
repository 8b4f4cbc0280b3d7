//! The device's slow path replayed on the host: which fold the inline compensator had in force
//! when a command passed through it.
//!
//! The firmware's sensor task (`src/app/sensors.rs`) wakes every sample period and reads every
//! sensor (f32 °C); the readings of a fold period are averaged and, once a fold period, the
//! model's [`LagBank`] runs on the averages with the time since the last fold and the model is
//! folded (`Model::fold`) — [`nanocal_compensator::slow_average`]; a `MOV` is corrected with the
//! last fold before it. [`DeviceSlowPath`] runs the same rule, through the same
//! [`SlowAverage`], over a recording's sensor samples: sample ticks every `sample_s` from the
//! first sample, a reading is the latest sample at or before the tick (the sensors are
//! sample-and-hold between the recording's rows), in f32 as the device stores it; a fold at the
//! first tick and then at the first tick a fold period after the last. The fold itself is a pure
//! function of the slow inputs, so it is computed only when a command needs it.

use nanocal_compensator::slow_average::SlowAverage;
use nanocal_model::{FastInputs, LagBank, LagSpec, SlowInputs, MAX_AUX, MAX_TEMPS};

use crate::data::dwell::Dwells;
use crate::data::recording::Recording;

/// The device's default sample period, s: the compensator's `Settings::default()
/// .sample_period_ms` (250 ms; a management setting, 50 ms – 60 s).
pub const DEVICE_SAMPLE_PERIOD_S: f64 = 0.25;

/// The device's default fold period, s: the compensator's `Settings::default().fold_period_ms`
/// (5 s; a management setting, 1–10 s). Paper 001 §VI: thermal terms "can be calculated in a
/// non-real-time process each 5-10 seconds".
pub const DEVICE_FOLD_PERIOD_S: f64 = 5.0;

/// The device's slow-path periods: how often it samples its sensors, how often it folds the
/// averages.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowPeriods {
    /// Sample period, s.
    pub sample_s: f64,
    /// Fold period, s.
    pub fold_s: f64,
}

impl SlowPeriods {
    /// The device's defaults ([`DEVICE_SAMPLE_PERIOD_S`], [`DEVICE_FOLD_PERIOD_S`]).
    pub const DEVICE: SlowPeriods = SlowPeriods {
        sample_s: DEVICE_SAMPLE_PERIOD_S,
        fold_s: DEVICE_FOLD_PERIOD_S,
    };
}

impl Default for SlowPeriods {
    fn default() -> Self {
        SlowPeriods::DEVICE
    }
}

/// A single period: one reading a fold (sample and fold every `period_s`).
impl From<f64> for SlowPeriods {
    fn from(period_s: f64) -> Self {
        SlowPeriods {
            sample_s: period_s,
            fold_s: period_s,
        }
    }
}

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
    /// of [`crate::fit::design`].
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
    periods: SlowPeriods,
    bank: LagBank,
    average: SlowAverage,
    /// Slow inputs of the last fold.
    slow: SlowInputs,
    /// Index of the next sample tick to run.
    next_tick: u64,
    /// Next stream sample not yet read.
    next_sample: usize,
    /// The latest stream sample read (the sensors' value until the next).
    reading: SlowInputs,
    folded: bool,
}

impl<'a> DeviceSlowPath<'a> {
    /// A device running a model's lag filters (`lags`, [`nanocal_model::Model::lags`]) over
    /// `stream` with the slow-path `periods` (the first sample tick at the first sample). A
    /// non-positive or non-finite period is taken as the device's default.
    pub fn new(
        lags: &[LagSpec],
        stream: &'a SensorStream,
        periods: impl Into<SlowPeriods>,
    ) -> Self {
        let mut periods = periods.into();
        let ok = |p: f64| p > 0.0 && p.is_finite();
        if !ok(periods.sample_s) {
            periods.sample_s = DEVICE_SAMPLE_PERIOD_S;
        }
        if !ok(periods.fold_s) {
            periods.fold_s = DEVICE_FOLD_PERIOD_S;
        }
        DeviceSlowPath {
            stream,
            periods,
            bank: LagBank::new(lags),
            average: SlowAverage::new(),
            slow: SlowInputs::default(),
            next_tick: 0,
            next_sample: 0,
            reading: SlowInputs::default(),
            folded: false,
        }
    }

    fn tick_time(&self, k: u64) -> f64 {
        self.stream.t_s.first().copied().unwrap_or(0.0) + k as f64 * self.periods.sample_s
    }

    /// The slow inputs of the last fold at or before `t_s` (those of the first fold if `t_s`
    /// precedes it).
    pub fn slow_at(&mut self, t_s: f64) -> SlowInputs {
        if self.stream.is_empty() {
            return self.slow;
        }
        let fold_ms = (self.periods.fold_s * 1000.0).round() as u32;
        while !self.folded || self.tick_time(self.next_tick) <= t_s + 1e-9 {
            let tick = self.tick_time(self.next_tick);
            while self.next_sample < self.stream.len()
                && self.stream.t_s[self.next_sample] <= tick + 1e-9
            {
                let i = self.next_sample;
                for (n, (_, col)) in self.stream.temps.iter().enumerate().take(MAX_TEMPS) {
                    self.reading.temps_c[n] = col[i];
                }
                for (n, (_, col)) in self.stream.aux.iter().enumerate().take(MAX_AUX) {
                    self.reading.aux[n] = col[i];
                }
                self.next_sample += 1;
            }
            // the device keeps its readings in f32
            for n in 0..self.stream.temps.len().min(MAX_TEMPS) {
                self.average.add_temp(n, self.reading.temps_c[n] as f32);
            }
            for n in 0..self.stream.aux.len().min(MAX_AUX) {
                self.average.add_aux(n, self.reading.aux[n] as f32);
            }
            let now_ms = ((tick - self.tick_time(0)) * 1000.0).round() as u32;
            if self.average.due(now_ms, fold_ms) {
                let slow = &mut self.slow;
                let dt_s = self.average.fold(now_ms, slow, |_| None);
                let temps_c = slow.temps_c;
                self.bank.update(&temps_c, dt_s, &mut slow.lagged_c);
                self.folded = true;
            }
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
    fn the_default_periods_are_the_devices_default_settings() {
        let s = nanocal_interface::settings::Settings::default();
        assert_eq!(
            DEVICE_SAMPLE_PERIOD_S,
            f64::from(s.sample_period_ms) / 1000.0
        );
        assert_eq!(DEVICE_FOLD_PERIOD_S, f64::from(s.fold_period_ms) / 1000.0);
    }

    #[test]
    fn readings_are_sample_and_hold_at_the_last_tick() {
        let m = ModelBuilder::new(1, 1, 1).unwrap().build().unwrap();
        let s = stream();
        // one reading a fold
        let mut dev = DeviceSlowPath::new(m.lags(), &s, 0.25);
        assert_eq!(dev.slow_at(0.0).temps_c[0], 20.0);
        assert_eq!(dev.slow_at(0.9).temps_c[0], 20.0);
        assert_eq!(dev.slow_at(1.1).temps_c[0], 21.0);
        assert_eq!(dev.slow_at(1.1).aux[0], 1001.0);
    }

    #[test]
    fn a_fold_averages_the_readings_of_its_period() {
        let m = ModelBuilder::new(1, 1, 1).unwrap().build().unwrap();
        let s = stream();
        // sampled every 0.5 s, folded every 2 s: the first fold at t = 0 (20), then at 2 s the
        // readings at 0.5, 1, 1.5, 2 s: 20, 21, 21, 22
        let periods = SlowPeriods {
            sample_s: 0.5,
            fold_s: 2.0,
        };
        let mut dev = DeviceSlowPath::new(m.lags(), &s, periods);
        assert_eq!(dev.slow_at(1.9).temps_c[0], 20.0);
        assert_eq!(dev.slow_at(2.0).temps_c[0], 21.0);
        assert_eq!(dev.slow_at(2.0).aux[0], 1001.0);
        // at 4 s: 22, 23, 23, 23
        assert_eq!(dev.slow_at(4.0).temps_c[0], 22.75);
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
