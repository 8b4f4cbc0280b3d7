//! `embassy-time` driver of the QEMU board: a clock the virtual bench drives.
//!
//! The board's time is its uptime in 1 MHz ticks (as the STM32 board's), but it only moves when
//! the executor is idle: [`idle`] jumps to the next timer if that lies within the bench's
//! horizon (nothing can happen in between — no task is ready and every input the board waits for
//! comes from the bench, which announces what it sends and the clock holds until a waiting
//! reader has it: [`input_on_its_way`]), or to the horizon itself, and
//! then waits (WFI) for the bench to move it. So a day of the firmware's timers — sensor samples,
//! fold ages, lag filters, timeouts — runs in as much wall time as its work takes, and time never
//! passes while the bench computes. See `nanocal_interface::bench_link` for the page and the
//! doorbells; without the page (QEMU started by hand) SysTick sets the horizon at 1×.
//!
//! The watchdog keeps its meaning on the bench's time: [`set_watchdog_deadline`] is a deadline in
//! board time that the clock will not pass — reaching it resets the board as the hardware
//! watchdog would — while the CMSDK watchdog (QEMU's own clock) catches a busy loop, in which no
//! time passes at all, and is paused while the board waits for the bench.

use super::{board, link, uart};
use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;
use nanocal_interface::bench_link as bl;

/// A `u64` written only inside a critical section (interrupts masked) and read anywhere
/// without one: a single-core board cannot interleave a read with a write it masks, so a read
/// sees a whole value. On the emulated board that is the point: QEMU leaves its execution loop
/// at every `CPSID` and `MSR PRIMASK` (each ends a translation block), and reading the clock
/// was ≈ 300 of the ≈ 640 critical sections of a campaign's step (issue 20 §5).
struct MaskedWriteU64 {
    lo: AtomicU32,
    hi: AtomicU32,
}

impl MaskedWriteU64 {
    const fn new(v: u64) -> Self {
        Self {
            lo: AtomicU32::new(v as u32),
            hi: AtomicU32::new((v >> 32) as u32),
        }
    }

    fn get(&self) -> u64 {
        (u64::from(self.hi.load(Ordering::Relaxed)) << 32)
            | u64::from(self.lo.load(Ordering::Relaxed))
    }

    /// The token is the proof that no read runs in between the two halves.
    fn set(&self, _cs: CriticalSection<'_>, v: u64) {
        self.lo.store(v as u32, Ordering::Relaxed);
        self.hi.store((v >> 32) as u32, Ordering::Relaxed);
    }
}

struct BenchClock {
    /// Uptime, ticks.
    now: MaskedWriteU64,
    /// Bench time of this boot, ticks.
    boot_at: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
    /// Next timer, uptime ticks (u64::MAX: none).
    next_at: Mutex<Cell<u64>>,
    /// The bench's page is present (else SysTick sets the horizon); set once at boot.
    linked: AtomicBool,
    /// Horizon from SysTick when there is no page, bench ticks.
    systick_horizon: Mutex<Cell<u64>>,
    /// Watchdog deadline, uptime ticks.
    watchdog_at: Mutex<Cell<u64>>,
    /// Bench time of the last "waiting" doorbell (one per instant: the bench waits for the
    /// board to reach a time, not for every wake-up at it).
    rung_at: Mutex<Cell<u64>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: BenchClock = BenchClock {
    now: MaskedWriteU64::new(0),
    boot_at: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
    next_at: Mutex::new(Cell::new(u64::MAX)),
    linked: AtomicBool::new(false),
    systick_horizon: Mutex::new(Cell::new(0)),
    watchdog_at: Mutex::new(Cell::new(u64::MAX)),
    rung_at: Mutex::new(Cell::new(u64::MAX)),
});

impl Driver for BenchClock {
    fn now(&self) -> u64 {
        self.now.get()
    }

    fn schedule_wake(&self, at: u64, waker: &core::task::Waker) {
        critical_section::with(|cs| {
            let mut q = self.queue.borrow_ref_mut(cs);
            if q.schedule_wake(at, waker) {
                let next = q.next_expiration(self.now.get());
                self.next_at.borrow(cs).set(next);
            }
        });
    }
}

/// SysTick period without the page: 1 ms.
const SYSTICK_TICKS: u64 = bl::TICK_HZ / 1000;

