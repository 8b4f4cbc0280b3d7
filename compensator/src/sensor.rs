//! Temperature amplifiers on SPI: MAX31856 (thermocouple) and MAX31865 (RTD), driven at register
//! level. [`Driver`] is one chip's state machine: it says which SPI transaction to run next
//! (configuration burst, fault-latch clear, register dump) and interprets what the chip clocked
//! back. The firmware only runs the transactions (CS low, bytes, CS high); the host tests run the
//! same driver against register-level simulations of the chips.
//!
//! What the driver does, and why (each rule is a defect the first firmware had):
//! - **Configuration bursts write to the right registers.** Both chips auto-increment the address
//!   within one CS-low transaction (MAX31856 datasheet, "Serial Interface"; MAX31865 datasheet,
//!   "Serial Interface", Table 1). The MAX31865's writable registers are 80h (configuration) and
//!   83h–86h (fault thresholds); 81h/82h are the read-only RTD registers. So the thresholds are
//!   written by a separate burst starting at 83h: a burst starting at 80h would put them two
//!   registers early and leave the high threshold at 0000h (every conversion a fault).
//! - **The same mains filter on both chips** ([`Mains`]): MAX31856 CR0 bit 0 (1 = 50 Hz),
//!   MAX31865 configuration D0 (1 = 50 Hz). The MAX31856's notch is set with CMODE = 0 and auto
//!   conversion started in a second write (datasheet, CR0: do not change the notch frequency
//!   while in automatic conversion mode).
//! - **The MAX31865 fault status is latched** until configuration D1 is written with 1 (and D5,
//!   D3, D2 with 0): after a fault reading the driver clears it before the next dump.
//! - **No reading before the first conversion** ([`Driver::first_conversion_ms`]): after
//!   configuration the conversion registers read 0 until the chip has converted.
//! - **Configuration read back every cycle.** Every poll dumps the configuration registers with
//!   the data; a chip that lost its configuration (brown-out, hot-plug: power-on defaults) is a
//!   fault for that reading and is configured again.
//! - **An absent chip is a fault, never a temperature**: with MISO pulled up an absent chip
//!   clocks back FFh (all ones); a dead bus clocks back 00h.

pub use nanocal_interface::settings::{Chip, Mains, TcType, Wires};
pub use nanocal_interface::status::SensorFault;

/// Longest SPI transaction the driver runs, bytes (the MAX31856 register dump: address + 16).
pub const MAX_TXN: usize = 17;

/// MAX31856 registers and bits (datasheet, Table "Register Memory Map" and register
/// descriptions).
pub mod max31856 {
    /// Read addresses 00h..0Fh; write address = read address | 80h.
    pub const WRITE: u8 = 0x80;
    /// Register count (00h CR0 … 0Fh SR).
    pub const REGS: usize = 16;
    /// CR0 address.
    pub const CR0: u8 = 0x00;
    /// CR1.
    pub const CR1: u8 = 0x01;
    /// MASK.
    pub const MASK: u8 = 0x02;
    /// CJHF (cold-junction high fault threshold, 1 °C/LSB).
    pub const CJHF: u8 = 0x03;
    /// CJTH (cold-junction temperature, high byte).
    pub const CJTH: u8 = 0x0A;
    /// LTCBH (linearised thermocouple temperature, high byte).
    pub const LTCBH: u8 = 0x0C;
    /// SR (fault status).
    pub const SR: u8 = 0x0F;
    /// CR0: automatic conversion mode.
    pub const CR0_CMODE: u8 = 0x80;
    /// CR0: one-shot (self-clearing).
    pub const CR0_1SHOT: u8 = 0x40;
    /// CR0: open-circuit detection, OCFAULT = 01.
    pub const CR0_OCFAULT_01: u8 = 0x10;
    /// CR0: interrupt (latched) fault mode; 0 = comparator mode.
    pub const CR0_FAULT_INT: u8 = 0x04;
    /// CR0: fault status clear (self-clearing).
    pub const CR0_FAULTCLR: u8 = 0x02;
    /// CR0: 50 Hz noise rejection (0 = 60 Hz).
    pub const CR0_50HZ: u8 = 0x01;
    /// CR1: AVGSEL = 010, four samples averaged per conversion.
    pub const CR1_AVG4: u8 = 0x20;
    /// Samples averaged (AVGSEL).
    pub const AVG_SAMPLES: u32 = 4;
    /// Power-on register values 00h..09h (datasheet register map "default").
    pub const DEFAULTS: [u8; 10] = [0x00, 0x03, 0xFF, 0x7F, 0xC0, 0x7F, 0xFF, 0x80, 0x00, 0x00];
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
    /// Conversion time of one sample, normally-off / first conversion, ms (datasheet,
    /// Electrical Characteristics, tCONV max: 155 ms at 60 Hz, 185 ms at 50 Hz); each further
    /// averaged sample adds 33.33 ms (60 Hz) or 40 ms (50 Hz) (CR1 AVGSEL description).
    pub const FIRST_CONVERSION_MS: [u32; 2] = [185, 155];
    /// Added per further averaged sample, ms (50 Hz, 60 Hz).
    pub const PER_SAMPLE_MS: [u32; 2] = [40, 34];
}

