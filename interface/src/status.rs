//! The device's status report (the `STATUS` reply's data), with its flags, the per-channel
//! sensor bits and the sensor fault codes.
//!
//! ```text
//! offset size            field
//!      0 u16             flags (Flags)
//!      2 u32             model_id (0: no model)
//!      6 u32             model_crc32 (the model's blob's own CRC-32, its last four bytes;
//!                        0: no model)
//!     10 u32             move_fold
//!     14 f32 × 16        temps_c (NaN: unusable)
//!     78 u8 × 16         sensor_bits (ChannelBits: state in bits 0..3, last fault in 4..7)
//!     94 u8              sensors configured
//!     95 u32             slow_outside (model input bits, nanocal_model::EnvelopeFlags)
//!     99 f64 × 3         kmz_um
//!    123 u32 × 7         host_lines, moves, refused, mapped_replies, uploads_ok,
//!                        uploads_rejected, folds
//!    151 i32             pending_error (GcsErrorCode code, 0: none)
//!    155 u8              last_upload_error (Refusal code, 0: none)
//!    156 u32             uptime_ms
//!    160 u8 × 12         uid
//!    172 u8              reset_cause (ResetCause code)
//!    173 u8              led (LedState code)
//!    174 u32             fold_age_ms
//!    178 u32             flash_ecc_errors
//!    182 u32             sensor_reconfigs
//!    186 f32 × 4         aux (NaN: unusable)
//!    202 u8 × 4          aux_bits (ChannelBits)
//!    206 u8              stale (StaleReasons: why MODEL_STALE is set, 0: it is not)
//!    207 u32             stale_since_ms (uptime when MODEL_STALE rose; 0: not stale)
//!    211 f32 × 3         kmz_residual_um (λ change of the last KMZ re-measurement; NaN: none)
//!    223 f32 × 3         kmz_limit_um (k standard errors of prediction there; NaN: no bound)
//!    235 f32             envelope_excess_c (largest distance of a model temperature beyond its
//!                        training envelope at the last fold, °C, ≤ 0 inside; NaN: none)
//!    239 u8              stage (StageCheck code: the provenance check)
//!    240 u8 + 24         model_serial: length n u8 (0..=24; 0: none) | 24 bytes, n ASCII then zeros
//!                        (the stage serial the model's blob records)
//!    265 u8 + 24         controller_serial: same layout (the serial in the controller's `*IDN?`;
//!                        0: not read, or its identification has none)
//!    290 u32             follow_reissues (held targets re-issued because the fold moved their
//!                        command, accepted by the controller)
//!    294 u32             follow_refused (re-issues the controller refused: swallowed,
//!                        following stopped)
//!    298                 end (Status::LEN)
//! ```
//! Protocol 8 appended following's counters (offset 290 on). Protocol 7 appended the provenance check's fields (offset 239 on). Protocol 5 put `model_crc32` where protocol 4 had a reserved byte (the flash slot of an
//! older store): every later field moved by 3 bytes. Protocol 6 appended the model-stale
//! check's fields (offset 206 on).
//!
//! All little-endian. Adding a field: the struct, [`Status::encode`], [`Status::decode`],
//! [`Status::LEN`], this diagram, the golden bytes in the tests, and a bump of
//! [`crate::mgmt::PROTOCOL`] — all in this file but the last.

use crate::gcs_error::GcsErrorCode;
use crate::identity::{ResetCause, UID_LEN};
use crate::led::LedState;
use crate::mgmt::{PayloadError, Reader, Refusal, Writer};
use core::fmt;
use core::ops::{BitOr, BitOrAssign};
use nanocal_model::provenance::{StageSerial, MAX_SERIAL};

/// Sensors in a status report (every temperature a model can read).
pub const STATUS_SENSORS: usize = nanocal_model::MAX_TEMPS;
/// Auxiliary inputs in a status report.
pub const STATUS_AUX: usize = nanocal_model::MAX_AUX;

