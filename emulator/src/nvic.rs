//! The Cortex-M4 system around the core that Unicorn does not have: NVIC, SCB, SysTick, DWT's
//! cycle counter, and the exception model (ARMv7-M Architecture Reference Manual, ARM DDI 0403E,
//! §B1.5 "ARMv7-M exception model", §B3.2 "System Control Space", §B3.3 "SysTick", §B3.4
//! "NVIC"). Exception entry and return are done by [`crate::board`] at instruction boundaries
//! with the registers this module decides on; Unicorn's core always runs in thread mode (IPSR 0),
//! so a return to an EXC_RETURN value is a plain branch that ends at an unmapped fetch, which the
//! board turns into the exception return.

/// Exception numbers (ARM DDI 0403E, Table B1-4).
pub mod exc {
    /// Non-maskable interrupt (on the L4: flash ECC double error, clock security system).
    pub const NMI: usize = 2;
    /// HardFault.
    pub const HARD_FAULT: usize = 3;
    /// SVCall.
    pub const SVCALL: usize = 11;
    /// PendSV.
    pub const PENDSV: usize = 14;
    /// SysTick.
    pub const SYSTICK: usize = 15;
    /// First external interrupt (IRQ 0).
    pub const IRQ0: usize = 16;
}

/// Exceptions the model knows: 16 system + 82 STM32L475 interrupts (RM0351 Table 57), rounded up.
pub const EXCEPTIONS: usize = 16 + 96;

/// NVIC, SCB, SysTick and DWT state.
pub struct Nvic {
    /// Interrupt enable, by exception number (IRQs only; system exceptions are always enabled).
    pub enabled: [bool; EXCEPTIONS],
    /// Pending, by exception number.
    pub pending: [bool; EXCEPTIONS],
    /// Active exceptions, innermost last.
    pub active: Vec<usize>,
    /// Priority byte by exception number (4 bits implemented on the STM32L4: the low nibble
    /// reads as zero, PM0214 §4.3.7).
    pub priority: [u8; EXCEPTIONS],
    /// Interrupt lines the peripherals hold high, by IRQ: a level keeps its interrupt pending.
    pub lines: [bool; EXCEPTIONS],
    /// SCB.VTOR.
    pub vtor: u32,
    /// SCB.AIRCR.PRIGROUP.
    pub prigroup: u32,
    /// SCB.SCR (SEVONPEND bit 4, SLEEPDEEP bit 2).
    pub scr: u32,
    /// SCB.CCR.
    pub ccr: u32,
    /// SCB.CPACR (the FPU's access bits; Unicorn's FPU is always on).
    pub cpacr: u32,
    /// The event register (WFE/SEV, ARM DDI 0403E §B1.5.18).
    pub event: bool,
    /// A system reset was requested (AIRCR.SYSRESETREQ).
    pub reset_request: bool,
    /// SysTick CSR (ENABLE 0, TICKINT 1, CLKSOURCE 2, COUNTFLAG 16).
    pub systick_csr: u32,
    /// SysTick reload value.
    pub systick_rvr: u32,
    /// Core cycles at which SysTick last reloaded.
    pub systick_base: u64,
    /// DWT CTRL (CYCCNTENA bit 0) and the cycle count at which CYCCNT was 0.
    pub dwt_ctrl: u32,
    /// Cycle count at which CYCCNT read 0.
    pub cyccnt_base: u64,
    /// DEMCR (TRCENA bit 24).
    pub demcr: u32,
    /// Accesses of the system region no model covers (address, written).
    pub unmodelled: Vec<(u32, bool)>,
}

impl Default for Nvic {
    fn default() -> Self {
        Self {
            enabled: [false; EXCEPTIONS],
            pending: [false; EXCEPTIONS],
            active: vec![],
            priority: [0; EXCEPTIONS],
            lines: [false; EXCEPTIONS],
            vtor: 0,
            prigroup: 0,
            scr: 0,
            ccr: 0x200, // STKALIGN
            cpacr: 0,
            event: false,
            reset_request: false,
            systick_csr: 0x4,
            systick_rvr: 0,
            systick_base: 0,
            dwt_ctrl: 0x4000_0000,
            cyccnt_base: 0,
            demcr: 0,
            unmodelled: vec![],
        }
    }
}

impl Nvic {
    /// Group priority of exception `n` (NMI −2, HardFault −1).
    pub fn group_priority(&self, n: usize) -> i32 {
        match n {
            exc::NMI => -2,
            exc::HARD_FAULT => -1,
            _ => {
                // PRIGROUP g: bits [7:g+1] are the group priority (ARM DDI 0403E §B1.5.4)
                let mask = 0xFFu32 << (self.prigroup + 1).min(8);
                i32::from(self.priority[n] & 0xF0) & mask as i32
            }
        }
    }

    /// The running priority: the highest (numerically lowest) active group priority, lowered
    /// by PRIMASK (to 0) and BASEPRI; 256 when nothing masks.
    pub fn execution_priority(&self, primask: bool, basepri: u32) -> i32 {
        let mut p = self
            .active
            .iter()
            .map(|&n| self.group_priority(n))
            .min()
            .unwrap_or(256);
        if basepri & 0xF0 != 0 {
            p = p.min((basepri & 0xF0) as i32);
        }
        if primask {
            p = p.min(0);
        }
        p
    }

