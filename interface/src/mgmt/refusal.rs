//! Result codes: why the device refused a request (the reply's first byte; 0 is success), and
//! the input code that follows [`Refusal::Input`].

use core::fmt;

code_enum! {
    /// Why the device refused a request: the reply's result byte when it is not 0. Codes
    /// 1..=9 are the upload's (the compensator's `UploadError` maps onto them), 20 and up the
    /// other requests'.
    pub enum Refusal: u8 {
        /// An upload chunk or commit arrived without a begin.
        UploadNotStarted = 1 => "upload step without a begin",
        /// The announced blob format version is not the one the firmware reads.
        UploadVersion = 2 => "blob format version not supported by the firmware",
        /// The announced length is zero or larger than the receive buffer.
        UploadLength = 3 => "announced length out of range",
        /// A chunk did not start where the previous one ended.
        UploadOutOfOrder = 4 => "chunk out of order",
        /// A chunk would run past the announced length.
        UploadOverrun = 5 => "chunk past the announced length",
        /// A repeated chunk differs from what was received before at that offset.
        UploadChunkMismatch = 6 => "repeated chunk differs",
        /// Commit before all bytes arrived.
        UploadIncomplete = 7 => "upload incomplete",
        /// The whole-blob CRC-32 differs from the announced one.
        UploadCrc = 8 => "whole-blob CRC mismatch",
        /// The blob itself is invalid (the model's decoder refused it).
        UploadBlob = 9 => "invalid blob",
        /// Storage (flash) failure: the old model stays in service.
        Storage = 20 => "storage (flash) failure; old model kept",
        /// The request needs a model and none is loaded.
        NoModel = 21 => "no model loaded",
        /// Malformed request payload.
        BadRequest = 22 => "malformed request",
        /// Unknown request kind.
        UnknownKind = 23 => "unknown request",
        /// The model uses an input this board cannot supply (the reply carries an
        /// [`InputCode`]); nothing stored.
        Input = 24 => "model uses an input this board cannot supply (see `nanocal device config`); nothing stored",
        /// Settings rejected (malformed or out of range).
        Settings = 25 => "settings rejected (malformed or out of range)",
    }
}

code_enum! {
    /// Why a model input cannot be supplied (the high nibble of an [`InputCode`]).
    pub enum InputWhy: u8 {
        /// A temperature input with no amplifier configured on its chip-select.
        NoTemperatureSensor = 1 => "temperature input with no amplifier configured on its chip-select",
        /// An aux input with no source.
        NoAuxSource = 2 => "aux input with no source (configure a force channel, or map it with --aux)",
        /// An air-pressure input, and the board's barometer does not answer.
        NoBarometer = 3 => "air-pressure input, and the board's barometer does not answer",
        /// A force input on an ADC channel the board lacks.
        NoAdcChannel = 4 => "force input on an ADC channel the board lacks",
        /// A per-command (fast) aux input whose source is not an ADC channel.
        NotFast = 5 => "per-command (fast) aux input whose source is not an ADC channel",
        /// A temperature input on a chip-select the board does not wire.
        NoChipSelect = 6 => "temperature input on a chip-select the board does not wire",
    }
}

/// The byte after [`Refusal::Input`]: which input (its index among the temperatures or the aux
/// inputs, 0..=15) and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputCode {
    /// Why it cannot be supplied.
    pub why: InputWhy,
    /// The input's index (low nibble).
    pub index: u8,
}

impl InputCode {
    /// The byte: why in the high nibble, the index in the low.
    pub const fn code(self) -> u8 {
        self.why.code() << 4 | (self.index & 0x0F)
    }

    /// The input code of a byte; `None` for an unknown reason.
    pub const fn from_code(b: u8) -> Option<Self> {
        match InputWhy::from_code(b >> 4) {
            Some(why) => Some(InputCode {
                why,
                index: b & 0x0F,
            }),
            None => None,
        }
    }
}

impl fmt::Display for InputCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "input {}, {}", self.index, self.why)
    }
}
