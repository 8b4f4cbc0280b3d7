//! STM32L4 internal flash as [`embedded_storage_async`] NOR flash, with the rules that matter
//! for power loss, and a simulation of those rules.
//!
//! The rules (RM0351 §3.3 "FLASH"):
//! - **64-bit double words with ECC** (§3.3.4, §3.3.7): programming writes 8 bytes and 8 ECC
//!   bits together; a double word can be programmed once between erases (programming a
//!   non-erased double word sets PROGERR), except with all zeros.
//! - **A torn double word is an ECC error** (§3.3.4): power lost while a double word is
//!   programmed (or a page erased) leaves data and ECC inconsistent; reading it with two bit
//!   errors sets FLASH_ECCR.ECCD and raises a **non-maskable interrupt**. cortex-m-rt's default
//!   NMI handler loops forever: every boot that reads the torn word would hang. The firmware's
//!   NMI handler clears ECCD and flags the error ([`RawFlash::take_ecc_error`]); [`L4Nor`]
//!   checks the flag after every double word it reads and hands the storage layer zeros for
//!   that double word, which no CRC accepts — the record is ignored, the boot goes on.
//! - **Page erase** (§3.3.6): 2 KiB pages; 22 ms typical, 24.5 ms maximum per page
//!   (STM32L475xx datasheet, Table "Flash memory characteristics", tERASE).
//! - **Read-while-write** (§3.3.1, "dual-bank"): the 1 MiB STM32L475VG has two 512 KiB banks;
//!   code runs from bank 1 while bank 2 is erased or programmed, so the executor keeps serving
//!   the command path while storage erases (the board polls BSY asynchronously).

use embedded_storage_async::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Physical page, bytes.
pub const PAGE: usize = 2048;
/// Programming unit, bytes.
pub const DWORD: usize = 8;
/// Page erase time used by the simulation, µs (typical, see the module docs).
pub const ERASE_PAGE_US: u32 = 22_020;
/// Double-word programming time, µs (datasheet tPROG, typical 81.7 µs).
pub const PROGRAM_DWORD_US: u32 = 82;

/// Flash operation failures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FlashError {
    /// Address or length not aligned to the operation's unit.
    Alignment,
    /// Outside the storage region.
    OutOfBounds,
    /// Programming a double word that is not erased (PROGERR).
    NotErased,
    /// The controller reported an error (PGSERR, WRPERR, …).
    Controller,
    /// The power went away in the middle of the operation (simulation).
    PowerLost,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::Alignment => NorFlashErrorKind::NotAligned,
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The flash controller as the storage needs it (the L4 registers on the board, [`L4Sim`] in
/// simulations). Offsets are relative to the storage region.
#[allow(async_fn_in_trait)]
pub trait RawFlash {
    /// Size of the storage region, bytes (a multiple of [`PAGE`]).
    fn capacity(&self) -> usize;
    /// Read one double word (may raise an ECC error, see [`RawFlash::take_ecc_error`]).
    fn read_dword(&mut self, offset: u32) -> [u8; DWORD];
    /// Whether a double-ECC error happened since the last call (and clear it).
    fn take_ecc_error(&mut self) -> bool;
    /// Erase one page.
    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError>;
    /// Program one double word.
    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError>;
}

/// NOR-flash view of the L4 flash: `ERASE` bytes per erase unit (a multiple of [`PAGE`], so that
/// the storage layer's items — a whole model blob — fit in one unit).
pub struct L4Nor<R, const ERASE: usize> {
    /// The controller.
    pub raw: R,
    /// Double words that failed ECC on read (handed over as zeros).
    pub ecc_errors: u32,
}

impl<R: RawFlash, const ERASE: usize> L4Nor<R, ERASE> {
    /// Wrap a controller.
    pub fn new(raw: R) -> Self {
        Self { raw, ecc_errors: 0 }
    }
}

/// Flash that counts the double words it handed over as corrupt (double ECC errors: torn by a
/// power cut), for the status.
pub trait EccErrors {
    /// Double words that failed ECC on read since start-up.
    fn ecc_errors(&self) -> u32;
}

impl<R, const ERASE: usize> EccErrors for L4Nor<R, ERASE> {
    fn ecc_errors(&self) -> u32 {
        self.ecc_errors
    }
}

impl<R, const ERASE: usize> ErrorType for L4Nor<R, ERASE> {
    type Error = FlashError;
}

impl<R: RawFlash, const ERASE: usize> ReadNorFlash for L4Nor<R, ERASE> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let end = offset as usize + bytes.len();
        if end > self.raw.capacity() {
            return Err(FlashError::OutOfBounds);
        }
        let mut at = offset as usize;
        while at < end {
            let base = at / DWORD * DWORD;
            let _ = self.raw.take_ecc_error();
            let mut d = self.raw.read_dword(base as u32);
            if self.raw.take_ecc_error() {
                self.ecc_errors = self.ecc_errors.wrapping_add(1);
                d = [0; DWORD];
            }
            let from = at - base;
            let n = (DWORD - from).min(end - at);
            let o = at - offset as usize;
            bytes[o..o + n].copy_from_slice(&d[from..from + n]);
            at += n;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.raw.capacity()
    }
}

