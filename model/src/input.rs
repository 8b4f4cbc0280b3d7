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
    /// Auxiliary channel `n`, in the unit of its [`AuxKind`] (air pressure hPa, force N).
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

/// What an auxiliary input measures, so a device can check that it can supply it (its unit is
/// the unit the model's coefficients and envelope use).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum AuxKind {
    /// Anything else, in its own unit: a device supplies it only if it was told how.
    #[default]
    Other,
    /// Air pressure, hPa (e.g. a barometer on the board).
    AirPressureHpa,
    /// Force, N (e.g. a force sensor on an ADC channel).
    ForceN,
}

impl AuxKind {
    /// The kind's byte in the blob.
    pub fn code(self) -> u8 {
        match self {
            AuxKind::Other => 0,
            AuxKind::AirPressureHpa => 1,
            AuxKind::ForceN => 2,
        }
    }

    /// The kind a blob byte stands for, if any.
    pub fn from_code(code: u8) -> Option<AuxKind> {
        match code {
            0 => Some(AuxKind::Other),
            1 => Some(AuxKind::AirPressureHpa),
            2 => Some(AuxKind::ForceN),
            _ => None,
        }
    }
}

/// How an auxiliary input is measured and when it is evaluated.
///
/// A *slow* aux input is folded with the temperatures ([`crate::Model::fold`], every few
/// seconds). A *fast* one is read per command and multiplied in by the fast path
/// ([`crate::Fold::correct`] takes its value in [`FastInputs`]): paper 001 §VI, "variations due
/// to external forces have imperatively to be compensated in real-time".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AuxSpec {
    /// What the input measures.
    pub kind: AuxKind,
    /// Evaluated per command (true) or folded with the slow inputs (false).
    pub fast: bool,
}

impl AuxSpec {
    /// A slow input of this kind (folded with the temperatures).
    pub const fn slow(kind: AuxKind) -> AuxSpec {
        AuxSpec { kind, fast: false }
    }

    /// A fast input of this kind (evaluated per command).
    pub const fn fast(kind: AuxKind) -> AuxSpec {
        AuxSpec { kind, fast: true }
    }
}

/// The fast inputs of one command: values of the aux inputs declared fast, in their units, by
/// aux index. A channel that is not supplied is NaN ([`FastInputs::NONE`]): a model that uses it
/// then yields NaN commands and flags the channel, it never evaluates with a silent default.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FastInputs {
    /// Aux channel values by aux index (only the fast ones are read), in their units.
    pub aux: [f32; MAX_AUX],
}

impl FastInputs {
    /// No fast input supplied (every channel NaN). Models without fast inputs never read it.
    pub const NONE: FastInputs = FastInputs {
        aux: [f32::NAN; MAX_AUX],
    };

    /// These inputs with aux channel `n` set to `value` (ignored for `n ≥ MAX_AUX`).
    pub fn with_aux(mut self, n: usize, value: f32) -> FastInputs {
        if let Some(v) = self.aux.get_mut(n) {
            *v = value;
        }
        self
    }
}

impl Default for FastInputs {
    fn default() -> Self {
        FastInputs::NONE
    }
}

/// The slow inputs: they change every few seconds at most and are folded into the fast
/// coefficients by [`crate::Model::fold`]. `aux` holds every aux channel's value: the fold reads
/// only the slow ones (a fast channel's value comes per command in [`FastInputs`]), while the
/// f64 reference [`crate::Model::eval_f64`] reads them all here.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlowInputs {
    /// Temperatures in °C, by sensor index.
    pub temps_c: [f64; MAX_TEMPS],
    /// Auxiliary channels in their units, by index (see above for fast channels).
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
pub struct EnvelopeFlags(pub u32);

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
