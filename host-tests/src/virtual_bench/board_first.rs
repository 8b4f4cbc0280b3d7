//! The bench's waits for the board give way to QEMU: a thread that polls the shared page or a
//! ring for the board runs at the scheduler's idle priority (Linux `SCHED_IDLE`) while it
//! polls, so that QEMU's vCPU and I/O threads — whose work is what it waits for — take a core
//! the moment they are runnable.
//!
//! **Why.** On the 2-core machine, `perf sched timehist` of the shortened campaign showed
//! QEMU's vCPU runnable but not running for 3.3 s in all (up to 2 ms at a time), and its I/O
//! thread for 3.5 s, of a 17 s run: an exchange's writer polled its ring for 2 ms while the
//! campaign's thread polled the page, and each spinner held a core the board needed to
//! answer it. The board's time and the result do not depend on this (the clock is lockstep);
//! only the wall time does.
//!
//! **Other work on the machine.** A thread at idle priority gets almost nothing while the
//! cores are busy with other work (another build, the test suite), and the board would then
//! wait for its bus replies (measured with two CPU hogs beside the shortened campaign: 35 %
//! slower than not lowering, with only the starvation check below). So the pollers lower
//! themselves only while the rest of the machine leaves a core free: every
//! [`LOAD_LOOK`] one of them reads `/proc/stat` and the CPU time of this process and of the
//! boards' QEMU processes ([`board_started`]), and what the others used decides
//! ([`MAX_OTHER_CORES`]); a lowered poller goes back at its next look once they use more. And
//! a poller that finds it was off its core for longer than [`STARVED`] between two looks goes
//! back at once, and no poller lowers itself for [`STARVED_BACKOFF`] after that.
//! `NANOCAL_BENCH_BOARD_FIRST=0` turns the lowering off.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// A gap this long between two looks of a lowered poller: other work took its core. (QEMU's
/// own threads take it for a few ms at most: 3 ms here went back needlessly, and the bench
/// lost most of the gain.)
pub const STARVED: Duration = Duration::from_millis(50);
/// How often the machine's other load is measured.
pub const LOAD_LOOK: Duration = Duration::from_millis(500);
/// The pollers lower themselves only while the other processes of the machine used less than
/// this many cores over the last [`LOAD_LOOK`].
pub const MAX_OTHER_CORES: f64 = 0.5;
/// After a starved poller, no poller lowers itself for this long.
pub const STARVED_BACKOFF: Duration = Duration::from_secs(5);

/// When a poller was last starved, shared by every poller of the process.
pub struct Starvation {
    epoch: Instant,
    /// ns since `epoch` (0: never).
    last_ns: AtomicU64,
}

impl Starvation {
    fn new() -> Self {
        Self {
            epoch: Instant::now(),
            last_ns: AtomicU64::new(0),
        }
    }

    fn since_epoch_ns(&self, t: Instant) -> u64 {
        t.saturating_duration_since(self.epoch).as_nanos() as u64
    }

    fn recent(&self, now: Instant) -> bool {
        let at = self.last_ns.load(Ordering::Relaxed);
        at != 0 && self.since_epoch_ns(now).saturating_sub(at) < STARVED_BACKOFF.as_nanos() as u64
    }

    fn record(&self, now: Instant) {
        self.last_ns
            .store(self.since_epoch_ns(now).max(1), Ordering::Relaxed);
    }
}

/// CPU time, in clock ticks, from a `/proc/stat` text: (busy, all) of the first (`cpu`) line
/// — busy is all but idle and iowait.
pub fn machine_ticks(proc_stat: &str) -> Option<(u64, u64)> {
    let line = proc_stat.lines().next()?;
    let mut f = line.split_whitespace();
    if f.next()? != "cpu" {
        return None;
    }
    let v: Vec<u64> = f.map(|x| x.parse().ok()).collect::<Option<_>>()?;
    if v.len() < 5 {
        return None;
    }
    let all: u64 = v.iter().take(8).sum();
    Some((all - v[3] - v[4], all))
}

