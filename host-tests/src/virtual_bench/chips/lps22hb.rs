//! LPS22HB MEMS pressure sensor (on the B-L475E-IOT01A, I2C2 address 5Dh), at register level.
//!
//! Followed from the LPS22HB datasheet (ST DocID027083):
//! - §9 "Register mapping": WHO_AM_I 0Fh = B1h; CTRL_REG1 10h (ODR[2:0] in bits 6:4, EN_LPFP,
//!   LPFP_CFG, BDU bit 1, SIM); CTRL_REG2 11h (BOOT, FIFO_EN, STOP_ON_FTH, IF_ADD_INC bit 4 =
//!   1 by default, I2C_DIS, SWRESET bit 2, ONE_SHOT bit 0); STATUS 27h (T_DA bit 1, P_DA bit 0,
//!   cleared when the data are read); PRESS_OUT_XL/L/H 28h–2Ah; TEMP_OUT_L/H 2Bh–2Ch.
//! - §6.1 / §7: the register address auto-increments on multi-byte access when IF_ADD_INC = 1.
//! - §4.3 / Table 17: power-down after reset (ODR = 000): no conversion until ODR is set (or a
//!   one-shot is requested); ODR 1, 10, 25, 50, 75 Hz.
//! - §4.4 / §9.18: pressure in hPa = PRESS_OUT (24-bit two's complement) / 4096; temperature
//!   in °C = TEMP_OUT (16-bit two's complement) / 100.

use super::I2cChip;

/// 7-bit I2C address of the board's LPS22HB (SA0 high).
pub const ADDRESS: u8 = 0x5D;

/// A simulated LPS22HB.
#[derive(Debug, Clone)]
pub struct Lps22hb {
    regs: [u8; 0x80],
    addr: u8,
    next_conv_s: Option<f64>,
    /// True air pressure, hPa.
    pub pressure_hpa: f64,
    /// True temperature, °C.
    pub temp_c: f64,
    /// Conversions completed.
    pub conversions: u64,
}

impl Lps22hb {
    /// A chip at power-on.
    pub fn new(pressure_hpa: f64) -> Self {
        let mut regs = [0u8; 0x80];
        regs[0x0F] = 0xB1;
        regs[0x11] = 0x10;
        Self {
            regs,
            addr: 0,
            next_conv_s: None,
            pressure_hpa,
            temp_c: 23.0,
            conversions: 0,
        }
    }

    fn odr_hz(&self) -> f64 {
        match (self.regs[0x10] >> 4) & 0x07 {
            1 => 1.0,
            2 => 10.0,
            3 => 25.0,
            4 => 50.0,
            5 => 75.0,
            _ => 0.0,
        }
    }

    fn advance(&mut self, now_s: f64) {
        while let Some(t) = self.next_conv_s {
            if t > now_s {
                break;
            }
            self.convert();
            let odr = self.odr_hz();
            self.next_conv_s = (odr > 0.0).then(|| t + 1.0 / odr);
        }
    }

    fn convert(&mut self) {
        self.conversions += 1;
        let p = (self.pressure_hpa * 4096.0).round() as i32;
        self.regs[0x28] = p as u8;
        self.regs[0x29] = (p >> 8) as u8;
        self.regs[0x2A] = (p >> 16) as u8;
        let t = (self.temp_c * 100.0).round() as i16;
        self.regs[0x2B] = t as u8;
        self.regs[0x2C] = (t >> 8) as u8;
        self.regs[0x27] |= 0x03;
        self.regs[0x11] &= !0x01; // one-shot done
    }
}

impl I2cChip for Lps22hb {
    fn write(&mut self, bytes: &[u8], now_s: f64) {
        self.advance(now_s);
        let Some((&a, data)) = bytes.split_first() else {
            return;
        };
        self.addr = a & 0x7F;
        for &v in data {
            match self.addr {
                0x10 => {
                    let was = self.odr_hz();
                    self.regs[0x10] = v & 0x7F;
                    if was == 0.0 && self.odr_hz() > 0.0 {
                        self.next_conv_s = Some(now_s + 1.0 / self.odr_hz());
                    }
                }
                0x11 => {
                    if v & 0x04 != 0 {
                        *self = Self {
                            pressure_hpa: self.pressure_hpa,
                            temp_c: self.temp_c,
                            ..Self::new(self.pressure_hpa)
                        };
                        return;
                    }
                    self.regs[0x11] = v;
                    if v & 0x01 != 0 && self.odr_hz() == 0.0 {
                        self.next_conv_s = Some(now_s + 0.0133);
                    }
                }
                0x0B..=0x0E | 0x12 | 0x14..=0x19 => self.regs[usize::from(self.addr)] = v,
                _ => {}
            }
            if self.regs[0x11] & 0x10 != 0 {
                self.addr = (self.addr + 1) & 0x7F;
            }
        }
    }

    fn read(&mut self, out: &mut [u8], now_s: f64) {
        self.advance(now_s);
        for b in out.iter_mut() {
            *b = self.regs[usize::from(self.addr)];
            if self.addr == 0x2A {
                self.regs[0x27] &= !0x01;
            }
            if self.addr == 0x2C {
                self.regs[0x27] &= !0x02;
            }
            if self.regs[0x11] & 0x10 != 0 {
                self.addr = (self.addr + 1) & 0x7F;
            }
        }
    }

    fn any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}
