//! Temperature sensor frames: MAX31856 (thermocouple) and MAX31865 (RTD) SPI register frames —
//! what to clock out, and how to decode what the chip clocks back, fault bits included.
//!
//! The same decode runs on the STM32 board (real SPI, one chip-select per sensor) and on the
//! QEMU board (a serial stand-in carrying the same bytes, see [`bus`]).

use core::fmt;

/// A sensor fault as reported by the chip (or detected in its frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SensorFault {
    /// Thermocouple input open (MAX31856 OPEN bit) or RTD input open (MAX31865 REFIN-/RTDIN-).
    Open,
    /// Input shorted to GND or VCC: over/under-voltage (MAX31856 OVUV, MAX31865 bit 2).
    ShortOrOvervoltage,
    /// Cold-junction temperature outside the thermocouple type's range (MAX31856 CJ Range).
    ColdJunctionRange,
    /// Thermocouple temperature outside the type's range (MAX31856 TC Range).
    ThermocoupleRange,
    /// Reading above the high or below the low threshold (MAX31856 CJHIGH/CJLOW/TCHIGH/TCLOW,
    /// MAX31865 D7/D6).
    Threshold,
    /// The bus did not answer (timeout, SPI error, all-ones/all-zeros frame).
    NoResponse,
    /// The decoded value is outside the plausible range configured for the channel.
    Implausible,
}

impl fmt::Display for SensorFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SensorFault::Open => "sensor input open",
            SensorFault::ShortOrOvervoltage => {
                "sensor input shorted to GND/VCC (over/under-voltage)"
            }
            SensorFault::ColdJunctionRange => "cold-junction temperature out of range",
            SensorFault::ThermocoupleRange => "thermocouple temperature out of range",
            SensorFault::Threshold => "reading beyond the chip's fault threshold",
            SensorFault::NoResponse => "sensor did not answer on the bus",
            SensorFault::Implausible => "reading outside the plausible range",
        })
    }
}

impl SensorFault {
    /// A stable small code for status reports (bit position in a fault mask).
    pub fn code(self) -> u8 {
        match self {
            SensorFault::Open => 1,
            SensorFault::ShortOrOvervoltage => 2,
            SensorFault::ColdJunctionRange => 3,
            SensorFault::ThermocoupleRange => 4,
            SensorFault::Threshold => 5,
            SensorFault::NoResponse => 6,
            SensorFault::Implausible => 7,
        }
    }
}

/// Which chip sits behind a chip-select.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Chip {
    /// MAX31856 thermocouple-to-digital converter.
    Max31856,
    /// MAX31865 RTD-to-digital converter with the given reference and nominal resistances (Ω).
    Max31865 {
        /// Reference resistor, Ω (430 for PT100 boards, 4300 for PT1000).
        r_ref_ohm: f32,
        /// RTD resistance at 0 °C, Ω (100 or 1000).
        r0_ohm: f32,
    },
}

/// Length of every frame on the bus (address byte + data), bytes.
pub const FRAME_LEN: usize = 8;

/// MAX31856 registers and bits.
pub mod max31856 {
    /// CR0 write address.
    pub const CR0_WRITE: u8 = 0x80;
    /// CR0: automatic conversion mode.
    pub const CR0_CMODE_AUTO: u8 = 0x80;
    /// CR0: open-circuit detection enabled (OCFAULT = 01).
    pub const CR0_OCFAULT_01: u8 = 0x10;
    /// CR1: type K thermocouple, 1 sample.
    pub const CR1_TYPE_K: u8 = 0x03;
    /// CR1: average 4 samples per conversion (AVGSEL = 010): the chip's own noise filter.
    pub const CR1_AVG4: u8 = 0x20;
    /// MASK register value: assert no FAULT pin (faults are read from SR).
    pub const MASK_NONE: u8 = 0xFF;
    /// First register of the read burst: CJTH (cold junction), then CJTL, LTCBH, LTCBM, LTCBL, SR.
    pub const READ_FROM: u8 = 0x0A;
    /// Status register bits.
    pub const SR_CJ_RANGE: u8 = 0x80;
    /// TC Range.
    pub const SR_TC_RANGE: u8 = 0x40;
    /// CJHIGH.
    pub const SR_CJHIGH: u8 = 0x20;
    /// CJLOW.
    pub const SR_CJLOW: u8 = 0x10;
    /// TCHIGH.
    pub const SR_TCHIGH: u8 = 0x08;
    /// TCLOW.
    pub const SR_TCLOW: u8 = 0x04;
    /// OVUV (input shorted to GND/VCC).
    pub const SR_OVUV: u8 = 0x02;
    /// OPEN (open thermocouple).
    pub const SR_OPEN: u8 = 0x01;
    /// Thermocouple temperature resolution, °C per LSB of the 19-bit value.
    pub const TC_LSB_C: f32 = 0.0078125;
    /// Cold-junction resolution, °C per LSB of the 14-bit value.
    pub const CJ_LSB_C: f32 = 0.015625;
}

