//! What stands behind the simulated controller: the stage (where an axis is, given what the
//! controller commanded and when) and the clock it runs on. Both are traits so that the digital
//! twin can play the stage and a test can drive time by hand.

use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Time as the controller sees it, seconds since some start.
pub trait Clock: Send + Sync {
    /// Now, s.
    fn now_s(&self) -> f64;
}

/// Wall-clock time since creation.
#[derive(Debug, Clone, Copy)]
pub struct SystemClock {
    start: Instant,
}

impl SystemClock {
    /// A clock starting now.
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
        }
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for SystemClock {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }
}

/// A clock that moves only when told (deterministic tests).
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    t_s: Arc<Mutex<f64>>,
}

impl ManualClock {
    /// A clock at 0 s.
    pub fn new() -> Self {
        Self::default()
    }
    /// Move time forward by `dt_s`.
    pub fn advance(&self, dt_s: f64) {
        *self.t_s.lock().expect("clock lock") += dt_s;
    }
    /// Set the time.
    pub fn set(&self, t_s: f64) {
        *self.t_s.lock().expect("clock lock") = t_s;
    }
}

impl Clock for ManualClock {
    fn now_s(&self) -> f64 {
        *self.t_s.lock().expect("clock lock")
    }
}

/// The physical stage behind the controller: where each axis is, given the controller's drive
/// commands and the time. Positions are physical (the controller adds its own coordinate offset,
/// which referencing and `POS`/`DFH` change without moving anything).
pub trait Plant: Send {
    /// From time `t_s` on, drive `axis` towards physical position `target` at `velocity`
    /// (units/s, > 0) and hold it there (closed loop).
    fn drive(&mut self, axis: usize, target: f64, velocity: f64, t_s: f64);
    /// Stop `axis` where it is at `t_s` and hold it there.
    fn stop(&mut self, axis: usize, t_s: f64);
    /// Physical position of `axis` at `t_s`.
    fn position(&self, axis: usize, t_s: f64) -> f64;
    /// True when `axis` has come to rest at its last drive target by `t_s`.
    fn settled(&self, axis: usize, t_s: f64) -> bool;
}

/// One axis of [`IdealPlant`]: a straight run at constant velocity from `from` at `t0` to `to`.
#[derive(Debug, Clone, Copy)]
struct Run {
    from: f64,
    to: f64,
    t0: f64,
    t1: f64,
}

impl Run {
    fn at(&self, t: f64) -> f64 {
        if t >= self.t1 || self.t1 <= self.t0 {
            self.to
        } else if t <= self.t0 {
            self.from
        } else {
            self.from + (self.to - self.from) * (t - self.t0) / (self.t1 - self.t0)
        }
    }
}

/// The default plant: every axis moves in a straight line at the commanded velocity and stops
/// exactly on target — no dynamics, no errors. (The digital twin provides the physics.)
#[derive(Debug, Clone)]
pub struct IdealPlant {
    runs: Vec<Run>,
}

impl IdealPlant {
    /// `axes` axes at physical positions `start`.
    pub fn new(start: &[f64]) -> Self {
        Self {
            runs: start
                .iter()
                .map(|&p| Run {
                    from: p,
                    to: p,
                    t0: 0.0,
                    t1: 0.0,
                })
                .collect(),
        }
    }
}

impl Plant for IdealPlant {
    fn drive(&mut self, axis: usize, target: f64, velocity: f64, t_s: f64) {
        let from = self.position(axis, t_s);
        let duration = (target - from).abs() / velocity.max(1e-12);
        self.runs[axis] = Run {
            from,
            to: target,
            t0: t_s,
            t1: t_s + duration,
        };
    }
    fn stop(&mut self, axis: usize, t_s: f64) {
        let p = self.position(axis, t_s);
        self.runs[axis] = Run {
            from: p,
            to: p,
            t0: t_s,
            t1: t_s,
        };
    }
    fn position(&self, axis: usize, t_s: f64) -> f64 {
        self.runs[axis].at(t_s)
    }
    fn settled(&self, axis: usize, t_s: f64) -> bool {
        t_s >= self.runs[axis].t1
    }
}
