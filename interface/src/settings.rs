//! The device's persistent settings: what is wired to the board and how the stage controller
//! talks. Set over the management channel (`CONFIG_GET`/`CONFIG_SET`, `nanocal device
//! config`), stored in flash next to the model in this same layout.
//!
//! ```text
//! offset  0  magic "NCST" | version u8 (= VERSION)
//!         5  stage_baud u32 LE
//!         9  sensors: SENSORS × { kind u8 (0 none, 1 MAX31856, 2 MAX31865) | a u8 (TC type 0..7
//!            B E J K N R S T, or RTD wires 2/3/4) | r_ref_ohm f32 | r0_ohm f32 }   (10 bytes each)
//!       169  mains u8 (50 or 60) | sample_period_ms u16 | reserved u8 (written 0, ignored)
//!       173  axis names: 3 × { len u8 | 8 bytes }                                    (9 bytes each)
//!       200  aux sources: MAX_AUX × { kind u8 (0 none, 1 air pressure hPa, 2 force N) | channel u8
//!            | scale f32 | offset f32 }                                            (10 bytes each)
//!       240  fold_period_ms u16 LE (1000..=10000)
//!       242  stale_k f32 LE (0 < k ≤ 100): the model-stale check's k standard errors
//!       246  extrapolation_c f32 LE (0..=50): how far, °C, the model may read temperatures
//!            beyond its training envelope before it counts as stale
//!       250  allow_other_stage u8 (0 or 1): compensate a stage whose controller's serial
//!            differs from the one the model was fitted on
//!       251  follow_nm u16 LE (0 off, else 1..=10000): re-issue a held target when the fold
//!            moves its command by more than this
//!       253  follow_interval_ms u16 LE (100..=60000): at most one re-issue per interval
//!       255  follow_step_nm u16 LE (0 no limit): largest change of a command per re-issue
//!       257  crc32 u32 LE (CRC-32/ISO-HDLC of bytes 0..257)
//! ```
//! Version 6 adds `allow_other_stage` (the provenance check, `nanocal_model::provenance`) and
//! *held targets follow the model* (`nanocal_compensator::proxy::FollowConfig`): 261 bytes, the
//! CRC moves from 250 to 257. Version 5 and 4 records (254 bytes) still decode, with
//! `allow_other_stage` off and following off.
//! Version 5 drops the stage unit (byte 172 in versions 2 to 4, 92 in version 1: 0 µm, 1 mm,
//! 2 nm): the firmware never read it, the proxy asks the controller (`PUN?`) and moves only
//! model axes in µm (GCS error 9007 otherwise), so the one unit worth declaring is the one
//! already required. The byte stays where it was, written 0 and ignored on decode: every offset
//! and length is unchanged, and so is the management protocol (6); a host built before layout 5
//! refuses a layout 5 record with [`SettingsError::Version`].
//! Version 4 adds the model-stale check's two numbers (`nanocal_compensator::stale`).
//! Version 3 (the fold period; the readings of a fold period are averaged and the model
//! folded once a period: `nanocal_compensator::slow_average`; 246 bytes, CRC at 242), version
//! 2 (16 chip-selects, no fold period: 244 bytes, CRC at 240) and version 1 (8 chip-selects,
//! 164 bytes, mains at 89, axes at 93, aux at 120, CRC at 160, chip-selects 8..15 empty) still
//! decode, with the defaults for what they lack and their stage unit ignored (whatever it held):
//! settings stored by an older firmware survive an update.

use core::fmt;
use nanocal_model::{MAX_AUX, MAX_AXES};

/// Model axes the settings name (the model's maximum).
pub const MAP_AXES: usize = MAX_AXES;

/// Longest GCS axis identifier (bytes).
pub const MAX_AXIS_ID: usize = 8;

/// A GCS axis identifier (1 to [`MAX_AXIS_ID`] bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisId {
    bytes: [u8; MAX_AXIS_ID],
    len: u8,
}

impl AxisId {
    /// A one-character identifier (PI's usual `1`, `2`, `3`, or `X`, `Y`, `Z`).
    pub const fn single(c: u8) -> Self {
        let mut bytes = [0; MAX_AXIS_ID];
        bytes[0] = c;
        Self { bytes, len: 1 }
    }
    /// An identifier from bytes; `None` when empty or too long.
    #[inline]
    pub fn new(id: &[u8]) -> Option<Self> {
        if id.is_empty() || id.len() > MAX_AXIS_ID {
            return None;
        }
        let mut bytes = [0; MAX_AXIS_ID];
        bytes[..id.len()].copy_from_slice(id);
        Some(Self {
            bytes,
            len: id.len() as u8,
        })
    }
    /// The identifier's bytes.
    #[inline]
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len as usize]
    }
}