/// MAX31865 registers and bits.
pub mod max31865 {
    /// Configuration write address.
    pub const CONFIG_WRITE: u8 = 0x80;
    /// Config: VBIAS on, auto conversion, 3-wire off, 50 Hz filter.
    pub const CONFIG_AUTO_50HZ: u8 = 0xC1;
    /// First register of the read burst: RTD MSB, RTD LSB, HFT MSB/LSB, LFT MSB/LSB, fault status.
    pub const READ_FROM: u8 = 0x01;
    /// Callendar–Van Dusen A (IEC 60751).
    pub const CVD_A: f32 = 3.9083e-3;
    /// Callendar–Van Dusen B.
    pub const CVD_B: f32 = -5.775e-7;
}

/// The frames to write once at start-up (each [`FRAME_LEN`] bytes, clocked out with CS low).
pub fn config_frames(chip: Chip) -> [[u8; FRAME_LEN]; 1] {
    match chip {
        Chip::Max31856 => [[
            max31856::CR0_WRITE,
            max31856::CR0_CMODE_AUTO | max31856::CR0_OCFAULT_01,
            max31856::CR1_AVG4 | max31856::CR1_TYPE_K,
            max31856::MASK_NONE,
            0x7F, // CJHF: +127 °C
            0xC0, // CJLF: -64 °C
            0x7F, // LTHFTH
            0xFF, // LTHFTL
        ]],
        Chip::Max31865 { .. } => [[
            max31865::CONFIG_WRITE,
            max31865::CONFIG_AUTO_50HZ,
            0xFF, // HFT MSB
            0xFF, // HFT LSB
            0x00, // LFT MSB
            0x00, // LFT LSB
            0,
            0,
        ]],
    }
}

/// The frame to clock out to read a conversion (address byte, then dummies).
pub fn read_frame(chip: Chip) -> [u8; FRAME_LEN] {
    let mut f = [0u8; FRAME_LEN];
    f[0] = match chip {
        Chip::Max31856 => max31856::READ_FROM,
        Chip::Max31865 { .. } => max31865::READ_FROM,
    };
    f
}

/// A decoded conversion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Measured temperature, °C.
    pub temp_c: f32,
    /// Cold-junction temperature, °C (MAX31856 only, else NaN).
    pub cold_junction_c: f32,
}

/// Decode the bytes clocked in during [`read_frame`] (byte 0 was clocked in while the address
/// went out and is ignored).
pub fn decode(chip: Chip, rx: &[u8; FRAME_LEN]) -> Result<Reading, SensorFault> {
    let d = &rx[1..];
    if d.iter().all(|&b| b == 0xFF) || d.iter().all(|&b| b == 0x00) {
        return Err(SensorFault::NoResponse);
    }
    match chip {
        Chip::Max31856 => decode_max31856(d),
        Chip::Max31865 { r_ref_ohm, r0_ohm } => decode_max31865(d, r_ref_ohm, r0_ohm),
    }
}

fn decode_max31856(d: &[u8]) -> Result<Reading, SensorFault> {
    use max31856::*;
    let (cjth, cjtl, b2, b1, b0, sr) = (d[0], d[1], d[2], d[3], d[4], d[5]);
    if sr & SR_OPEN != 0 {
        return Err(SensorFault::Open);
    }
    if sr & SR_OVUV != 0 {
        return Err(SensorFault::ShortOrOvervoltage);
    }
    if sr & SR_CJ_RANGE != 0 {
        return Err(SensorFault::ColdJunctionRange);
    }
    if sr & SR_TC_RANGE != 0 {
        return Err(SensorFault::ThermocoupleRange);
    }
    if sr & (SR_CJHIGH | SR_CJLOW | SR_TCHIGH | SR_TCLOW) != 0 {
        return Err(SensorFault::Threshold);
    }
    // 19-bit two's complement, left-aligned in 24 bits
    let raw24 = (u32::from(b2) << 16) | (u32::from(b1) << 8) | u32::from(b0);
    let tc = ((raw24 << 8) as i32) >> 13;
    // 14-bit two's complement, left-aligned in 16 bits
    let cj = (((u16::from(cjth) << 8) | u16::from(cjtl)) as i16) >> 2;
    Ok(Reading {
        temp_c: tc as f32 * TC_LSB_C,
        cold_junction_c: f32::from(cj) * CJ_LSB_C,
    })
}

