//! MAX31856 precision thermocouple-to-digital converter, at register level.
//!
//! Followed from the MAX31856 datasheet (Maxim 19-7175):
//! - "Serial Interface": the first byte after CS falls is the address (A7 = 1 write); data
//!   bytes follow and the address increments after each byte (multi-byte transfers), for reads
//!   and writes, wrapping after 0Fh.
//! - Table "Register Memory Map": 00h CR0 … 09h CJTO read/write, 0Ah/0Bh CJTH/CJTL (writable
//!   only while the cold-junction sensor is disabled, CR0.CJ = 1), 0Ch–0Eh LTCB and 0Fh SR
//!   read-only; power-on values as listed there.
//! - CR0: CMODE (auto conversion), 1SHOT (conversion when CS rises, self-clearing), OCFAULT
//!   (open-circuit detection), FAULT (0 comparator mode: SR follows the conditions; 1 interrupt
//!   mode: SR bits stay set until FAULTCLR), FAULTCLR (self-clearing), 50/60 Hz notch.
//! - Electrical Characteristics, conversion time: first conversion (or one-shot) 143 ms at
//!   60 Hz, 169 ms at 50 Hz typical; continuous conversions every 82/98 ms; each further
//!   averaged sample (CR1 AVGSEL) adds 33.33/40 ms. Until the first conversion the temperature
//!   registers hold their power-on zeros.
//! - SR bits: CJ Range, TC Range, CJHIGH, CJLOW, TCHIGH, TCLOW, OVUV, OPEN; thresholds LTHFT/
//!   LTLFT (0.0625 °C/LSB, 16-bit) and CJHF/CJLF (1 °C/LSB).
//! - Electrical Characteristics, input-referred noise: a conversion reads the thermocouple
//!   temperature plus white noise of [`Max31856::noise_c`] (°C RMS; 0 by default); with a
//!   [`TempSource`] each conversion samples the temperature at the instant it completes.

use super::SpiChip;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// The thermocouple's temperature as a function of the bench's time (s) — e.g. the digital
/// twin's room — sampled by each conversion when it completes.
#[derive(Clone)]
pub struct TempSource(pub Arc<dyn Fn(f64) -> f64 + Send + Sync>);

impl std::fmt::Debug for TempSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TempSource")
    }
}

const DEFAULTS: [u8; 16] = [
    0x00, 0x03, 0xFF, 0x7F, 0xC0, 0x7F, 0xFF, 0x80, 0x00, 0x00, 0, 0, 0, 0, 0, 0,
];

/// A simulated MAX31856 with its thermocouple.
#[derive(Debug, Clone)]
pub struct Max31856 {
    regs: [u8; 16],
    addr: u8,
    write: bool,
    first: bool,
    /// Time of the next completed conversion (None: not converting).
    next_conv_s: Option<f64>,
    /// True thermocouple (hot-junction) temperature, °C.
    pub temp_c: f64,
    /// True cold-junction (die) temperature, °C.
    pub cold_junction_c: f64,
    /// The thermocouple is broken (open circuit).
    pub open: bool,
    /// An input is shorted to a supply (over/under-voltage).
    pub shorted: bool,
    /// Conversions completed.
    pub conversions: u64,
    /// Where the temperature comes from (else [`Max31856::temp_c`]).
    pub source: Option<TempSource>,
    /// Reading noise, °C RMS per conversion.
    pub noise_c: f64,
    rng: ChaCha8Rng,
    now: f64,
}

impl Max31856 {
    /// A chip at power-on with its thermocouple at `temp_c` and the die at 25 °C.
    pub fn new(temp_c: f64) -> Self {
        Self {
            regs: DEFAULTS,
            addr: 0,
            write: false,
            first: true,
            next_conv_s: None,
            temp_c,
            cold_junction_c: 25.0,
            open: false,
            shorted: false,
            conversions: 0,
            source: None,
            noise_c: 0.0,
            rng: ChaCha8Rng::seed_from_u64(0x3185_6000),
            now: 0.0,
        }
    }

    /// The same chip with its temperature from `source`, `noise_c` °C RMS of reading noise, and
    /// its noise seeded with `seed`.
    pub fn following(mut self, source: TempSource, noise_c: f64, seed: u64) -> Self {
        self.source = Some(source);
        self.noise_c = noise_c;
        self.rng = ChaCha8Rng::seed_from_u64(seed);
        self
    }

    /// The register file (for tests).
    pub fn regs(&self) -> &[u8; 16] {
        &self.regs
    }

    fn fifty(&self) -> bool {
        self.regs[0] & 0x01 != 0
    }

    fn samples(&self) -> f64 {
        match (self.regs[1] >> 4) & 0x07 {
            0 => 1.0,
            1 => 2.0,
            2 => 4.0,
            3 => 8.0,
            _ => 16.0,
        }
    }