/// MAX31865 registers and bits (datasheet, Table 1 "Register Names, Addresses, and Defaults").
pub mod max31865 {
    /// Configuration write address.
    pub const CONFIG_WRITE: u8 = 0x80;
    /// High fault threshold MSB write address (83h: HFT MSB, 84h HFT LSB, 85h/86h LFT).
    pub const HFT_WRITE: u8 = 0x83;
    /// Register count (00h configuration … 07h fault status).
    pub const REGS: usize = 8;
    /// RTD MSB read address.
    pub const RTD_MSB: u8 = 0x01;
    /// Fault status read address.
    pub const FAULT: u8 = 0x07;
    /// Configuration: VBIAS on.
    pub const CFG_VBIAS: u8 = 0x80;
    /// Configuration: automatic conversion.
    pub const CFG_AUTO: u8 = 0x40;
    /// Configuration: one-shot (self-clearing).
    pub const CFG_1SHOT: u8 = 0x20;
    /// Configuration: 3-wire RTD.
    pub const CFG_3WIRE: u8 = 0x10;
    /// Configuration: fault detection cycle bits D3:D2.
    pub const CFG_FAULT_CYCLE: u8 = 0x0C;
    /// Configuration: fault status clear (self-clearing).
    pub const CFG_FAULT_CLEAR: u8 = 0x02;
    /// Configuration: 50 Hz filter (0 = 60 Hz).
    pub const CFG_50HZ: u8 = 0x01;
    /// Fault status: RTD above the high threshold.
    pub const FAULT_HIGH: u8 = 0x80;
    /// Fault status: RTD below the low threshold.
    pub const FAULT_LOW: u8 = 0x40;
    /// Fault status: REFIN- > 0.85 × VBIAS, REFIN- < 0.85 × VBIAS (FORCE- open),
    /// RTDIN- < 0.85 × VBIAS (FORCE- open).
    pub const FAULT_OPEN: u8 = 0x38;
    /// Fault status: over/under-voltage.
    pub const FAULT_OVUV: u8 = 0x04;
    /// Power-on register values 00h..07h.
    pub const DEFAULTS: [u8; 8] = [0x00, 0x00, 0x00, 0xFF, 0xFF, 0x00, 0x00, 0x00];
    /// Callendar–Van Dusen A (IEC 60751).
    pub const CVD_A: f32 = 3.9083e-3;
    /// Callendar–Van Dusen B.
    pub const CVD_B: f32 = -5.775e-7;
    /// First conversion after automatic mode is entered, ms: the one-shot conversion time
    /// (datasheet, Electrical Characteristics, tCONV one-shot max: 62.5 ms at 50 Hz, 52 ms at
    /// 60 Hz); then one conversion every 20 ms (50 Hz) / 16.7 ms (60 Hz).
    pub const FIRST_CONVERSION_MS: [u32; 2] = [63, 52];
}

fn mains_index(m: Mains) -> usize {
    match m {
        Mains::Hz50 => 0,
        Mains::Hz60 => 1,
    }
}

/// The values the driver keeps in a MAX31856's registers 00h..08h.
pub fn max31856_config(tc: TcType, mains: Mains) -> [u8; 9] {
    use max31856::*;
    let notch = if mains == Mains::Hz50 { CR0_50HZ } else { 0 };
    [
        CR0_CMODE | CR0_OCFAULT_01 | notch, // comparator fault mode: SR follows the input
        CR1_AVG4 | tc as u8,
        0xFF, // MASK: FAULT pin not used (faults are read from SR)
        0x7F, // CJHF +127 °C
        0xC0, // CJLF −64 °C
        0x7F, // LTHFT +2047.9375 °C
        0xFF,
        0x80, // LTLFT −2048 °C
        0x00,
    ]
}