/// Start the clock: from the bench's page if present (the bench time of this boot is the clock
/// it left off at: a reset takes no time), else from SysTick at 1×.
pub fn init(mut syst: SYST) {
    let linked = link::present();
    critical_section::with(|cs| {
        DRIVER.linked.store(linked, Ordering::Relaxed);
        if linked {
            let boot_at = link::read_u64(bl::NOW);
            DRIVER.boot_at.borrow(cs).set(boot_at);
            link::write_u64(bl::BOOT_AT, boot_at);
            link::write_u64(bl::NEXT_ALARM, u64::MAX);
            link::write_u32(bl::WAITING, 0);
            // no writer or ring reader of this boot waits yet (one of the last may have, when
            // it reset), nor is it halted
            link::write_u32(bl::TX_WAITING, 0);
            link::write_u32(bl::RX_ARMED, 0);
            link::write_u32(bl::HALTED, 0);
            link::barrier();
            uart::wake_init();
            link::write_u32(bl::BOOTS, link::read_u32(bl::BOOTS).wrapping_add(1));
        }
    });
    if linked {
        syst.disable_interrupt();
        syst.disable_counter();
    } else {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload((u64::from(super::SYSCLK_HZ) / 1000) as u32 - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
    }
}

/// True when the bench drives the clock.
pub fn linked() -> bool {
    DRIVER.linked.load(Ordering::Relaxed)
}

/// Call from the SysTick exception handler (only runs without the bench's page).
pub fn on_systick() {
    critical_section::with(|cs| {
        let h = DRIVER.systick_horizon.borrow(cs);
        h.set(h.get() + SYSTICK_TICKS);
    });
}

/// The watchdog fires if the clock reaches `uptime_ticks` (the supervisor moves it on with every
/// pet).
pub fn set_watchdog_deadline(uptime_ticks: u64) {
    critical_section::with(|cs| DRIVER.watchdog_at.borrow(cs).set(uptime_ticks));
}

/// Uptime, ticks.
pub fn uptime_ticks() -> u64 {
    DRIVER.now()
}

/// The bench announced bytes (`bench_link::ANNOUNCED`) on a serial port whose reader waits, and
/// the board has not read them all. A reader that does not wait does not hold the clock: the
/// bytes wait for it in QEMU as they would in a real UART's buffer, and a task that needs time
/// to pass before it reads again gets it.
fn input_on_its_way() -> bool {
    (0..uart::COUNT).any(|n| n != uart::BENCH && uart::rx_armed(n) && link::announced_unread(n))
}

/// A writer of the board waits for room (its bytes are on their way to the bench through
/// QEMU) and the bench, running freely, reads them: no time passes until they are out
/// (`bench_link::TX_WAITING`; in lockstep, or when the bench stops reading, it clears
/// `TX_HOLD` and time passes — the writer's own timeout then decides).
fn output_on_its_way() -> bool {
    link::read_u32(bl::TX_HOLD) != 0 && link::read_u32(bl::TX_WAITING) != 0
}

/// The executor has nothing ready: move the clock to the next timer if the horizon allows (and
/// wake its tasks), else to the horizon, and wait there for the bench. Call with interrupts
/// masked (a pending interrupt ends the wait).
pub fn idle() {
    critical_section::with(|cs| {
        let d = &DRIVER;
        let linked = d.linked.load(Ordering::Relaxed);
        // bytes in a ring for a waiting reader (or room for a waiting writer): its task runs
        // first, at this instant, as a UART byte's interrupt would have made it
        if linked && uart::ring_wake() {
            return;
        }
        let boot_at = d.boot_at.borrow(cs).get();
        let now = d.now.get();
        let next = d.next_at.borrow(cs).get();
        let horizon_bench = if linked {
            link::read_u64(bl::HORIZON)
        } else {
            d.systick_horizon.borrow(cs).get()
        };
        let horizon = horizon_bench.saturating_sub(boot_at);
        // bytes the bench has written to a port whose reader waits for them are still on
        // their way through QEMU: no time passes until they are in (timers already due run);
        // likewise bytes the board wrote, while the free-running bench takes them
        let horizon = if linked && (input_on_its_way() || output_on_its_way()) {
            horizon.min(now)
        } else {
            horizon
        };
        let watchdog_at = d.watchdog_at.borrow(cs).get();
        if next.min(horizon) >= watchdog_at {
            // as the hardware watchdog would have: the supervisor stopped petting in time
            board::watchdog_fire();
        }
        if next <= horizon {
            let t = next.max(now);
            d.now.set(cs, t);
            if linked {
                link::write_u64(bl::NOW, boot_at + t);
            }
            let next = d.queue.borrow_ref_mut(cs).next_expiration(t);
            d.next_at.borrow(cs).set(next);
            return;
        }
        if now < horizon {
            d.now.set(cs, horizon);
        }
        if linked {
            let now = d.now.get();
            link::write_u64(bl::NOW, boot_at + now);
            link::write_u64(bl::NEXT_ALARM, next.saturating_add(boot_at));
            link::barrier();
            link::write_u32(bl::WAITING, 1);
            link::barrier();
            // the bench may have moved the horizon meanwhile: then no wait
            if link::read_u64(bl::HORIZON) == horizon_bench {
                let rung = d.rung_at.borrow(cs);
                if rung.get() != boot_at + now && link::read_u32(bl::WATCHING) == 0 {
                    rung.set(boot_at + now);
                    uart::ring(bl::RING_WAITING);
                }
                // halt at once. The bench knows from the page that the board is halted and
                // rings for what it writes then (bytes in a ring, room made, a new horizon);
                // a busy wait for those, as the board did before (500 µs of QEMU's clock), was
                // 43 % of the guest instructions of a campaign's step, spent while the bench
                // worked on its own side (issue 20 §5). Mark the halt, then look once more
                // (the bench writes its bytes or the horizon, then looks at the mark).
                let ready = || uart::ring_ready() || link::read_u64(bl::HORIZON) != horizon_bench;
                // a bench that gave the board a core of its own lets it watch for a while
                // first (`bench_link::IDLE_SPIN`): its next command then finds the board awake
                // instead of ringing it out of a halt (≈ 100 µs each through QEMU's I/O thread)
                if link::spin_until(link::read_u32(bl::IDLE_SPIN), ready) {
                    super::board::watchdog_reload_lazily();
                } else {
                    link::halt(ready, true);
                }
            }
            link::write_u32(bl::WAITING, 0);
        } else {
            cortex_m::asm::wfi();
        }
    });
}
