//! The small peripherals: GPIO (RM0351 §8 "General-purpose I/Os", registers §8.5), the general
//! purpose timer embassy-time runs on (TIM15, §31 "General-purpose timers (TIM15/TIM16/TIM17)",
//! registers §31.6), the independent watchdog (§32 "Independent watchdog (IWDG)", registers
//! §32.4) and ADC1 (§18 "Analog-to-digital converters (ADC)", registers §18.6).

use crate::rcc::Rcc;

/// One GPIO port.
#[derive(Clone)]
pub struct Gpio {
    /// MODER, OTYPER, OSPEEDR, PUPDR.
    pub moder: u32,
    /// OTYPER.
    pub otyper: u32,
    /// OSPEEDR.
    pub ospeedr: u32,
    /// PUPDR.
    pub pupdr: u32,
    /// ODR.
    pub odr: u32,
    /// AFRL, AFRH.
    pub afr: [u32; 2],
    /// ASCR (analog switch, L47x).
    pub ascr: u32,
    /// Levels driven from outside on input pins (None: floating, the pull decides).
    pub external: [Option<bool>; 16],
}

impl Gpio {
    /// Reset state of port `n` (A = 0): RM0351 §8.5.1 and §8.5.4 reset values (PA13/PA14/PA15,
    /// PB3/PB4 are the debug pins).
    pub fn reset(n: usize) -> Self {
        let (moder, ospeedr, pupdr) = match n {
            0 => (0xABFF_FFFF, 0x0C00_0000, 0x6400_0000),
            1 => (0xFFFF_FEBF, 0, 0x100),
            _ => (0xFFFF_FFFF, 0, 0),
        };
        Self {
            moder,
            otyper: 0,
            ospeedr,
            pupdr,
            odr: 0,
            afr: [0; 2],
            ascr: 0,
            external: [None; 16],
        }
    }

    /// The level on pin `p`.
    pub fn level(&self, p: usize) -> bool {
        let mode = (self.moder >> (2 * p)) & 3;
        if mode == 1 {
            let driven = self.odr & (1 << p) != 0;
            // open drain: a high output only releases the line; something outside may hold
            // it low (an I2C slave on SDA)
            let open_drain = self.otyper & (1 << p) != 0;
            return driven && !(open_drain && self.external[p] == Some(false));
        }
        if let Some(l) = self.external[p] {
            return l;
        }
        (self.pupdr >> (2 * p)) & 3 == 1
    }

    /// Mode of pin `p` (0 input, 1 output, 2 alternate, 3 analog) and its alternate function.
    pub fn mode(&self, p: usize) -> (u32, u32) {
        let af = (self.afr[p / 8] >> (4 * (p % 8))) & 0xF;
        ((self.moder >> (2 * p)) & 3, af)
    }

    /// Read a register.
    pub fn read(&self, off: u32) -> u32 {
        match off {
            0x00 => self.moder,
            0x04 => self.otyper,
            0x08 => self.ospeedr,
            0x0C => self.pupdr,
            0x10 => (0..16).fold(0, |v, p| v | (u32::from(self.level(p)) << p)),
            0x14 => self.odr,
            0x20 => self.afr[0],
            0x24 => self.afr[1],
            0x2C => self.ascr,
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32) {
        match off {
            0x00 => self.moder = v,
            0x04 => self.otyper = v,
            0x08 => self.ospeedr = v,
            0x0C => self.pupdr = v,
            0x14 => self.odr = v & 0xFFFF,
            0x18 => self.odr = (self.odr | (v & 0xFFFF)) & !(v >> 16),
            0x20 => self.afr[0] = v,
            0x24 => self.afr[1] = v,
            0x28 => self.odr &= !(v & 0xFFFF),
            0x2C => self.ascr = v,
            _ => {}
        }
    }
}

/// A 16-bit general-purpose timer with two compare channels (TIM15): PSC, ARR, CNT, CCR1/2,
/// DIER, SR, EGR, CR1. The counter is a function of the board's time while CEN is set.
pub struct Timer {
    /// CR1 (CEN bit 0, URS bit 2).
    pub cr1: u32,
    /// DIER (UIE 0, CC1IE 1, CC2IE 2).
    pub dier: u32,
    /// SR (UIF 0, CC1IF 1, CC2IF 2).
    pub sr: u32,
    /// PSC and its shadow (loaded at an update event).
    pub psc: u32,
    psc_active: u32,
    /// ARR.
    pub arr: u32,
    /// CCR1, CCR2.
    pub ccr: [u32; 2],
    /// Other registers (CR2, SMCR, CCMR, CCER, …): stored.
    pub other: [u32; 32],
    /// Counter value at `base_ticks` of the counter clock.
    cnt_base: u32,
    /// Counter-clock ticks (timer clock / (PSC+1)) at the last reference point, and when.
    base_ps: u64,
    /// Last time flags were computed.
    last_ps: u64,
}

impl Default for Timer {
    fn default() -> Self {
        Self {
            cr1: 0,
            dier: 0,
            sr: 0,
            psc: 0,
            psc_active: 0,
            arr: 0xFFFF,
            ccr: [0; 2],
            other: [0; 32],
            cnt_base: 0,
            base_ps: 0,
            last_ps: 0,
        }
    }
}

impl Timer {
    fn tick_ps(&self, clk: u64) -> u64 {
        if clk == 0 {
            return u64::MAX;
        }
        (1_000_000_000_000 * (u64::from(self.psc_active) + 1)) / clk
    }