code_enum! {
    /// A sensor fault as the chip reports it (or as its registers show it); its code is the
    /// high nibble of [`ChannelBits`].
    pub enum SensorFault: u8 {
        /// Thermocouple input open (MAX31856 OPEN bit) or RTD input open (MAX31865
        /// REFIN-/RTDIN-).
        Open = 1 => "sensor input open",
        /// Input shorted to GND or VCC: over/under-voltage (MAX31856 OVUV, MAX31865 bit 2).
        ShortOrOvervoltage = 2 => "sensor input shorted to GND/VCC (over/under-voltage)",
        /// Cold-junction temperature outside the thermocouple type's range (MAX31856 CJ Range).
        ColdJunctionRange = 3 => "cold-junction temperature out of range",
        /// Thermocouple temperature outside the type's range (MAX31856 TC Range).
        ThermocoupleRange = 4 => "thermocouple temperature out of range",
        /// Reading above the high or below the low threshold (MAX31856
        /// CJHIGH/CJLOW/TCHIGH/TCLOW, MAX31865 D7/D6).
        Threshold = 5 => "reading beyond the chip's fault threshold",
        /// The bus did not answer: timeout, SPI error, or the all-ones (absent chip, MISO
        /// pull-up) or all-zeros register dump.
        NoResponse = 6 => "sensor did not answer on the bus (absent or unpowered)",
        /// The decoded value is outside the plausible range configured for the channel.
        Implausible = 7 => "reading outside the plausible range",
        /// The chip's configuration registers differ from what was written (brown-out or
        /// hot-plug reset it): it is configured again.
        ConfigLost = 8 => "chip lost its configuration (reconfigured)",
    }
}

code_enum! {
    /// A sensor or aux channel's state under the fault policy (low nibble of [`ChannelBits`]).
    pub enum ChannelStatus: u8 {
        /// A good reading is in use.
        Ok = 0 => "ok",
        /// Faulted: the last good value is held (moves still allowed).
        Holding = 1 => "holding last good value",
        /// Faulted for longer than the hold time: moves refused until it recovers.
        Failed = 2 => "FAILED",
        /// Never read successfully yet.
        NotRead = 4 => "not read yet",
    }
}

/// One channel's byte in the status: its state and the last fault it saw (kept after
/// recovery).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChannelBits {
    /// State under the fault policy.
    pub state: ChannelStatus,
    /// The last fault seen, if any.
    pub last_fault: Option<SensorFault>,
}

impl Default for ChannelBits {
    fn default() -> Self {
        ChannelBits {
            state: ChannelStatus::Ok,
            last_fault: None,
        }
    }
}

impl ChannelBits {
    /// The byte: state in bits 0..3, the last fault's code in bits 4..7 (0: none).
    pub const fn code(self) -> u8 {
        let fault = match self.last_fault {
            Some(f) => f.code(),
            None => 0,
        };
        self.state.code() | fault << 4
    }

    /// The bits of a byte; `None` when the state or the fault code is unknown.
    pub const fn from_code(b: u8) -> Option<Self> {
        let Some(state) = ChannelStatus::from_code(b & 0x0F) else {
            return None;
        };
        let last_fault = match b >> 4 {
            0 => None,
            c => match SensorFault::from_code(c) {
                Some(f) => Some(f),
                None => return None,
            },
        };
        Some(ChannelBits { state, last_fault })
    }
}

/// Status flags (bit set = condition present). Unknown bits are kept as they came.
#[derive(Clone, Copy, PartialEq, Eq, Default, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Flags(u16);

