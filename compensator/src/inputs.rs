//! Which model inputs this board can supply, the refusal of a model that needs one it cannot,
//! and the latest samples of the fast inputs: the firmware never evaluates a model with a
//! silent default for a missing input.
//!
//! Temperatures come from the amplifiers configured per chip-select
//! ([`Settings::sensors`]); auxiliary inputs from the board's own sources (the
//! LPS22HB barometer, an ADC force channel). The model says what each aux input is (blob v2:
//! [`AuxKind`], and whether it is fast); the settings say where a force sensor is wired and how
//! it is scaled, and where an input of kind [`AuxKind::Other`] (or of a version 1 blob, which
//! names none) comes from. [`aux_source`] is the one place that decides.

use crate::proxy::FoldCorrector;
use crate::sensor::SensorFault;
use core::fmt;
#[cfg(doc)]
use nanocal_interface::mgmt::Refusal;
use nanocal_interface::mgmt::{InputCode, InputWhy};
use nanocal_interface::settings::{AuxSource, Settings};
#[cfg(doc)]
use nanocal_model::MAX_PLAY;
use nanocal_model::{AuxKind, FastInputs, Model, MAX_AUX};

/// Sources the board has (what was found at start-up).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Board {
    /// The barometer answered (LPS22HB WHO_AM_I = B1h).
    pub barometer: bool,
    /// ADC channels that exist on this board (bit per channel).
    pub adc_channels: u32,
    /// Chip-select lines wired for temperature amplifiers (chip-selects `0..chip_selects`).
    pub chip_selects: u8,
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
    /// The model reads aux input `index` and neither its kind nor the settings give it a
    /// source (a force input with no force channel configured, or an input of kind "other"
    /// the settings do not map).
    NoAuxSource {
        /// Aux input index.
        index: u8,
    },
    /// Aux input `index` is air pressure and the board's barometer does not answer.
    NoBarometer {
        /// Aux input index.
        index: u8,
    },
    /// Aux input `index` is a force on an ADC channel the board does not have.
    NoAdcChannel {
        /// Aux input index.
        index: u8,
        /// ADC channel.
        channel: u8,
    },
    /// The model reads temperature `index` and an amplifier is configured on that
    /// chip-select, but the board has no such chip-select line wired.
    NoChipSelect {
        /// Temperature input index.
        index: u8,
    },
    /// Aux input `index` is evaluated per command (fast) but its source is not sampled fast
    /// (only ADC channels are; the barometer is read once per sample period).
    NotFast {
        /// Aux input index.
        index: u8,
    },
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InputError::NoTemperatureSensor { index } => write!(
                f,
                "model reads temperature {index} but no amplifier is configured on chip-select {index}"
            ),
            InputError::NoAuxSource { index } => write!(
                f,
                "model reads aux input {index} but the board has no source for it (configure \
                 a force channel, or map an input of kind \"other\" with --aux)"
            ),
            InputError::NoBarometer { index } => write!(
                f,
                "aux input {index} is air pressure but the board's barometer does not answer"
            ),
            InputError::NoAdcChannel { index, channel } => write!(
                f,
                "aux input {index} is force on ADC channel {channel}, which this board lacks"
            ),
            InputError::NoChipSelect { index } => write!(
                f,
                "model reads temperature {index} but this board wires no chip-select {index}"
            ),
            InputError::NotFast { index } => write!(
                f,
                "aux input {index} is evaluated per command but its source is not an ADC \
                 channel sampled per command"
            ),
        }
    }
}

impl InputError {
    /// The code the management reply carries after [`Refusal::Input`]: the input and why.
    pub fn code(&self) -> InputCode {
        let (why, index) = match *self {
            InputError::NoTemperatureSensor { index } => (InputWhy::NoTemperatureSensor, index),
            InputError::NoAuxSource { index } => (InputWhy::NoAuxSource, index),
            InputError::NoBarometer { index } => (InputWhy::NoBarometer, index),
            InputError::NoAdcChannel { index, .. } => (InputWhy::NoAdcChannel, index),
            InputError::NotFast { index } => (InputWhy::NotFast, index),
            InputError::NoChipSelect { index } => (InputWhy::NoChipSelect, index),
        };
        InputCode {
            why,
            index: index & 0x0F,
        }
    }
}