    fn running(&self, clk: u64, enabled: bool) -> bool {
        enabled && self.cr1 & 1 != 0 && clk != 0
    }

    /// Ticks counted (unwrapped) since the base.
    fn ticks(&self, now_ps: u64, clk: u64) -> u64 {
        now_ps.saturating_sub(self.base_ps) / self.tick_ps(clk)
    }

    /// The counter now.
    pub fn cnt(&self, now_ps: u64, clk: u64, enabled: bool) -> u32 {
        if !self.running(clk, enabled) {
            return self.cnt_base;
        }
        let period = u64::from(self.arr) + 1;
        ((u64::from(self.cnt_base) + self.ticks(now_ps, clk)) % period) as u32
    }

    /// Re-base the counter at `now_ps` (before a change of CEN, PSC or CNT).
    fn rebase(&mut self, now_ps: u64, clk: u64, enabled: bool) {
        self.update(now_ps, clk, enabled);
        self.cnt_base = self.cnt(now_ps, clk, enabled);
        self.base_ps = now_ps;
        self.last_ps = now_ps;
    }

    /// Set the flags for everything that happened up to `now_ps`.
    pub fn update(&mut self, now_ps: u64, clk: u64, enabled: bool) {
        if !self.running(clk, enabled) || now_ps <= self.last_ps {
            self.last_ps = self.last_ps.max(now_ps);
            return;
        }
        let period = u64::from(self.arr) + 1;
        let a = u64::from(self.cnt_base) + self.ticks(self.last_ps, clk);
        let b = u64::from(self.cnt_base) + self.ticks(now_ps, clk);
        if b > a {
            // an update when the counter wrapped between a and b
            if b / period > a / period {
                self.sr |= 1;
            }
            // compare matches: CNT reached CCRx (in (a, b])
            for (i, &c) in self.ccr.iter().enumerate() {
                let c = u64::from(c);
                let first = (a / period) * period + c;
                let hit = if first > a {
                    first <= b
                } else {
                    first + period <= b
                };
                if hit {
                    self.sr |= 2 << i;
                }
            }
        }
        self.last_ps = now_ps;
    }

    /// When the next flag that would interrupt sets, ps.
    pub fn next_event(&self, clk: u64, enabled: bool) -> Option<u64> {
        if !self.running(clk, enabled) || self.dier & 7 == 0 {
            return None;
        }
        let period = u64::from(self.arr) + 1;
        let a = u64::from(self.cnt_base) + self.ticks(self.last_ps, clk);
        let mut best = u64::MAX;
        if self.dier & 1 != 0 {
            best = best.min((a / period + 1) * period);
        }
        for i in 0..2 {
            if self.dier & (2 << i) != 0 {
                let c = u64::from(self.ccr[i]);
                let mut t = (a / period) * period + c;
                if t <= a {
                    t += period;
                }
                best = best.min(t);
            }
        }
        let ticks = best - u64::from(self.cnt_base);
        Some(self.base_ps + ticks * self.tick_ps(clk))
    }