    /// Latch the peripherals' interrupt lines into pending (a level-sensitive line re-pends its
    /// interrupt as long as it is high, RM0351 §11.1: "the NVIC … 82 maskable interrupt
    /// channels").
    pub fn latch_lines(&mut self) {
        for n in exc::IRQ0..EXCEPTIONS {
            if self.lines[n] {
                self.pending[n] = true;
            }
        }
    }

    /// The pending exception that would preempt now, if any (highest priority, lowest number
    /// first among equals).
    pub fn next_exception(&self, primask: bool, basepri: u32) -> Option<usize> {
        let running = self.execution_priority(primask, basepri);
        let mut best: Option<(i32, usize)> = None;
        for n in 1..EXCEPTIONS {
            if !self.pending[n] || (n >= exc::IRQ0 && !self.enabled[n]) {
                continue;
            }
            let p = self.group_priority(n);
            if p < running && best.is_none_or(|(bp, _)| p < bp) {
                best = Some((p, n));
            }
        }
        best.map(|(_, n)| n)
    }

    /// True when a pending, enabled exception would wake WFI (masked by PRIMASK or not: ARM DDI
    /// 0403E §B1.5.19).
    pub fn wfi_wake(&self, basepri: u32) -> bool {
        self.next_exception(false, basepri).is_some()
    }

    /// SysTick's current value at core cycle `cycles` and whether it wrapped since `since`.
    fn systick_value(&self, cycles: u64) -> u32 {
        if self.systick_csr & 1 == 0 || self.systick_rvr == 0 {
            return 0;
        }
        let period = u64::from(self.systick_rvr) + 1;
        let elapsed = cycles.saturating_sub(self.systick_base);
        (self.systick_rvr as u64 - elapsed % period) as u32
    }

    /// Core cycle of SysTick's next wrap after `cycles`, if it counts with its interrupt on.
    pub fn systick_next(&self, cycles: u64) -> Option<u64> {
        if self.systick_csr & 3 != 3 || self.systick_rvr == 0 {
            return None;
        }
        let period = u64::from(self.systick_rvr) + 1;
        let elapsed = cycles.saturating_sub(self.systick_base);
        Some(self.systick_base + (elapsed / period + 1) * period)
    }

    /// Move SysTick to `cycles`: pend its exception for every wrap passed since `from`.
    pub fn systick_advance(&mut self, from: u64, to: u64) {
        if self.systick_csr & 1 == 0 || self.systick_rvr == 0 {
            return;
        }
        let period = u64::from(self.systick_rvr) + 1;
        let a = from.saturating_sub(self.systick_base) / period;
        let b = to.saturating_sub(self.systick_base) / period;
        if b > a {
            self.systick_csr |= 1 << 16;
            if self.systick_csr & 2 != 0 {
                self.pending[exc::SYSTICK] = true;
            }
        }
    }

    /// Read a word of the system control space at `addr` (0xE000_0000..).
    pub fn read(&mut self, addr: u32, cycles: u64) -> u32 {
        match addr {
            0xE000_1000 => self.dwt_ctrl,
            0xE000_1004 => cycles.wrapping_sub(self.cyccnt_base) as u32,
            0xE000_E004 => 2, // ICTR: 96 interrupts
            0xE000_E010 => {
                let v = self.systick_csr;
                self.systick_csr &= !(1 << 16);
                v
            }
            0xE000_E014 => self.systick_rvr,
            0xE000_E018 => self.systick_value(cycles),
            0xE000_E01C => 0x4000_0000, // CALIB: no reference clock
            0xE000_E100..=0xE000_E10C => self.bits(&self.enabled, addr - 0xE000_E100, true),
            0xE000_E180..=0xE000_E18C => self.bits(&self.enabled, addr - 0xE000_E180, true),
            0xE000_E200..=0xE000_E20C => self.bits(&self.pending, addr - 0xE000_E200, true),
            0xE000_E280..=0xE000_E28C => self.bits(&self.pending, addr - 0xE000_E280, true),
            0xE000_E300..=0xE000_E30C => {
                let mut act = [false; EXCEPTIONS];
                for &n in &self.active {
                    act[n] = true;
                }
                self.bits(&act, addr - 0xE000_E300, true)
            }
            0xE000_E400..=0xE000_E45C => {
                let base = exc::IRQ0 + (addr - 0xE000_E400) as usize;
                u32::from_le_bytes(std::array::from_fn(|i| self.priority[base + i]))
            }
            0xE000_ED00 => 0x410F_C241, // CPUID: Cortex-M4 r0p1
            0xE000_ED04 => {
                let active = self.active.last().copied().unwrap_or(0) as u32;
                let pend = (exc::IRQ0..EXCEPTIONS)
                    .chain(1..exc::IRQ0)
                    .find(|&n| self.pending[n])
                    .unwrap_or(0) as u32;
                active
                    | (pend << 12)
                    | (u32::from(self.pending[exc::SYSTICK]) << 26)
                    | (u32::from(self.pending[exc::PENDSV]) << 28)
                    | (u32::from(self.pending[exc::NMI]) << 31)
            }
            0xE000_ED08 => self.vtor,
            0xE000_ED0C => 0xFA05_0000 | (self.prigroup << 8),
            0xE000_ED10 => self.scr,
            0xE000_ED14 => self.ccr,
            0xE000_ED18..=0xE000_ED20 => {
                let base = 4 + (addr - 0xE000_ED18) as usize;
                u32::from_le_bytes(std::array::from_fn(|i| self.priority[base + i]))
            }
            0xE000_ED24..=0xE000_ED3C => 0, // SHCSR, fault status: no faults modelled
            0xE000_ED88 => self.cpacr,
            0xE000_EDFC => self.demcr,
            0xE000_EF34 => 0xC000_0000, // FPCCR: ASPEN, LSPEN (reset value)
            _ => {
                self.unmodelled.push((addr, false));
                0
            }
        }
    }

