//! Reset and clock control (RM0351 Rev 9 §6 "Reset and clock control (RCC)", registers §6.4) and
//! the power controller's part in it (§5 "Power control (PWR)", registers §5.4).
//!
//! Modelled: the oscillators and their ready flags (MSI with its ranges and the PLL mode that
//! trims it from the LSE, §6.2.3; HSI16; LSE in the backup domain, writable only with PWR_CR1.DBP
//! set, §5.1.5 and §6.4.29; LSI), the main PLL with its input/VCO/output limits (§6.2.5), the
//! system clock switch with SWS following SW, the bus prescalers, the peripheral clock enables
//! (a peripheral whose enable bit is off does not progress: its model sees no clock), the
//! kernel-clock multiplexers of CCIPR (§6.4.28), and the reset flags of CSR (§6.4.29). The board
//! has no HSE crystal fitted (UM2153 §6.5: X3 not fitted; the ST-LINK's MCO is not connected by
//! default), so HSERDY never sets.

/// Clock frequencies derived from the RCC registers, Hz (0: that clock is not running).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Clocks {
    /// SYSCLK.
    pub sysclk: u64,
    /// HCLK (AHB, core).
    pub hclk: u64,
    /// PCLK1 (APB1).
    pub pclk1: u64,
    /// PCLK2 (APB2).
    pub pclk2: u64,
    /// Timer clock of APB1 / APB2 (×2 when the APB prescaler divides).
    pub tim1: u64,
    /// Timer clock of APB2.
    pub tim2: u64,
    /// MSI output.
    pub msi: u64,
    /// PLL "R" output (0 when not enabled or not locked).
    pub pll_r: u64,
    /// PLL "Q" output.
    pub pll_q: u64,
    /// PLLSAI1 "R" output.
    pub pllsai1_r: u64,
    /// MSI is trimmed by the LSE (MSIPLLEN with LSE ready).
    pub msi_trimmed: bool,
}

/// MSI frequencies by range (RM0351 §6.4.1, MSIRANGE).
const MSI_HZ: [u64; 12] = [
    100_000, 200_000, 400_000, 800_000, 1_000_000, 2_000_000, 4_000_000, 8_000_000, 16_000_000,
    24_000_000, 32_000_000, 48_000_000,
];

/// Why a peripheral does not progress: the board's models query these.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Enable {
    /// AHB1ENR bit.
    Ahb1(u32),
    /// AHB2ENR bit.
    Ahb2(u32),
    /// APB1ENR1 bit.
    Apb1(u32),
    /// APB2ENR bit.
    Apb2(u32),
}

/// Reset flags of RCC_CSR (RM0351 §6.4.29).
pub mod csr {
    /// Firewall reset.
    pub const FWRSTF: u32 = 1 << 24;
    /// Option byte loader reset.
    pub const OBLRSTF: u32 = 1 << 25;
    /// NRST pin (set with every internal reset too: the reset drives the pin).
    pub const PINRSTF: u32 = 1 << 26;
    /// Brown-out (and power-on).
    pub const BORRSTF: u32 = 1 << 27;
    /// Software reset (AIRCR.SYSRESETREQ).
    pub const SFTRSTF: u32 = 1 << 28;
    /// Independent watchdog.
    pub const IWDGRSTF: u32 = 1 << 29;
    /// Remove reset flags.
    pub const RMVF: u32 = 1 << 23;
}