    /// The interrupt line.
    pub fn irq(&self) -> bool {
        self.sr & self.dier & 7 != 0
    }

    /// Read a register.
    pub fn read(&mut self, off: u32, now_ps: u64, clk: u64, enabled: bool) -> u32 {
        self.update(now_ps, clk, enabled);
        match off {
            0x00 => self.cr1,
            0x0C => self.dier,
            0x10 => self.sr,
            0x24 => self.cnt(now_ps, clk, enabled),
            0x28 => self.psc,
            0x2C => self.arr,
            0x34 => self.ccr[0],
            0x38 => self.ccr[1],
            _ => self.other[(off / 4) as usize % 32],
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, now_ps: u64, clk: u64, enabled: bool) {
        self.update(now_ps, clk, enabled);
        match off {
            0x00 => {
                self.rebase(now_ps, clk, enabled);
                self.cr1 = v & 0x3FF;
            }
            0x0C => self.dier = v,
            0x10 => self.sr &= v, // rc_w0
            0x14 => {
                if v & 1 != 0 {
                    // UG: reinitialise the counter, load the prescaler; UIF unless URS
                    self.rebase(now_ps, clk, enabled);
                    self.psc_active = self.psc;
                    self.cnt_base = 0;
                    if self.cr1 & 4 == 0 {
                        self.sr |= 1;
                    }
                }
            }
            0x24 => {
                self.rebase(now_ps, clk, enabled);
                self.cnt_base = v & 0xFFFF;
            }
            0x28 => self.psc = v & 0xFFFF,
            0x2C => self.arr = v & 0xFFFF,
            0x34 => self.ccr[0] = v & 0xFFFF,
            0x38 => self.ccr[1] = v & 0xFFFF,
            _ => self.other[(off / 4) as usize % 32] = v,
        }
    }
}

/// The independent watchdog, on the 32 kHz LSI (RM0351 §32.3: started by 0xCCCC, reloaded by
/// 0xAAAA, PR/RLR unlocked by 0x5555; the counter counts down from RLR at LSI / 4·2^PR; at 0
/// the chip resets).
#[derive(Default)]
pub struct Iwdg {
    /// Started (it cannot be stopped but by a reset).
    pub running: bool,
    unlocked: bool,
    /// PR.
    pub pr: u32,
    /// RLR.
    pub rlr: u32,
    /// When the counter reaches 0, ps.
    pub deadline_ps: u64,
    /// When it was started or last reloaded, ps.
    fed_at_ps: u64,
    /// The longest it has counted between a start or reload and the next reload, ps.
    longest_wait_ps: u64,
}

/// LSI frequency, Hz (RM0351 §6.2.6, datasheet fLSI 29.5–34 kHz: nominal 32 kHz).
pub const LSI_HZ: u64 = 32_000;

impl Iwdg {
    /// After a reset: stopped, PR 0, RLR 0xFFF.
    pub fn reset() -> Self {
        Self {
            rlr: 0xFFF,
            ..Self::default()
        }
    }

    fn period_ps(&self) -> u64 {
        let div = 4u64 << self.pr.min(6);
        (u64::from(self.rlr) + 1) * div * 1_000_000_000_000 / LSI_HZ
    }