impl Flags {
    /// A model is loaded.
    pub const MODEL: Flags = Flags(1 << 0);
    /// Compensation is bypassed.
    pub const BYPASS: Flags = Flags(1 << 1);
    /// Moves are refused because a sensor failed.
    pub const SENSOR_BLOCK: Flags = Flags(1 << 2);
    /// A temperature/aux input is outside the training envelope (extrapolation).
    pub const EXTRAPOLATING: Flags = Flags(1 << 3);
    /// An upload is in progress.
    pub const UPLOADING: Flags = Flags(1 << 4);
    /// Moves are refused: the controller's position unit (`PUN?`) is not the model's µm, or
    /// the controller did not tell it ([`GcsErrorCode::UnitMismatch`] on the host's `ERR?`).
    pub const UNIT_MISMATCH: Flags = Flags(1 << 5);
    /// The thermal fold is older than the sensor hold time (sensor task stalled): moves refused.
    pub const FOLD_STALE: Flags = Flags(1 << 8);
    /// A host has the GCS port open (USB DTR set).
    pub const HOST_CONNECTED: Flags = Flags(1 << 9);
    /// Sensors are warming up: a sensor the model uses has no valid reading yet.
    pub const WARMING_UP: Flags = Flags(1 << 10);
    /// [`Status::move_fold`] is reported (always set by firmware that knows the field).
    pub const MOVE_FOLD: Flags = Flags(1 << 11);
    /// The model in service has gone stale ([`Status::stale`] says why): a KMZ re-measurement
    /// fell outside its prediction interval, or the temperatures left its training envelope by
    /// more than it was shown to extrapolate. Moves are still corrected.
    pub const MODEL_STALE: Flags = Flags(1 << 12);
    /// The controller's identification names another stage serial than the model was fitted
    /// on ([`Status::stage`] says whether moves are refused or, by the setting
    /// `allow_other_stage`, corrected all the same).
    pub const STAGE_MISMATCH: Flags = Flags(1 << 13);

    /// Every flag with its name, in bit order (the table `Debug` prints from).
    pub const ALL: &'static [(Flags, &'static str)] = &[
        (Flags::MODEL, "MODEL"),
        (Flags::BYPASS, "BYPASS"),
        (Flags::SENSOR_BLOCK, "SENSOR_BLOCK"),
        (Flags::EXTRAPOLATING, "EXTRAPOLATING"),
        (Flags::UPLOADING, "UPLOADING"),
        (Flags::UNIT_MISMATCH, "UNIT_MISMATCH"),
        (Flags::FOLD_STALE, "FOLD_STALE"),
        (Flags::HOST_CONNECTED, "HOST_CONNECTED"),
        (Flags::WARMING_UP, "WARMING_UP"),
        (Flags::MOVE_FOLD, "MOVE_FOLD"),
        (Flags::MODEL_STALE, "MODEL_STALE"),
        (Flags::STAGE_MISMATCH, "STAGE_MISMATCH"),
    ];

    /// No flag set.
    pub const fn empty() -> Self {
        Flags(0)
    }
    /// The bits on the wire.
    pub const fn bits(self) -> u16 {
        self.0
    }
    /// Flags from wire bits, unknown bits kept.
    pub const fn from_bits_retain(bits: u16) -> Self {
        Flags(bits)
    }
    /// True when every flag of `other` is set.
    pub const fn contains(self, other: Flags) -> bool {
        self.0 & other.0 == other.0
    }
    /// True when any flag of `other` is set.
    pub const fn intersects(self, other: Flags) -> bool {
        self.0 & other.0 != 0
    }
    /// Set the flags of `other`.
    pub fn insert(&mut self, other: Flags) {
        self.0 |= other.0;
    }
    /// Set or clear the flags of `other`.
    pub fn set(&mut self, other: Flags, on: bool) {
        if on {
            self.0 |= other.0;
        } else {
            self.0 &= !other.0;
        }
    }
}

impl BitOr for Flags {
    type Output = Flags;
    fn bitor(self, rhs: Flags) -> Flags {
        Flags(self.0 | rhs.0)
    }
}

impl BitOrAssign for Flags {
    fn bitor_assign(&mut self, rhs: Flags) {
        self.0 |= rhs.0;
    }
}

impl fmt::Debug for Flags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Flags(")?;
        let mut rest = self.0;
        let mut first = true;
        for (flag, name) in Flags::ALL {
            if self.contains(*flag) {
                write!(f, "{}{name}", if first { "" } else { " | " })?;
                first = false;
                rest &= !flag.0;
            }
        }
        if rest != 0 {
            write!(f, "{}{rest:#06x}", if first { "" } else { " | " })?;
        }
        write!(f, ")")
    }
}

