//! `embassy-time` driver on SysTick: 10 kHz ticks (the tick rate also paces QEMU's serial
//! receive path, see `../shared/notes/qemu.md`), one timer queue.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

struct SysTickDriver {
    /// High word of the tick counter is kept in `ticks_hi` (u32 wrap every 4.9 days at 10 kHz).
    ticks_lo: AtomicU32,
    ticks_hi: AtomicU32,
    queue: Mutex<RefCell<Queue>>,
    next_at: Mutex<Cell<u64>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    ticks_lo: AtomicU32::new(0),
    ticks_hi: AtomicU32::new(0),
    queue: Mutex::new(RefCell::new(Queue::new())),
    next_at: Mutex::new(Cell::new(u64::MAX)),
});

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        loop {
            let hi = self.ticks_hi.load(Ordering::Acquire);
            let lo = self.ticks_lo.load(Ordering::Acquire);
            if hi == self.ticks_hi.load(Ordering::Acquire) {
                return (u64::from(hi) << 32) | u64::from(lo);
            }
        }
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut q = self.queue.borrow_ref_mut(cs);
            if q.schedule_wake(at, waker) {
                let next = q.next_expiration(self.now());
                self.next_at.borrow(cs).set(next);
            }
        });
    }
}

impl SysTickDriver {
    fn tick(&self) {
        let lo = self.ticks_lo.load(Ordering::Relaxed).wrapping_add(1);
        if lo == 0 {
            self.ticks_hi.fetch_add(1, Ordering::Release);
        }
        self.ticks_lo.store(lo, Ordering::Release);
        let now = self.now();
        critical_section::with(|cs| {
            if now >= self.next_at.borrow(cs).get() {
                let next = self.queue.borrow_ref_mut(cs).next_expiration(now);
                self.next_at.borrow(cs).set(next);
            }
        });
    }
}

/// Start SysTick at `embassy_time::TICK_HZ` from the processor clock.
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(super::SYSCLK_HZ / embassy_time_driver::TICK_HZ as u32 - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// Call from the SysTick exception handler.
pub fn on_systick() {
    DRIVER.tick();
}
