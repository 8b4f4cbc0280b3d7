//! What a campaign runs on. A real bench and the virtual one differ only in time and in what
//! can be seen: on a real bench time is the wall clock and the stage link is out of sight; on
//! the virtual bench time is the emulated board's clock, which moves only when the campaign lets
//! it, and the simulated controller shows every command the firmware sent. The campaign knows
//! benches only through [`BenchDriver`]: whoever opens a bench (the CLI, a test, the
//! `stm32-bench` binary) implements it, so the campaign imports no simulator.

use super::reference::{ClockMap, ReferenceError, ReferenceSource, Sample};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Errors of the bench's time and exchanges.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BenchError {
    /// The bench's clock stopped following (an emulated board hung, reset in a loop, or its
    /// emulator went away).
    #[error("bench clock: {0}")]
    Clock(Box<dyn std::error::Error + Send + Sync>),
    /// Anything else the bench reports.
    #[error("bench: {0}")]
    Other(String),
}

/// Time and exchanges of a bench.
pub trait BenchDriver: Send {
    /// Plan time now, s.
    fn now_s(&self) -> f64;
    /// Let time run to plan time `t_s`. Returns false if `stop` was set first (Ctrl-C).
    fn wait_until(&mut self, t_s: f64, stop: &AtomicBool) -> Result<bool, BenchError>;
    /// Run one exchange with the compensator (management or GCS) to its end. On the virtual
    /// bench the board's clock stays put while the board takes the request in and moves on
    /// only while the board waits for its own time (a flash erase), in small steps, so every
    /// byte reaches the board at a known board time.
    fn exchange(&mut self, op: &mut (dyn FnMut() + Send)) -> Result<(), BenchError>;
    /// Commands the stage controller received since the last call (plan time, target per
    /// axis), when the bench can see them.
    fn stage_commands(&mut self) -> Option<Vec<(f64, Vec<f64>)>>;
    /// What running the bench cost so far, where the bench can tell (an emulated board's
    /// CPU time and bus transactions); None on a real bench.
    fn usage(&self) -> Option<BenchUsage> {
        None
    }
}

/// What an emulated bench cost, for the campaign's outcome and the benchmarks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BenchUsage {
    /// CPU time of the emulator's process (user + system), s.
    pub emulator_cpu_s: Option<f64>,
    /// Sensor-bus transactions the bench served.
    pub bus_transactions: Option<u64>,
}

/// A real bench: time is the wall clock.
pub struct WallClock {
    origin: Instant,
    plan_at_origin_s: f64,
}

impl WallClock {
    /// Plan time `plan_now_s` is now.
    pub fn new(plan_now_s: f64) -> Self {
        Self {
            origin: Instant::now(),
            plan_at_origin_s: plan_now_s,
        }
    }
}

impl BenchDriver for WallClock {
    fn now_s(&self) -> f64 {
        self.plan_at_origin_s + self.origin.elapsed().as_secs_f64()
    }

    fn wait_until(&mut self, t_s: f64, stop: &AtomicBool) -> Result<bool, BenchError> {
        loop {
            if stop.load(Ordering::Acquire) {
                return Ok(false);
            }
            let left = t_s - self.now_s();
            if left <= 0.0 {
                return Ok(true);
            }
            std::thread::sleep(Duration::from_secs_f64(left.min(0.1)));
        }
    }

    fn exchange(&mut self, op: &mut (dyn FnMut() + Send)) -> Result<(), BenchError> {
        op();
        Ok(())
    }

    fn stage_commands(&mut self) -> Option<Vec<(f64, Vec<f64>)>> {
        None
    }
}

/// The reference instrument as the campaign reads it: samples in plan time, in order.
pub struct ReferenceReader {
    src: Box<dyn ReferenceSource>,
    map: ClockMap,
    pending: VecDeque<(f64, Vec<f64>)>,
    last_t: Option<f64>,
    period_s: f64,
    /// Longest wall time without a sample before the instrument counts as silent.
    pub silent_after: Duration,
    last_arrival: Instant,
}

impl ReferenceReader {
    /// Read `src`, mapping its clock with `map`.
    pub fn new(src: Box<dyn ReferenceSource>, map: ClockMap) -> Self {
        Self {
            src,
            map,
            pending: VecDeque::new(),
            last_t: None,
            period_s: 1.0,
            silent_after: Duration::from_secs(10),
            last_arrival: Instant::now(),
        }
    }

    fn take(&mut self, samples: Vec<Sample>, now_s: f64) {
        for s in samples {
            let t = self.map.map(s.t_s, now_s);
            if let Some(prev) = self.last_t {
                if t <= prev {
                    continue; // a repeated or out-of-order sample
                }
                // a running estimate of the sample period
                self.period_s = 0.9 * self.period_s + 0.1 * (t - prev);
            }
            self.last_t = Some(t);
            self.pending.push_back((t, s.pos_um));
        }
    }

    /// Wait for the first sample (the instrument answers at all).
    pub fn first(&mut self, now_s: f64, timeout: Duration) -> Result<(), ReferenceError> {
        let t0 = Instant::now();
        while self.last_t.is_none() {
            let got = self.src.poll(Duration::from_millis(50))?;
            if !got.is_empty() {
                self.last_arrival = Instant::now();
            }
            self.take(got, now_s);
            if self.last_t.is_none() && t0.elapsed() > timeout {
                return Err(ReferenceError::Silent {
                    source_name: self.src.name().to_string(),
                    waited: timeout,
                    last: String::new(),
                });
            }
        }
        Ok(())
    }

    /// Every sample before plan time `t_end_s` (the bench's clock is there now): waits until a
    /// sample at or after `t_end_s − 1.5 periods` has arrived, so none is missing.
    pub fn until(
        &mut self,
        t_end_s: f64,
        now_s: f64,
    ) -> Result<Vec<(f64, Vec<f64>)>, ReferenceError> {
        loop {
            let have = self
                .last_t
                .is_some_and(|t| t >= t_end_s - 1.5 * self.period_s);
            if have {
                break;
            }
            let got = self.src.poll(Duration::from_millis(50))?;
            if got.is_empty() {
                if self.last_arrival.elapsed() > self.silent_after {
                    return Err(ReferenceError::Silent {
                        source_name: self.src.name().to_string(),
                        waited: self.silent_after,
                        last: self
                            .last_t
                            .map(|t| format!(", last at t = {t:.1} s"))
                            .unwrap_or_default(),
                    });
                }
            } else {
                self.last_arrival = Instant::now();
            }
            self.take(got, now_s);
        }
        let mut out = Vec::new();
        while self.pending.front().is_some_and(|s| s.0 < t_end_s) {
            out.push(self.pending.pop_front().expect("checked"));
        }
        Ok(out)
    }

    /// Drop the samples before plan time `t_s` (not part of the plan).
    pub fn discard_before(&mut self, t_s: f64) {
        while self.pending.front().is_some_and(|s| s.0 < t_s) {
            self.pending.pop_front();
        }
    }
}
