//! The rest of the QEMU board: CMSDK APB watchdog (and its deadline on the board's clock), FPGA LED, reset cause, storage in RAM that
//! survives a system reset, the host-link line state.
//!
//! CMSDK APB watchdog (ARM DDI 0479, "Cortex-M System Design Kit", §4.4; QEMU
//! `cmsdk-apb-watchdog` at 0x4000_8000 on mps2-an386): LOAD 00h, VALUE 04h, CONTROL 08h (bit 0
//! INTEN, bit 1 RESEN), INTCLR 0Ch (clears the interrupt and reloads), LOCK C00h (1ACCE551h
//! unlocks). The counter runs at the 25 MHz system clock; the first expiry raises its interrupt,
//! a second expiry with the interrupt still set resets the system.

use core::mem::MaybeUninit;
use core::ptr::{addr_of_mut, read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};
use nanocal_compensator::l4flash::{FlashError, L4Sim, RawFlash, DWORD, ERASE_PAGE_US};
use nanocal_interface::identity::ResetCause;

const WDOG: usize = 0x4000_8000;
/// CMSDK APB timer 0 (ARM DDI 0479 §4.3: CTRL 00h, VALUE 04h, RELOAD 08h), used only to wake
/// QEMU's I/O loop (see [`kick_io`]).
const TIMER0: usize = 0x4000_0000;
/// CMSDK APB timer 1: a free-running down-counter of QEMU's clock (25 MHz).
const TIMER1: usize = 0x4000_1000;
const FPGAIO_LED: usize = 0x4002_8000;

fn w(addr: usize, v: u32) {
    // SAFETY: MMIO register of the board, 32-bit access.
    unsafe { write_volatile(addr as *mut u32, v) }
}

/// Watchdog timeout in force, ms (0: not started).
static WATCHDOG_MS: AtomicU32 = AtomicU32::new(0);

/// Start the watchdog: a hang of more than `timeout_ms` (twice, interrupt then reset) resets.
pub fn watchdog_start(timeout_ms: u32) {
    WATCHDOG_MS.store(timeout_ms, Ordering::Relaxed);
    w(WDOG + 0xC00, 0x1ACC_E551);
    w(WDOG, super::SYSCLK_HZ / 1000 * timeout_ms);
    w(WDOG + 0x08, 0b11);
    w(WDOG + 0xC00, 0);
    watchdog_deadline(timeout_ms);
}

/// The same deadline on the board's clock (see [`super::time`]): two expiries, as the CMSDK
/// watchdog's interrupt-then-reset.
fn watchdog_deadline(timeout_ms: u32) {
    let ticks = 2 * u64::from(timeout_ms) * (embassy_time_driver::TICK_HZ / 1000);
    super::time::set_watchdog_deadline(super::time::uptime_ticks().saturating_add(ticks));
}

/// QEMU-clock time of the last reload of the CMSDK watchdog (timer 1's count).
static LAST_RELOAD: AtomicU32 = AtomicU32::new(0);

/// Reload the watchdog: its deadline on the board's clock at every pet; the CMSDK counter (on
/// QEMU's clock, which only catches a busy loop) at most every 100 ms of QEMU's clock — each
/// reload re-arms a QEMU timer and wakes QEMU's I/O loop, which would cost more than the rest of
/// a pet when the board's clock runs thousands of times faster than QEMU's.
pub fn watchdog_pet() {
    let ms = WATCHDOG_MS.load(Ordering::Relaxed);
    if ms != 0 {
        watchdog_deadline(ms);
    }
    watchdog_reload_lazily();
}

/// Reload the CMSDK counter if its last reload is 100 ms of QEMU's clock ago or more: at a pet,
/// and when the board waited for the bench and the bench answered (an idle spin that ended with
/// its input — no busy loop, as after a halt, whose resume reloads the counter).
pub fn watchdog_reload_lazily() {
    let now = r(TIMER1 + 0x04);
    if LAST_RELOAD.load(Ordering::Relaxed).wrapping_sub(now) >= super::SYSCLK_HZ / 10 {
        LAST_RELOAD.store(now, Ordering::Relaxed);
        w(WDOG + 0xC00, 0x1ACC_E551);
        w(WDOG + 0x0C, 1);
        w(WDOG + 0xC00, 0);
    }
}

/// Stop the CMSDK watchdog's counter while the board waits for the bench (no board time passes
/// then; QEMU's clock does).
pub fn watchdog_pause() {
    if WATCHDOG_MS.load(Ordering::Relaxed) != 0 {
        w(WDOG + 0xC00, 0x1ACC_E551);
        w(WDOG + 0x08, 0);
        w(WDOG + 0xC00, 0);
    }
}