/// Mains frequency: both chips' digital filters notch it (and its harmonics).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mains {
    /// 50 Hz mains (Europe, most of Asia, Africa).
    #[default]
    Hz50,
    /// 60 Hz mains (the Americas, parts of Japan).
    Hz60,
}

/// Thermocouple types the MAX31856 linearises (CR1 TC TYPE, datasheet Table "CR1").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[allow(missing_docs)]
pub enum TcType {
    B = 0,
    E = 1,
    J = 2,
    K = 3,
    N = 4,
    R = 5,
    S = 6,
    T = 7,
}

impl TcType {
    /// From the CR1 code (0..=7).
    pub fn from_code(c: u8) -> Option<Self> {
        use TcType::*;
        Some(match c {
            0 => B,
            1 => E,
            2 => J,
            3 => K,
            4 => N,
            5 => R,
            6 => S,
            7 => T,
            _ => return None,
        })
    }

    /// The letter.
    pub fn letter(self) -> char {
        b"BEJKNRST"[self as usize] as char
    }
}

/// RTD wiring (MAX31865 configuration D4: 1 = 3-wire, 0 = 2- or 4-wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Wires {
    /// 2-wire.
    Two = 2,
    /// 3-wire.
    Three = 3,
    /// 4-wire.
    Four = 4,
}

/// Which chip sits behind a chip-select, and how it is wired.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Chip {
    /// MAX31856 thermocouple-to-digital converter.
    Max31856 {
        /// Thermocouple type.
        tc: TcType,
    },
    /// MAX31865 RTD-to-digital converter.
    Max31865 {
        /// Reference resistor, Ω (430 on PT100 boards, 4300 on PT1000 boards).
        r_ref_ohm: f32,
        /// RTD resistance at 0 °C, Ω (100 for PT100, 1000 for PT1000).
        r0_ohm: f32,
        /// Wiring.
        wires: Wires,
    },
}

impl Chip {
    /// A type K thermocouple on a MAX31856.
    pub const K: Chip = Chip::Max31856 { tc: TcType::K };
    /// A 3-wire PT100 on a MAX31865 with a 430 Ω reference (Adafruit/Maxim evaluation boards).
    pub const PT100_3W: Chip = Chip::Max31865 {
        r_ref_ohm: 430.0,
        r0_ohm: 100.0,
        wires: Wires::Three,
    };
}

/// Chip-selects the settings can configure for temperature amplifiers (one per temperature
/// input a model can read).
pub const SENSORS: usize = nanocal_model::MAX_TEMPS;
/// Settings magic.
pub const MAGIC: [u8; 4] = *b"NCST";
/// Layout version; bumped whenever the bytes change.
pub const VERSION: u8 = 6;
/// Encoded length.
pub const LEN: usize = Layout::of(SENSORS, true, true, true).len;
/// Largest re-issue threshold the settings accept, nm (10 µm: beyond it a drift is no thermal
/// correction to follow quietly).
pub const MAX_FOLLOW_NM: u16 = 10_000;
/// Re-issue interval unless set, ms.
pub const DEFAULT_FOLLOW_INTERVAL_MS: u16 = 10_000;
/// Shortest re-issue interval the settings accept, ms.
pub const MIN_FOLLOW_INTERVAL_MS: u16 = 100;
/// Longest re-issue interval the settings accept, ms.
pub const MAX_FOLLOW_INTERVAL_MS: u16 = 60_000;
/// The model-stale check's `k` unless set: a KMZ re-measurement more than 3 standard errors of
/// prediction from the model's prediction raises `MODEL_STALE` (a chance of 0.3 % per
/// re-measurement for a model that still holds, with normal residuals).
pub const DEFAULT_STALE_K: f32 = 3.0;
/// Largest `k` the settings accept.
pub const MAX_STALE_K: f32 = 100.0;
/// How far beyond its training envelope a model may read temperatures unless set, °C: 0.1 °C,
/// about six times the single-reading noise of the type K channels (≈ 16 mK) and a third of
/// the 0.2–0.3 °C swings paper 000 §4.3.2 calls "basically within the temperature range of
/// training" — the fold's averages wander that far over the envelope of the training's
/// single readings while the model still holds (measured on the virtual bench: README,
/// *The model knows when it has gone stale*).
pub const DEFAULT_EXTRAPOLATION_C: f32 = 0.1;
/// Largest extrapolation margin the settings accept, °C.
pub const MAX_EXTRAPOLATION_C: f32 = 50.0;
/// Fold period of settings that do not say (the default, and versions 1 and 2), ms: paper 001
/// §VI's "each 5-10 seconds" at its short end.
pub const DEFAULT_FOLD_PERIOD_MS: u16 = 5_000;
/// Shortest fold period the settings accept, ms.
pub const MIN_FOLD_PERIOD_MS: u16 = 1_000;
/// Longest fold period the settings accept, ms (paper 001 §VI: "each 5-10 seconds").
pub const MAX_FOLD_PERIOD_MS: u16 = 10_000;