impl<R: RawFlash, const ERASE: usize> NorFlash for L4Nor<R, ERASE> {
    const WRITE_SIZE: usize = DWORD;
    const ERASE_SIZE: usize = ERASE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if !(from as usize).is_multiple_of(ERASE)
            || !(to as usize).is_multiple_of(ERASE)
            || from > to
        {
            return Err(FlashError::Alignment);
        }
        if to as usize > self.raw.capacity() {
            return Err(FlashError::OutOfBounds);
        }
        let mut p = from;
        while p < to {
            self.raw.erase_page(p).await?;
            p += PAGE as u32;
        }
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        if !(offset as usize).is_multiple_of(DWORD) || !bytes.len().is_multiple_of(DWORD) {
            return Err(FlashError::Alignment);
        }
        if offset as usize + bytes.len() > self.raw.capacity() {
            return Err(FlashError::OutOfBounds);
        }
        for (i, c) in bytes.chunks_exact(DWORD).enumerate() {
            let mut d = [0u8; DWORD];
            d.copy_from_slice(c);
            self.raw
                .program_dword(offset + (i * DWORD) as u32, d)
                .await?;
        }
        Ok(())
    }
}

/// State of a simulated double word.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cell {
    Erased,
    Programmed,
    /// Data and ECC inconsistent: reading raises a double-ECC error.
    Torn,
}

/// Simulated L4 flash region of `SIZE` bytes with the rules of the module docs: double-word
/// programming once between erases (zeros excepted), ECC errors on torn double words, erase
/// and programming time, and a power cut after a given number of operations.
pub struct L4Sim<const SIZE: usize> {
    data: [u8; SIZE],
    cells: [[Cell; PAGE / DWORD]; 64],
    ecc: bool,
    /// Operations (double-word programs, page erases) left before the power fails: the
    /// operation that finds 0 here is torn and every later one fails. `None`: no cut.
    pub ops_until_cut: Option<u32>,
    /// Operations performed since power-on.
    pub ops: u32,
    /// Time the controller was busy, µs (erase and program times).
    pub busy_us: u64,
    /// Page erases per page (wear).
    pub erases: [u32; 64],
    powered: bool,
    seed: u32,
}

impl<const SIZE: usize> Default for L4Sim<SIZE> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const SIZE: usize> L4Sim<SIZE> {
    const PAGES: usize = SIZE / PAGE;

    /// A fully erased region (`SIZE`: a multiple of [`PAGE`], at most 64 pages).
    pub const fn new() -> Self {
        assert!(SIZE.is_multiple_of(PAGE) && SIZE / PAGE <= 64);
        Self {
            data: [0xFF; SIZE],
            cells: [[Cell::Erased; PAGE / DWORD]; 64],
            ecc: false,
            ops_until_cut: None,
            ops: 0,
            busy_us: 0,
            erases: [0; 64],
            powered: true,
            seed: 0x1234_5678,
        }
    }

    /// A copy of this flash (state, wear and all).
    pub fn clone_sim(&self) -> Self {
        Self {
            data: self.data,
            cells: self.cells,
            ecc: self.ecc,
            ops_until_cut: self.ops_until_cut,
            ops: self.ops,
            busy_us: self.busy_us,
            erases: self.erases,
            powered: self.powered,
            seed: self.seed,
        }
    }

    /// Power comes back (after a cut): the controller works again; torn words stay torn.
    pub fn power_on(&mut self) {
        self.powered = true;
        self.ops_until_cut = None;
        self.ops = 0;
        self.ecc = false;
    }

    /// Double words that read with an ECC error.
    pub fn torn_dwords(&self) -> usize {
        self.cells[..Self::PAGES]
            .iter()
            .flatten()
            .filter(|c| **c == Cell::Torn)
            .count()
    }