/// utime + stime, in clock ticks, from a `/proc/<pid>/stat` text (fields 14 and 15; the
/// command name, field 2, may hold spaces and parentheses: fields are counted after its last
/// `)`).
pub fn process_ticks(pid_stat: &str) -> Option<u64> {
    let rest = &pid_stat[pid_stat.rfind(')')? + 1..];
    let mut f = rest.split_whitespace().skip(11);
    Some(f.next()?.parse::<u64>().ok()? + f.next()?.parse::<u64>().ok()?)
}

/// Cores the other processes kept busy between two samples: the machine's busy ticks less
/// this process's and its boards', over the elapsed ticks per core.
pub fn other_cores(before: Sample, after: Sample, cores: usize) -> f64 {
    let elapsed = after.all.saturating_sub(before.all) as f64 / cores.max(1) as f64;
    if elapsed <= 0.0 {
        return 0.0;
    }
    let busy = after.busy.saturating_sub(before.busy) as f64;
    let ours = after.ours.saturating_sub(before.ours) as f64;
    ((busy - ours) / elapsed).max(0.0)
}

/// One look at the machine's CPU time (clock ticks).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    /// Busy ticks of all cores.
    pub busy: u64,
    /// All ticks of all cores.
    pub all: u64,
    /// This process's and its boards' ticks.
    pub ours: u64,
}

/// The QEMU processes of this process's boards.
fn boards() -> &'static Mutex<Vec<u32>> {
    static B: OnceLock<Mutex<Vec<u32>>> = OnceLock::new();
    B.get_or_init(|| Mutex::new(Vec::new()))
}

/// A board's QEMU process started: its CPU time is the bench's, not other work.
pub fn board_started(pid: u32) {
    boards().lock().unwrap().push(pid);
}

/// A board's QEMU process is gone.
pub fn board_stopped(pid: u32) {
    boards().lock().unwrap().retain(|&p| p != pid);
}

fn sample_now() -> Option<Sample> {
    let (busy, all) = machine_ticks(&std::fs::read_to_string("/proc/stat").ok()?)?;
    let mut ours = process_ticks(&std::fs::read_to_string("/proc/self/stat").ok()?)?;
    for pid in boards().lock().unwrap().iter() {
        // a board that has just gone counts nothing
        if let Ok(t) = std::fs::read_to_string(format!("/proc/{pid}/stat")) {
            ours += process_ticks(&t).unwrap_or(0);
        }
    }
    Some(Sample { busy, all, ours })
}

/// Whether the rest of the machine leaves room for idle-priority pollers, as last measured.
struct Room {
    last: Mutex<(Instant, Option<Sample>)>,
    free: AtomicBool,
}

fn room() -> &'static Room {
    static R: OnceLock<Room> = OnceLock::new();
    R.get_or_init(|| Room {
        last: Mutex::new((Instant::now(), sample_now())),
        // until measured: the pollers' own starvation check guards the first half second
        free: AtomicBool::new(true),
    })
}

/// Whether the other processes left a core free at the last measurement (measured again if
/// that is [`LOAD_LOOK`] old; one caller measures, the others take the last answer).
fn machine_has_room(now: Instant) -> bool {
    let r = room();
    if let Ok(mut last) = r.last.try_lock() {
        if now.duration_since(last.0) >= LOAD_LOOK {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            let s = sample_now();
            if let (Some(a), Some(b)) = (last.1, s) {
                let free = other_cores(a, b, cores) < MAX_OTHER_CORES;
                r.free.store(free, Ordering::Relaxed);
                super::core_split::machine_measured(free);
            }
            *last = (now, s);
        }
    }
    r.free.load(Ordering::Relaxed)
}

/// The process's pollers' [`Starvation`].
fn process_starvation() -> &'static Starvation {
    static S: OnceLock<Starvation> = OnceLock::new();
    S.get_or_init(Starvation::new)
}

fn enabled() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var("NANOCAL_BENCH_BOARD_FIRST").map_or(true, |v| v != "0"))
}

