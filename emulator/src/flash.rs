//! The embedded flash and its controller (RM0351 Rev 9 §3 "Embedded flash memory (FLASH)",
//! registers §3.7), with the store's part of bank 2 on `nanocal_compensator::l4flash::L4Sim` —
//! the same rules the store's native tests use (double words programmed once between erases,
//! torn double words read with a double ECC error, erase and program times, power cuts).
//!
//! Modelled:
//! - **Wait states against HCLK** (§3.3.3, Table 12 "Number of wait states according to CPU
//!   clock (HCLK) frequency"): too few for the clock in force is a fault the board reports (the
//!   real chip reads wrong instructions), not silence.
//! - **Programming and erase** through KEYR/CR/SR (§3.3.5 unlock sequence, §3.3.6 page erase,
//!   §3.3.7 double-word programming: PG set, two words, BSY for the programming time), with
//!   PGSERR/PGAERR/WRPERR for sequences the hardware refuses.
//! - **ECC** (§3.3.4): reading a torn double word of the store sets ECCR.ECCD with its address and
//!   raises the NMI.
//! - **The data cache** (§3.3.3: 8 lines of 32 bytes on the D-code bus; DCEN, DCRST) and the
//!   erratum in ES0250 (STM32L47x/L48x errata) "Data cache might be corrupted during Flash memory
//!   read-while-write operation": a program or erase of bank 2 started while DCEN is set leaves
//!   the lines the cache holds stale — later reads of them return the old contents until DCRST.
//!   ST's HAL and Zephyr switch DCEN off and reset the cache around every program and erase.

use nanocal_compensator::l4flash::{
    FlashError, L4Sim, RawFlash, DWORD, ERASE_PAGE_US, PAGE, PROGRAM_DWORD_US,
};

/// Flash base.
pub const BASE: u32 = 0x0800_0000;
/// Bank 2 base (1 MiB part, DUALBANK).
pub const BANK2: u32 = 0x0808_0000;
/// The store region: the last 64 KiB of bank 2 (the firmware's memory.x leaves it out).
pub const STORE_BASE: u32 = 0x080F_0000;
/// Store size.
pub const STORE_SIZE: usize = 64 * 1024;
/// Data-cache line size, bytes.
const LINE: u32 = 32;
/// Data-cache lines.
const LINES: usize = 8;

/// The store's flash, kept over resets and power cuts (it is flash).
pub type StoreFlash = L4Sim<STORE_SIZE>;

/// Wait states needed at `hclk` Hz in voltage range `vos` (RM0351 Table 12).
pub fn wait_states_needed(hclk: u64, vos: u32) -> u32 {
    let mhz_limits: &[u64] = if vos == 1 {
        &[16, 32, 48, 64, 80]
    } else {
        &[6, 12, 18, 26]
    };
    mhz_limits
        .iter()
        .position(|&m| hclk <= m * 1_000_000)
        .map(|p| p as u32)
        .unwrap_or(u32::MAX)
}

/// An operation the controller is busy with.
#[derive(Clone, Copy, Debug)]
struct Busy {
    until_ps: u64,
}

/// Controller registers and the data cache.
pub struct FlashCtl {
    /// ACR (LATENCY 2:0, PRFTEN 8, ICEN 9, DCEN 10, ICRST 11, DCRST 12).
    pub acr: u32,
    /// SR.
    pub sr: u32,
    /// CR.
    pub cr: u32,
    /// ECCR.
    pub eccr: u32,
    key_step: u8,
    first_word: Option<(u32, u32)>,
    busy: Option<Busy>,
    /// The data cache in fill order: line address, contents, stale (ES0250), and the double
    /// words of the line that failed ECC when it was filled (bit per double word: reported
    /// when one of them is read).
    cache: Vec<(u32, [u8; LINE as usize], bool, u8)>,
    /// Operations (programs, erases) on the store since power-on.
    pub ops: u64,
    /// Reads that returned stale cached data (ES0250 erratum).
    pub stale_reads: u64,
    /// Of those, reads whose bytes differ from what the flash holds (the line was programmed
    /// or erased since it was cached: the read returned the old contents).
    pub stale_wrong: u64,
    /// Double ECC errors raised.
    pub ecc_errors: u64,
    /// Refused sequences and writes outside the store (for the fault report).
    pub errors: Vec<String>,
    /// A power cut tore an operation: the board loses power.
    pub power_lost: bool,
    /// Injected: the next read of a double word in this range fails with a double ECC error.
    pub ecc_inject: Option<std::ops::Range<u32>>,
}

impl Default for FlashCtl {
    fn default() -> Self {
        Self {
            acr: 0x600, // ICEN, DCEN, 0 wait states
            sr: 0,
            cr: 0xC000_0000,
            eccr: 0,
            key_step: 0,
            first_word: None,
            busy: None,
            cache: vec![],
            ops: 0,
            stale_reads: 0,
            stale_wrong: 0,
            ecc_errors: 0,
            errors: vec![],
            power_lost: false,
            ecc_inject: None,
        }
    }
}