/// Where an auxiliary model input comes from on this board.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AuxSource {
    /// Nothing: a model using this aux channel is refused at upload.
    #[default]
    None,
    /// Air pressure, hPa, from the board's LPS22HB barometer.
    AirPressure,
    /// Force, N, from an ADC channel: `force_n = offset_n + scale_n_per_count × code`.
    Force {
        /// ADC channel.
        channel: u8,
        /// N per ADC count.
        scale_n_per_count: f32,
        /// N at code 0.
        offset_n: f32,
    },
}

/// Everything the user configures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Stage link baud rate (8N1).
    pub stage_baud: u32,
    /// Amplifier behind each chip-select (`None` = nothing fitted).
    pub sensors: [Option<Chip>; SENSORS],
    /// Mains frequency the amplifiers' filters reject.
    pub mains: Mains,
    /// Sensor sampling period, ms.
    pub sample_period_ms: u16,
    /// Fold period, ms: the readings of a period are averaged and the model folded with the
    /// averages once a period (1000..=10000; `nanocal_compensator::slow_average`).
    pub fold_period_ms: u16,
    /// GCS identifiers of model axes 0, 1, 2.
    pub axis_names: [AxisId; MAP_AXES],
    /// Source of each auxiliary model input: a force channel, or what an input of kind "other"
    /// reads (the compensator's `inputs::aux_source` decides).
    pub aux: [AuxSource; MAX_AUX],
    /// The model-stale check's `k`: a KMZ re-measurement whose λ change leaves `k` standard
    /// errors of prediction raises `MODEL_STALE` (0 < k ≤ [`MAX_STALE_K`]).
    pub stale_k: f32,
    /// How far a temperature may leave the model's training envelope, °C, before the model
    /// counts as stale: what the model was shown to extrapolate (0..=[`MAX_EXTRAPOLATION_C`]).
    pub extrapolation_c: f32,
    /// Compensate moves even when the controller's identification (`*IDN?`) names another
    /// stage serial than the model was fitted on (status still reports the mismatch). Off
    /// unless set: a model on the wrong stage is refused, not applied.
    pub allow_other_stage: bool,
    /// Held targets follow the model: re-issue the corrected command of the target the stage
    /// holds when the fold moves it by more than this, nm (0: off, the default;
    /// ..=[`MAX_FOLLOW_NM`]).
    pub follow_nm: u16,
    /// At most one re-issue per this many ms ([`MIN_FOLLOW_INTERVAL_MS`]..=
    /// [`MAX_FOLLOW_INTERVAL_MS`]); the first no sooner after the host's move.
    pub follow_interval_ms: u16,
    /// Largest change of a command per re-issue, nm (0: no limit).
    pub follow_step_nm: u16,
}

impl Default for Settings {
    fn default() -> Self {
        let mut sensors = [None; SENSORS];
        for s in sensors.iter_mut().take(4) {
            *s = Some(Chip::K);
        }
        Self {
            stage_baud: 115_200,
            sensors,
            mains: Mains::Hz50,
            sample_period_ms: 250,
            fold_period_ms: DEFAULT_FOLD_PERIOD_MS,
            axis_names: [
                AxisId::single(b'1'),
                AxisId::single(b'2'),
                AxisId::single(b'3'),
            ],
            aux: [AuxSource::None; MAX_AUX],
            stale_k: DEFAULT_STALE_K,
            extrapolation_c: DEFAULT_EXTRAPOLATION_C,
            allow_other_stage: false,
            follow_nm: 0,
            follow_interval_ms: DEFAULT_FOLLOW_INTERVAL_MS,
            follow_step_nm: 0,
        }
    }
}