/// RCC and PWR registers.
pub struct Rcc {
    /// CR.
    pub cr: u32,
    /// CFGR.
    pub cfgr: u32,
    /// PLLCFGR.
    pub pllcfgr: u32,
    /// PLLSAI1CFGR.
    pub pllsai1cfgr: u32,
    /// PLLSAI2CFGR.
    pub pllsai2cfgr: u32,
    /// AHB1ENR, AHB2ENR, AHB3ENR.
    pub ahbenr: [u32; 3],
    /// APB1ENR1, APB1ENR2, APB2ENR.
    pub apbenr: [u32; 3],
    /// Reset registers AHB1..APB2 (0x28..0x40).
    pub rstr: [u32; 7],
    /// Sleep/stop enables 0x68..0x80 (stored, not used).
    pub smenr: [u32; 7],
    /// CIER, CIFR.
    pub cier: u32,
    /// CCIPR.
    pub ccipr: u32,
    /// BDCR (backup domain: kept over a system reset).
    pub bdcr: u32,
    /// RTC backup registers BKP0R..BKP31R (backup domain: kept over a system reset, cleared by
    /// a power cut — the board has no backup battery — and by BDCR.BDRST; RM0351 §38.3.15).
    pub bkp: [u32; 32],
    /// CSR.
    pub csr: u32,
    /// ICSCR.
    pub icscr: u32,
    /// PWR_CR1 (LPMS, DBP bit 8, VOS bits 10:9).
    pub pwr_cr1: u32,
    /// PWR_CR2 (PVME, IOSV bit 9, USV bit 10).
    pub pwr_cr2: u32,
    /// PWR_CR3, CR4, SCR, PUCRx/PDCRx (stored).
    pub pwr_other: [u32; 32],
    /// Clock settings the hardware refuses that software asked for (for the fault report).
    pub errors: Vec<String>,
}

/// AHB2ENR bits.
pub mod ahb2 {
    /// GPIO port n clock: bit n.
    pub const GPIO0: u32 = 0;
    /// USB OTG FS.
    pub const OTGFS: u32 = 12;
    /// ADC.
    pub const ADC: u32 = 13;
}

impl Rcc {
    /// Power-on state (backup domain cleared).
    pub fn power_on() -> Self {
        let mut r = Self::system_reset(0);
        r.csr |= csr::BORRSTF | csr::PINRSTF;
        r
    }

    /// State after a system reset, keeping the backup domain `bdcr` (RM0351 §6.1.3: a system
    /// reset resets all registers except the reset flags in CSR and the backup domain).
    pub fn system_reset(bdcr: u32) -> Self {
        Self {
            cr: 0x63, // MSION, MSIRDY, MSIRANGE 6 (4 MHz)
            cfgr: 0,
            pllcfgr: 0x1000,
            pllsai1cfgr: 0x1000,
            pllsai2cfgr: 0x1000,
            ahbenr: [0x100, 0, 0], // FLASHEN
            apbenr: [0, 0, 0],
            rstr: [0; 7],
            smenr: [0; 7],
            cier: 0,
            ccipr: 0,
            bdcr,
            bkp: [0; 32],
            csr: 0x0C00_0600 & !(csr::BORRSTF | csr::PINRSTF), // MSISRANGE 6
            icscr: 0x1000_0000,
            pwr_cr1: 0x200, // VOS range 1
            pwr_cr2: 0,
            pwr_other: [0; 32],
            errors: vec![],
        }
    }

    /// Is the bus clock of a peripheral on?
    pub fn enabled(&self, e: Enable) -> bool {
        match e {
            Enable::Ahb1(b) => self.ahbenr[0] & (1 << b) != 0,
            Enable::Ahb2(b) => self.ahbenr[1] & (1 << b) != 0,
            Enable::Apb1(b) => self.apbenr[0] & (1 << b) != 0,
            Enable::Apb2(b) => self.apbenr[2] & (1 << b) != 0,
        }
    }

    /// Voltage scaling range (1 or 2).
    pub fn vos_range(&self) -> u32 {
        if (self.pwr_cr1 >> 9) & 3 == 2 {
            2
        } else {
            1
        }
    }

    fn msi_hz(&self) -> u64 {
        let range = if self.cr & (1 << 3) != 0 {
            (self.cr >> 4) & 0xF
        } else {
            (self.csr >> 8) & 0xF
        };
        MSI_HZ.get(range as usize).copied().unwrap_or(0)
    }

    fn pll_input(&self, cfg: u32) -> u64 {
        match cfg & 3 {
            1 if self.cr & 2 != 0 => self.msi_hz(),
            2 if self.cr & (1 << 10) != 0 => 16_000_000,
            _ => 0,
        }
    }