    /// Read a register.
    pub fn read(&self, off: u32) -> u32 {
        match off {
            0x04 => self.pr,
            0x08 => self.rlr,
            0x0C => 0, // SR: PVU/RVU/WVU clear, updates take effect at once
            0x10 => 0xFFF,
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, now_ps: u64, rcc: &mut Rcc) {
        match (off, v & 0xFFFF) {
            (0x00, 0xCCCC) => {
                if !self.running {
                    self.fed_at_ps = now_ps;
                }
                self.running = true;
                rcc.csr |= 3; // the LSI starts with the watchdog (RM0351 §32.3.2)
                self.deadline_ps = now_ps + self.period_ps();
            }
            (0x00, 0xAAAA) => {
                self.unlocked = false;
                self.deadline_ps = now_ps + self.period_ps();
                if self.running {
                    self.longest_wait_ps = self.longest_wait_ps.max(now_ps - self.fed_at_ps);
                    self.fed_at_ps = now_ps;
                }
            }
            (0x00, 0x5555) => self.unlocked = true,
            (0x00, _) => self.unlocked = false,
            (0x04, _) if self.unlocked => self.pr = v & 7,
            (0x08, _) if self.unlocked => self.rlr = v & 0xFFF,
            _ => {}
        }
    }

    /// The longest the watchdog has counted without a reload in this boot, up to `now_ps`
    /// (0 while it is not started), ps.
    pub fn longest_wait_ps(&self, now_ps: u64) -> u64 {
        if !self.running {
            return 0;
        }
        self.longest_wait_ps
            .max(now_ps - self.fed_at_ps.min(now_ps))
    }

    /// The time it counts from a reload to a reset, ps.
    pub fn timeout_ps(&self) -> u64 {
        self.period_ps()
    }

    /// True when the watchdog has expired by `now_ps`.
    pub fn expired(&self, now_ps: u64) -> bool {
        self.running && now_ps >= self.deadline_ps
    }
}

/// ADC1 with the common registers (ADC123_COMMON). Calibration, enable and conversions
/// progress only while the ADC has a clock: its bus clock (AHB2ENR.ADCEN) and either the
/// synchronous HCLK (CCR.CKMODE ≠ 0) or the asynchronous kernel clock selected by
/// RCC_CCIPR.ADCSEL (§18.4.3) — with ADCSEL = 00 ("no clock") and CKMODE = 00, ADCAL stays set
/// for ever (§18.4.8).
pub struct Adc {
    /// CR (ADEN 0, ADDIS 1, ADSTART 2, ADSTP 4, ADVREGEN 28, DEEPPWD 29, ADCAL 31).
    pub cr: u32,
    /// ISR (ADRDY 0, EOSMP 1, EOC 2, EOS 3, OVR 4).
    pub isr: u32,
    /// IER.
    pub ier: u32,
    /// CFGR, CFGR2, SMPR1/2, SQR1..4, …: stored.
    pub other: [u32; 64],
    /// DR.
    pub dr: u32,
    /// Common CCR (CKMODE 17:16, PRESC 21:18).
    pub ccr: u32,
    /// When calibration / enable / conversion completes, ps (in ADC clock time).
    cal_done: Option<u64>,
    rdy_at: Option<u64>,
    conv_done: Option<u64>,
    /// The enable completed (ADRDY was set; clearing the flag does not disable the ADC).
    ready: bool,
}

/// The board's analog inputs by ADC1 channel: A0 = PC5 is ADC12_IN14 (datasheet DS10969,
/// Table 16 "STM32L475xx pin definitions"), the force input the bench's channel 0 drives.
fn bench_channel(adc_channel: u32) -> Option<u8> {
    (adc_channel == 14).then_some(0)
}

impl Default for Adc {
    fn default() -> Self {
        Self {
            cr: 0x2000_0000, // DEEPPWD at reset (§18.6.3)
            isr: 0,
            ier: 0,
            other: [0; 64],
            dr: 0,
            ccr: 0,
            cal_done: None,
            rdy_at: None,
            conv_done: None,
            ready: false,
        }
    }
}

impl Adc {
    /// The ADC clock now, Hz (0: none).
    pub fn clock_hz(&self, rcc: &Rcc) -> u64 {
        if rcc.ahbenr[1] & (1 << crate::rcc::ahb2::ADC) == 0 {
            return 0;
        }
        let ckmode = (self.ccr >> 16) & 3;
        if ckmode != 0 {
            return rcc.clocks().hclk >> (ckmode - 1);
        }
        let presc = (self.ccr >> 18) & 0xF;
        let div = [1, 2, 4, 6, 8, 10, 12, 16, 32, 64, 128, 256]
            .get(presc as usize)
            .copied()
            .unwrap_or(256);
        rcc.adc_kernel_hz() / div
    }

    fn cycles_ps(hz: u64, cycles: u64) -> Option<u64> {
        (hz != 0).then(|| cycles * 1_000_000_000_000 / hz)
    }

