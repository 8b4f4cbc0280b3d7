//! The firmware's own fatal errors, kept over the reset they cause: a panic (its source line),
//! a double ECC error outside the store (the address), a HardFault (the PC). RCC_CSR alone says
//! "independent watchdog" or "software reset" for all of them; the next boot reads this record
//! and reports the cause and the site in HELLO (`nanocal device status`).
//!
//! Kept in the RTC backup registers (RM0351 §38.3.15 "Backup registers", §38.6.20 RTC_BKPxR):
//! a system reset keeps them, a power cut clears them (the board has no backup battery). Reading
//! needs the RTC's APB clock (RCC_APB1ENR1.RTCAPBEN, with PWREN); writing also needs the backup
//! domain unlocked (PWR_CR1.DBP, §5.1.5).

use core::ptr::{read_volatile, write_volatile};
use nanocal_interface::identity::{ResetCause, Site};

const RCC_APB1ENR1: usize = 0x4002_1058;
const APB1ENR1_PWREN: u32 = 1 << 28;
const APB1ENR1_RTCAPBEN: u32 = 1 << 10;
const PWR_CR1: usize = 0x4000_7000;
const CR1_DBP: u32 = 1 << 8;
const RTC_BKP0R: usize = 0x4000_2850;
/// "NC" and the kind in the low byte: anything else in BKP0R is no record.
const MAGIC: u32 = 0x4E43_0000;
/// The firmware's flash (bank 1 and bank 2 below the store): where a panic's file name is.
const FLASH: core::ops::Range<u32> = 0x0800_0000..0x080F_0000;

/// What ended the last run.
#[derive(Clone, Copy)]
#[repr(u32)]
pub enum Kind {
    /// `#[panic_handler]`: file name (address, length) and line.
    Panic = 1,
    /// NMI for a double ECC error outside the store: the double word's address.
    FlashEcc = 2,
    /// HardFault: the faulting PC.
    Fault = 3,
}

fn reg(a: usize) -> u32 {
    // SAFETY: RCC/PWR/RTC register, 32-bit access.
    unsafe { read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(a as *mut u32, v) }
}

fn open_backup_domain() {
    set(
        RCC_APB1ENR1,
        reg(RCC_APB1ENR1) | APB1ENR1_PWREN | APB1ENR1_RTCAPBEN,
    );
    cortex_m::asm::dsb();
    set(PWR_CR1, reg(PWR_CR1) | CR1_DBP);
    cortex_m::asm::dsb();
}

/// Record `kind` with its words (from a panic, NMI or HardFault handler: no allocation, no
/// locks). An earlier record of this run stays (a panic ends in UDF, whose HardFault must not
/// overwrite the panic's line).
pub fn record(kind: Kind, a: u32, b: u32, c: u32) {
    open_backup_domain();
    if reg(RTC_BKP0R) & 0xFFFF_0000 == MAGIC {
        return;
    }
    set(RTC_BKP0R + 4, a);
    set(RTC_BKP0R + 8, b);
    set(RTC_BKP0R + 12, c);
    set(RTC_BKP0R, MAGIC | kind as u32);
}

/// The record of the last run, if any (and clear it): the reset cause it stands for and the
/// site. Call first thing at boot, before embassy-stm32 configures the backup domain.
pub fn take() -> Option<(ResetCause, Site<'static>)> {
    open_backup_domain();
    let k = reg(RTC_BKP0R);
    let (a, b, c) = (reg(RTC_BKP0R + 4), reg(RTC_BKP0R + 8), reg(RTC_BKP0R + 12));
    set(RTC_BKP0R, 0);
    if k & 0xFFFF_0000 != MAGIC {
        return None;
    }
    match k & 0xFF {
        1 => {
            // the file name is a string of this very image; a record from another image (the
            // board was reflashed between) may point anywhere in flash: check before reading
            let ok = FLASH.contains(&a) && c <= 200 && FLASH.contains(&(a + c));
            let file = ok
                .then(|| {
                    // SAFETY: `c` bytes of flash from `a`, inside the firmware's flash (checked).
                    let bytes = unsafe { core::slice::from_raw_parts(a as *const u8, c as usize) };
                    core::str::from_utf8(bytes).ok()
                })
                .flatten()
                .unwrap_or("?");
            Some((ResetCause::Panic, Site::Line { file, line: b }))
        }
        2 => Some((ResetCause::FlashEcc, Site::Address(a))),
        3 => Some((ResetCause::Fault, Site::Address(a))),
        _ => None,
    }
}

/// A panic records its source line (defmt logs it over RTT too; the message would pull in
/// `core::fmt`, about 3 KiB of flash, for the few panics the firmware has) and ends in a
/// permanent UDF: probe-rs halts there with a backtrace; without a probe the HardFault handler
/// resets the board, and the next boot reports "panic at file:line".
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(l) => {
            defmt::error!("panic at {=str}:{=u32}", l.file(), l.line());
            record(
                Kind::Panic,
                l.file().as_ptr() as u32,
                l.line(),
                l.file().len() as u32,
            );
        }
        None => {
            defmt::error!("panic");
            record(Kind::Panic, 0, 0, 0);
        }
    }
    cortex_m::asm::udf()
}

/// A HardFault (the UDF a panic ends in, an undefined instruction, a bad access) records the
/// faulting PC — unless a panic recorded its line first — and resets the board at once instead
/// of waiting for the watchdog.
#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    record(Kind::Fault, ef.pc(), 0, 0);
    cortex_m::peripheral::SCB::sys_reset()
}

/// Why the chip reset: the firmware's own record when it made one (a panic, an ECC error
/// outside the store, a HardFault — RCC_CSR would say "watchdog" or "software"), else RCC_CSR
/// (RM0351 §6.4.29); the flags are cleared (RMVF).
pub fn reset_cause() -> (ResetCause, Site<'static>) {
    const RCC_CSR: usize = 0x4002_1094;
    let csr = reg(RCC_CSR);
    set(RCC_CSR, csr | (1 << 23));
    take().unwrap_or((ResetCause::from_rcc_csr(csr), Site::None))
}