    /// VCO of the main PLL (input / M × N), 0 when its input is off.
    fn pll_vco(&self) -> u64 {
        let m = u64::from((self.pllcfgr >> 4) & 7) + 1;
        let n = u64::from((self.pllcfgr >> 8) & 0x7F);
        self.pll_input(self.pllcfgr) / m * n
    }

    /// The frequencies in force.
    pub fn clocks(&self) -> Clocks {
        let msi = if self.cr & 2 != 0 { self.msi_hz() } else { 0 };
        let pll_locked = self.cr & (1 << 25) != 0;
        let vco = self.pll_vco();
        let pll_r = if pll_locked && self.pllcfgr & (1 << 24) != 0 {
            vco / (2 * (u64::from((self.pllcfgr >> 25) & 3) + 1))
        } else {
            0
        };
        let pll_q = if pll_locked && self.pllcfgr & (1 << 20) != 0 {
            vco / (2 * (u64::from((self.pllcfgr >> 21) & 3) + 1))
        } else {
            0
        };
        let sai1_locked = self.cr & (1 << 27) != 0;
        let pllsai1_r = if sai1_locked && self.pllsai1cfgr & (1 << 24) != 0 {
            let m = u64::from((self.pllcfgr >> 4) & 7) + 1;
            let n = u64::from((self.pllsai1cfgr >> 8) & 0x7F);
            self.pll_input(self.pllcfgr) / m * n
                / (2 * (u64::from((self.pllsai1cfgr >> 25) & 3) + 1))
        } else {
            0
        };
        let sysclk = match (self.cfgr >> 2) & 3 {
            0 => msi,
            1 => 16_000_000,
            2 => 0,
            _ => pll_r,
        };
        let hpre = (self.cfgr >> 4) & 0xF;
        let hdiv = if hpre < 8 {
            1
        } else {
            [2, 4, 8, 16, 64, 128, 256, 512][(hpre - 8) as usize]
        };
        let hclk = sysclk / hdiv;
        let apb = |p: u32| if p < 4 { 1 } else { 1 << (p - 3) };
        let (d1, d2) = (apb((self.cfgr >> 8) & 7), apb((self.cfgr >> 11) & 7));
        let (pclk1, pclk2) = (hclk / d1, hclk / d2);
        Clocks {
            sysclk,
            hclk,
            pclk1,
            pclk2,
            tim1: if d1 == 1 { pclk1 } else { 2 * pclk1 },
            tim2: if d2 == 1 { pclk2 } else { 2 * pclk2 },
            msi,
            pll_r,
            pll_q,
            pllsai1_r,
            msi_trimmed: self.cr & 4 != 0 && self.bdcr & 2 != 0,
        }
    }

    /// The ADC's asynchronous kernel clock (CCIPR.ADCSEL, RM0351 §6.4.28: 00 no clock, 01
    /// PLLSAI1 "R", 10 PLLSAI2 "R", 11 SYSCLK), Hz; 0 when none runs.
    pub fn adc_kernel_hz(&self) -> u64 {
        let c = self.clocks();
        match (self.ccipr >> 28) & 3 {
            1 => c.pllsai1_r,
            3 => c.sysclk,
            _ => 0,
        }
    }

    /// The 48 MHz clock of USB OTG FS (CCIPR.CLK48SEL: 00 none on the STM32L475, 01 PLLSAI1 "Q",
    /// 10 PLL "Q", 11 MSI), Hz, and whether it is accurate enough for USB (MSI only when
    /// trimmed by the LSE, §6.2.3).
    pub fn clk48(&self) -> (u64, bool) {
        let c = self.clocks();
        match (self.ccipr >> 26) & 3 {
            2 => (c.pll_q, true),
            3 => (c.msi, c.msi_trimmed),
            _ => (0, false),
        }
    }

    /// Kernel clock of UART4 (CCIPR.UART4SEL: 00 PCLK1, 01 SYSCLK, 10 HSI16, 11 LSE), Hz.
    pub fn uart4_hz(&self) -> u64 {
        let c = self.clocks();
        match (self.ccipr >> 6) & 3 {
            0 => c.pclk1,
            1 => c.sysclk,
            2 if self.cr & (1 << 10) != 0 => 16_000_000,
            3 if self.bdcr & 2 != 0 => 32_768,
            _ => 0,
        }
    }

