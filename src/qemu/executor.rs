//! The QEMU board's executor loop: embassy's raw executor, and when no task is ready the board's
//! clock moves on ([`super::time::idle`]: to the next timer within the bench's horizon, or a WFI
//! until the bench moves it). embassy's cortex-m thread executor cannot be used: it sleeps on
//! WFE, which QEMU runs as a plain yield (a busy loop), and it has no idle hook for the clock.

use core::sync::atomic::{AtomicBool, Ordering};
use embassy_executor::{raw, Spawner};
use static_cell::StaticCell;

/// A task was woken since the last poll.
static WOKEN: AtomicBool = AtomicBool::new(true);

#[export_name = "__pender"]
fn pender(_context: *mut ()) {
    WOKEN.store(true, Ordering::Release);
}

static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();

/// Run the executor for ever; `init` spawns the tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    init(executor.spawner());
    loop {
        WOKEN.store(false, Ordering::Release);
        // SAFETY: the only call site, never re-entered (the pender only sets a flag).
        unsafe { executor.poll() };
        cortex_m::interrupt::free(|_| {
            if !WOKEN.load(Ordering::Acquire) {
                // a pending interrupt ends the wait; its handler runs once this returns
                super::time::idle();
            }
        });
    }
}