    fn noise(&mut self) -> u8 {
        self.seed ^= self.seed << 13;
        self.seed ^= self.seed >> 17;
        self.seed ^= self.seed << 5;
        self.seed as u8
    }

    /// Count one operation; `Err` when the power is (or just went) out, `Ok(true)` when this
    /// operation is the one the cut tears.
    fn step(&mut self) -> Result<bool, FlashError> {
        if !self.powered {
            return Err(FlashError::PowerLost);
        }
        self.ops += 1;
        match &mut self.ops_until_cut {
            Some(0) => {
                self.powered = false;
                Ok(true)
            }
            Some(n) => {
                *n -= 1;
                Ok(false)
            }
            None => Ok(false),
        }
    }

    fn cell(&mut self, offset: u32) -> &mut Cell {
        let o = offset as usize;
        &mut self.cells[o / PAGE][(o % PAGE) / DWORD]
    }

    /// Synchronous page erase (see [`RawFlash::erase_page`]).
    pub fn erase_now(&mut self, offset: u32) -> Result<(), FlashError> {
        let o = offset as usize;
        if !o.is_multiple_of(PAGE) {
            return Err(FlashError::Alignment);
        }
        if o >= SIZE {
            return Err(FlashError::OutOfBounds);
        }
        let torn = self.step()?;
        let page = o / PAGE;
        self.erases[page] += 1;
        self.busy_us += u64::from(ERASE_PAGE_US);
        if torn {
            // an interrupted erase leaves a page of undefined cells: some erased, some not,
            // the rest with broken ECC
            for w in 0..PAGE / DWORD {
                let r = self.noise();
                self.cells[page][w] = match r % 3 {
                    0 => Cell::Erased,
                    1 => Cell::Programmed,
                    _ => Cell::Torn,
                };
                if self.cells[page][w] == Cell::Erased {
                    self.data[o + w * DWORD..o + (w + 1) * DWORD].fill(0xFF);
                }
            }
            return Err(FlashError::PowerLost);
        }
        self.data[o..o + PAGE].fill(0xFF);
        self.cells[page] = [Cell::Erased; PAGE / DWORD];
        Ok(())
    }

    /// Synchronous double-word programming (see [`RawFlash::program_dword`]).
    pub fn program_now(&mut self, offset: u32, d: [u8; DWORD]) -> Result<(), FlashError> {
        let o = offset as usize;
        if !o.is_multiple_of(DWORD) {
            return Err(FlashError::Alignment);
        }
        if o + DWORD > SIZE {
            return Err(FlashError::OutOfBounds);
        }
        let zeros = d == [0; DWORD];
        if *self.cell(offset) != Cell::Erased && !zeros {
            return Err(FlashError::NotErased);
        }
        let torn = self.step()?;
        self.busy_us += u64::from(PROGRAM_DWORD_US);
        if torn {
            for b in &mut self.data[o..o + DWORD] {
                *b &= self.seed as u8 | 0x0F;
            }
            let _ = self.noise();
            *self.cell(offset) = Cell::Torn;
            return Err(FlashError::PowerLost);
        }
        self.data[o..o + DWORD].copy_from_slice(&d);
        *self.cell(offset) = Cell::Programmed;
        Ok(())
    }
}

impl<const SIZE: usize> RawFlash for L4Sim<SIZE> {
    fn capacity(&self) -> usize {
        SIZE
    }
    fn read_dword(&mut self, offset: u32) -> [u8; DWORD] {
        let o = offset as usize;
        if *self.cell(offset) == Cell::Torn {
            self.ecc = true;
        }
        let mut d = [0u8; DWORD];
        d.copy_from_slice(&self.data[o..o + DWORD]);
        d
    }
    fn take_ecc_error(&mut self) -> bool {
        core::mem::take(&mut self.ecc)
    }
    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError> {
        self.erase_now(offset)
    }
    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError> {
        self.program_now(offset, data)
    }
}

impl<T: RawFlash + ?Sized> RawFlash for &mut T {
    fn capacity(&self) -> usize {
        (**self).capacity()
    }
    fn read_dword(&mut self, offset: u32) -> [u8; DWORD] {
        (**self).read_dword(offset)
    }
    fn take_ecc_error(&mut self) -> bool {
        (**self).take_ecc_error()
    }
    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError> {
        (**self).erase_page(offset).await
    }
    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError> {
        (**self).program_dword(offset, data).await
    }
}
