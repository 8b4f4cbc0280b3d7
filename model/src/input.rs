//! Inputs of the model: which channel, how it is scaled, the slow inputs folded per update.

use crate::limits::{MAX_AUX, MAX_AXES, MAX_LAGS, MAX_TEMPS};

/// One input channel of the model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Input {
    /// Commanded (calibrated) position of axis `n`, in µm.
    Axis(u8),
    /// Temperature sensor `n`, in °C.
    Temp(u8),
    /// Auxiliary channel `n` (e.g. air pressure in hPa), in its own unit.
    Aux(u8),
}

impl Input {
    /// Position of this input in the flat order axes, temperatures, aux (for envelope bit masks).
    pub fn flat_index(self) -> usize {
        match self {
            Input::Axis(n) => n as usize,
            Input::Temp(n) => MAX_AXES + n as usize,
            Input::Aux(n) => MAX_AXES + MAX_TEMPS + n as usize,
        }
    }
}

/// Centring and scaling of one input: `u = (v - centre) / half_range`, so that training data spans
/// about −1…1 and `f32` evaluation keeps its precision.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Scaling {
    /// Value mapped to 0.
    pub centre: f64,
    /// Distance from the centre mapped to ±1; always > 0.
    pub half_range: f64,
}

impl Scaling {
    /// The identity scaling (centre 0, half range 1).
    pub const IDENTITY: Scaling = Scaling {
        centre: 0.0,
        half_range: 1.0,
    };

    /// Scaling that maps `[min, max]` onto `[-1, 1]` (a degenerate range gets half range 1).
    pub fn from_range(min: f64, max: f64) -> Scaling {
        let half = 0.5 * (max - min);
        Scaling {
            centre: 0.5 * (min + max),
            half_range: if half > 0.0 && half.is_finite() {
                half
            } else {
                1.0
            },
        }
    }

    /// Scaled value of `v`.
    #[inline]
    pub fn apply(&self, v: f64) -> f64 {
        (v - self.centre) / self.half_range
    }

    /// Whether the scaling can be used: finite, with a positive half range.
    pub fn is_valid(&self) -> bool {
        self.centre.is_finite() && self.half_range.is_finite() && self.half_range > 0.0
    }
}

/// A closed interval `[min, max]`: training envelope of an input, or travel of an axis.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Range {
    /// Lower bound.
    pub min: f64,
    /// Upper bound.
    pub max: f64,
}

impl Range {
    /// The whole real line: nothing is outside.
    pub const UNBOUNDED: Range = Range {
        min: f64::NEG_INFINITY,
        max: f64::INFINITY,
    };

    /// Whether `v` lies in the interval (NaN never does).
    #[inline]
    pub fn contains(&self, v: f64) -> bool {
        v >= self.min && v <= self.max
    }

    /// Whether the interval can be used: not NaN, `min <= max`.
    pub fn is_valid(&self) -> bool {
        !self.min.is_nan() && !self.max.is_nan() && self.min <= self.max
    }
}

/// The slow inputs: they change every few seconds at most and are folded into the fast
/// coefficients by [`crate::Model::fold`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlowInputs {
    /// Temperatures in °C, by sensor index.
    pub temps_c: [f64; MAX_TEMPS],
    /// Auxiliary channels in their units, by index.
    pub aux: [f64; MAX_AUX],
    /// Output of each declared lag filter, in °C, by lag index (see [`crate::LagBank`]).
    pub lagged_c: [f64; MAX_LAGS],
}

impl Default for SlowInputs {
    fn default() -> Self {
        SlowInputs {
            temps_c: [0.0; MAX_TEMPS],
            aux: [0.0; MAX_AUX],
            lagged_c: [0.0; MAX_LAGS],
        }
    }
}

/// Bit mask of inputs outside their training envelope; bit `i` is [`Input::flat_index`] `i`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EnvelopeFlags(pub u16);

impl EnvelopeFlags {
    /// True when every input lies inside the envelope.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Whether `input` is flagged.
    pub fn contains(self, input: Input) -> bool {
        self.0 & (1 << input.flat_index()) != 0
    }
}