/// Why settings bytes or values were refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SettingsError {
    /// Wrong length.
    Length,
    /// Not settings (magic).
    Magic,
    /// Written by another layout version.
    Version(u8),
    /// CRC mismatch (torn or corrupted record).
    Crc,
    /// A field holds a value outside its range (byte offset of the field).
    Field(u16),
}

impl fmt::Display for SettingsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SettingsError::Length => write!(f, "settings record is not {LEN} bytes"),
            SettingsError::Magic => f.write_str("settings record has no NCST magic"),
            SettingsError::Version(v) => {
                write!(f, "settings layout version {v}, expected {VERSION}")
            }
            SettingsError::Crc => f.write_str("settings record CRC mismatch"),
            SettingsError::Field(o) => write!(f, "settings field at byte {o} out of range"),
        }
    }
}

const SENSOR_AT: usize = 9;

/// Where the fields after the sensors sit, for a layout with `sensors` chip-selects (and the
/// fold period, and the stale check, or not).
struct Layout {
    sensors: usize,
    mains_at: usize,
    axes_at: usize,
    aux_at: usize,
    fold_at: Option<usize>,
    stale_at: Option<usize>,
    stage_at: Option<usize>,
    follow_at: Option<usize>,
    crc_at: usize,
    len: usize,
}

impl Layout {
    /// `v6`: the provenance flag and the following settings (layout 6).
    const fn of(sensors: usize, fold: bool, stale: bool, v6: bool) -> Layout {
        let mains_at = SENSOR_AT + 10 * sensors;
        let axes_at = mains_at + 4;
        let aux_at = axes_at + 9 * MAP_AXES;
        let end = aux_at + 10 * MAX_AUX;
        let (fold_at, end) = if fold {
            (Some(end), end + 2)
        } else {
            (None, end)
        };
        let (stale_at, end) = if stale {
            (Some(end), end + 8)
        } else {
            (None, end)
        };
        let (stage_at, follow_at, crc_at) = if v6 {
            (Some(end), Some(end + 1), end + 7)
        } else {
            (None, None, end)
        };
        Layout {
            sensors,
            mains_at,
            axes_at,
            aux_at,
            fold_at,
            stale_at,
            stage_at,
            follow_at,
            crc_at,
            len: crc_at + 4,
        }
    }

    /// The layout of a record of `version`.
    fn of_version(version: u8) -> Option<Layout> {
        match version {
            1 => Some(Layout::of(8, false, false, false)),
            2 => Some(Layout::of(SENSORS, false, false, false)),
            3 => Some(Layout::of(SENSORS, true, false, false)),
            // 5 only reserved the stage unit's byte: the same places
            4 | 5 => Some(Layout::of(SENSORS, true, true, false)),
            VERSION => Some(Layout::of(SENSORS, true, true, true)),
            _ => None,
        }
    }
}

const NOW: Layout = Layout::of(SENSORS, true, true, true);
const MAINS_AT: usize = NOW.mains_at;
const AXES_AT: usize = NOW.axes_at;
const AUX_AT: usize = NOW.aux_at;
const FOLD_AT: usize = AUX_AT + 10 * MAX_AUX;
const STALE_AT: usize = FOLD_AT + 2;
const STAGE_AT: usize = STALE_AT + 8;
const FOLLOW_AT: usize = STAGE_AT + 1;
const _: () = assert!(FOLLOW_AT + 6 == CRC_AT);
const CRC_AT: usize = NOW.crc_at;

/// Lowest stage-link baud rate: the STM32 board's UART4 divides its 80 MHz clock by at most
/// 65 535 and has no prescaler (RM0351 §40.5.4), so 1 221 Bd is its floor; 1 200 Bd was
/// accepted, then the UART could not be configured and the board stopped at every boot.
pub const MIN_STAGE_BAUD: u32 = 2_400;
/// Highest stage-link baud rate.
pub const MAX_STAGE_BAUD: u32 = 1_000_000;

