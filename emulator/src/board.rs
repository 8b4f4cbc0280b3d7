//! The B-L475E-IOT01A: the STM32L475VG's Cortex-M4F core on Unicorn, its memory map, its
//! peripherals ([`crate::chip`]), resets (power-on, software, watchdog, power cut), and the clock
//! the board lives on.
//!
//! **Time** ([`crate::clock`]). The core runs one instruction per HCLK cycle; board time advances
//! by the cycles run (a busy loop takes board time, so a spin on a flag that never sets starves
//! the watchdog after 2 s of board time, as on the chip). While the core sleeps (WFE/WFI) board
//! time jumps to the next event of a peripheral or SysTick. It never passes the horizon the
//! driver sets, and never looks at the wall clock: a loaded machine runs the same board, slower.
//!
//! **Exceptions** (ARM DDI 0403E §B1.5.6 "Exception entry behavior", §B1.5.8 "Exception return
//! behavior"): at an instruction boundary the highest-priority pending exception that beats the
//! execution priority (active exceptions, PRIMASK, BASEPRI) is entered: the eight-word frame
//! (R0–R3, R12, LR, return address, xPSR with bit 9 for the alignment pad) is pushed on MSP, LR
//! gets EXC_RETURN, PC the vector. The FP caller-saved registers (S0–S15, FPSCR) are saved and
//! restored by the model on the side (the lazy-stacking area is not reserved on the stack). The
//! core stays in thread mode for Unicorn, so `bx lr` to EXC_RETURN is a branch to 0xFFFF_FFFx,
//! whose fetch faults; that fault is the exception return.

use crate::chip::{Chip, Halt};
use crate::clock::Clock;
use crate::elf::Image;
use crate::flash::{StoreFlash, STORE_BASE, STORE_SIZE};
use crate::io::Io;
use crate::nvic::exc;
use crate::rcc::{csr, Rcc};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use unicorn_engine::unicorn_const::{uc_error, Arch, Mode, Prot};
use unicorn_engine::{ArmCpuModel, HookType, RegisterARM, Unicorn};

use crate::clock::PS;
/// Instructions per slice: interrupts are taken and peripherals move between slices (≈ 25 µs
/// at 80 MHz).
const SLICE: u64 = 2_000;

/// The chip's 96-bit unique ID (RM0351 §47.1) of the emulated board.
pub const UID: [u8; 12] = *b"nanocal-emu1";

/// Why the board is in its current boot (what RCC_CSR said).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetKind {
    /// Power applied (or restored after a cut).
    PowerOn,
    /// AIRCR.SYSRESETREQ.
    Software,
    /// The IWDG expired.
    Watchdog,
}

/// What the board has done, for the tests.
#[derive(Clone, Debug, Default)]
pub struct Status {
    /// Boots so far, with why each started.
    pub boots: Vec<ResetKindRecord>,
    /// Board time, s.
    pub now_s: f64,
    /// Instructions executed since the board was created.
    pub instructions: u64,
    /// The board stopped: why.
    pub halt: Option<String>,
    /// LD2 (PB14) lit.
    pub led: bool,
    /// Times LD2 was switched on in the current boot.
    pub led_rises: u64,
    /// Registers accessed that no model covers.
    pub unmodelled: Vec<u32>,
    /// Double ECC errors the flash raised since the board was created.
    pub ecc_errors: u64,
    /// Reads that returned stale data from the flash data cache (ES0250), since creation.
    pub stale_cache_reads: u64,
    /// Of those, reads whose bytes differ from what the flash holds (a line programmed since
    /// it was cached), since creation.
    pub stale_cache_wrong: u64,
    /// Stage-link bytes lost to UART overruns, since creation.
    pub uart_overruns: u64,
    /// Flash operations (programs, erases) on the store since power-on.
    pub flash_ops: u64,
    /// Times a chip-select went low while another was still low (two chips on the bus).
    pub cs_conflicts: u64,
    /// UART4's baud rate in force (from BRR and its clock).
    pub stage_baud: u64,
    /// The longest stretch the core ran without sleeping (WFI/WFE) since the board was
    /// created or [`Inject::reset_busy_record`], s: how long the executor was blocked at most.
    pub longest_busy_s: f64,
    /// The longest the IWDG counted without a reload in the current boot (from its start or a
    /// reload to the next reload, or to now), s; 0 before it is started.
    pub longest_watchdog_wait_s: f64,
    /// The IWDG's timeout as programmed (PR, RLR at the LSI's 32 kHz), s.
    pub watchdog_timeout_s: f64,
    /// The PC where the core last was, with its function.
    pub pc: String,
    /// Notable events (faults taken, resets), oldest first (the last 100).
    pub log: Vec<String>,
}

/// One boot: why, and when (board time since the board was created, s).
#[derive(Clone, Debug)]
pub struct ResetKindRecord {
    /// Why.
    pub kind: ResetKind,
    /// When, s.
    pub at_s: f64,
}