/// What a register access asks of the board besides the value.
#[derive(Default)]
pub struct Effects {
    /// Raise the NMI (double ECC error).
    pub nmi: bool,
}

impl FlashCtl {
    /// After a system reset (the cache is cleared; the store keeps its contents).
    pub fn reset() -> Self {
        Self::default()
    }

    /// The next data read of a double word in `range` fails with a double ECC error.
    pub fn inject_ecc(&mut self, range: std::ops::Range<u32>) {
        self.ecc_inject = Some(range);
    }

    /// A read of `addr` (anywhere in the flash) with an injected ECC error pending for it:
    /// ECCR records it (ADDR is the double word's offset in its bank, BK_ECC its bank, ECCD,
    /// RM0351 §3.7.7) and the caller raises the NMI. True when it was the injected one.
    pub fn take_injected_ecc(&mut self, addr: u32) -> bool {
        if !self.ecc_inject.as_ref().is_some_and(|r| r.contains(&addr)) {
            return false;
        }
        self.ecc_inject = None;
        self.record_ecc(addr & !7);
        true
    }

    fn record_ecc(&mut self, a: u32) {
        let (bank2, off) = if a >= BANK2 {
            (1 << 19, a - BANK2)
        } else {
            (0, a - BASE)
        };
        self.eccr = (self.eccr & (1 << 24)) | (1 << 31) | bank2 | (off & 0x7_FFFF);
        self.ecc_errors += 1;
    }

    /// Wait states programmed.
    pub fn latency(&self) -> u32 {
        self.acr & 7
    }

    /// Complete the operation in progress if its time has come.
    pub fn finish(&mut self, now_ps: u64) {
        if let Some(b) = self.busy {
            if now_ps >= b.until_ps {
                self.busy = None;
                self.sr |= 1; // EOP (RM0351 §3.7.5: set when EOPIE is set; harmless)
            }
        }
    }

    /// When the controller becomes idle, ps (to wake a board that waits for it).
    pub fn busy_until(&self) -> Option<u64> {
        self.busy.map(|b| b.until_ps)
    }

    /// Read a controller register.
    pub fn read(&mut self, off: u32, now_ps: u64) -> u32 {
        self.finish(now_ps);
        match off {
            0x00 => self.acr,
            0x10 => self.sr | if self.busy.is_some() { 1 << 16 } else { 0 },
            0x14 => self.cr,
            0x18 => self.eccr,
            0x20 => 0xFFEF_F8AA, // OPTR: DUALBANK, RDP level 0 (§3.7.8 reset value)
            _ => 0,
        }
    }

    /// Write a controller register.
    pub fn write(&mut self, off: u32, v: u32, now_ps: u64, store: &mut StoreFlash) {
        self.finish(now_ps);
        match off {
            0x00 => {
                if v & (1 << 12) != 0 {
                    // DCRST: "can be written only when the data cache is disabled" (§3.7.1)
                    if v & (1 << 10) == 0 {
                        self.cache.clear();
                    } else {
                        self.errors
                            .push("DCRST written with DCEN set (RM0351 §3.7.1)".into());
                    }
                }
                self.acr = v & !(1 << 11 | 1 << 12);
            }
            0x08 => {
                self.key_step = match (self.key_step, v) {
                    (0, 0x4567_0123) => 1,
                    (1, 0xCDEF_89AB) => {
                        self.cr &= !(1 << 31);
                        0
                    }
                    _ => {
                        // a wrong key locks the controller until the next reset (§3.3.5)
                        self.errors
                            .push(format!("wrong FLASH_KEYR value {v:#010x}"));
                        0
                    }
                };
            }
            0x10 => {
                // write 1 to clear (§3.7.5)
                self.sr &= !(v & 0xC3FB);
            }
            0x14 => {
                if self.cr & (1 << 31) != 0 {
                    return; // locked: writes ignored
                }
                self.cr = v;
                if v & (1 << 16) != 0 && v & 2 != 0 {
                    self.start_erase(now_ps, store);
                }
            }
            0x18 => {
                // ECCC/ECCD are write-1-to-clear; ECCCIE writable
                let mut e = self.eccr & !(v & (3 << 30));
                e = (e & !(1 << 24)) | (v & (1 << 24));
                self.eccr = e;
            }
            _ => {}
        }
    }