    fn bits(&self, set: &[bool; EXCEPTIONS], off: u32, irq: bool) -> u32 {
        let first = if irq { exc::IRQ0 } else { 0 } + 8 * off as usize;
        (0..32)
            .filter(|i| first + i < EXCEPTIONS && set[first + i])
            .fold(0, |v, i| v | 1 << i)
    }

    fn set_bits(set: &mut [bool; EXCEPTIONS], off: u32, v: u32, to: bool) {
        let first = exc::IRQ0 + 8 * off as usize;
        for i in 0..32 {
            if v & (1 << i) != 0 && first + i < EXCEPTIONS {
                set[first + i] = to;
            }
        }
    }

    /// Write a system control space register (`size` bytes at `addr`).
    pub fn write(&mut self, addr: u32, size: usize, v: u32, cycles: u64) {
        match addr {
            0xE000_1000 => self.dwt_ctrl = (self.dwt_ctrl & !1) | (v & 1),
            0xE000_1004 => self.cyccnt_base = cycles.wrapping_sub(u64::from(v)),
            0xE000_E010 => {
                if v & 1 != 0 && self.systick_csr & 1 == 0 {
                    self.systick_base = cycles;
                }
                self.systick_csr = (self.systick_csr & (1 << 16)) | (v & 7);
            }
            0xE000_E014 => self.systick_rvr = v & 0x00FF_FFFF,
            0xE000_E018 => {
                self.systick_base = cycles;
                self.systick_csr &= !(1 << 16);
            }
            0xE000_E100..=0xE000_E10C => {
                Self::set_bits(&mut self.enabled, addr - 0xE000_E100, v, true)
            }
            0xE000_E180..=0xE000_E18C => {
                Self::set_bits(&mut self.enabled, addr - 0xE000_E180, v, false)
            }
            0xE000_E200..=0xE000_E20C => {
                Self::set_bits(&mut self.pending, addr - 0xE000_E200, v, true)
            }
            0xE000_E280..=0xE000_E28C => {
                Self::set_bits(&mut self.pending, addr - 0xE000_E280, v, false)
            }
            0xE000_E400..=0xE000_E45F => {
                let base = exc::IRQ0 + (addr - 0xE000_E400) as usize;
                for i in 0..size {
                    self.priority[base + i] = (v >> (8 * i)) as u8 & 0xF0;
                }
            }
            0xE000_ED04 => {
                if v & (1 << 31) != 0 {
                    self.pending[exc::NMI] = true;
                }
                if v & (1 << 28) != 0 {
                    self.pending[exc::PENDSV] = true;
                }
                if v & (1 << 27) != 0 {
                    self.pending[exc::PENDSV] = false;
                }
                if v & (1 << 26) != 0 {
                    self.pending[exc::SYSTICK] = true;
                }
                if v & (1 << 25) != 0 {
                    self.pending[exc::SYSTICK] = false;
                }
            }
            0xE000_ED08 => self.vtor = v & 0xFFFF_FF80,
            0xE000_ED0C => {
                if v >> 16 == 0x05FA {
                    self.prigroup = (v >> 8) & 7;
                    if v & 4 != 0 {
                        self.reset_request = true;
                    }
                }
            }
            0xE000_ED10 => self.scr = v & 0x16,
            0xE000_ED14 => self.ccr = v,
            0xE000_ED18..=0xE000_ED23 => {
                let base = 4 + (addr - 0xE000_ED18) as usize;
                for i in 0..size {
                    self.priority[base + i] = (v >> (8 * i)) as u8 & 0xF0;
                }
            }
            0xE000_ED88 => self.cpacr = v,
            0xE000_EDFC => self.demcr = v,
            0xE000_EF00 => {
                let n = exc::IRQ0 + (v & 0x1FF) as usize;
                if n < EXCEPTIONS {
                    self.pending[n] = true;
                }
            }
            0xE000_EF34 | 0xE000_EF38 => {}
            _ => self.unmodelled.push((addr, true)),
        }
    }
}