    /// Progress calibration, enable and conversion up to `now_ps` (a conversion samples its
    /// channel from `io`; an unconnected input reads 0).
    pub fn update(&mut self, now_ps: u64, io: &mut crate::io::Io) {
        if self.cal_done.is_some_and(|t| now_ps >= t) {
            self.cal_done = None;
            self.cr &= !(1 << 31);
            self.other[0x60 / 4] = 0x40; // CALFACT
        }
        if self.rdy_at.is_some_and(|t| now_ps >= t) {
            self.rdy_at = None;
            self.isr |= 1;
            self.ready = true;
        }
        if self.conv_done.is_some_and(|t| now_ps >= t) {
            self.conv_done = None;
            let ch = (self.other[0x30 / 4] >> 6) & 0x1F; // SQR1.SQ1
            self.dr = u32::from(
                bench_channel(ch)
                    .and_then(|c| io.adc(c))
                    .unwrap_or(0)
                    .min(0xFFF),
            );
            if self.isr & (1 << 2) != 0 {
                self.isr |= 1 << 4; // OVR
            }
            self.isr |= (1 << 1) | (1 << 2) | (1 << 3);
            self.cr &= !(1 << 2);
        }
    }

    /// When something completes, ps.
    pub fn next_event(&self) -> Option<u64> {
        [self.cal_done, self.rdy_at, self.conv_done]
            .into_iter()
            .flatten()
            .min()
    }

    /// The interrupt line.
    pub fn irq(&self) -> bool {
        self.isr & self.ier & 0x7FF != 0
    }

    /// Read an ADC1 register (offset from 0x5004_0000) or a common one (0x300..).
    pub fn read(&mut self, off: u32, now_ps: u64, io: &mut crate::io::Io) -> u32 {
        self.update(now_ps, io);
        match off {
            0x00 => self.isr,
            0x04 => self.ier,
            0x08 => self.cr,
            0x40 => {
                self.isr &= !(1 << 2);
                self.dr
            }
            0x300 => 0,
            0x308 => self.ccr,
            0x30C => 0,
            _ => self.other[(off / 4) as usize % 64],
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, now_ps: u64, rcc: &Rcc, io: &mut crate::io::Io) {
        self.update(now_ps, io);
        let hz = self.clock_hz(rcc);
        match off {
            0x00 => self.isr &= !v,
            0x04 => self.ier = v,
            0x08 => {
                let regulator = v & (1 << 28) != 0 && v & (1 << 29) == 0;
                let mut cr = (self.cr & ((1 << 31) | 4 | 1)) | (v & !((1 << 31) | 7 | 0x30));
                if v & (1 << 31) != 0 && self.cr & 1 == 0 && regulator {
                    // ADCAL: 116 ADC clock cycles (§18.4.8); never without a clock
                    cr |= 1 << 31;
                    self.cal_done = Self::cycles_ps(hz, 116).map(|d| now_ps + d);
                }
                if v & 1 != 0 && cr & (1 << 31) == 0 {
                    cr |= 1;
                    if self.cr & 1 == 0 {
                        self.rdy_at = Self::cycles_ps(hz, 2).map(|d| now_ps + d);
                    }
                }
                if v & 2 != 0 && cr & 1 != 0 {
                    cr &= !1; // ADDIS
                    self.isr &= !1;
                    self.ready = false;
                }
                // ADSTART: "only when ADEN = 1 and ADDIS = 0" (§18.6.3), once enabled
                if v & 4 != 0 && cr & 1 != 0 && self.ready {
                    cr |= 4;
                    // sampling time of SQ1's channel + 12.5 cycles (12-bit)
                    let ch = (self.other[0x30 / 4] >> 6) & 0x1F;
                    let smpr = self.other[(0x14 + 4 * (ch / 10)) as usize / 4];
                    let smp = (smpr >> (3 * (ch % 10))) & 7;
                    let sample = [3, 7, 13, 25, 48, 93, 248, 641][smp as usize];
                    self.conv_done = Self::cycles_ps(hz, sample + 13).map(|d| now_ps + d);
                }
                if v & 0x10 != 0 {
                    cr &= !4; // ADSTP
                    self.conv_done = None;
                }
                self.cr = cr;
            }
            0x308 => self.ccr = v,
            _ => self.other[(off / 4) as usize % 64] = v,
        }
    }
}
