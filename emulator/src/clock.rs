//! The board's clock: virtual, never the wall clock.
//!
//! Board time advances by the instructions the core runs (one per HCLK cycle) and, while the
//! core sleeps (WFI/WFE), jumps to the next event a peripheral or SysTick has scheduled. It
//! never passes the **horizon** that whoever drives the board sets: there the board pauses
//! (after the slice it is in, so where the horizon falls never changes what the firmware
//! executes) and waits for the horizon to move. Input from outside (a client's bytes on a USB
//! port socket) is taken in when the board resumes, so bytes written while the board is paused
//! arrive at the same board time on an idle machine and on a loaded one — only later in wall
//! time.
//!
//! Two ways to drive it:
//! - **await** (the tests): a caller raises the horizon step by step and looks at the board
//!   each time it pauses (`Stm32::run_until` in the test rig, or a client stream that advances
//!   the board while it waits for a reply). The board also pauses by itself right after it
//!   hands bytes to a USB client ([`Clock::pause_on_output`]), so a reply is seen at the board
//!   time it was sent.
//! - **paced** ([`Clock::pace`]): a thread moves the horizon with the wall clock × a scale, for
//!   clients the rig cannot step (an external process such as PIPython or the CLI).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// Picoseconds per second.
pub const PS: u64 = 1_000_000_000_000;

/// Where the board is, as of its last pause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pause {
    /// Board time, ps.
    pub now_ps: u64,
    /// When the board would wake by itself next (a timer or peripheral event), ps.
    pub next_event_ps: Option<u64>,
    /// The horizon generation the board paused at (see [`Clock::set_horizon`]).
    pub generation: u64,
}

#[derive(Default)]
struct State {
    /// The board is waiting at the horizon (or has stopped): `pause` says where.
    paused: bool,
    stopped: bool,
    pause: Pause,
    generation: u64,
}

/// The clock shared by the board (which runs on it) and whoever drives it.
pub struct Clock {
    horizon_ps: AtomicU64,
    state: Mutex<State>,
    /// Wakes the board (the horizon moved, or stop).
    board_cv: Condvar,
    /// Wakes drivers (the board paused or stopped).
    driver_cv: Condvar,
    /// The board lowers the horizon to "now" after it handed bytes to a USB client.
    pause_on_output: AtomicBool,
    /// A pacing thread is running.
    pacing: AtomicBool,
    pacer: Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Default for Clock {
    fn default() -> Self {
        Self {
            horizon_ps: AtomicU64::new(0),
            state: Mutex::new(State::default()),
            board_cv: Condvar::new(),
            driver_cv: Condvar::new(),
            pause_on_output: AtomicBool::new(true),
            pacing: AtomicBool::new(false),
            pacer: Mutex::new(None),
        }
    }
}

/// A wall-clock guard for drivers: a board that does not pause within this much wall time is
/// hung (a bug of the emulator, never a result of a test).
pub const HANG_GUARD: Duration = Duration::from_secs(600);

impl Clock {
    /// The horizon, ps.
    pub fn horizon_ps(&self) -> u64 {
        self.horizon_ps.load(Ordering::Acquire)
    }

    /// Move the horizon to `ps` (it may move back: the board then pauses where it is) and wake
    /// the board; returns the new generation, which the board's next pause reports.
    pub fn set_horizon(&self, ps: u64) -> u64 {
        let mut s = self.state.lock().unwrap();
        s.generation += 1;
        self.horizon_ps.store(ps, Ordering::Release);
        self.board_cv.notify_all();
        s.generation
    }

    /// Board side: lower the horizon to `now_ps` (the board pauses at its next check).
    pub fn hold_at(&self, now_ps: u64) {
        if self.pause_on_output.load(Ordering::Relaxed) && !self.pacing.load(Ordering::Relaxed) {
            self.horizon_ps.fetch_min(now_ps, Ordering::AcqRel);
        }
    }

    /// Whether the board pauses by itself after it hands bytes to a USB client.
    pub fn pause_on_output(&self, on: bool) {
        self.pause_on_output.store(on, Ordering::Relaxed);
    }

    /// Board side: pause at `now_ps` until the horizon is beyond it (true) or the board is
    /// stopped (false).
    pub fn pause(&self, now_ps: u64, next_event_ps: Option<u64>) -> bool {
        let mut s = self.state.lock().unwrap();
        s.pause = Pause {
            now_ps,
            next_event_ps,
            generation: s.generation,
        };
        s.paused = true;
        self.driver_cv.notify_all();
        while !s.stopped && self.horizon_ps.load(Ordering::Acquire) <= now_ps {
            s = self.board_cv.wait(s).unwrap();
            s.pause.generation = s.generation;
            self.driver_cv.notify_all();
        }
        s.paused = false;
        !s.stopped
    }

    /// The board stopped for good (halt, or asked to): drivers stop waiting.
    pub fn stop(&self, now_ps: u64) {
        let mut s = self.state.lock().unwrap();
        s.stopped = true;
        s.paused = true;
        s.pause.now_ps = s.pause.now_ps.max(now_ps);
        self.board_cv.notify_all();
        self.driver_cv.notify_all();
    }

    /// True once the board has stopped.
    pub fn stopped(&self) -> bool {
        self.state.lock().unwrap().stopped
    }

    /// Driver side: wait until the board pauses at generation `generation` or later (or stops);
    /// where it is. Panics after [`HANG_GUARD`] of wall time (an emulator bug).
    pub fn wait_paused(&self, generation: u64) -> Pause {
        let deadline = Instant::now() + HANG_GUARD;
        let mut s = self.state.lock().unwrap();
        while !(s.stopped || (s.paused && s.pause.generation >= generation)) {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "the emulated board did not pause within {HANG_GUARD:?} of wall time (emulator hung)");
            s = self.driver_cv.wait_timeout(s, left).unwrap().0;
        }
        s.pause
    }

    /// Driver side: let the board run to `ps` and wait until it pauses (at `ps`, or earlier
    /// after handing a USB client bytes, or because it stopped).
    pub fn run_to(&self, ps: u64) -> Pause {
        let g = self.set_horizon(ps);
        self.wait_paused(g)
    }

    /// Where the board last paused (without waiting).
    pub fn last_pause(&self) -> Pause {
        self.state.lock().unwrap().pause
    }

    /// Move the horizon with the wall clock × `scale` from where the board is, until
    /// [`Self::stop_pacing`]: for clients the rig cannot step (external processes). Board time
    /// then depends on the machine's speed — the only mode where it does.
    pub fn pace(self: &Arc<Self>, scale: f64) {
        if self.pacing.swap(true, Ordering::AcqRel) {
            return;
        }
        let clock = self.clone();
        *self.pacer.lock().unwrap() = Some(std::thread::spawn(move || {
            let t0 = Instant::now();
            let base = clock.horizon_ps().max(clock.last_pause().now_ps);
            while clock.pacing.load(Ordering::Acquire) && !clock.stopped() {
                let t = base + (t0.elapsed().as_secs_f64() * scale * PS as f64) as u64;
                clock.set_horizon(t);
                std::thread::sleep(Duration::from_millis(1));
            }
        }));
    }

    /// Stop the pacing thread and wait until the board pauses where the horizon was left.
    pub fn stop_pacing(&self) -> Pause {
        self.pacing.store(false, Ordering::Release);
        if let Some(t) = self.pacer.lock().unwrap().take() {
            let _ = t.join();
        }
        let h = self.horizon_ps();
        self.run_to(h)
    }
}