/// Handles shared with the tests while the board runs.
#[derive(Clone)]
pub struct Control {
    /// Ask the board to stop.
    pub stop: Arc<AtomicBool>,
    /// What the board has done.
    pub status: Arc<Mutex<Status>>,
    /// Cut the power when the store's flash has done this many more operations (the one that
    /// finds 0 is torn), then power on again.
    pub cut_after_ops: Arc<Mutex<Option<u32>>>,
    /// Power the board off and on again now, with this store flash in it (a test's fixed
    /// starting point, on a board whose emulator is warm).
    pub power_cycle_with: Arc<Mutex<Option<Box<StoreFlash>>>>,
    /// The board's clock: the horizon it runs to, where it paused.
    pub clock: Arc<Clock>,
    /// Faults to inject, taken by the board at its next step.
    pub inject: Arc<Mutex<Inject>>,
}

/// Faults a test injects into the board (each taken once).
#[derive(Clone, Debug, Default)]
pub struct Inject {
    /// Lose a byte UART4 receives to an overrun, as if the CPU had been too slow to read it:
    /// the byte this many bytes from now (0: the next).
    pub uart_lose_byte: Option<u32>,
    /// The next data read of a flash double word in this address range (bank 1 or 2) fails
    /// with a double ECC error (ECCR.ECCD and the NMI, RM0351 §3.3.4).
    pub ecc_in: Option<std::ops::Range<u32>>,
    /// SPI1 stops shifting (SCK held) until the next reset: a transfer in progress never ends.
    pub spi_stall: bool,
    /// UART4's transmitter stops (TXE/TC never set again) until the next reset.
    pub uart_tx_stall: bool,
    /// Start [`Status::longest_busy_s`] afresh.
    pub reset_busy_record: bool,
    /// Call the function at this address with these four arguments (R0–R3) from thread mode
    /// at the next instruction boundary outside an exception — as if the code running had
    /// called it (e.g. `core::panicking::panic_bounds_check`, to exercise the panic path).
    pub call: Option<(u32, [u32; 4])>,
}

impl Default for Control {
    fn default() -> Self {
        Self {
            stop: Arc::new(AtomicBool::new(false)),
            status: Arc::new(Mutex::new(Status::default())),
            cut_after_ops: Arc::new(Mutex::new(None)),
            power_cycle_with: Arc::new(Mutex::new(None)),
            clock: Arc::new(Clock::default()),
            inject: Arc::new(Mutex::new(Inject::default())),
        }
    }
}

/// A saved exception context (the FP registers the model keeps aside).
struct Frame {
    exc_return: u32,
    fp: [u64; 8],
    fpscr: u64,
}

/// What stopped a slice early.
#[derive(Clone, Copy, PartialEq)]
enum Hint {
    Wfe,
    Wfi,
    Sev,
}

/// Unicorn's data: the chip plus the slice bookkeeping the hooks share.
pub struct Cpu {
    /// The chip.
    pub chip: Chip,
    executed: u64,
    limit: u64,
    hint: Option<(Hint, u32)>,
}

/// The board.
pub struct Board<'a> {
    uc: Unicorn<'a, Cpu>,
    image: Image,
    frames: Vec<Frame>,
    sleeping: Option<Hint>,
    control: Control,
    /// Instructions executed since the board was created.
    instructions: u64,
    boots: Vec<ResetKindRecord>,
    /// The read watch of an injected ECC error in bank 1.
    ecc_hook: Option<unicorn_engine::UcHookId>,
    /// A call injected, waiting for thread mode.
    pending_call: Option<(u32, [u32; 4])>,
    /// When the core last woke (or the record started), ps.
    awake_since: u64,
    /// The longest stretch awake, ps.
    longest_busy_ps: u64,
}

/// Board set-up failures.
#[derive(Debug)]
#[non_exhaustive]
pub enum BoardError {
    /// The ELF file does not parse.
    Elf(crate::elf::ElfError),
    /// A segment lies outside the flash.
    Segment(u32),
    /// Unicorn refused.
    Unicorn(uc_error),
}

impl std::fmt::Display for BoardError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BoardError::Elf(e) => write!(f, "firmware image: {e}"),
            BoardError::Segment(a) => write!(f, "firmware segment at {a:#010x} outside flash"),
            BoardError::Unicorn(e) => write!(f, "unicorn: {e}"),
        }
    }
}

impl std::error::Error for BoardError {}

impl From<uc_error> for BoardError {
    fn from(e: uc_error) -> Self {
        BoardError::Unicorn(e)
    }
}

fn map_periph(uc: &mut Unicorn<'_, Cpu>, base: u64, size: u64) -> Result<(), uc_error> {
    uc.mmio_map(
        base,
        size,
        Some(move |uc: &mut Unicorn<'_, Cpu>, off: u64, size: usize| {
            let cpu = uc.get_data_mut();
            let v = cpu.chip.read((base + off) as u32, size);
            if cpu.chip.stop_slice {
                cpu.limit = cpu.executed;
            }
            u64::from(v)
        }),
        Some(
            move |uc: &mut Unicorn<'_, Cpu>, off: u64, size: usize, v: u64| {
                let cpu = uc.get_data_mut();
                cpu.chip.write((base + off) as u32, size, v as u32);
                // a write may raise an interrupt (or fault): end the slice so it is taken now
                cpu.chip.update();
                cpu.limit = cpu.executed;
            },
        ),
    )
}

