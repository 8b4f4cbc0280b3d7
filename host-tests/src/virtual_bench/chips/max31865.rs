//! MAX31865 RTD-to-digital converter, at register level.
//!
//! Followed from the MAX31865 datasheet (Maxim 19-6478):
//! - "Serial Interface" and Table 1 "Register Names, Addresses, and Defaults": reads at 00h–07h,
//!   writes at 80h (configuration) and 83h–86h (high/low fault thresholds); the address
//!   increments after every byte of a multi-byte transfer. 01h/02h (RTD) and 07h (fault status)
//!   are read-only: a write burst that runs over them changes nothing there.
//! - Configuration (00h): D7 VBIAS, D6 automatic conversion, D5 1-shot (conversion when CS
//!   rises, self-clearing), D4 3-wire, D3:D2 fault detection cycle, D1 fault status clear
//!   (self-clearing; clears D7:D2 of the fault status and D0 of the RTD LSB when written with
//!   D5, D3, D2 = 0), D0 50 Hz filter (0 = 60 Hz).
//! - RTD register: 15-bit ratio R_RTD/R_REF × 2^15 in D15:D1, fault flag in D0.
//! - Fault thresholds: a conversion ≥ the high threshold sets fault status D7, below the low
//!   threshold D6 (15-bit compare); "The Fault Status Register bits latch" until cleared.
//! - Conversion time: one-shot 52 ms (60 Hz) / 62.5 ms (50 Hz); automatic mode converts every
//!   16.7 / 20 ms after the first.
//! - RTD resistance from IEC 60751 Callendar–Van Dusen (A = 3.9083e-3, B = -5.775e-7,
//!   C = -4.183e-12 below 0 °C).

use super::SpiChip;

const DEFAULTS: [u8; 8] = [0x00, 0x00, 0x00, 0xFF, 0xFF, 0x00, 0x00, 0x00];

/// A simulated MAX31865 with its RTD.
#[derive(Debug, Clone)]
pub struct Max31865 {
    regs: [u8; 8],
    addr: u8,
    write: bool,
    next_conv_s: Option<f64>,
    now: f64,
    /// True RTD temperature, °C.
    pub temp_c: f64,
    /// RTD resistance at 0 °C, Ω.
    pub r0_ohm: f64,
    /// Reference resistor on the board, Ω.
    pub r_ref_ohm: f64,
    /// A wire to the RTD is broken.
    pub open: bool,
    /// Conversions completed.
    pub conversions: u64,
}

/// IEC 60751 resistance of a platinum RTD.
pub fn rtd_ohm(r0: f64, t: f64) -> f64 {
    let (a, b, c) = (3.9083e-3, -5.775e-7, -4.183e-12);
    if t >= 0.0 {
        r0 * (1.0 + a * t + b * t * t)
    } else {
        r0 * (1.0 + a * t + b * t * t + c * (t - 100.0) * t * t * t)
    }
}

impl Max31865 {
    /// A chip at power-on with a PT100 (`r0_ohm` = 100, `r_ref_ohm` = 430) or PT1000 at
    /// `temp_c`.
    pub fn new(temp_c: f64, r0_ohm: f64, r_ref_ohm: f64) -> Self {
        Self {
            regs: DEFAULTS,
            addr: 0,
            write: false,
            next_conv_s: None,
            now: 0.0,
            temp_c,
            r0_ohm,
            r_ref_ohm,
            open: false,
            conversions: 0,
        }
    }

    /// The register file (for tests).
    pub fn regs(&self) -> &[u8; 8] {
        &self.regs
    }

    fn fifty(&self) -> bool {
        self.regs[0] & 0x01 != 0
    }

    fn advance(&mut self, now_s: f64) {
        while let Some(t) = self.next_conv_s {
            if t > now_s {
                break;
            }
            self.convert();
            let auto = self.regs[0] & 0xC0 == 0xC0;
            self.next_conv_s = auto.then(|| t + if self.fifty() { 0.020 } else { 0.01667 });
        }
    }

    fn convert(&mut self) {
        self.conversions += 1;
        let mut fault = 0u8;
        let code = if self.open {
            fault |= 0x18; // REFIN- < 0.85 VBIAS, RTDIN- < 0.85 VBIAS: FORCE- open
            0x7FFF
        } else if self.regs[0] & 0x80 == 0 {
            0 // no bias: the ADC sees 0 V
        } else {
            let r = rtd_ohm(self.r0_ohm, self.temp_c);
            ((r / self.r_ref_ohm * 32768.0).round() as i64).clamp(0, 0x7FFF) as u16
        };
        let hft = u16::from_be_bytes([self.regs[3], self.regs[4]]) >> 1;
        let lft = u16::from_be_bytes([self.regs[5], self.regs[6]]) >> 1;
        if code >= hft {
            fault |= 0x80;
        }
        if code < lft {
            fault |= 0x40;
        }
        self.regs[7] |= fault; // latched until cleared
        let raw = (code << 1) | u16::from(self.regs[7] != 0);
        self.regs[1] = (raw >> 8) as u8;
        self.regs[2] = raw as u8;
    }

    fn write_reg(&mut self, a: u8, v: u8) {
        match a {
            0x00 => {
                let was_auto = self.regs[0] & 0x40 != 0;
                if v & 0x02 != 0 && v & 0x2C == 0 {
                    self.regs[7] = 0;
                    self.regs[2] &= !0x01;
                }
                self.regs[0] = v & !0x02;
                let auto = v & 0xC0 == 0xC0;
                if auto && !was_auto {
                    let first = if self.fifty() { 0.0625 } else { 0.052 };
                    self.next_conv_s = Some(self.now + first);
                } else if !auto && v & 0x20 == 0 {
                    self.next_conv_s = None;
                }
            }
            0x03..=0x06 => self.regs[usize::from(a)] = v,
            _ => {} // 01h, 02h, 07h are read-only
        }
    }
}

impl SpiChip for Max31865 {
    fn select(&mut self, now_s: f64) {
        self.advance(now_s);
        self.now = now_s;
        self.addr = 0xFF;
        self.write = false;
    }

    fn exchange(&mut self, mosi: u8) -> u8 {
        if self.addr == 0xFF {
            self.write = mosi & 0x80 != 0;
            self.addr = mosi & 0x07;
            return 0xFF;
        }
        let a = self.addr;
        self.addr = (self.addr + 1) & 0x07;
        if self.write {
            self.write_reg(a, mosi);
            0xFF
        } else {
            self.regs[usize::from(a)]
        }
    }

    fn deselect(&mut self, now_s: f64) {
        if self.regs[0] & 0x20 != 0 {
            self.regs[0] &= !0x20;
            let t = if self.fifty() { 0.0625 } else { 0.052 };
            self.next_conv_s = Some(now_s + t);
        }
    }

    fn any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn power_on_reset(&mut self, _now_s: f64) {
        let keep = (self.temp_c, self.r0_ohm, self.r_ref_ohm, self.open);
        *self = Self::new(keep.0, keep.1, keep.2);
        self.open = keep.3;
    }
}