    /// Kernel clock of I2C2 (CCIPR.I2C2SEL: 00 PCLK1, 01 SYSCLK, 10 HSI16), Hz.
    pub fn i2c2_hz(&self) -> u64 {
        let c = self.clocks();
        match (self.ccipr >> 14) & 3 {
            0 => c.pclk1,
            1 => c.sysclk,
            2 if self.cr & (1 << 10) != 0 => 16_000_000,
            _ => 0,
        }
    }

    /// Read RCC register at offset `off`.
    pub fn read(&self, off: u32) -> u32 {
        match off {
            0x00 => self.cr,
            0x04 => self.icscr,
            0x08 => self.cfgr,
            0x0C => self.pllcfgr,
            0x10 => self.pllsai1cfgr,
            0x14 => self.pllsai2cfgr,
            0x18 => self.cier,
            0x1C | 0x20 => 0,
            0x28..=0x40 => self.rstr[((off - 0x28) / 4) as usize],
            0x48..=0x50 => self.ahbenr[((off - 0x48) / 4) as usize],
            0x58..=0x60 => self.apbenr[((off - 0x58) / 4) as usize],
            0x68..=0x80 => self.smenr[((off - 0x68) / 4) as usize],
            0x88 => self.ccipr,
            0x90 => self.bdcr,
            0x94 => self.csr,
            _ => 0,
        }
    }

    /// Write RCC register at offset `off`; oscillators and PLLs lock at once (their start-up
    /// times are far below what the firmware waits for).
    pub fn write(&mut self, off: u32, v: u32) {
        match off {
            0x00 => self.write_cr(v),
            0x04 => self.icscr = v,
            0x08 => {
                // SWS follows SW when the selected clock runs (HSE never does here)
                let sw = v & 3;
                let running = match sw {
                    0 => self.cr & 2 != 0,
                    1 => self.cr & (1 << 10) != 0,
                    2 => false,
                    _ => self.cr & (1 << 25) != 0,
                };
                let sws = if running { sw } else { (self.cfgr >> 2) & 3 };
                self.cfgr = (v & !0xC) | (sws << 2);
            }
            0x0C => {
                if self.cr & (1 << 24) != 0 {
                    self.errors
                        .push("PLLCFGR written while the PLL is on (RM0351 §6.4.4)".into());
                    return;
                }
                self.pllcfgr = v;
            }
            0x10 => self.pllsai1cfgr = v,
            0x14 => self.pllsai2cfgr = v,
            0x18 => self.cier = v,
            0x20 => {}
            0x28..=0x40 => self.rstr[((off - 0x28) / 4) as usize] = v,
            0x48..=0x50 => self.ahbenr[((off - 0x48) / 4) as usize] = v,
            0x58..=0x60 => self.apbenr[((off - 0x58) / 4) as usize] = v,
            0x68..=0x80 => self.smenr[((off - 0x68) / 4) as usize] = v,
            0x88 => self.ccipr = v,
            0x90 => {
                // backup domain write protection (RM0351 §5.1.5): without DBP the write is lost
                if self.pwr_cr1 & (1 << 8) == 0 {
                    return;
                }
                if v & (1 << 16) != 0 {
                    self.bkp = [0; 32]; // BDRST resets the backup domain
                }
                let mut b = v & !(1 << 1 | 1 << 6);
                if v & 1 != 0 {
                    b |= 1 << 1; // LSERDY: the board's 32.768 kHz crystal X2 (UM2153 §6.5)
                }
                if v & (1 << 16) != 0 {
                    b = 1 << 16; // BDRST
                }
                self.bdcr = b;
            }
            0x94 => {
                let mut c = (self.csr & 0xFF00_0000) | (v & 0x0000_0F01);
                if v & 1 != 0 {
                    c |= 2; // LSIRDY
                }
                if v & csr::RMVF != 0 {
                    c &= 0x00FF_FFFF;
                }
                self.csr = c;
            }
            _ => {}
        }
    }