code_enum! {
    /// The provenance check: is the controller the stage the model was fitted on
    /// (`nanocal_model::provenance`)? Its code is [`Status::stage`]'s byte.
    pub enum StageCheck: u8 {
        /// Nothing to check: no model, or the model records no stage serial (a blob older
        /// than format version 4, or fitted without the stage's identification).
        Unchecked = 0 => "not checked: the model records no stage serial",
        /// The controller's identification is not read yet: the proxy reads it before the
        /// first corrected move (or from the host's own `*IDN?`), and no move is corrected
        /// before it has.
        NotRead = 1 => "the controller's identification is not read yet (read before the first corrected move)",
        /// The controller's serial is the one the model was fitted on.
        Match = 2 => "the controller is the stage the model was fitted on",
        /// The controller's serial differs from the model's (or its identification names
        /// none): moves are refused (GCS error 9015).
        Mismatch = 3 => "ANOTHER STAGE than the model was fitted on: moves refused (GCS error 9015; setting allow_other_stage overrides)",
        /// As [`StageCheck::Mismatch`], but the setting `allow_other_stage` is on: moves are
        /// corrected all the same.
        MismatchAllowed = 4 => "ANOTHER STAGE than the model was fitted on: moves corrected all the same (setting allow_other_stage)",
        /// The controller's identification went unanswered or is no usable line: moves are
        /// refused (GCS error 9014).
        Unanswered = 5 => "the controller's identification went unanswered: moves refused (GCS error 9014)",
    }
}

impl StageCheck {
    /// True when the controller is known to be another stage than the model's
    /// ([`Flags::STAGE_MISMATCH`]).
    pub const fn mismatch(self) -> bool {
        matches!(self, StageCheck::Mismatch | StageCheck::MismatchAllowed)
    }
}

/// Why the model in service is stale ([`Flags::MODEL_STALE`]): bits of [`Status::stale`].
#[derive(Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StaleReasons(u8);

impl StaleReasons {
    /// At a KMZ re-measurement the λ change the model needed left `k` standard errors of
    /// prediction (`k` from the settings): the model no longer predicts the stage.
    pub const KMZ_OUTSIDE_INTERVAL: StaleReasons = StaleReasons(1 << 0);
    /// A temperature the model reads left its training envelope by more than the settings'
    /// extrapolation margin (what the model was shown to extrapolate).
    pub const BEYOND_ENVELOPE: StaleReasons = StaleReasons(1 << 1);

    /// Every reason with its words, in bit order.
    pub const ALL: &'static [(StaleReasons, &'static str)] = &[
        (
            StaleReasons::KMZ_OUTSIDE_INTERVAL,
            "a KMZ re-measurement fell outside the prediction interval",
        ),
        (
            StaleReasons::BEYOND_ENVELOPE,
            "a temperature left the training envelope by more than the extrapolation margin",
        ),
    ];

    /// No reason: not stale.
    pub const fn empty() -> Self {
        StaleReasons(0)
    }
    /// The bits on the wire.
    pub const fn bits(self) -> u8 {
        self.0
    }
    /// Reasons from wire bits, unknown bits kept.
    pub const fn from_bits_retain(bits: u8) -> Self {
        StaleReasons(bits)
    }
    /// True when no reason is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// True when every reason of `other` is set.
    pub const fn contains(self, other: StaleReasons) -> bool {
        self.0 & other.0 == other.0
    }
    /// Set the reasons of `other`.
    pub fn insert(&mut self, other: StaleReasons) {
        self.0 |= other.0;
    }
}

impl fmt::Debug for StaleReasons {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "StaleReasons({:#04x})", self.0)
    }
}

impl fmt::Display for StaleReasons {
    /// The reasons in words, `; `-separated (`not stale` when none).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_empty() {
            return f.write_str("not stale");
        }
        let mut first = true;
        let mut rest = self.0;
        for (r, words) in StaleReasons::ALL {
            if self.contains(*r) {
                write!(f, "{}{words}", if first { "" } else { "; " })?;
                first = false;
                rest &= !r.0;
            }
        }
        if rest != 0 {
            write!(
                f,
                "{}reason bits {rest:#04x}",
                if first { "" } else { "; " }
            )?;
        }
        Ok(())
    }
}

