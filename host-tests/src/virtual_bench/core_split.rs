//! A campaign's bench and its board on cores of their own: while the machine has room, every
//! thread of the bench runs on one core and QEMU's vCPU thread on another.
//!
//! **Why.** Traced on the shortened campaign (issue 20 §5, every bus request the advance served,
//! timed on the bench): the round trip within a sensor sample had a median of 4.4 µs, but 712
//! of 83,000 took 0.3–1 ms (665 of them with a halt of the board between), and 152 of the gaps
//! between samples more than 1 ms — together 39 % of the time the advances took. The likely
//! cause: the bench's pollers run at `SCHED_IDLE` ([`super::board_first`]), and Linux counts a
//! core that runs only such a thread as idle when it places a waking thread, so QEMU's vCPU,
//! waking from a halt, could land on the core where the bench polled for it while the other
//! core stayed idle; the bench then waited off its core until the load balancer moved it, and
//! the board, spinning for a bus reply nobody could give, halted. Pinned apart, the vCPU never
//! shares the bench's core, and QEMU's I/O thread still takes the bench's core at once when it
//! wakes (the poller there is idle-priority). Measured in turn (3 pairs): the shortened
//! campaign 6.2–7.2 s → 3.9–4.7 s wall, QEMU's CPU 3.6–4.7 → 2.2–2.8 s, halts −40 %.
//!
//! **Only a campaign's one board, only with room.** The split is opt-in ([`allow`]: the CLI's
//! `campaign --virtual`; never the test harness, whose threads run many boards at once), holds
//! only while exactly one board runs, and only while the rest of the machine leaves a core free
//! (the measurement [`super::board_first`] makes every 500 ms: a pinned thread cannot move away
//! from other work). When either stops holding, every thread goes back to the cores it had.
//! `NANOCAL_BENCH_CORE_SPLIT=0` turns it off.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Mutex;

/// The cores for the bench and for the board from the cores the process may use (in order):
/// the first two, or `None` with fewer than two.
pub fn pick_cores(allowed: &[usize]) -> Option<(usize, usize)> {
    match allowed {
        [bench, board, ..] => Some((*bench, *board)),
        _ => None,
    }
}

/// Whether a QEMU thread's name (`/proc/PID/task/TID/comm`, with `-name …,debug-threads=on`)
/// is a vCPU thread: "CPU 0/TCG" (one thread per vCPU) or "ALL CPUs/TCG" (round-robin TCG, as
/// a one-core board runs).
pub fn is_vcpu_thread(comm: &str) -> bool {
    comm.trim_end().ends_with("/TCG")
}

/// Turns the board may spin, idle at the horizon, before it halts while the split holds
/// (`bench_link::IDLE_SPIN`): ≈ 1–2 ms of its loop, longer than the bench takes from one
/// command of a step to the next. With its own core the spin costs the bench nothing, and the
/// next command finds the board awake: the shortened campaign's halts 3,693–3,891 → 56–67.
pub const IDLE_SPIN_TURNS: u32 = 10_000;

/// What the board may spin now: [`IDLE_SPIN_TURNS`] while the split holds, else 0 (a spinning
/// board would hold the core its bench needs).
pub fn idle_spin_turns() -> u32 {
    if STATE.lock().unwrap().applied {
        IDLE_SPIN_TURNS
    } else {
        0
    }
}

static ALLOWED: AtomicBool = AtomicBool::new(false);
/// Times the split was made, and undone (for the campaign's profile).
static MADE: AtomicU32 = AtomicU32::new(0);
static UNDONE: AtomicU32 = AtomicU32::new(0);

/// How often the split was made and undone so far.
pub fn transitions() -> (u32, u32) {
    (MADE.load(Ordering::Relaxed), UNDONE.load(Ordering::Relaxed))
}

/// Let this process split the cores for its board (see the module's text).
pub fn allow() {
    ALLOWED.store(true, Ordering::Relaxed);
}

fn enabled() -> bool {
    ALLOWED.load(Ordering::Relaxed)
        && std::env::var("NANOCAL_BENCH_CORE_SPLIT").map_or(true, |v| v != "0")
}

struct State {
    /// The boards running (QEMU pids).
    boards: Vec<u32>,
    /// Whether the split is in force.
    applied: bool,
    /// Whether the machine had room at the last measurement.
    room: bool,
}

static STATE: Mutex<State> = Mutex::new(State {
    boards: Vec::new(),
    applied: false,
    room: true,
});

/// A campaign's board (its QEMU process, running) starts: split if it is the only one and the
/// machine has room.
pub fn board_started(qemu_pid: u32) {
    if !enabled() {
        return;
    }
    let mut s = STATE.lock().unwrap();
    s.boards.push(qemu_pid);
    settle(&mut s);
}

/// The board is gone (or going): every thread back to its cores if it was the split's.
pub fn board_stopped(qemu_pid: u32) {
    let mut s = STATE.lock().unwrap();
    s.boards.retain(|&p| p != qemu_pid);
    settle(&mut s);
}

