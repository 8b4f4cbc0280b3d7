//! The store's flash: the last 64 KiB of bank 2 (pages 224..255), erased and programmed through
//! the flash controller's registers (RM0351 §3.3, §3.7) with BSY polled asynchronously, and the
//! NMI of a double ECC error (§3.3.4).

use super::crash::{self, Kind};
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m_rt::exception;
use embassy_time::Timer;
use nanocal_compensator::l4flash::{FlashError, RawFlash, DWORD, PAGE};

/// The store: the last 64 KiB of flash (bank 2, pages 224..255), excluded from FLASH in
/// memory.x.
pub const STORE_BASE: u32 = 0x080F_0000;
/// Store size, bytes.
pub const STORE_SIZE: usize = 64 * 1024;
const BANK1_BASE: u32 = 0x0800_0000;
const BANK2_BASE: u32 = 0x0808_0000;
/// Store erase unit: four 2 KiB pages (a whole blob fits one unit).
pub const ERASE: usize = 8 * 1024;

const FLASH_KEYR: usize = 0x4002_2008;
const FLASH_SR: usize = 0x4002_2010;
const FLASH_CR: usize = 0x4002_2014;
const FLASH_ECCR: usize = 0x4002_2018;
const FLASH_ACR: usize = 0x4002_2000;
const SR_BSY: u32 = 1 << 16;
/// OPTVERR, RDERR, FASTERR, MISERR, PGSERR, SIZERR, PGAERR, WRPERR, PROGERR, OPERR.
const SR_ERRORS: u32 = 0xC3FA;
const CR_PG: u32 = 1 << 0;
const CR_PER: u32 = 1 << 1;
const CR_BKER: u32 = 1 << 11;
const CR_STRT: u32 = 1 << 16;
const CR_LOCK: u32 = 1 << 31;
const ECCR_ECCD: u32 = 1 << 31;
const ECCR_BK_ECC: u32 = 1 << 19;
const ECCR_ADDR: u32 = 0x7_FFFF;
const ACR_DCEN: u32 = 1 << 10;
const ACR_DCRST: u32 = 1 << 12;
/// IWDG key register (RM0351 §32.4.1): 0xAAAA reloads the counter.
const IWDG_KR: usize = 0x4000_3000;

/// Set by the NMI handler when a read of the store hit a double ECC error.
static ECC_ERROR: AtomicBool = AtomicBool::new(false);

/// True until the executor runs the tasks: the store's flash waits spin instead of awaiting a
/// timer (embassy-time's timers need an executor task; at start-up nothing else runs).
static BOOTING: AtomicBool = AtomicBool::new(true);

/// The tasks run from now on: flash waits await timers.
pub fn booted() {
    BOOTING.store(false, Ordering::Relaxed);
}

fn reg(a: usize) -> u32 {
    // SAFETY: FLASH controller or flash word, 32-bit access.
    unsafe { read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(a as *mut u32, v) }
}

/// Reload the watchdog while the store is read (and repaired) at boot, before any task runs:
/// the supervisor is not there yet to do it. Once the tasks run this does nothing.
fn feed_watchdog_while_booting() {
    if BOOTING.load(Ordering::Relaxed) {
        set(IWDG_KR, 0xAAAA);
    }
}

/// The flash address ECCR reports (ADDR_ECC is the double word's offset in its bank, BK_ECC
/// the bank, RM0351 §3.7.7).
fn ecc_address(eccr: u32) -> u32 {
    let bank = if eccr & ECCR_BK_ECC != 0 {
        BANK2_BASE
    } else {
        BANK1_BASE
    };
    bank + (eccr & ECCR_ADDR)
}

/// A flash read with two bit errors raises the NMI (RM0351 §3.3.4). Inside the store's pages
/// it is a double word a power cut tore: clear ECCD and flag it, so the read returns and the
/// store treats that double word as corrupt (cortex-m-rt's default handler would loop and every
/// boot reading a torn double word would hang). Anywhere else it is the firmware's own code or
/// constants: nothing read there can be trusted, so the board records the address and resets
/// (and keeps resetting, with the address reported, until it is reflashed). Any other NMI
/// (clock security system) stops here and the IWDG resets the board.
#[exception]
unsafe fn NonMaskableInt() {
    let eccr = reg(FLASH_ECCR);
    if eccr & ECCR_ECCD != 0 {
        let addr = ecc_address(eccr);
        if (STORE_BASE..STORE_BASE + STORE_SIZE as u32).contains(&addr) {
            set(FLASH_ECCR, eccr);
            ECC_ERROR.store(true, Ordering::SeqCst);
            return;
        }
        crash::record(Kind::FlashEcc, addr, 0, 0);
        cortex_m::peripheral::SCB::sys_reset();
    }
    loop {
        cortex_m::asm::nop();
    }
}