    fn write_cr(&mut self, v: u32) {
        let mut cr = v & !(1 << 1 | 1 << 10 | 1 << 17 | 1 << 25 | 1 << 27 | 1 << 29);
        // RM0351 §6.4.1: MSIRANGE may only change while MSI is off or ready
        if v & 1 != 0 {
            cr |= 2; // MSIRDY
        }
        if v & (1 << 8) != 0 {
            cr |= 1 << 10; // HSIRDY
        }
        if v & 4 != 0 && self.bdcr & 2 == 0 {
            // MSIPLLEN: "must be enabled after LSE is enabled and ready" (§6.4.1)
            self.errors
                .push("MSIPLLEN set while the LSE is not ready (RM0351 §6.4.1)".into());
        }
        if v & (1 << 24) != 0 {
            match self.pll_check() {
                Ok(()) => cr |= 1 << 25,
                Err(e) => {
                    if self.cr & (1 << 25) == 0 {
                        self.errors.push(e);
                    }
                }
            }
        }
        if v & (1 << 26) != 0 {
            cr |= 1 << 27;
        }
        if v & (1 << 28) != 0 {
            cr |= 1 << 29;
        }
        // switching off the clock the system runs on is ignored by the hardware
        let sws = (self.cfgr >> 2) & 3;
        if sws == 0 && cr & 1 == 0 {
            cr |= 3;
        }
        if sws == 3 && cr & (1 << 24) == 0 {
            cr |= 3 << 24;
        }
        self.cr = cr;
    }

    /// RM0351 §6.2.5 and §6.4.4: PLL input 4..16 MHz, VCO 64..344 MHz, N 8..86.
    fn pll_check(&self) -> Result<(), String> {
        let m = u64::from((self.pllcfgr >> 4) & 7) + 1;
        let n = (self.pllcfgr >> 8) & 0x7F;
        let input = self.pll_input(self.pllcfgr) / m;
        let vco = self.pll_vco();
        if input == 0 {
            return Err("PLL enabled with no running input clock (RM0351 §6.4.4 PLLSRC)".into());
        }
        if !(4_000_000..=16_000_000).contains(&input) {
            return Err(format!(
                "PLL input {input} Hz outside 4..16 MHz (RM0351 §6.4.4 PLLM)"
            ));
        }
        if !(8..=86).contains(&n) || !(64_000_000..=344_000_000).contains(&vco) {
            return Err(format!("PLL VCO {vco} Hz (N = {n}) outside 64..344 MHz"));
        }
        Ok(())
    }

    /// Read an RTC register (offset from 0x4000_2800): the backup registers; the rest reads 0
    /// (the calendar is not modelled).
    pub fn rtc_read(&self, off: u32) -> u32 {
        match off {
            0x50..=0xCC => self.bkp[((off - 0x50) / 4) as usize],
            _ => 0,
        }
    }

    /// Write an RTC register: the backup registers, with the backup domain unlocked (DBP).
    pub fn rtc_write(&mut self, off: u32, v: u32) {
        if let 0x50..=0xCC = off {
            if self.pwr_cr1 & (1 << 8) != 0 {
                self.bkp[((off - 0x50) / 4) as usize] = v;
            }
        }
    }

    /// Read a PWR register.
    pub fn pwr_read(&self, off: u32) -> u32 {
        match off {
            0x00 => self.pwr_cr1,
            0x04 => self.pwr_cr2,
            // SR2: VOSF (bit 10) clear: the regulator settles at once; REGLPF clear
            0x14 => 0,
            0x10 => 0,
            _ => self.pwr_other[(off / 4) as usize % 32],
        }
    }

    /// Write a PWR register.
    pub fn pwr_write(&mut self, off: u32, v: u32) {
        match off {
            0x00 => self.pwr_cr1 = v,
            0x04 => self.pwr_cr2 = v,
            _ => self.pwr_other[(off / 4) as usize % 32] = v,
        }
    }
}