/// The MAX31865 configuration register value the driver keeps.
pub fn max31865_config(wires: Wires, mains: Mains) -> u8 {
    use max31865::*;
    let w = if wires == Wires::Three { CFG_3WIRE } else { 0 };
    let notch = if mains == Mains::Hz50 { CFG_50HZ } else { 0 };
    CFG_VBIAS | CFG_AUTO | w | notch
}

/// The transactions a driver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Txn {
    /// Configuration burst number `n` (0-based).
    Configure(u8),
    /// Clear the MAX31865's latched fault status.
    ClearFault,
    /// Dump every register (configuration read-back, conversion, status).
    Poll,
}

/// What a completed transaction produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// Run the next transaction ([`Driver::next`]).
    Continue,
    /// Nothing to report this cycle (configuring, waiting for the first conversion).
    Waiting,
    /// A reading (or a fault) for this cycle.
    Reading(Result<Reading, SensorFault>),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Configuration burst `n` is next.
    Configuring(u8),
    /// Configured at `since_ms`; waiting for the first conversion.
    Warming { since_ms: u32 },
    /// Converting: every cycle dumps the registers.
    Running,
}

/// One chip's driver (pure: time is passed in).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Driver {
    chip: Chip,
    mains: Mains,
    state: State,
    clear_fault: bool,
    /// Times the chip was found without its configuration and configured again.
    pub reconfigurations: u32,
}

impl Driver {
    /// A driver that configures `chip` on its first transaction.
    pub fn new(chip: Chip, mains: Mains) -> Self {
        Self {
            chip,
            mains,
            state: State::Configuring(0),
            clear_fault: false,
            reconfigurations: 0,
        }
    }

    /// The chip driven.
    pub fn chip(&self) -> Chip {
        self.chip
    }

    /// Time from configuration to the first valid conversion, ms (datasheet maximum, see
    /// [`max31856::FIRST_CONVERSION_MS`], [`max31865::FIRST_CONVERSION_MS`]).
    pub fn first_conversion_ms(&self) -> u32 {
        let m = mains_index(self.mains);
        match self.chip {
            Chip::Max31856 { .. } => {
                max31856::FIRST_CONVERSION_MS[m]
                    + (max31856::AVG_SAMPLES - 1) * max31856::PER_SAMPLE_MS[m]
            }
            Chip::Max31865 { .. } => max31865::FIRST_CONVERSION_MS[m],
        }
    }

    fn bursts(&self) -> u8 {
        match self.chip {
            Chip::Max31856 { .. } => 2,
            Chip::Max31865 { .. } => 2,
        }
    }

    /// The next transaction to run at `now_ms`, or `None` when there is nothing to do this
    /// cycle (waiting for the first conversion).
    pub fn next(&mut self, now_ms: u32) -> Option<Txn> {
        match self.state {
            State::Configuring(n) => Some(Txn::Configure(n)),
            State::Warming { since_ms } => {
                if now_ms.wrapping_sub(since_ms) >= self.first_conversion_ms() {
                    self.state = State::Running;
                    self.next(now_ms)
                } else {
                    None
                }
            }
            State::Running if self.clear_fault => Some(Txn::ClearFault),
            State::Running => Some(Txn::Poll),
        }
    }

    /// Fill `buf` with the bytes to clock out for `txn`; returns the transaction's length.
    pub fn fill(&self, txn: Txn, buf: &mut [u8; MAX_TXN]) -> usize {
        buf.fill(0);
        match (self.chip, txn) {
            (Chip::Max31856 { tc }, Txn::Configure(n)) => {
                let cfg = max31856_config(tc, self.mains);
                if n == 0 {
                    // everything, with CMODE = 0 (the notch may only change when not converting)
                    buf[0] = max31856::WRITE | max31856::CR0;
                    buf[1..10].copy_from_slice(&cfg);
                    buf[1] &= !max31856::CR0_CMODE;
                    10
                } else {
                    buf[0] = max31856::WRITE | max31856::CR0;
                    buf[1] = cfg[0];
                    2
                }
            }
            (Chip::Max31865 { wires, .. }, Txn::Configure(n)) => {
                if n == 0 {
                    buf[0] = max31865::CONFIG_WRITE;
                    buf[1] = max31865_config(wires, self.mains);
                    2
                } else {
                    // thresholds start at 83h: 81h/82h are the read-only RTD registers
                    buf[..5].copy_from_slice(&[max31865::HFT_WRITE, 0xFF, 0xFF, 0x00, 0x00]);
                    5
                }
            }
            (Chip::Max31865 { wires, .. }, Txn::ClearFault) => {
                buf[0] = max31865::CONFIG_WRITE;
                buf[1] = max31865_config(wires, self.mains) | max31865::CFG_FAULT_CLEAR;
                2
            }
            (Chip::Max31856 { .. }, Txn::ClearFault) => {
                // comparator mode: nothing latched; a dump does no harm
                1 + max31856::REGS
            }
            (Chip::Max31856 { .. }, Txn::Poll) => 1 + max31856::REGS,
            (Chip::Max31865 { .. }, Txn::Poll) => 1 + max31865::REGS,
        }
    }

