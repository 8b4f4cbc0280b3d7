//! Which model inputs this board can supply, and the refusal of a model that needs one it
//! cannot: the firmware never evaluates a model with a silent default for a missing input.
//!
//! Temperatures come from the amplifiers configured per chip-select
//! ([`crate::settings::Settings::sensors`]); auxiliary inputs from the board's own sources (the
//! LPS22HB barometer, an ADC force channel). Today the blob names aux inputs only by index, so
//! the mapping index → source is the persistent settings'; it lives in [`aux_source`] alone, to
//! be switched to the blob's aux kinds (blob v2) in one place.

use crate::settings::{AuxSource, Settings};
use core::fmt;
use nanocal_model::Model;

/// Sources the board has (what was found at start-up).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Board {
    /// The barometer answered (LPS22HB WHO_AM_I = B1h).
    pub barometer: bool,
    /// ADC channels that exist on this board (bit per channel).
    pub adc_channels: u32,
}

/// Why a model cannot run on this board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum InputError {
    /// The model reads temperature `index` and no amplifier is configured on that chip-select.
    NoTemperatureSensor {
        /// Temperature input index.
        index: u8,
    },
    /// The model reads aux input `index` and the settings give it no source.
    NoAuxSource {
        /// Aux input index.
        index: u8,
    },
    /// Aux input `index` is mapped to the barometer and the board has none answering.
    NoBarometer {
        /// Aux input index.
        index: u8,
    },
    /// Aux input `index` is mapped to an ADC channel the board does not have.
    NoAdcChannel {
        /// Aux input index.
        index: u8,
        /// ADC channel.
        channel: u8,
    },
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InputError::NoTemperatureSensor { index } => write!(
                f,
                "model reads temperature {index} but no amplifier is configured on chip-select {index}"
            ),
            InputError::NoAuxSource { index } => {
                write!(f, "model reads aux input {index} but the settings give it no source")
            }
            InputError::NoBarometer { index } => write!(
                f,
                "aux input {index} is air pressure but the board's barometer does not answer"
            ),
            InputError::NoAdcChannel { index, channel } => write!(
                f,
                "aux input {index} is force on ADC channel {channel}, which this board lacks"
            ),
        }
    }
}

impl InputError {
    /// Compact code for the management protocol: kind in the high nibble, index in the low.
    pub fn code(&self) -> u8 {
        match *self {
            InputError::NoTemperatureSensor { index } => 0x10 | (index & 0x0F),
            InputError::NoAuxSource { index } => 0x20 | (index & 0x0F),
            InputError::NoBarometer { index } => 0x30 | (index & 0x0F),
            InputError::NoAdcChannel { index, .. } => 0x40 | (index & 0x0F),
        }
    }
}

/// The source of aux input `index`. The one place that decides it: from the settings today,
/// from the blob's aux kind once blob v2 carries one.
pub fn aux_source(settings: &Settings, _model: &Model, index: usize) -> AuxSource {
    settings.aux.get(index).copied().unwrap_or(AuxSource::None)
}

/// Check that the board supplies every input `model` uses.
pub fn check(model: &Model, settings: &Settings, board: &Board) -> Result<(), InputError> {
    for i in 0..model.temps() {
        if settings.sensors.get(i).copied().flatten().is_none() {
            return Err(InputError::NoTemperatureSensor { index: i as u8 });
        }
    }
    for i in 0..model.aux() {
        let index = i as u8;
        match aux_source(settings, model, i) {
            AuxSource::None => return Err(InputError::NoAuxSource { index }),
            AuxSource::AirPressure if !board.barometer => {
                return Err(InputError::NoBarometer { index })
            }
            AuxSource::Force { channel, .. }
                if channel >= 32 || board.adc_channels & (1 << channel) == 0 =>
            {
                return Err(InputError::NoAdcChannel { index, channel })
            }
            _ => {}
        }
    }
    Ok(())
}