/// The machine's load was measured ([`super::board_first`]): split or unsplit as it says.
pub(crate) fn machine_measured(has_room: bool) {
    if !enabled() {
        return;
    }
    let mut s = STATE.lock().unwrap();
    s.room = has_room;
    settle(&mut s);
}

fn settle(s: &mut State) {
    let want = s.room && s.boards.len() == 1;
    if want == s.applied {
        return;
    }
    s.applied = if want {
        let made = affinity::split(s.boards[0]);
        if made {
            MADE.fetch_add(1, Ordering::Relaxed);
        }
        made
    } else {
        affinity::unsplit(s.boards.first().copied());
        UNDONE.fetch_add(1, Ordering::Relaxed);
        false
    };
}

#[cfg(target_os = "linux")]
mod affinity {
    use super::{is_vcpu_thread, pick_cores};
    use std::sync::Mutex;

    /// The cores the process could use before the split.
    static FULL: Mutex<Vec<usize>> = Mutex::new(Vec::new());

    fn get(tid: libc::pid_t) -> Option<Vec<usize>> {
        // SAFETY: a zeroed cpu_set_t is a valid empty set; the kernel writes at most its size
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            if libc::sched_getaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
                return None;
            }
            Some(
                (0..libc::CPU_SETSIZE as usize)
                    .filter(|&c| libc::CPU_ISSET(c, &set))
                    .collect(),
            )
        }
    }

    /// Set `tid`'s cores; false if it is gone or refused.
    pub fn set(tid: libc::pid_t, cores: &[usize]) -> bool {
        // SAFETY: as in `get`; the set lives across the call
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for &c in cores {
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
        }
    }

    fn tasks(pid: &str) -> Vec<libc::pid_t> {
        std::fs::read_dir(format!("/proc/{pid}/task"))
            .map(|d| {
                d.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok())
                    .collect()
            })
            .unwrap_or_default()
    }

    fn vcpu_threads(qemu_pid: u32) -> Vec<libc::pid_t> {
        tasks(&qemu_pid.to_string())
            .into_iter()
            .filter(|t| {
                std::fs::read_to_string(format!("/proc/{qemu_pid}/task/{t}/comm"))
                    .is_ok_and(|c| is_vcpu_thread(&c))
            })
            .collect()
    }

    /// Every thread of this process on the bench's core, the board's vCPU on its own; false
    /// (nothing changed) without two cores or a vCPU thread to find.
    pub fn split(qemu_pid: u32) -> bool {
        let Some(full) = get(0) else { return false };
        let Some((bench, board)) = pick_cores(&full) else {
            return false;
        };
        let vcpus = vcpu_threads(qemu_pid);
        if vcpus.is_empty() {
            return false;
        }
        *FULL.lock().unwrap() = full;
        for t in vcpus {
            set(t, &[board]);
        }
        for t in tasks("self") {
            set(t, &[bench]);
        }
        true
    }

    /// Every thread of this process, and the board's vCPU if it still runs, back on the cores
    /// the process had.
    pub fn unsplit(qemu_pid: Option<u32>) {
        let full = std::mem::take(&mut *FULL.lock().unwrap());
        if full.is_empty() {
            return;
        }
        for t in tasks("self") {
            set(t, &full);
        }
        for t in qemu_pid.map(vcpu_threads).unwrap_or_default() {
            set(t, &full);
        }
    }

    #[cfg(test)]
    pub fn cores_of(tid: libc::pid_t) -> Option<Vec<usize>> {
        get(tid)
    }
}

#[cfg(not(target_os = "linux"))]
mod affinity {
    pub fn split(_qemu_pid: u32) -> bool {
        false
    }
    pub fn unsplit(_qemu_pid: Option<u32>) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bench_takes_the_first_allowed_core_and_the_board_the_second() {
        assert_eq!(pick_cores(&[2, 5, 7]), Some((2, 5)));
        assert_eq!(pick_cores(&[0, 1]), Some((0, 1)));
        assert_eq!(pick_cores(&[3]), None);
        assert_eq!(pick_cores(&[]), None);
    }

    #[test]
    fn qemu_names_its_tcg_vcpu_threads_and_nothing_else_matches() {
        assert!(is_vcpu_thread("CPU 0/TCG\n"));
        assert!(is_vcpu_thread("ALL CPUs/TCG\n"));
        assert!(!is_vcpu_thread("qemu-system-arm\n"));
        assert!(!is_vcpu_thread("IO mon_iothread\n"));
        assert!(!is_vcpu_thread("worker\n"));
    }

    /// A thread's cores are set and read back (the split's one system call), on a thread of
    /// its own so that no other test's threads move.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_thread_is_pinned_and_given_back_its_cores() {
        let full = affinity::cores_of(0).expect("own cores");
        let first = full[0];
        std::thread::spawn(move || {
            // SAFETY: the calling thread's id
            let tid = unsafe { libc::gettid() };
            assert!(affinity::set(tid, &[first]));
            assert_eq!(affinity::cores_of(tid), Some(vec![first]));
            assert!(affinity::set(tid, &full));
            assert_eq!(affinity::cores_of(tid), Some(full));
        })
        .join()
        .unwrap();
    }
}