/// The device's status report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Status {
    /// Flags.
    pub flags: Flags,
    /// Model id (0 without a model). Chosen by whoever fitted the model: it names the model,
    /// it does not tell two models apart — [`Status::model_crc32`] does.
    pub model_id: u32,
    /// The content hash of the model in service: the CRC-32 its blob carries
    /// ([`nanocal_model::blob::stored_crc`], the blob's last four bytes, as the device stored
    /// it; 0 without a model). A blob file's own CRC: the device serves exactly that file when
    /// id and CRC match. λ_KMZ set later (`SET_KMZ`) does not change it ([`Status::kmz_um`]
    /// has the one in use).
    pub model_crc32: u32,
    /// The fold (the value [`Status::folds`] had) that corrected the last move forwarded to the
    /// controller; 0: no move since start-up. With [`Flags::MOVE_FOLD`] (firmware that reports
    /// it; the field was an unused 0 before). A host that reads `move_fold == folds` knows the
    /// temperatures in this report are the ones its last move was corrected with.
    pub move_fold: u32,
    /// Temperatures in use — the last fold's inputs, the readings averaged over the fold period
    /// (protocol 5) — °C (NaN when unusable or not folded yet).
    pub temps_c: [f32; STATUS_SENSORS],
    /// Per-sensor state and last fault.
    pub sensor_bits: [ChannelBits; STATUS_SENSORS],
    /// Sensors configured (chip-selects up to the last one with an amplifier).
    pub sensors: u8,
    /// Slow inputs outside the training envelope at the last fold (model input bits,
    /// [`nanocal_model::EnvelopeFlags`]: 3 axes, 16 temperatures, 4 aux need a u32).
    pub slow_outside: u32,
    /// λ_KMZ per axis, µm.
    pub kmz_um: [f64; 3],
    /// Host lines seen.
    pub host_lines: u32,
    /// Moves corrected and forwarded.
    pub moves: u32,
    /// Moves refused.
    pub refused: u32,
    /// Replies mapped through the inverse.
    pub mapped_replies: u32,
    /// Uploads accepted.
    pub uploads_ok: u32,
    /// Uploads rejected.
    pub uploads_rejected: u32,
    /// Folds computed (slow path runs).
    pub folds: u32,
    /// Error waiting for the host's next `ERR?`.
    pub pending_error: Option<GcsErrorCode>,
    /// Why the last rejected upload was rejected.
    pub last_upload_error: Option<Refusal>,
    /// Uptime, ms.
    pub uptime_ms: u32,
    /// Chip unique ID (96 bits).
    pub uid: [u8; UID_LEN],
    /// Why the device last reset.
    pub reset_cause: ResetCause,
    /// What the status LED shows.
    pub led: LedState,
    /// Age of the thermal fold in use, ms.
    pub fold_age_ms: u32,
    /// Flash double words that failed ECC on read since start-up.
    pub flash_ecc_errors: u32,
    /// Times a sensor was found without its configuration and reconfigured.
    pub sensor_reconfigs: u32,
    /// Auxiliary inputs in use — the last fold's inputs, as [`Status::temps_c`] — in their units
    /// (NaN when unusable).
    pub aux: [f32; STATUS_AUX],
    /// Per-aux state and last fault (as [`Status::sensor_bits`]).
    pub aux_bits: [ChannelBits; STATUS_AUX],
    /// Why the model in service is stale ([`Flags::MODEL_STALE`]; empty: it is not). Latched
    /// until another model is loaded or the device resets.
    pub stale: StaleReasons,
    /// Uptime when [`Flags::MODEL_STALE`] rose, ms (0: not stale).
    pub stale_since_ms: u32,
    /// λ change of the last KMZ re-measurement per axis, µm: the command minus what the model
    /// predicted for the measured position (NaN: none since the model was loaded).
    pub kmz_residual_um: [f32; 3],
    /// `k` standard errors of prediction at that KMZ per axis, µm: the limit the residual was
    /// held to (NaN: no KMZ yet, or the model carries no prediction bound for the axis).
    pub kmz_limit_um: [f32; 3],
    /// Largest distance of a temperature the model reads beyond its training envelope at the
    /// last fold, °C (≤ 0: inside; NaN: the model reads no temperature, or no fold yet).
    pub envelope_excess_c: f32,
    /// The provenance check (protocol 7).
    pub stage: StageCheck,
    /// The stage serial the model in service records (`None`: no model, or none recorded).
    pub model_serial: Option<StageSerial>,
    /// The serial in the controller's identification (`None`: not read, or it has none).
    pub controller_serial: Option<StageSerial>,
    /// Held targets re-issued because the fold moved their command, and accepted by the
    /// controller (protocol 8; the proxy's `Counters::follow_reissues`). Only a following
    /// device (settings' threshold non-zero) counts them.
    pub follow_reissues: u32,
    /// Re-issues the controller refused (its error swallowed, following stopped until the
    /// host's next move; the proxy's `Counters::follow_refused`). A lab that sees this rise
    /// has a controller refusing small moves (servo off, limits) behind the host's back.
    pub follow_refused: u32,
}