/// The source of aux input `index` of `model`. The one place that decides it: air pressure is
/// the board's barometer; a force is the settings' force channel at that index, else the only
/// force channel the settings configure; an input of kind "other" (or of a blob that names no
/// kind) is whatever the settings map to that index.
pub fn aux_source(settings: &Settings, model: &Model, index: usize) -> AuxSource {
    let mapped = settings.aux.get(index).copied().unwrap_or(AuxSource::None);
    match model.aux_kind(index) {
        None => AuxSource::None,
        Some(AuxKind::AirPressureHpa) => AuxSource::AirPressure,
        Some(AuxKind::ForceN) => {
            if matches!(mapped, AuxSource::Force { .. }) {
                return mapped;
            }
            let mut forces = settings
                .aux
                .iter()
                .filter(|s| matches!(s, AuxSource::Force { .. }));
            match (forces.next(), forces.next()) {
                (Some(&only), None) => only,
                _ => AuxSource::None,
            }
        }
        Some(_) => mapped,
    }
}

/// Check that the board supplies every input `model` uses (temperatures, slow and fast aux
/// inputs). Hysteresis needs no check: the proxy's memory ([`nanocal_model::HysteresisState`])
/// holds as many play operators as any valid model declares ([`MAX_PLAY`]).
pub fn check(model: &Model, settings: &Settings, board: &Board) -> Result<(), InputError> {
    for i in 0..model.temps() {
        if settings.sensors.get(i).copied().flatten().is_none() {
            return Err(InputError::NoTemperatureSensor { index: i as u8 });
        }
        if i >= usize::from(board.chip_selects) {
            return Err(InputError::NoChipSelect { index: i as u8 });
        }
    }
    for i in 0..model.aux() {
        let index = i as u8;
        match aux_source(settings, model, i) {
            AuxSource::None => return Err(InputError::NoAuxSource { index }),
            AuxSource::AirPressure if !board.barometer => {
                return Err(InputError::NoBarometer { index })
            }
            AuxSource::AirPressure if model.is_fast(i) => {
                return Err(InputError::NotFast { index })
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

/// The latest sample of every fast aux input and when it was taken: what the command path
/// corrects with. A command needs every fast input it uses sampled successfully within the
/// freshness limit; a failed or stale sample refuses the command (never a default value).
/// Position replies are mapped with the latest good value whatever its age.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FastSamples {
    value: [f32; MAX_AUX],
    at_ms: [u32; MAX_AUX],
    /// Bit n: the last sampling of input n succeeded.
    ok: u8,
}

impl Default for FastSamples {
    fn default() -> Self {
        Self::new()
    }
}

impl FastSamples {
    /// Nothing sampled.
    pub const fn new() -> Self {
        Self {
            value: [f32::NAN; MAX_AUX],
            at_ms: [0; MAX_AUX],
            ok: 0,
        }
    }

    /// Record a sampling of fast input `n` at `now_ms`: a value in its unit, or a failure (the
    /// last good value stays for replies, commands are refused).
    pub fn record(&mut self, n: usize, sample: Result<f32, SensorFault>, now_ms: u32) {
        if n >= MAX_AUX {
            return;
        }
        match sample {
            Ok(v) if v.is_finite() => {
                self.value[n] = v;
                self.at_ms[n] = now_ms;
                self.ok |= 1 << n;
            }
            _ => self.ok &= !(1 << n),
        }
    }

    /// Forget every sample (a new model, a reconfigured source).
    pub fn clear(&mut self) {
        *self = Self::new();
    }

    /// The latest good values (NaN where none), by aux index.
    pub fn latest(&self) -> FastInputs {
        FastInputs { aux: self.value }
    }

    /// Bit n: input n was sampled successfully at most `stale_ms` before `now_ms`.
    pub fn fresh(&self, now_ms: u32, stale_ms: u32) -> u8 {
        let mut fresh = 0;
        for n in 0..MAX_AUX {
            if self.ok & (1 << n) != 0 && now_ms.wrapping_sub(self.at_ms[n]) <= stale_ms {
                fresh |= 1 << n;
            }
        }
        fresh
    }

    /// Give the corrector this command's fast inputs.
    pub fn apply(&self, c: &mut FoldCorrector, now_ms: u32, stale_ms: u32) {
        if c.fold.fast_aux_mask() != 0 {
            c.fast = self.latest();
            c.fast_fresh = self.fresh(now_ms, stale_ms);
        }
    }
}