/// Restart it after a wait (ARM DDI 0479 §4.4: setting INTEN again reloads the counter).
pub fn watchdog_resume() {
    if WATCHDOG_MS.load(Ordering::Relaxed) != 0 {
        w(WDOG + 0xC00, 0x1ACC_E551);
        w(WDOG + 0x08, 0b11);
        w(WDOG + 0xC00, 0);
    }
}

/// The watchdog's deadline passed on the board's clock: reset as the watchdog does (no
/// software-reset marker, so the next boot reports the watchdog).
pub fn watchdog_fire() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

/// Wake QEMU's I/O loop. QEMU's CMSDK UART model takes the next received byte from its socket
/// only when QEMU's main loop runs again, and reading the data register does not wake that loop
/// (`hw/char/cmsdk-apb-uart.c` calls no `qemu_chr_fe_accept_input`): a byte stream into the
/// board would trickle at the pace of unrelated events. Re-arming timer 0 to expire at once
/// moves a QEMU timer deadline, which wakes the loop, which then hands over the next byte. The
/// timer's interrupt stays disabled; on hardware there is nothing to do.
pub fn kick_io() {
    w(TIMER0 + 0x04, 2);
}

/// Set timer 0 up for [`kick_io`], and timer 1 as a free-running counter of QEMU's clock (for
/// [`watchdog_pet`]): enabled, no interrupt, reloading from the largest value.
pub fn kick_io_init() {
    for t in [TIMER0, TIMER1] {
        w(t + 0x08, u32::MAX);
        w(t, 1);
    }
}

fn r(addr: usize) -> u32 {
    // SAFETY: MMIO register of the board, 32-bit access.
    unsafe { read_volatile(addr as *const u32) }
}

/// Light FPGA LED 0.
pub fn set_led(on: bool) {
    w(FPGAIO_LED, u32::from(on));
}

const MAGIC: u32 = 0x4E43_424F; // "NCBO"
const SOFT: u32 = 0x534F_4654; // "SOFT"

#[link_section = ".uninit.NANOCAL_BOOT"]
static mut BOOT: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();

/// Why this boot happened: RAM survives QEMU's system reset (only the image is reloaded), so a
/// marker in `.uninit` tells a warm reset from a power-on, and a software reset leaves a second
/// marker; a warm reset without it is the watchdog's.
pub fn reset_cause() -> ResetCause {
    // SAFETY: single-threaded, before any task runs; plain words.
    unsafe {
        let p = addr_of_mut!(BOOT) as *mut u32;
        let (magic, soft) = (read_volatile(p), read_volatile(p.add(1)));
        write_volatile(p, MAGIC);
        write_volatile(p.add(1), 0);
        match (magic == MAGIC, soft == SOFT) {
            (false, _) => ResetCause::PowerOn,
            (true, true) => ResetCause::Software,
            (true, false) => ResetCause::Watchdog,
        }
    }
}

/// Reset the system (software reset).
pub fn software_reset() -> ! {
    // SAFETY: as above.
    unsafe { write_volatile((addr_of_mut!(BOOT) as *mut u32).add(1), SOFT) };
    cortex_m::peripheral::SCB::sys_reset()
}

/// Storage size of the board, bytes.
pub const FLASH_SIZE: usize = 64 * 1024;

#[link_section = ".uninit.NANOCAL_FLASH"]
static mut FLASH: MaybeUninit<L4Sim<FLASH_SIZE>> = MaybeUninit::uninit();

/// The simulated L4 flash: kept across resets (not across QEMU restarts); erased at power-on.
///
/// # Safety
/// Call once.
pub unsafe fn flash(cause: ResetCause) -> &'static mut L4Sim<FLASH_SIZE> {
    // SAFETY: called once; initialised on power-on, otherwise as the last boot left it.
    unsafe {
        let f = &mut *addr_of_mut!(FLASH);
        if cause == ResetCause::PowerOn {
            f.write(L4Sim::new());
        }
        let f = f.assume_init_mut();
        f.power_on();
        f
    }
}

/// The simulated flash with the controller's timing: erases take their time asynchronously
/// (the executor serves the command path meanwhile, as read-while-write does on the L4).
pub struct TimedFlash(pub &'static mut L4Sim<FLASH_SIZE>);

impl RawFlash for TimedFlash {
    fn capacity(&self) -> usize {
        FLASH_SIZE
    }
    fn read_dword(&mut self, offset: u32) -> [u8; DWORD] {
        self.0.read_dword(offset)
    }
    fn take_ecc_error(&mut self) -> bool {
        self.0.take_ecc_error()
    }
    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError> {
        embassy_time::Timer::after_micros(u64::from(ERASE_PAGE_US)).await;
        self.0.erase_now(offset)
    }
    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError> {
        self.0.program_now(offset, data)
    }
}