    /// Interpret the bytes clocked in during `txn` (`Err` when the bus failed or timed out).
    pub fn complete(&mut self, txn: Txn, rx: Result<&[u8], SensorFault>, now_ms: u32) -> Outcome {
        match txn {
            Txn::Configure(n) => {
                if rx.is_err() {
                    self.state = State::Configuring(0);
                    return Outcome::Reading(Err(SensorFault::NoResponse));
                }
                if n + 1 < self.bursts() {
                    self.state = State::Configuring(n + 1);
                    Outcome::Continue
                } else {
                    self.state = State::Warming { since_ms: now_ms };
                    self.clear_fault = matches!(self.chip, Chip::Max31865 { .. });
                    Outcome::Waiting
                }
            }
            Txn::ClearFault => {
                self.clear_fault = false;
                if rx.is_err() {
                    self.state = State::Configuring(0);
                    return Outcome::Reading(Err(SensorFault::NoResponse));
                }
                Outcome::Continue
            }
            Txn::Poll => {
                let r = match rx {
                    Ok(b) if !b.is_empty() => self.decode_dump(&b[1..]),
                    _ => Err(SensorFault::NoResponse),
                };
                match r {
                    Err(SensorFault::NoResponse) | Err(SensorFault::ConfigLost) => {
                        // absent, unpowered or reset: configure again (hot-plug comes back)
                        self.state = State::Configuring(0);
                        if r == Err(SensorFault::ConfigLost) {
                            self.reconfigurations = self.reconfigurations.wrapping_add(1);
                        }
                    }
                    Err(_) => {
                        // the MAX31865 keeps its fault bits until cleared
                        self.clear_fault = matches!(self.chip, Chip::Max31865 { .. });
                    }
                    Ok(_) => {}
                }
                Outcome::Reading(r)
            }
        }
    }

    /// Decode a register dump (registers from 00h on).
    pub fn decode_dump(&self, regs: &[u8]) -> Result<Reading, SensorFault> {
        if regs.iter().all(|&b| b == 0xFF) || regs.iter().all(|&b| b == 0x00) {
            return Err(SensorFault::NoResponse);
        }
        match self.chip {
            Chip::Max31856 { tc } => {
                if regs.len() < max31856::REGS {
                    return Err(SensorFault::NoResponse);
                }
                let want = max31856_config(tc, self.mains);
                let got_cr0 = regs[0] & !(max31856::CR0_1SHOT | max31856::CR0_FAULTCLR);
                if got_cr0 != want[0] || regs[1..9] != want[1..] {
                    return Err(SensorFault::ConfigLost);
                }
                decode_max31856(&regs[10..16])
            }
            Chip::Max31865 {
                r_ref_ohm,
                r0_ohm,
                wires,
            } => {
                if regs.len() < max31865::REGS {
                    return Err(SensorFault::NoResponse);
                }
                let want = max31865_config(wires, self.mains);
                if regs[0] & !(max31865::CFG_1SHOT | max31865::CFG_FAULT_CLEAR) != want
                    || regs[3..7] != [0xFF, 0xFF, 0x00, 0x00]
                {
                    return Err(SensorFault::ConfigLost);
                }
                decode_max31865(regs[1], regs[2], regs[7], r_ref_ohm, r0_ohm)
            }
        }
    }
}

/// A decoded conversion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Measured temperature, °C.
    pub temp_c: f32,
    /// Cold-junction temperature, °C (MAX31856 only, else NaN).
    pub cold_junction_c: f32,
}

/// Decode MAX31856 registers 0Ah..0Fh (CJTH, CJTL, LTCBH, LTCBM, LTCBL, SR).
pub fn decode_max31856(d: &[u8]) -> Result<Reading, SensorFault> {
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

/// Decode MAX31865 RTD MSB/LSB and fault status.
pub fn decode_max31865(
    msb: u8,
    lsb: u8,
    fault: u8,
    r_ref: f32,
    r0: f32,
) -> Result<Reading, SensorFault> {
    use max31865::*;
    if lsb & 1 != 0 || fault != 0 {
        return Err(if fault & FAULT_OPEN != 0 {
            SensorFault::Open
        } else if fault & FAULT_OVUV != 0 {
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