fn decode_max31865(d: &[u8], r_ref: f32, r0: f32) -> Result<Reading, SensorFault> {
    use max31865::*;
    let (msb, lsb, fault) = (d[0], d[1], d[6]);
    if lsb & 1 != 0 || fault != 0 {
        return Err(if fault & 0x38 != 0 {
            SensorFault::Open
        } else if fault & 0x04 != 0 {
            SensorFault::ShortOrOvervoltage
        } else {
            SensorFault::Threshold
        });
    }
    let code = ((u16::from(msb) << 8) | u16::from(lsb)) >> 1;
    let r = f32::from(code) * r_ref / 32768.0;
    // Callendar–Van Dusen for T >= 0 °C (and a good approximation slightly below)
    let disc = CVD_A * CVD_A - 4.0 * CVD_B * (1.0 - r / r0);
    if disc.is_nan() || disc < 0.0 {
        return Err(SensorFault::Implausible);
    }
    let t = (-CVD_A + libm::sqrtf(disc)) / (2.0 * CVD_B);
    Ok(Reading {
        temp_c: t,
        cold_junction_c: f32::NAN,
    })
}

/// Encode a MAX31856 read-burst reply (what the chip clocks out) — for simulators and tests.
pub fn encode_max31856(temp_c: f32, cold_junction_c: f32, sr: u8) -> [u8; FRAME_LEN] {
    use max31856::*;
    let tc = libm::roundf(temp_c / TC_LSB_C) as i32;
    let tc = tc.clamp(-(1 << 18), (1 << 18) - 1);
    let raw24 = ((tc << 5) as u32) & 0x00FF_FFFF;
    let cj = libm::roundf(cold_junction_c / CJ_LSB_C) as i32;
    let cj = cj.clamp(-(1 << 13), (1 << 13) - 1);
    let cj16 = ((cj << 2) as u32 & 0xFFFF) as u16;
    [
        0xFF,
        (cj16 >> 8) as u8,
        cj16 as u8,
        (raw24 >> 16) as u8,
        (raw24 >> 8) as u8,
        raw24 as u8,
        sr,
        0xFF,
    ]
}

/// The QEMU sensor-bus stand-in: a serial port carrying SPI transfers.
///
/// Request (firmware → sensors): `0xA5, cs, n, n bytes` (the bytes clocked out with chip-select
/// `cs` low). Reply (sensors → firmware): `0x5A, cs, n, n bytes` (the bytes clocked in). A reply
/// that does not arrive in time is [`SensorFault::NoResponse`].
pub mod bus {
    use super::FRAME_LEN;

    /// Request start byte.
    pub const REQ: u8 = 0xA5;
    /// Reply start byte.
    pub const REP: u8 = 0x5A;
    /// Length of a request or reply on the wire.
    pub const WIRE_LEN: usize = 3 + FRAME_LEN;

    /// Wrap a transfer for the wire.
    pub fn request(cs: u8, tx: &[u8; FRAME_LEN]) -> [u8; WIRE_LEN] {
        let mut w = [0u8; WIRE_LEN];
        w[0] = REQ;
        w[1] = cs;
        w[2] = FRAME_LEN as u8;
        w[3..].copy_from_slice(tx);
        w
    }

    /// Unwrap a reply for chip-select `cs`; `None` when it is malformed or for another chip.
    pub fn reply(cs: u8, wire: &[u8; WIRE_LEN]) -> Option<[u8; FRAME_LEN]> {
        if wire[0] != REP || wire[1] != cs || usize::from(wire[2]) != FRAME_LEN {
            return None;
        }
        let mut f = [0u8; FRAME_LEN];
        f.copy_from_slice(&wire[3..]);
        Some(f)
    }
}