/// The store's flash: bank 2, erased and programmed through the controller's registers with
/// BSY polled asynchronously. Code runs from bank 1, so while bank 2 is busy the executor keeps
/// serving the command path (read-while-write, RM0351 §3.3.1) instead of stalling ~22 ms per
/// page as embassy-stm32's blocking flash driver does.
pub struct L4Flash;

impl L4Flash {
    fn unlock() {
        if reg(FLASH_CR) & CR_LOCK != 0 {
            set(FLASH_KEYR, 0x4567_0123);
            set(FLASH_KEYR, 0xCDEF_89AB);
        }
    }

    async fn wait_idle(poll_us: u64) -> Result<(), FlashError> {
        while reg(FLASH_SR) & SR_BSY != 0 {
            if BOOTING.load(Ordering::Relaxed) {
                feed_watchdog_while_booting();
                continue;
            }
            if poll_us == 0 {
                embassy_futures::yield_now().await;
            } else {
                Timer::after_micros(poll_us).await;
            }
        }
        let sr = reg(FLASH_SR);
        set(FLASH_SR, sr & (SR_ERRORS | 1));
        if sr & SR_ERRORS != 0 {
            return Err(FlashError::Controller);
        }
        Ok(())
    }

    /// Switch the data cache off for a program or erase of bank 2; whether it was on.
    ///
    /// Errata ES0250 ("Data cache might be corrupted during Flash memory read-while-write
    /// operation"): with DCEN set while bank 2 is programmed or erased and code runs from bank
    /// 1, the data cache can keep stale lines. ST's HAL and Zephyr's L4 driver switch DCEN off
    /// around every program and erase and reset the cache after it; so does this driver
    /// (tests/e2e_stm32_power_cut.rs `stm32_kmz_item_read_back_while_a_page_is_freed_…`: with
    /// the cache left on across programming, the store's read-back of an item it had just
    /// programmed came from a line cached while that spot was still erased).
    fn dcache_off() -> bool {
        let acr = reg(FLASH_ACR);
        set(FLASH_ACR, acr & !ACR_DCEN);
        acr & ACR_DCEN != 0
    }

    /// Reset the data cache (DCRST works only with DCEN clear, RM0351 §3.7.1) and switch it
    /// back on if it was.
    fn dcache_restore(was_on: bool) {
        let acr = reg(FLASH_ACR) & !ACR_DCEN;
        set(FLASH_ACR, acr | ACR_DCRST);
        set(FLASH_ACR, acr & !ACR_DCRST);
        if was_on {
            set(FLASH_ACR, acr | ACR_DCEN);
        }
    }
}

impl RawFlash for L4Flash {
    fn capacity(&self) -> usize {
        STORE_SIZE
    }

    fn read_dword(&mut self, offset: u32) -> [u8; DWORD] {
        feed_watchdog_while_booting();
        let a = (STORE_BASE + offset) as usize;
        let (lo, hi) = (reg(a), reg(a + 4));
        // the ECC error's NMI comes after the read completes: wait for it here, before the
        // caller asks whether there was one (RM0351 §3.3.4; PM0214 §4.1: DSB completes the
        // reads, ISB lets the pending NMI in before the next instruction)
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        let mut d = [0u8; DWORD];
        d[..4].copy_from_slice(&lo.to_le_bytes());
        d[4..].copy_from_slice(&hi.to_le_bytes());
        d
    }

    fn take_ecc_error(&mut self) -> bool {
        ECC_ERROR.swap(false, Ordering::SeqCst)
    }

    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError> {
        let page = (STORE_BASE + offset - BANK2_BASE) / PAGE as u32;
        Self::wait_idle(500).await?;
        Self::unlock();
        let dcache = Self::dcache_off();
        set(FLASH_CR, CR_PER | CR_BKER | (page << 3));
        set(FLASH_CR, CR_PER | CR_BKER | (page << 3) | CR_STRT);
        let r = Self::wait_idle(1000).await;
        set(FLASH_CR, CR_LOCK);
        Self::dcache_restore(dcache);
        r
    }

    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError> {
        let a = (STORE_BASE + offset) as usize;
        Self::wait_idle(0).await?;
        Self::unlock();
        let dcache = Self::dcache_off();
        set(FLASH_CR, CR_PG);
        let w = |i: usize| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
        set(a, w(0));
        set(a + 4, w(4));
        let r = Self::wait_idle(0).await;
        set(FLASH_CR, CR_LOCK);
        Self::dcache_restore(dcache);
        r
    }
}
