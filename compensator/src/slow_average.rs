//! The slow path's clock: every reading a sample cycle takes is averaged over the fold period,
//! and the model is folded once a fold period with the averages.
//!
//! Paper 001 §VI: "Thermal variations are very slow, so they can be calculated in a
//! non-real-time process each 5-10 seconds." The sensors sample faster than that (every sample
//! period, 250 ms by default): folding each single reading puts the amplifier's noise (≈ 16 mK
//! a type K reading on a MAX31856) times the model's thermal coefficients (a few µm/°C) on every
//! command — tens of nm of jitter through any unlagged thermal term. Averaging the readings of a
//! fold period divides that by √(readings); the fold period (1–10 s,
//! `nanocal_interface::settings::Settings::fold_period_ms`) stays far below the thermal time constants.
//!
//! The rule, which the firmware's sensor task (`src/app/sensors.rs`) and the host's replay of it
//! (`nanocal::device::device_path::DeviceSlowPath`) both run through this type:
//! - every sample cycle adds each channel's good reading of that cycle ([`SlowAverage::add`]);
//! - a fold is due at the first cycle, and then at the first cycle at least one fold period
//!   after the last fold ([`SlowAverage::due`]);
//! - at a fold ([`SlowAverage::fold`]) each channel's input is the mean of its readings since
//!   the last fold — summed and divided in f32, as the device keeps its readings; a channel
//!   without a reading in the period takes what the caller holds for it (the fault policy's
//!   held value); the time since the last fold is returned for the lag filters, which run once
//!   per fold on the averages.

use nanocal_model::{SlowInputs, MAX_AUX, MAX_TEMPS};

pub use nanocal_interface::settings::{MAX_FOLD_PERIOD_MS, MIN_FOLD_PERIOD_MS};

/// Channels of a fold: the temperatures, then the aux inputs.
const CHANNELS: usize = MAX_TEMPS + MAX_AUX;

/// The averages of one fold period and when the last fold was (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowAverage {
    /// Sums of the readings (f32, as the device keeps them), temperatures then aux inputs.
    sum: [f32; CHANNELS],
    count: [u16; CHANNELS],
    last_fold_ms: Option<u32>,
}

impl Default for SlowAverage {
    fn default() -> Self {
        Self::new()
    }
}

impl SlowAverage {
    /// No reading yet, no fold yet.
    pub const fn new() -> Self {
        SlowAverage {
            sum: [0.0; CHANNELS],
            count: [0; CHANNELS],
            last_fold_ms: None,
        }
    }

    fn add(&mut self, i: usize, v: f32) {
        if i < CHANNELS && v.is_finite() {
            self.sum[i] += v;
            self.count[i] = self.count[i].saturating_add(1);
        }
    }

    /// A good reading of temperature channel `i` this cycle, °C (ignored when not finite).
    pub fn add_temp(&mut self, i: usize, v_c: f32) {
        if i < MAX_TEMPS {
            self.add(i, v_c);
        }
    }

    /// A good reading of aux input `i` this cycle, in its unit.
    pub fn add_aux(&mut self, i: usize, v: f32) {
        if i < MAX_AUX {
            self.add(MAX_TEMPS + i, v);
        }
    }

    /// Whether a fold is due at `now_ms` with a fold period of `period_ms`: at the first cycle,
    /// then once `period_ms` have passed since the last fold.
    pub fn due(&self, now_ms: u32, period_ms: u32) -> bool {
        self.last_fold_ms
            .is_none_or(|t| now_ms.wrapping_sub(t) >= period_ms)
    }

    /// Fold now: the averages of the period (f32: the sum of the f32 readings over their
    /// count) into `slow`'s temperatures and aux inputs; a channel without a reading takes
    /// `held(channel)` (temperatures `0..MAX_TEMPS`, then aux inputs), or keeps its value when
    /// that is `None`. Returns the time since the last fold, s (0 at the first; computed in
    /// f32).
    pub fn fold(
        &mut self,
        now_ms: u32,
        slow: &mut SlowInputs,
        held: impl Fn(usize) -> Option<f32>,
    ) -> f64 {
        for i in 0..CHANNELS {
            let v = if self.count[i] > 0 {
                Some(self.sum[i] / f32::from(self.count[i]))
            } else {
                held(i)
            };
            if let Some(v) = v {
                let slot = match i.checked_sub(MAX_TEMPS) {
                    None => &mut slow.temps_c[i],
                    Some(a) => &mut slow.aux[a],
                };
                *slot = f64::from(v);
            }
        }
        self.sum = [0.0; CHANNELS];
        self.count = [0; CHANNELS];
        let dt_ms = self.last_fold_ms.map_or(0, |t| now_ms.wrapping_sub(t));
        self.last_fold_ms = Some(now_ms);
        // u32 → f32 is one instruction on the Cortex-M4F (exact below 2^24 ms, 4.6 h)
        f64::from(dt_ms as f32 * 1e-3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_average_the_readings_of_the_period() {
        let mut a = SlowAverage::new();
        let mut s = SlowInputs::default();
        let none = |_: usize| None;
        // the first cycle folds at once
        a.add_temp(0, 20.0);
        assert!(a.due(0, 5000));
        assert_eq!(a.fold(0, &mut s, none), 0.0);
        assert_eq!(s.temps_c[0], 20.0);
        // four cycles of 1 s: not due until 5 s have passed
        for (k, v) in [21.0f32, 22.0, 23.0, 24.0, 25.0].iter().enumerate() {
            let now = 1000 * (k as u32 + 1);
            a.add_temp(0, *v);
            a.add_aux(1, 1000.0 + *v);
            if now < 5000 {
                assert!(!a.due(now, 5000));
            }
        }
        assert!(a.due(5000, 5000));
        let held = |i: usize| (i == 1).then_some(7.5);
        assert_eq!(a.fold(5000, &mut s, held), f64::from(5.0f32));
        assert_eq!(s.temps_c[0], 23.0, "the mean of 21 … 25");
        assert_eq!(s.temps_c[1], 7.5, "no reading: the held value");
        assert_eq!(s.aux[1], 1023.0);
        // nothing read and nothing held: unchanged
        assert_eq!(a.fold(6000, &mut s, none), f64::from(1.0f32));
        assert_eq!((s.temps_c[0], s.aux[1]), (23.0, 1023.0));
    }

    #[test]
    fn the_mean_is_the_f32_sum_over_the_count() {
        let mut a = SlowAverage::new();
        let mut s = SlowInputs::default();
        for v in [22.1f32, 22.2, 22.3] {
            a.add_temp(0, v);
        }
        a.fold(0, &mut s, |_| None);
        let want = (22.1f32 + 22.2f32 + 22.3f32) / 3.0;
        assert_eq!(s.temps_c[0], f64::from(want));
    }
}