impl Settings {
    /// Check ranges: baud [`MIN_STAGE_BAUD`]..=[`MAX_STAGE_BAUD`], sample period 50 ms..=60 s,
    /// fold period 1..=10 s,
    /// resistors positive.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if !(MIN_STAGE_BAUD..=MAX_STAGE_BAUD).contains(&self.stage_baud) {
            return Err(SettingsError::Field(5));
        }
        self.validate_stored()
    }

    /// [`Self::validate`] without the baud rate's range, for a stored record: one stored by a
    /// firmware with other limits still gives its sensors, axes and inputs (the board falls
    /// back to the default rate when it cannot make the stored one).
    pub fn validate_stored(&self) -> Result<(), SettingsError> {
        for (i, s) in self.sensors.iter().enumerate() {
            if let Some(Chip::Max31865 {
                r_ref_ohm, r0_ohm, ..
            }) = s
            {
                let ok = |v: f32| v.is_finite() && v > 0.0;
                if !ok(*r_ref_ohm) || !ok(*r0_ohm) {
                    return Err(SettingsError::Field((SENSOR_AT + 10 * i) as u16));
                }
            }
        }
        if !(50..=60_000).contains(&self.sample_period_ms) {
            return Err(SettingsError::Field(MAINS_AT as u16 + 1));
        }
        if !(MIN_FOLD_PERIOD_MS..=MAX_FOLD_PERIOD_MS).contains(&self.fold_period_ms) {
            return Err(SettingsError::Field(FOLD_AT as u16));
        }
        // written so that NaN fails too
        if !(self.stale_k > 0.0 && self.stale_k <= MAX_STALE_K) {
            return Err(SettingsError::Field(STALE_AT as u16));
        }
        if !(self.extrapolation_c >= 0.0 && self.extrapolation_c <= MAX_EXTRAPOLATION_C) {
            return Err(SettingsError::Field(STALE_AT as u16 + 4));
        }
        if self.follow_nm > MAX_FOLLOW_NM {
            return Err(SettingsError::Field(FOLLOW_AT as u16));
        }
        if !(MIN_FOLLOW_INTERVAL_MS..=MAX_FOLLOW_INTERVAL_MS).contains(&self.follow_interval_ms) {
            return Err(SettingsError::Field(FOLLOW_AT as u16 + 2));
        }
        for (i, a) in self.aux.iter().enumerate() {
            if let AuxSource::Force {
                scale_n_per_count,
                offset_n,
                ..
            } = a
            {
                if !scale_n_per_count.is_finite() || !offset_n.is_finite() {
                    return Err(SettingsError::Field((AUX_AT + 10 * i) as u16));
                }
            }
        }
        Ok(())
    }

    /// Encode (see the layout in the module docs).
    pub fn encode(&self) -> [u8; LEN] {
        let mut b = [0u8; LEN];
        b[..4].copy_from_slice(&MAGIC);
        b[4] = VERSION;
        b[5..9].copy_from_slice(&self.stage_baud.to_le_bytes());
        for (i, s) in self.sensors.iter().enumerate() {
            let o = SENSOR_AT + 10 * i;
            let (kind, a, rr, r0) = match *s {
                None => (0, 0, 0.0, 0.0),
                Some(Chip::Max31856 { tc }) => (1, tc as u8, 0.0, 0.0),
                Some(Chip::Max31865 {
                    r_ref_ohm,
                    r0_ohm,
                    wires,
                }) => (2, wires as u8, r_ref_ohm, r0_ohm),
            };
            b[o] = kind;
            b[o + 1] = a;
            b[o + 2..o + 6].copy_from_slice(&f32::to_le_bytes(rr));
            b[o + 6..o + 10].copy_from_slice(&f32::to_le_bytes(r0));
        }
        b[MAINS_AT] = match self.mains {
            Mains::Hz50 => 50,
            Mains::Hz60 => 60,
        };
        b[MAINS_AT + 1..MAINS_AT + 3].copy_from_slice(&self.sample_period_ms.to_le_bytes());
        // b[MAINS_AT + 3]: reserved (the stage unit of layouts 1 to 4), 0
        for (i, id) in self.axis_names.iter().enumerate() {
            let o = AXES_AT + 9 * i;
            let s = id.as_bytes();
            b[o] = s.len() as u8;
            b[o + 1..o + 1 + s.len()].copy_from_slice(s);
        }
        for (i, a) in self.aux.iter().enumerate() {
            let o = AUX_AT + 10 * i;
            let (kind, ch, sc, off) = match *a {
                AuxSource::None => (0, 0, 0.0, 0.0),
                AuxSource::AirPressure => (1, 0, 0.0, 0.0),
                AuxSource::Force {
                    channel,
                    scale_n_per_count,
                    offset_n,
                } => (2, channel, scale_n_per_count, offset_n),
            };
            b[o] = kind;
            b[o + 1] = ch;
            b[o + 2..o + 6].copy_from_slice(&f32::to_le_bytes(sc));
            b[o + 6..o + 10].copy_from_slice(&f32::to_le_bytes(off));
        }
        b[FOLD_AT..FOLD_AT + 2].copy_from_slice(&self.fold_period_ms.to_le_bytes());
        b[STALE_AT..STALE_AT + 4].copy_from_slice(&self.stale_k.to_le_bytes());
        b[STALE_AT + 4..STALE_AT + 8].copy_from_slice(&self.extrapolation_c.to_le_bytes());
        b[STAGE_AT] = u8::from(self.allow_other_stage);
        b[FOLLOW_AT..FOLLOW_AT + 2].copy_from_slice(&self.follow_nm.to_le_bytes());
        b[FOLLOW_AT + 2..FOLLOW_AT + 4].copy_from_slice(&self.follow_interval_ms.to_le_bytes());
        b[FOLLOW_AT + 4..FOLLOW_AT + 6].copy_from_slice(&self.follow_step_nm.to_le_bytes());
        let crc = crate::crc32(&b[..CRC_AT]);
        b[CRC_AT..].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// Decode (this version's layout, or an older one's) and validate as a stored record
    /// ([`Self::validate_stored`]: the baud rate is not held to this firmware's range).
    pub fn decode(b: &[u8]) -> Result<Self, SettingsError> {
        if b.len() < 5 {
            return Err(SettingsError::Length);
        }
        if b[..4] != MAGIC {
            return Err(SettingsError::Magic);
        }
        let l = Layout::of_version(b[4]).ok_or(SettingsError::Version(b[4]))?;
        if b.len() != l.len {
            return Err(SettingsError::Length);
        }
        let c = l.crc_at;
        let crc = u32::from_le_bytes([b[c], b[c + 1], b[c + 2], b[c + 3]]);
        if crate::crc32(&b[..c]) != crc {
            return Err(SettingsError::Crc);
        }
        let f32_at = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let mut s = Settings {
            stage_baud: u32::from_le_bytes([b[5], b[6], b[7], b[8]]),
            ..Settings::default()
        };
        for i in 0..l.sensors {
            let o = SENSOR_AT + 10 * i;
            let bad = SettingsError::Field(o as u16);
            s.sensors[i] = match b[o] {
                0 => None,
                1 => Some(Chip::Max31856 {
                    tc: TcType::from_code(b[o + 1]).ok_or(bad)?,
                }),
                2 => Some(Chip::Max31865 {
                    wires: match b[o + 1] {
                        2 => Wires::Two,
                        3 => Wires::Three,
                        4 => Wires::Four,
                        _ => return Err(bad),
                    },
                    r_ref_ohm: f32_at(o + 2),
                    r0_ohm: f32_at(o + 6),
                }),
                _ => return Err(bad),
            };
        }
        s.mains = match b[l.mains_at] {
            50 => Mains::Hz50,
            60 => Mains::Hz60,
            _ => return Err(SettingsError::Field(l.mains_at as u16)),
        };
        s.sample_period_ms = u16::from_le_bytes([b[l.mains_at + 1], b[l.mains_at + 2]]);
        // b[l.mains_at + 3]: the stage unit of layouts 1 to 4 (never applied) or reserved:
        // ignored, so a record stored with any unit still loads
        for i in 0..MAP_AXES {
            let o = l.axes_at + 9 * i;
            let n = usize::from(b[o]).min(8);
            s.axis_names[i] =
                AxisId::new(&b[o + 1..o + 1 + n]).ok_or(SettingsError::Field(o as u16))?;
        }
        for i in 0..MAX_AUX {
            let o = l.aux_at + 10 * i;
            s.aux[i] = match b[o] {
                0 => AuxSource::None,
                1 => AuxSource::AirPressure,
                2 => AuxSource::Force {
                    channel: b[o + 1],
                    scale_n_per_count: f32_at(o + 2),
                    offset_n: f32_at(o + 6),
                },
                _ => return Err(SettingsError::Field(o as u16)),
            };
        }
        if let Some(o) = l.fold_at {
            s.fold_period_ms = u16::from_le_bytes([b[o], b[o + 1]]);
        }
        if let Some(o) = l.stale_at {
            s.stale_k = f32_at(o);
            s.extrapolation_c = f32_at(o + 4);
        }
        if let Some(o) = l.stage_at {
            s.allow_other_stage = match b[o] {
                0 => false,
                1 => true,
                _ => return Err(SettingsError::Field(o as u16)),
            };
        }
        if let Some(o) = l.follow_at {
            let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]);
            s.follow_nm = u16_at(o);
            s.follow_interval_ms = u16_at(o + 2);
            s.follow_step_nm = u16_at(o + 4);
        }
        s.validate_stored()?;
        Ok(s)
    }
}