/// While alive (and lowered), the calling thread runs at idle priority; dropped, it runs at
/// the priority it had.
pub struct BoardFirst {
    /// The thread's own policy, to go back to (`None`: not lowered).
    saved: Option<libc::c_int>,
    last_look: Instant,
    starvation: &'static Starvation,
    /// Go back once the machine has no room ([`machine_has_room`]; off in unit tests).
    check_room: bool,
}

impl BoardFirst {
    /// Lower the calling thread while it polls for the board (unless turned off, recently
    /// starved, or the thread is not at the normal policy: a real-time or idle caller is left
    /// as it is).
    pub fn enter() -> Self {
        if !enabled() || !machine_has_room(Instant::now()) {
            return Self::unlowered(process_starvation(), false);
        }
        Self::enter_in(process_starvation(), true)
    }

    /// Lowered unless `starvation` is recent; `check_room`: see the field.
    fn enter_in(starvation: &'static Starvation, check_room: bool) -> Self {
        let mut guard = Self::unlowered(starvation, check_room);
        if !starvation.recent(guard.last_look) {
            guard.saved = policy::lower();
        }
        guard
    }

    fn unlowered(starvation: &'static Starvation, check_room: bool) -> Self {
        Self {
            saved: None,
            last_look: Instant::now(),
            starvation,
            check_room,
        }
    }

    /// Whether the thread is lowered now.
    pub fn lowered(&self) -> bool {
        self.saved.is_some()
    }

    /// Call at every turn of the poll loop: a lowered thread that was off its core for longer
    /// than [`STARVED`] since the last look goes back to its own priority (and tells the other
    /// pollers to stay there for a while), as does one that finds the machine busy with other
    /// work.
    pub fn look(&mut self) {
        let now = Instant::now();
        if self.saved.is_some() {
            if now.duration_since(self.last_look) > STARVED {
                self.starvation.record(now);
                self.restore();
            } else if self.check_room && !machine_has_room(now) {
                self.restore();
            }
        }
        self.last_look = now;
    }

    /// The poller slept on purpose (a timed wait): the gap until the next look is not
    /// starvation.
    pub fn rested(&mut self) {
        self.last_look = Instant::now();
    }

    fn restore(&mut self) {
        if let Some(p) = self.saved.take() {
            policy::set(p);
        }
    }
}

/// The calling thread's scheduling policy (Linux: `SCHED_IDLE` exists only there; elsewhere
/// nothing is lowered).
#[cfg(target_os = "linux")]
mod policy {
    /// Lower the calling thread to `SCHED_IDLE` if it runs at the normal policy; its policy
    /// before, or `None` (not lowered).
    pub fn lower() -> Option<libc::c_int> {
        // SAFETY: plain system calls on the calling thread (pid 0), no memory handed over but
        // a parameter block that lives across the call
        unsafe {
            let policy = libc::sched_getscheduler(0);
            if policy != libc::SCHED_OTHER && policy != libc::SCHED_BATCH {
                return None;
            }
            let param = libc::sched_param { sched_priority: 0 };
            (libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) == 0).then_some(policy)
        }
    }

    /// Put the calling thread back at `policy`.
    pub fn set(policy: libc::c_int) {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: as in `lower`
        unsafe {
            libc::sched_setscheduler(0, policy, &param);
        }
    }
}

#[cfg(not(target_os = "linux"))]
mod policy {
    pub fn lower() -> Option<libc::c_int> {
        None
    }
    pub fn set(_policy: libc::c_int) {}
}

impl Drop for BoardFirst {
    fn drop(&mut self) {
        self.restore();
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    fn policy() -> libc::c_int {
        // SAFETY: a query of the calling thread
        unsafe { libc::sched_getscheduler(0) }
    }

    /// A process-wide record of its own, so that the tests do not see each other's starvation.
    fn fresh() -> &'static Starvation {
        Box::leak(Box::new(Starvation::new()))
    }