/// Thumb-2 instructions in `size` bytes from `addr` (a halfword 0b11101…, 0b11110…, 0b11111…
/// starts a 32-bit instruction, ARM DDI 0403E §A5.1).
fn count_instructions(code: &[(u32, Vec<u8>)], addr: u32, size: u32) -> u64 {
    let Some((base, bytes)) = code
        .iter()
        .find(|(b, v)| *b <= addr && addr + size <= b + v.len() as u32)
    else {
        return u64::from(size.div_ceil(2)).max(1);
    };
    let mut off = (addr - base) as usize;
    let end = off + size as usize;
    let mut n = 0;
    while off < end {
        let h = u16::from_le_bytes([bytes[off], bytes[off + 1]]);
        off += if h >> 11 >= 0b11101 { 4 } else { 2 };
        n += 1;
    }
    n.max(1)
}

impl<'a> Board<'a> {
    /// A board with `elf` in its flash, the store's flash `store` (erased: `None`), and `io`
    /// around it; powered on.
    pub fn new(
        elf: &[u8],
        store: Option<Box<StoreFlash>>,
        io: Io,
        control: Control,
    ) -> Result<Self, BoardError> {
        let image = Image::parse(elf).map_err(BoardError::Elf)?;
        let store = store.unwrap_or_else(|| Box::new(StoreFlash::new()));
        let cpu = Cpu {
            chip: Chip::power_on(store, io),
            executed: 0,
            limit: SLICE,
            hint: None,
        };
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB, cpu)?;
        uc.ctl_set_cpu_model(ArmCpuModel::CORTEX_M4 as i32)?;
        // memory map (RM0351 §2.2.2): flash bank 1 and bank 2 below the store as ROM, the store
        // through the flash controller, SRAM1/SRAM2, system memory, peripherals, the PPB
        let code_len = u64::from(STORE_BASE - crate::flash::BASE);
        uc.mem_map(0x0800_0000, code_len, Prot::READ | Prot::EXEC)?;
        uc.mmio_map(
            u64::from(STORE_BASE),
            STORE_SIZE as u64,
            Some(|uc: &mut Unicorn<'_, Cpu>, off: u64, size: usize| {
                let cpu = uc.get_data_mut();
                let chip = &mut cpu.chip;
                let (v, fx) = chip
                    .flash
                    .read_store(STORE_BASE + off as u32, size, &mut chip.store);
                if fx.nmi {
                    // the flash interface signals the ECC error after the read completes: the
                    // core takes the NMI at the end of the translation block holding the read
                    // (the firmware's DSB+ISB after a store read ends the block, as the
                    // barrier makes it precise on the chip; the slice limit is counted in
                    // whole blocks, so "two instructions on" was the block after next)
                    chip.nvic.pending[exc::NMI] = true;
                    cpu.limit = cpu.executed;
                }
                v
            }),
            Some(|uc: &mut Unicorn<'_, Cpu>, off: u64, size: usize, v: u64| {
                let cpu = uc.get_data_mut();
                let chip = &mut cpu.chip;
                if size != 4 {
                    chip.fault(format!(
                        "{size}-byte write to flash {:#010x}: programming takes 32-bit words (RM0351 §3.3.7)",
                        STORE_BASE + off as u32
                    ));
                } else {
                    let now = chip.now_ps;
                    chip.flash
                        .program_word(STORE_BASE + off as u32, v as u32, now, &mut chip.store);
                    chip.check_clocks();
                }
                cpu.limit = cpu.executed;
            }),
        )?;
        // SRAM without EXEC: Unicorn treats every RAM page as holding code until told
        // otherwise, so stores to executable RAM take the slow path that invalidates
        // translations (the firmware runs from flash only; a jump into RAM stops the board)
        uc.mem_map(0x1000_0000, 32 * 1024, Prot::READ | Prot::WRITE)?;
        uc.mem_map(0x2000_0000, 96 * 1024, Prot::READ | Prot::WRITE)?;
        uc.mem_map(0x1FFF_0000, 0x8000, Prot::READ)?;
        for (base, size) in [
            (0x4000_0000u64, 0x3_0000u64),
            (0x4800_0000, 0x2000),
            (0x5000_0000, 0x6_1000),
        ] {
            map_periph(&mut uc, base, size)?;
        }
        uc.mmio_map(
            0xE000_0000,
            0x10_0000,
            Some(|uc: &mut Unicorn<'_, Cpu>, off: u64, _size: usize| {
                let cpu = uc.get_data_mut();
                let cycles = cpu.chip.cycles + cpu.executed;
                u64::from(cpu.chip.nvic.read(0xE000_0000 + off as u32, cycles))
            }),
            Some(|uc: &mut Unicorn<'_, Cpu>, off: u64, size: usize, v: u64| {
                let cpu = uc.get_data_mut();
                let cycles = cpu.chip.cycles + cpu.executed;
                cpu.chip
                    .nvic
                    .write(0xE000_0000 + off as u32, size, v as u32, cycles);
                cpu.limit = cpu.executed;
            }),
        )?;
        for seg in &image.segments {
            let end = seg.paddr as u64 + seg.data.len() as u64;
            if seg.paddr < 0x0800_0000 || end > u64::from(STORE_BASE) {
                return Err(BoardError::Segment(seg.paddr));
            }
            uc.mem_write(u64::from(seg.paddr), &seg.data)?;
        }
        // system memory: UID (RM0351 §47.1), flash size in KiB (§47.2), package (§47.3)
        uc.mem_write(0x1FFF_7590, &UID)?;
        uc.mem_write(0x1FFF_75E0, &1024u16.to_le_bytes())?;
        uc.mem_write(0x1FFF_7500, &0x11u16.to_le_bytes())?; // LQFP100
                                                            // the instruction counter and the slice limit, per translation block: a block's
                                                            // instructions are counted when it starts (Thumb-2 lengths from the first halfword);
                                                            // a slice ends at the first block boundary past its limit
                                                            // (block size, instructions) by halfword of the code region: a lookup per block
        let mut lengths = vec![(0u32, 0u32); (code_len / 2) as usize];
        let code = image.code.clone();
        uc.add_block_hook(1, 0, move |uc: &mut Unicorn<'_, Cpu>, addr, size| {
            let cpu = uc.get_data_mut();
            if cpu.executed >= cpu.limit {
                let _ = uc.emu_stop();
                return;
            }
            let n = match lengths.get_mut(((addr as u32).wrapping_sub(0x0800_0000) / 2) as usize) {
                Some(e) if e.0 == size => u64::from(e.1),
                Some(e) => {
                    let n = count_instructions(&code, addr as u32, size);
                    *e = (size, n as u32);
                    n
                }
                None => count_instructions(&code, addr as u32, size),
            };
            cpu.executed += n;
        })?;
        for (op, hint) in [(2u16, Hint::Wfe), (3, Hint::Wfi), (4, Hint::Sev)] {
            for a in image.hints(op) {
                uc.add_code_hook(
                    u64::from(a),
                    u64::from(a),
                    move |uc: &mut Unicorn<'_, Cpu>, addr, _| {
                        uc.get_data_mut().hint = Some((hint, addr as u32));
                        let _ = uc.emu_stop();
                    },
                )?;
            }
        }
        let mut b = Self {
            uc,
            image,
            frames: vec![],
            sleeping: None,
            control,
            instructions: 0,
            ecc_hook: None,
            pending_call: None,
            awake_since: 0,
            longest_busy_ps: 0,
            boots: vec![],
        };
        b.boot(ResetKind::PowerOn)?;
        Ok(b)
    }

    fn chip(&mut self) -> &mut Chip {
        &mut self.uc.get_data_mut().chip
    }

    /// Start the core from the vector table (ARM DDI 0403E §B1.5.5 "Reset behavior").
    fn boot(&mut self, kind: ResetKind) -> Result<(), BoardError> {
        let mut w = [0u8; 8];
        self.uc.mem_read(0x0800_0000, &mut w)?;
        let sp = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        let pc = u32::from_le_bytes([w[4], w[5], w[6], w[7]]);
        for r in [
            RegisterARM::R0,
            RegisterARM::R1,
            RegisterARM::R2,
            RegisterARM::R3,
            RegisterARM::R4,
            RegisterARM::R5,
            RegisterARM::R6,
            RegisterARM::R7,
            RegisterARM::R8,
            RegisterARM::R9,
            RegisterARM::R10,
            RegisterARM::R11,
            RegisterARM::R12,
        ] {
            self.uc.reg_write(r, 0)?;
        }
        self.uc.reg_write(RegisterARM::PRIMASK, 0)?;
        self.uc.reg_write(RegisterARM::BASEPRI, 0)?;
        self.uc.reg_write(RegisterARM::CONTROL, 0)?;
        self.uc.reg_write(RegisterARM::MSP, u64::from(sp))?;
        self.uc.reg_write(RegisterARM::SP, u64::from(sp))?;
        self.uc.reg_write(RegisterARM::LR, 0xFFFF_FFFF)?;
        self.uc.reg_write(RegisterARM::PC, u64::from(pc | 1))?;
        self.frames.clear();
        if self.sleeping.take().is_some() {
            self.awake_since = self.uc.get_data().chip.now_ps;
        }
        let at_s = self.uc.get_data().chip.now_ps as f64 / PS as f64;
        self.boots.push(ResetKindRecord { kind, at_s });
        self.control.status.lock().unwrap().boots = self.boots.clone();
        Ok(())
    }

    /// A system reset: every register to its reset value except the backup domain and the
    /// CSR reset flags, which get `flag` (and PINRSTF: the reset drives NRST, RM0351 §6.1.2).
    fn system_reset(&mut self, kind: ResetKind) -> Result<(), BoardError> {
        let flag = match kind {
            ResetKind::PowerOn => csr::BORRSTF,
            ResetKind::Software => csr::SFTRSTF,
            ResetKind::Watchdog => csr::IWDGRSTF,
        };
        let old = std::mem::replace(
            self.chip(),
            Chip::power_on(
                Box::new(StoreFlash::new()),
                Io::new(
                    Arc::new(Mutex::new(crate::io::NoChips)),
                    None,
                    crate::usb::Host::placeholder(),
                ),
            ),
        );
        let (bdcr, csr_flags) = if kind == ResetKind::PowerOn {
            (0, 0)
        } else {
            (old.rcc.bdcr, old.rcc.csr & 0xFF00_0000)
        };
        let mut rcc = Rcc::system_reset(bdcr);
        if kind != ResetKind::PowerOn {
            rcc.bkp = old.rcc.bkp;
        }
        rcc.csr |= csr_flags | flag | csr::PINRSTF;
        let mut store = old.store;
        if kind == ResetKind::PowerOn {
            store.power_on();
        }
        let mut io = old.io;
        io.usb.bus_reset_by_device();
        let mut chip = Chip::with_rcc(rcc, store, io);
        chip.now_ps = old.now_ps;
        chip.cycles = old.cycles;
        // the board's tallies run over resets
        chip.flash.ecc_errors = old.flash.ecc_errors;
        chip.flash.stale_reads = old.flash.stale_reads;
        chip.flash.stale_wrong = old.flash.stale_wrong;
        chip.uart4.overruns = old.uart4.overruns;
        self.uc.get_data_mut().chip = chip;
        self.boot(kind)
    }

    fn reg(&self, r: RegisterARM) -> u32 {
        self.uc.reg_read(r).unwrap_or(0) as u32
    }

    fn set(&mut self, r: RegisterARM, v: u32) {
        let _ = self.uc.reg_write(r, u64::from(v));
    }

    /// IT-block state (CPSR bits 26:25, 15:10): exceptions are taken outside IT blocks only
    /// (the model cannot restore EPSR.IT through Unicorn).
    fn in_it_block(&self) -> bool {
        let cpsr = self.reg(RegisterARM::CPSR);
        cpsr & 0x0600_FC00 != 0
    }

    fn read_u32(&self, a: u32) -> u32 {
        let mut w = [0u8; 4];
        let _ = self.uc.mem_read(u64::from(a), &mut w);
        u32::from_le_bytes(w)
    }

    fn vector(&mut self, n: usize) -> u32 {
        let vtor = self.chip().nvic.vtor;
        let base = if vtor < 0x0010_0000 {
            0x0800_0000 + vtor
        } else {
            vtor
        };
        self.read_u32(base + 4 * n as u32)
    }

    /// Exception entry (ARM DDI 0403E §B1.5.6).
    fn enter(&mut self, n: usize) {
        let mut sp = self.reg(RegisterARM::SP);
        let pc = self.reg(RegisterARM::PC);
        let mut xpsr = (self.reg(RegisterARM::XPSR) & 0xF80F_0000) | (1 << 24);
        if let Some(&outer) = self.chip().nvic.active.last() {
            xpsr |= outer as u32;
        }
        if sp & 4 != 0 {
            sp -= 4;
            xpsr |= 1 << 9;
        }
        sp -= 32;
        let frame = [
            self.reg(RegisterARM::R0),
            self.reg(RegisterARM::R1),
            self.reg(RegisterARM::R2),
            self.reg(RegisterARM::R3),
            self.reg(RegisterARM::R12),
            self.reg(RegisterARM::LR),
            pc,
            xpsr,
        ];
        let bytes: Vec<u8> = frame.iter().flat_map(|w| w.to_le_bytes()).collect();
        if self.uc.mem_write(u64::from(sp), &bytes).is_err() {
            self.chip()
                .fault(format!("stack overflow: exception frame at {sp:#010x}"));
            return;
        }
        let mut fp = [0u64; 8];
        for (i, r) in [
            RegisterARM::D0,
            RegisterARM::D1,
            RegisterARM::D2,
            RegisterARM::D3,
            RegisterARM::D4,
            RegisterARM::D5,
            RegisterARM::D6,
            RegisterARM::D7,
        ]
        .into_iter()
        .enumerate()
        {
            fp[i] = self.uc.reg_read(r).unwrap_or(0);
        }
        let fpscr = self.uc.reg_read(RegisterARM::FPSCR).unwrap_or(0);
        let thread = self.chip().nvic.active.is_empty();
        let exc_return = if thread { 0xFFFF_FFF9 } else { 0xFFFF_FFF1 };
        self.frames.push(Frame {
            exc_return,
            fp,
            fpscr,
        });
        let vec = self.vector(n);
        let nv = &mut self.chip().nvic;
        nv.pending[n] = false;
        nv.active.push(n);
        nv.event = true;
        self.set(RegisterARM::SP, sp);
        self.set(RegisterARM::LR, exc_return);
        self.set(RegisterARM::PC, vec | 1);
    }

    /// Exception return to `exc_return` (ARM DDI 0403E §B1.5.8).
    fn exit(&mut self, exc_return: u32) {
        let Some(frame) = self.frames.pop() else {
            self.chip().fault(format!(
                "exception return to {exc_return:#010x} with no exception active"
            ));
            return;
        };
        if frame.exc_return | 0x10 != exc_return | 0x10 {
            self.chip().fault(format!(
                "exception return with {exc_return:#010x}, entered with {:#010x}",
                frame.exc_return
            ));
            return;
        }
        let sp = self.reg(RegisterARM::SP);
        let mut w = [0u8; 32];
        let _ = self.uc.mem_read(u64::from(sp), &mut w);
        let f: Vec<u32> = w
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        for (r, v) in [
            (RegisterARM::R0, f[0]),
            (RegisterARM::R1, f[1]),
            (RegisterARM::R2, f[2]),
            (RegisterARM::R3, f[3]),
            (RegisterARM::R12, f[4]),
            (RegisterARM::LR, f[5]),
        ] {
            self.set(r, v);
        }
        for (i, r) in [
            RegisterARM::D0,
            RegisterARM::D1,
            RegisterARM::D2,
            RegisterARM::D3,
            RegisterARM::D4,
            RegisterARM::D5,
            RegisterARM::D6,
            RegisterARM::D7,
        ]
        .into_iter()
        .enumerate()
        {
            let _ = self.uc.reg_write(r, frame.fp[i]);
        }
        let _ = self.uc.reg_write(RegisterARM::FPSCR, frame.fpscr);
        let xpsr = f[7];
        let _ = self.uc.reg_write(RegisterARM::XPSR_NZCVQG, u64::from(xpsr));
        let pad = if xpsr & (1 << 9) != 0 { 4 } else { 0 };
        self.set(RegisterARM::SP, sp + 32 + pad);
        self.set(RegisterARM::PC, f[6] | 1);
        let nv = &mut self.chip().nvic;
        nv.active.pop();
        nv.event = true;
    }

    fn advance(&mut self, instrs: u64, delta_ps: u64) {
        let chip = self.chip();
        let hclk = chip.rcc.clocks().hclk.max(1);
        let d = if instrs > 0 {
            instrs * PS / hclk
        } else {
            delta_ps
        };
        let cyc = if instrs > 0 {
            instrs
        } else {
            delta_ps * hclk / PS
        };
        let from = chip.cycles;
        chip.now_ps += d;
        chip.cycles += cyc;
        chip.io.now_s = chip.now_ps as f64 / PS as f64;
        chip.nvic.systick_advance(from, chip.cycles);
    }

    /// Move the peripherals the DMA serves (SPI1 on channels 2 and 3).
    fn service_dma(&mut self) {
        for _ in 0..64 {
            let chip = &mut self.uc.get_data_mut().chip;
            let (rx_req, tx_req) = chip.spi1.dma_requests();
            let mut moved = false;
            for (c, req) in [(1usize, rx_req), (2, tx_req)] {
                if !req || !chip.dma1.selects(c, 1) {
                    continue;
                }
                let Some(step) = chip.dma1.step(c) else {
                    continue;
                };
                let now = chip.now_ps;
                if step.to_periph {
                    let mut b = [0u8];
                    let _ = self.uc.mem_read(u64::from(step.mem), &mut b);
                    let chip = &mut self.uc.get_data_mut().chip;
                    let gpio = chip.gpio.clone();
                    chip.spi1.dma_write(b[0], now, &mut chip.io, &gpio);
                    chip.dma1.done_item(c);
                } else {
                    let b = chip.spi1.dma_read();
                    chip.dma1.done_item(c);
                    let _ = self.uc.mem_write(u64::from(step.mem), &[b]);
                }
                moved = true;
                break;
            }
            if !moved {
                break;
            }
        }
    }

    fn publish(&mut self) {
        let pc = self.reg(RegisterARM::PC);
        let name = self.image.name_of(pc);
        let instructions = self.instructions;
        let chip = &mut self.uc.get_data_mut().chip;
        let total = chip.now_ps;
        let led = chip.gpio[1].odr & (1 << 14) != 0 && (chip.gpio[1].moder >> 28) & 3 == 1;
        let mut st = self.control.status.lock().unwrap();
        st.now_s = total as f64 / PS as f64;
        st.instructions = instructions;
        st.led = led;
        st.led_rises = chip.led_rises;
        st.unmodelled = chip.unmodelled.iter().copied().collect();
        st.ecc_errors = chip.flash.ecc_errors;
        st.stale_cache_reads = chip.flash.stale_reads;
        st.stale_cache_wrong = chip.flash.stale_wrong;
        st.uart_overruns = chip.uart4.overruns;
        st.flash_ops = chip.flash.ops;
        st.cs_conflicts = chip.io.cs_conflicts;
        st.stage_baud = chip.uart4.baud;
        let awake = if self.sleeping.is_none() {
            total - self.awake_since.min(total)
        } else {
            0
        };
        st.longest_busy_s = self.longest_busy_ps.max(awake) as f64 / PS as f64;
        let chip = &self.uc.get_data().chip;
        st.longest_watchdog_wait_s = chip.iwdg.longest_wait_ps(total) as f64 / PS as f64;
        st.watchdog_timeout_s = chip.iwdg.timeout_ps() as f64 / PS as f64;
        st.pc = format!("{pc:#010x} {name}");
    }

    /// The core went to sleep: the stretch it was awake ends.
    fn note_sleep(&mut self) {
        let now = self.uc.get_data().chip.now_ps;
        self.longest_busy_ps = self.longest_busy_ps.max(now - self.awake_since.min(now));
    }

    /// Apply the faults a test asked for.
    fn take_injections(&mut self) {
        let inj = std::mem::take(&mut *self.control.inject.lock().unwrap());
        if inj.call.is_some() {
            self.pending_call = inj.call;
        }
        let chip = &mut self.uc.get_data_mut().chip;
        if let Some(k) = inj.uart_lose_byte {
            chip.io.uart_rx.lose_in = Some(k);
        }
        if inj.spi_stall {
            chip.spi1.stalled = true;
        }
        if inj.uart_tx_stall {
            chip.uart4.tx_stalled = true;
        }
        let now = chip.now_ps;
        if inj.reset_busy_record {
            self.longest_busy_ps = 0;
            self.awake_since = now;
        }
        if let Some(r) = inj.ecc_in {
            let in_code = (crate::flash::BASE..STORE_BASE).contains(&r.start);
            chip.flash.inject_ecc(r.clone());
            if in_code && self.ecc_hook.is_none() {
                // code and constants are plain ROM for Unicorn: watch data reads of the range
                // (instruction fetches are not modelled failing)
                self.ecc_hook = self
                    .uc
                    .add_mem_hook(
                        HookType::MEM_READ,
                        u64::from(r.start),
                        u64::from(r.end.max(r.start + 1) - 1),
                        |uc: &mut Unicorn<'_, Cpu>, _, addr, _, _| {
                            let cpu = uc.get_data_mut();
                            if cpu.chip.flash.take_injected_ecc(addr as u32) {
                                cpu.chip.nvic.pending[exc::NMI] = true;
                                cpu.limit = cpu.executed + 2;
                            }
                            true
                        },
                    )
                    .ok();
            }
        }
    }

    /// Pause at the horizon (publishing where the board is first); false when asked to stop.
    fn pause(&mut self, next_event_ps: Option<u64>) -> bool {
        self.publish();
        let now = self.chip().now_ps;
        let go_on = self.control.clock.clone().pause(now, next_event_ps);
        // what the clients did while the board was paused arrives now
        self.chip().io.poll_inputs();
        go_on
    }

    /// Run until stopped or halted.
    pub fn run(&mut self) -> Option<Halt> {
        let clock = self.control.clock.clone();
        let mut slices = 0u64;
        // sleeping steps in a row that found an event due but could not move time
        let mut stuck = 0u32;
        let result = loop {
            if self.control.stop.load(Ordering::Relaxed) {
                self.publish();
                break None;
            }
            let cut = self.control.cut_after_ops.lock().unwrap().take();
            if let Some(n) = cut {
                self.chip().store.ops_until_cut = Some(n);
            }
            self.take_injections();
            // resets
            let (sysreset, wdg, cut) = {
                let c = self.chip();
                (
                    c.nvic.reset_request,
                    c.iwdg.expired(c.now_ps),
                    c.flash.power_lost,
                )
            };
            let replaced = self.control.power_cycle_with.lock().unwrap().take();
            let cut = cut || replaced.is_some();
            if let Some(store) = replaced {
                *self.chip().store = *store;
            }
            let reset = if cut {
                Some(ResetKind::PowerOn)
            } else if wdg {
                Some(ResetKind::Watchdog)
            } else if sysreset {
                Some(ResetKind::Software)
            } else {
                None
            };
            if let Some(kind) = reset {
                self.log(format!("reset: {kind:?}"));
                if let Err(e) = self.system_reset(kind) {
                    break Some(Halt::Fault(format!("reset failed: {e}")));
                }
                continue;
            }
            if let Some(h) = self.chip().halt.clone() {
                self.publish();
                let pc = self.control.status.lock().unwrap().pc.clone();
                let Halt::Fault(why) = h;
                let h = Halt::Fault(format!("{why} (at {pc})"));
                self.control.status.lock().unwrap().halt = Some(format!("{h:?}"));
                break Some(h);
            }
            self.chip().update();
            self.service_dma();
            if self.chip().io.flush() {
                // a client got bytes: let whoever drives the board look at them at this time
                let now = self.chip().now_ps;
                clock.hold_at(now);
            }
            if self.pending_call.is_some()
                && self.chip().nvic.active.is_empty()
                && !self.in_it_block()
            {
                let (target, args) = self.pending_call.take().unwrap_or_default();
                let pc = self.reg(RegisterARM::PC);
                for (r, v) in [
                    RegisterARM::R0,
                    RegisterARM::R1,
                    RegisterARM::R2,
                    RegisterARM::R3,
                ]
                .into_iter()
                .zip(args)
                {
                    self.set(r, v);
                }
                self.set(RegisterARM::LR, pc | 1);
                self.set(RegisterARM::PC, target | 1);
                if self.sleeping.take().is_some() {
                    self.awake_since = self.chip().now_ps;
                }
                self.log(format!("injected call to {target:#010x}"));
            }
            // exceptions
            let primask = self.reg(RegisterARM::PRIMASK) & 1 != 0;
            let basepri = self.reg(RegisterARM::BASEPRI);
            let next = self.chip().nvic.next_exception(primask, basepri);
            if let Some(n) = next {
                if !self.in_it_block() {
                    self.enter(n);
                    if self.sleeping.take().is_some() {
                        self.awake_since = self.chip().now_ps;
                    }
                    continue;
                }
            }
            let horizon = clock.horizon_ps();
            let now = self.chip().now_ps;
            if let Some(kind) = self.sleeping {
                let wake = match kind {
                    Hint::Wfi => self.chip().nvic.wfi_wake(basepri),
                    _ => {
                        let nv = &mut self.chip().nvic;
                        let e = nv.event;
                        nv.event = false;
                        e || next.is_some()
                    }
                };
                if wake {
                    self.sleeping = None;
                    self.awake_since = now;
                    stuck = 0;
                    continue;
                }
                let cycles = self.chip().cycles;
                let hclk = self.chip().rcc.clocks().hclk.max(1);
                let systick = self
                    .chip()
                    .nvic
                    .systick_next(cycles)
                    .map(|c| now + (c - cycles) * PS / hclk);
                let target = [self.chip().next_event(), systick]
                    .into_iter()
                    .flatten()
                    .min();
                match target {
                    Some(t) if t <= now => {
                        // due now: update() handles it; if it never does, a model is broken
                        stuck += 1;
                        if stuck > 10_000 {
                            self.chip().fault(format!(
                                "an event due at {t} ps is never handled (board at {now} ps)"
                            ));
                        }
                        continue;
                    }
                    Some(t) if t <= horizon => {
                        stuck = 0;
                        self.advance(0, t - now);
                        continue;
                    }
                    _ => {}
                }
                stuck = 0;
                if now < horizon {
                    self.advance(0, horizon - now);
                    continue;
                }
                if !self.pause(target) {
                    break None;
                }
                continue;
            }
            if now >= horizon {
                if !self.pause(None) {
                    break None;
                }
                continue;
            }
            // run a slice
            let pc = self.reg(RegisterARM::PC);
            {
                let cpu = self.uc.get_data_mut();
                cpu.executed = 0;
                cpu.limit = if next.is_some() { 1 } else { SLICE };
                cpu.hint = None;
                cpu.chip.stop_slice = false;
            }
            let r = self.uc.emu_start(u64::from(pc | 1), 0, 0, 0);
            let (executed, hint) = {
                let cpu = self.uc.get_data_mut();
                (cpu.executed, cpu.hint.take())
            };
            self.instructions += executed;
            self.advance(executed.max(1), 0);
            slices += 1;
            if slices.is_multiple_of(64) {
                self.chip().io.poll_inputs();
            }
            if slices.is_multiple_of(4096) {
                self.publish();
            }
            let pc_now = self.reg(RegisterARM::PC);
            match r {
                Ok(()) => {}
                // QEMU's M-profile translator turns a fetch from the EXC_RETURN range into an
                // exception-exit exception; an unmapped fetch there ends the same way
                Err(uc_error::FETCH_UNMAPPED | uc_error::EXCEPTION) if pc_now >= 0xFFFF_FF00 => {
                    self.exit(pc_now | 1);
                    continue;
                }
                Err(uc_error::EXCEPTION | uc_error::INSN_INVALID) => {
                    let name = self.image.name_of(pc_now);
                    let lr = self.reg(RegisterARM::LR);
                    let caller = self.stack_trace();
                    self.log(format!(
                        "HardFault: undefined instruction at {pc_now:#010x} {name} (LR {lr:#010x} {caller})"
                    ));
                    // UDF (a panic ends in one) and other undefined instructions: UsageFault,
                    // escalated to HardFault (no fault handlers enabled)
                    self.enter(exc::HARD_FAULT);
                    continue;
                }
                Err(e) => {
                    let name = self.image.name_of(pc_now);
                    self.chip()
                        .fault(format!("CPU: {e:?} at {pc_now:#010x} {name}"));
                    continue;
                }
            }
            if let Some((h, addr)) = hint {
                if pc_now == addr {
                    self.set(RegisterARM::PC, (addr + 2) | 1);
                    match h {
                        Hint::Sev => self.chip().nvic.event = true,
                        Hint::Wfe => {
                            let nv = &mut self.chip().nvic;
                            if nv.event {
                                nv.event = false;
                            } else {
                                self.sleeping = Some(Hint::Wfe);
                                self.note_sleep();
                            }
                        }
                        Hint::Wfi => {
                            self.sleeping = Some(Hint::Wfi);
                            self.note_sleep();
                        }
                    }
                }
            }
        };
        let now = self.chip().now_ps;
        clock.stop(now);
        result
    }

    /// Return addresses found on the stack (a crude backtrace: code addresses with the Thumb
    /// bit, innermost first).
    fn stack_trace(&self) -> String {
        let sp = self.reg(RegisterARM::SP);
        let mut out = vec![];
        for i in 0..64 {
            let w = self.read_u32(sp + 4 * i);
            if w & 1 == 1 && (0x0800_0000..crate::flash::STORE_BASE).contains(&w) {
                out.push(self.image.name_of(w & !1));
                if out.len() == 8 {
                    break;
                }
            }
        }
        out.join(" < ")
    }

    fn log(&mut self, what: String) {
        let t = self.uc.get_data().chip.now_ps as f64 / PS as f64;
        let mut st = self.control.status.lock().unwrap();
        st.log.push(format!("{t:.6} s: {what}"));
        if st.log.len() > 100 {
            st.log.remove(0);
        }
    }

    /// The image's symbol table.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// Take the store's flash out (when the board is dropped: a power cycle keeps it).
    pub fn into_store(mut self) -> Box<StoreFlash> {
        std::mem::replace(&mut self.chip().store, Box::new(StoreFlash::new()))
    }
}