    fn start_erase(&mut self, now_ps: u64, store: &mut StoreFlash) {
        if self.busy.is_some() {
            self.sr |= 1 << 7; // PGSERR
            return;
        }
        let page = (self.cr >> 3) & 0xFF;
        let bank2 = self.cr & (1 << 11) != 0;
        let addr = if bank2 { BANK2 } else { BASE } + page * PAGE as u32;
        if !(STORE_BASE..STORE_BASE + STORE_SIZE as u32).contains(&addr) {
            self.errors.push(format!(
                "page erase of {addr:#010x}, outside the store (the firmware erased its own code)"
            ));
            self.sr |= 1 << 4; // WRPERR
            return;
        }
        self.cache_on_write();
        self.ops += 1;
        match store.erase_now(addr - STORE_BASE) {
            Ok(()) => {}
            Err(FlashError::PowerLost) => self.power_lost = true,
            Err(_) => self.sr |= 1 << 1,
        }
        self.busy = Some(Busy {
            until_ps: now_ps + u64::from(ERASE_PAGE_US) * 1_000_000,
        });
    }

    /// A data cache left on across a bank-2 program or erase goes stale (ES0250).
    fn cache_on_write(&mut self) {
        if self.acr & (1 << 10) != 0 {
            for l in &mut self.cache {
                l.2 = true;
            }
        }
    }

    /// A word written into the flash address space (programming).
    pub fn program_word(&mut self, addr: u32, v: u32, now_ps: u64, store: &mut StoreFlash) {
        self.finish(now_ps);
        if self.cr & 1 == 0 || self.cr & (1 << 31) != 0 {
            self.errors.push(format!(
                "write to flash {addr:#010x} without PG set (a wild write)"
            ));
            self.sr |= 1 << 7; // PGSERR
            return;
        }
        if self.busy.is_some() {
            self.sr |= 1 << 7;
            return;
        }
        match self.first_word.take() {
            None => {
                if !addr.is_multiple_of(8) {
                    self.sr |= 1 << 5; // PGAERR
                    return;
                }
                self.first_word = Some((addr, v));
            }
            Some((a0, w0)) => {
                if addr != a0 + 4 {
                    self.sr |= 1 << 5;
                    return;
                }
                if !(STORE_BASE..STORE_BASE + STORE_SIZE as u32).contains(&a0) {
                    self.errors
                        .push(format!("programming {a0:#010x}, outside the store"));
                    self.sr |= 1 << 4;
                    return;
                }
                let mut d = [0u8; DWORD];
                d[..4].copy_from_slice(&w0.to_le_bytes());
                d[4..].copy_from_slice(&v.to_le_bytes());
                self.cache_on_write();
                self.ops += 1;
                match store.program_now(a0 - STORE_BASE, d) {
                    Ok(()) => {}
                    Err(FlashError::NotErased) => self.sr |= 1 << 3, // PROGERR
                    Err(FlashError::PowerLost) => self.power_lost = true,
                    Err(_) => self.sr |= 1 << 1,
                }
                self.busy = Some(Busy {
                    until_ps: now_ps + u64::from(PROGRAM_DWORD_US) * 1_000_000,
                });
            }
        }
    }

    /// A data read of the store (`size` bytes at `addr`): through the data cache when DCEN is
    /// set; a torn double word raises the ECC error.
    pub fn read_store(&mut self, addr: u32, size: usize, store: &mut StoreFlash) -> (u64, Effects) {
        let mut fx = Effects::default();
        let line = addr & !(LINE - 1);
        let dcen = self.acr & (1 << 10) != 0;
        let cached = self.cache.iter().find(|l| l.0 == line).copied();
        let (bytes, torn) = match (dcen, cached) {
            (true, Some((_, data, stale, torn))) => {
                if stale {
                    self.stale_reads += 1;
                    let o = (addr - line) as usize;
                    let k = o / DWORD;
                    let now = store.read_dword(line + (k * DWORD) as u32 - STORE_BASE);
                    let _ = store.take_ecc_error();
                    if data[k * DWORD..(k + 1) * DWORD] != now {
                        self.stale_wrong += 1;
                    }
                }
                (data, torn)
            }
            _ => {
                let mut data = [0u8; LINE as usize];
                let mut torn = 0u8;
                for k in 0..(LINE as usize / DWORD) {
                    let a = line + (k * DWORD) as u32;
                    let _ = store.take_ecc_error();
                    let d = store.read_dword(a - STORE_BASE);
                    if store.take_ecc_error() {
                        torn |= 1 << k;
                    }
                    data[k * DWORD..(k + 1) * DWORD].copy_from_slice(&d);
                }
                if dcen {
                    if self.cache.len() == LINES {
                        self.cache.remove(0);
                    }
                    self.cache.push((line, data, false, torn));
                }
                (data, torn)
            }
        };
        // only the double word actually read reports (§3.3.4), also from a cached line
        let k = (addr - line) as usize / DWORD;
        let a = line + (k * DWORD) as u32;
        if torn & (1 << k) != 0 {
            self.record_ecc(a);
            fx.nmi = true;
        } else if self.take_injected_ecc(a) {
            fx.nmi = true;
        }
        let o = (addr - line) as usize;
        let mut v = 0u64;
        for i in 0..size {
            v |= u64::from(bytes[o + i]) << (8 * i);
        }
        (v, fx)
    }
}