    fn conversion_s(&self, first: bool) -> f64 {
        let (base, extra) = match (self.fifty(), first) {
            (true, true) => (0.169, 0.040),
            (false, true) => (0.143, 0.03333),
            (true, false) => (0.098, 0.040),
            (false, false) => (0.082, 0.03333),
        };
        base + (self.samples() - 1.0) * extra
    }

    /// Run conversions due by `now_s`.
    fn advance(&mut self, now_s: f64) {
        while let Some(t) = self.next_conv_s {
            if t > now_s {
                break;
            }
            self.convert(t);
            self.first = false;
            self.next_conv_s = if self.regs[0] & 0x80 != 0 {
                Some(t + self.conversion_s(false))
            } else {
                None
            };
        }
    }

    fn convert(&mut self, at_s: f64) {
        self.conversions += 1;
        if let Some(src) = &self.source {
            self.temp_c = (src.0)(at_s);
        }
        let reading_c = self.temp_c + self.noise_c * crate::twin::normal(&mut self.rng);
        let cj = (self.cold_junction_c / 0.015625)
            .round()
            .clamp(-8192.0, 8191.0) as i32;
        let cj16 = ((cj << 2) as u32 & 0xFFFF) as u16;
        self.regs[0x0A] = (cj16 >> 8) as u8;
        self.regs[0x0B] = cj16 as u8;
        let tc = (reading_c / 0.0078125).round().clamp(-262_144.0, 262_143.0) as i32;
        let raw = ((tc << 5) as u32) & 0x00FF_FFFF;
        self.regs[0x0C] = (raw >> 16) as u8;
        self.regs[0x0D] = (raw >> 8) as u8;
        self.regs[0x0E] = raw as u8;
        let mut sr = 0u8;
        if self.open && self.regs[0] & 0x30 != 0 {
            sr |= 0x01;
        }
        if self.shorted {
            sr |= 0x02;
        }
        let lthft = i16::from_be_bytes([self.regs[5], self.regs[6]]) as f64 * 0.0625;
        let ltlft = i16::from_be_bytes([self.regs[7], self.regs[8]]) as f64 * 0.0625;
        if reading_c > lthft {
            sr |= 0x08;
        }
        if reading_c < ltlft {
            sr |= 0x04;
        }
        if self.cold_junction_c > f64::from(self.regs[3] as i8) {
            sr |= 0x20;
        }
        if self.cold_junction_c < f64::from(self.regs[4] as i8) {
            sr |= 0x10;
        }
        if self.regs[0] & 0x04 != 0 {
            self.regs[0x0F] |= sr; // interrupt mode: latched
        } else {
            self.regs[0x0F] = sr; // comparator mode
        }
    }

    fn write_reg(&mut self, a: u8, v: u8, now_s: f64) {
        match a {
            0x00 => {
                let was_auto = self.regs[0] & 0x80 != 0;
                if v & 0x02 != 0 {
                    self.regs[0x0F] = 0; // FAULTCLR
                }
                self.regs[0] = v & !0x02;
                let auto = v & 0x80 != 0;
                if auto && !was_auto {
                    self.next_conv_s = Some(now_s + self.conversion_s(true));
                } else if !auto && self.regs[0] & 0x40 == 0 {
                    self.next_conv_s = None;
                }
            }
            0x01..=0x09 => self.regs[usize::from(a)] = v,
            0x0A | 0x0B if self.regs[0] & 0x08 != 0 => self.regs[usize::from(a)] = v,
            _ => {} // read-only
        }
    }
}

impl SpiChip for Max31856 {
    fn select(&mut self, now_s: f64) {
        self.advance(now_s);
        self.first = self.first && self.conversions == 0;
        self.addr = 0xFF; // the next byte is the address
        self.write = false;
        self.now_cache(now_s);
    }

    fn exchange(&mut self, mosi: u8) -> u8 {
        if self.addr == 0xFF {
            self.write = mosi & 0x80 != 0;
            self.addr = mosi & 0x0F;
            return 0xFF; // SDO is high-impedance during the address: pulled up
        }
        let a = self.addr;
        self.addr = (self.addr + 1) & 0x0F;
        if self.write {
            let now = self.now;
            self.write_reg(a, mosi, now);
            0xFF
        } else {
            self.regs[usize::from(a)]
        }
    }

    fn deselect(&mut self, now_s: f64) {
        if self.regs[0] & 0x40 != 0 {
            // 1SHOT: conversion starts when CS rises, the bit clears when it is done
            self.regs[0] &= !0x40;
            if self.next_conv_s.is_none() {
                self.next_conv_s = Some(now_s + self.conversion_s(true));
            }
        }
    }

    fn any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn power_on_reset(&mut self, _now_s: f64) {
        let fresh = Self::new(self.temp_c);
        let keep = std::mem::replace(self, fresh);
        (self.cold_junction_c, self.open, self.shorted) =
            (keep.cold_junction_c, keep.open, keep.shorted);
        (self.source, self.noise_c, self.rng) = (keep.source, keep.noise_c, keep.rng);
    }
}

impl Max31856 {
    fn now_cache(&mut self, now_s: f64) {
        self.now = now_s;
    }
}