impl Default for Status {
    fn default() -> Self {
        Status {
            flags: Flags::empty(),
            model_id: 0,
            model_crc32: 0,
            move_fold: 0,
            temps_c: [0.0; STATUS_SENSORS],
            sensor_bits: [ChannelBits::default(); STATUS_SENSORS],
            sensors: 0,
            slow_outside: 0,
            kmz_um: [0.0; 3],
            host_lines: 0,
            moves: 0,
            refused: 0,
            mapped_replies: 0,
            uploads_ok: 0,
            uploads_rejected: 0,
            folds: 0,
            pending_error: None,
            last_upload_error: None,
            uptime_ms: 0,
            uid: [0; UID_LEN],
            reset_cause: ResetCause::Unknown,
            led: LedState::NoModel,
            fold_age_ms: 0,
            flash_ecc_errors: 0,
            sensor_reconfigs: 0,
            aux: [0.0; STATUS_AUX],
            aux_bits: [ChannelBits::default(); STATUS_AUX],
            stale: StaleReasons::empty(),
            stale_since_ms: 0,
            kmz_residual_um: [f32::NAN; 3],
            kmz_limit_um: [f32::NAN; 3],
            envelope_excess_c: f32::NAN,
            stage: StageCheck::Unchecked,
            model_serial: None,
            controller_serial: None,
            follow_reissues: 0,
            follow_refused: 0,
        }
    }
}

impl Status {
    /// Encoded length.
    pub const LEN: usize = 2
        + 4
        + 4
        + 4
        + 4 * STATUS_SENSORS
        + STATUS_SENSORS
        + 1
        + 4
        + 8 * 3
        + 7 * 4
        + 4
        + 1
        + 4
        + UID_LEN
        + 1
        + 1
        + 4 * 3
        + 5 * STATUS_AUX
        + 1
        + 4
        + 4 * 3
        + 4 * 3
        + 4
        + 1
        + 2 * (1 + MAX_SERIAL)
        + 4 * 2;