    #[test]
    fn a_poller_runs_at_idle_priority_and_returns_to_its_own() {
        // on a thread of its own, at the normal policy as threads start
        std::thread::spawn(|| {
            assert_eq!(policy(), libc::SCHED_OTHER);
            {
                let mut g = BoardFirst::enter_in(fresh(), false);
                assert!(g.lowered(), "any thread may lower itself");
                assert_eq!(policy(), libc::SCHED_IDLE);
                g.look();
                assert!(g.lowered(), "an immediate look is no starvation");
                g.rested();
                assert_eq!(policy(), libc::SCHED_IDLE);
            }
            assert_eq!(
                policy(),
                libc::SCHED_OTHER,
                "dropped: back to its own policy"
            );
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_starved_poller_goes_back_at_once_and_the_next_stays_at_its_priority() {
        std::thread::spawn(|| {
            let starvation = fresh();
            let mut g = BoardFirst::enter_in(starvation, false);
            assert!(g.lowered());
            // off its core for longer than STARVED, as far as the guard can tell
            g.last_look = Instant::now() - STARVED * 2;
            g.look();
            assert!(!g.lowered());
            assert_eq!(policy(), libc::SCHED_OTHER);
            let g2 = BoardFirst::enter_in(starvation, false);
            assert!(!g2.lowered(), "within the back-off nobody lowers itself");
            assert_eq!(policy(), libc::SCHED_OTHER);
            // another process-wide record (no starvation seen): lowered again
            assert!(BoardFirst::enter_in(fresh(), false).lowered());
        })
        .join()
        .unwrap();
    }

    #[test]
    fn the_machine_and_process_ticks_are_read_as_proc_5_describes_them() {
        // proc(5): cpu user nice system idle iowait irq softirq steal guest guest_nice
        let stat = "cpu  100 5 20 800 30 1 2 3 40 0\ncpu0 50 2 10 400 15 0 1 1 20 0\n";
        // busy = everything but idle and iowait; guest is inside user already (not added)
        assert_eq!(machine_ticks(stat), Some((131, 961)));
        assert_eq!(machine_ticks("intr 1 2 3\n"), None);
        assert_eq!(machine_ticks("cpu 1 2\n"), None);
        // the command name may hold spaces and parentheses
        let pid = "4242 (qemu (x) arm) S 1 4242 4242 0 -1 4194560 100 0 0 0 250 75 0 0 20 0";
        assert_eq!(process_ticks(pid), Some(325));
        assert_eq!(process_ticks("4242 (short) S 1"), None);
    }

    #[test]
    fn other_work_is_the_machines_busy_time_less_ours() {
        let a = Sample {
            busy: 1_000,
            all: 10_000,
            ours: 400,
        };
        // 2 cores, 100 ticks each elapsed: 150 busy ticks, 120 of them ours → 0.3 core
        let b = Sample {
            busy: 1_150,
            all: 10_200,
            ours: 520,
        };
        assert!((other_cores(a, b, 2) - 0.3).abs() < 1e-12);
        // two hogs beside us: 200 other ticks of 100 per core → 2 cores
        let c = Sample {
            busy: 1_300,
            all: 10_200,
            ours: 500,
        };
        assert!((other_cores(a, c, 2) - 2.0).abs() < 1e-12);
        // our time counted by the kernel a tick later than the machine's: never below 0
        let d = Sample {
            busy: 1_100,
            all: 10_200,
            ours: 520,
        };
        assert_eq!(other_cores(a, d, 2), 0.0);
        assert_eq!(other_cores(a, a, 2), 0.0);
    }

    #[test]
    fn a_thread_at_another_policy_is_left_as_it_is() {
        std::thread::spawn(|| {
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: the calling thread, a parameter block that outlives the call
            assert_eq!(
                unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) },
                0
            );
            let g = BoardFirst::enter_in(fresh(), false);
            assert!(!g.lowered());
            drop(g);
            assert_eq!(policy(), libc::SCHED_IDLE, "not raised on drop either");
        })
        .join()
        .unwrap();
    }
}