    /// Encode (the layout in the module docs).
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), PayloadError> {
        w.u16(self.flags.bits())?;
        w.u32(self.model_id)?;
        w.u32(self.model_crc32)?;
        w.u32(self.move_fold)?;
        for t in self.temps_c {
            w.f32(t)?;
        }
        for b in self.sensor_bits {
            w.u8(b.code())?;
        }
        w.u8(self.sensors)?;
        w.u32(self.slow_outside)?;
        for k in self.kmz_um {
            w.f64(k)?;
        }
        for c in [
            self.host_lines,
            self.moves,
            self.refused,
            self.mapped_replies,
            self.uploads_ok,
            self.uploads_rejected,
            self.folds,
        ] {
            w.u32(c)?;
        }
        w.i32(self.pending_error.map_or(0, GcsErrorCode::code))?;
        w.u8(self.last_upload_error.map_or(0, Refusal::code))?;
        w.u32(self.uptime_ms)?;
        w.bytes(&self.uid)?;
        w.u8(self.reset_cause.code())?;
        w.u8(self.led.code())?;
        w.u32(self.fold_age_ms)?;
        w.u32(self.flash_ecc_errors)?;
        w.u32(self.sensor_reconfigs)?;
        for a in self.aux {
            w.f32(a)?;
        }
        for b in self.aux_bits {
            w.u8(b.code())?;
        }
        w.u8(self.stale.bits())?;
        w.u32(self.stale_since_ms)?;
        for v in self.kmz_residual_um.iter().chain(&self.kmz_limit_um) {
            w.f32(*v)?;
        }
        w.f32(self.envelope_excess_c)?;
        w.u8(self.stage.code())?;
        for serial in [&self.model_serial, &self.controller_serial] {
            let b = serial.as_ref().map_or(&[][..], |s| s.as_bytes());
            w.u8(b.len() as u8)?;
            w.bytes(b)?;
            w.bytes(&[0; MAX_SERIAL][b.len()..])?;
        }
        w.u32(self.follow_reissues)?;
        w.u32(self.follow_refused)?;
        Ok(())
    }

    /// Decode (the layout in the module docs); a code no enum has is an error naming the field.
    pub fn decode(r: &mut Reader<'_>) -> Result<Self, PayloadError> {
        let mut s = Status {
            flags: Flags::from_bits_retain(r.u16()?),
            model_id: r.u32()?,
            model_crc32: r.u32()?,
            ..Default::default()
        };
        s.move_fold = r.u32()?;
        for t in s.temps_c.iter_mut() {
            *t = r.f32()?;
        }
        for b in s.sensor_bits.iter_mut() {
            *b = channel_bits(r.u8()?, "sensor_bits")?;
        }
        s.sensors = r.u8()?;
        s.slow_outside = r.u32()?;
        for k in s.kmz_um.iter_mut() {
            *k = r.f64()?;
        }
        s.host_lines = r.u32()?;
        s.moves = r.u32()?;
        s.refused = r.u32()?;
        s.mapped_replies = r.u32()?;
        s.uploads_ok = r.u32()?;
        s.uploads_rejected = r.u32()?;
        s.folds = r.u32()?;
        s.pending_error = match r.i32()? {
            0 => None,
            c => Some(GcsErrorCode::from_code(c).ok_or(PayloadError::Value {
                field: "pending_error",
                value: c as u32,
            })?),
        };
        s.last_upload_error = match r.u8()? {
            0 => None,
            c => Some(Refusal::from_code(c).ok_or(PayloadError::Value {
                field: "last_upload_error",
                value: c.into(),
            })?),
        };
        s.uptime_ms = r.u32()?;
        s.uid.copy_from_slice(r.bytes(UID_LEN)?);
        let c = r.u8()?;
        s.reset_cause = ResetCause::from_code(c).ok_or(PayloadError::Value {
            field: "reset_cause",
            value: c.into(),
        })?;
        let c = r.u8()?;
        s.led = LedState::from_code(c).ok_or(PayloadError::Value {
            field: "led",
            value: c.into(),
        })?;
        s.fold_age_ms = r.u32()?;
        s.flash_ecc_errors = r.u32()?;
        s.sensor_reconfigs = r.u32()?;
        for a in s.aux.iter_mut() {
            *a = r.f32()?;
        }
        for b in s.aux_bits.iter_mut() {
            *b = channel_bits(r.u8()?, "aux_bits")?;
        }
        s.stale = StaleReasons::from_bits_retain(r.u8()?);
        s.stale_since_ms = r.u32()?;
        for v in s.kmz_residual_um.iter_mut() {
            *v = r.f32()?;
        }
        for v in s.kmz_limit_um.iter_mut() {
            *v = r.f32()?;
        }
        s.envelope_excess_c = r.f32()?;
        let c = r.u8()?;
        s.stage = StageCheck::from_code(c).ok_or(PayloadError::Value {
            field: "stage",
            value: c.into(),
        })?;
        s.model_serial = serial(r, "model_serial")?;
        s.controller_serial = serial(r, "controller_serial")?;
        s.follow_reissues = r.u32()?;
        s.follow_refused = r.u32()?;
        Ok(s)
    }
}

/// A serial field: its length byte, then [`MAX_SERIAL`] bytes (the serial, then zeros).
fn serial(r: &mut Reader<'_>, field: &'static str) -> Result<Option<StageSerial>, PayloadError> {
    let n = r.u8()?;
    let b = r.bytes(MAX_SERIAL)?;
    let bad = PayloadError::Value {
        field,
        value: n.into(),
    };
    match usize::from(n) {
        0 => Ok(None),
        n if n <= MAX_SERIAL => StageSerial::new(&b[..n]).map(Some).ok_or(bad),
        _ => Err(bad),
    }
}

fn channel_bits(b: u8, field: &'static str) -> Result<ChannelBits, PayloadError> {
    ChannelBits::from_code(b).ok_or(PayloadError::Value {
        field,
        value: b.into(),
    })
}
