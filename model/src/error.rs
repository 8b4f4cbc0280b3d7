//! Why a model cannot be built or used.

use core::fmt;

/// A model description that breaks the format's rules.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ModelError {
    /// More axes, temperatures, aux channels or lags than the fixed capacity allows.
    TooManyInputs,
    /// A model needs at least one axis.
    NoAxes,
    /// More than `MAX_TERMS` distinct terms.
    TooManyTerms,
    /// A term names an output axis, axis power, factor or direction the model does not have.
    TermOutOfRange {
        /// Index of the offending term.
        term: u16,
    },
    /// A term's power is above `MAX_POWER`.
    DegreeTooHigh {
        /// Index of the offending term.
        term: u16,
    },
    /// A coefficient, offset, scaling or bound is NaN or infinite where it must be finite.
    NonFinite,
    /// A scaling has a half range that is not positive.
    InvalidScaling {
        /// Flat index of the input (axes, temperatures, aux).
        input: u8,
    },
    /// An envelope or travel range has min > max.
    InvalidRange {
        /// Flat index of the input (axes, temperatures, aux); travel ranges use the axis index.
        input: u8,
    },
    /// The terms' degrees need more dense fast-path coefficients than a fold holds
    /// (`FOLD_CAPACITY`): lower the degree of some output or direction term.
    FoldTooLarge {
        /// Coefficients the fold would need.
        coefficients: u16,
    },
    /// A lag filter follows a sensor the model does not have, or has τ ≤ 0.
    InvalidLag {
        /// Index of the lag filter.
        lag: u8,
    },
    /// A play operator names an axis the model does not have, has a negative or non-finite
    /// threshold, or is out of order (operators go grouped by axis in axis order, thresholds
    /// strictly ascending within an axis).
    InvalidPlay {
        /// Index of the play operator.
        operator: u8,
    },
    /// A play-operator term has position powers, a direction, or an output other than the
    /// operator's own axis.
    InvalidPlayTerm {
        /// Index of the offending term.
        term: u16,
    },
    /// An axis' play operators would flatten or reverse a branch of `q(x)`: with thresholds
    /// ascending, `1 + Σ_{i ≤ j} w_i` falls below `MIN_BANK_SLOPE` (the inverse would not be
    /// well posed).
    BankNotMonotone {
        /// The axis.
        axis: u8,
    },
    /// A prediction bound has more regressors than `MAX_BOUND_TERMS`, other than one per term
    /// of its axis, a non-positive `s`, t quantile or scale, or a zero on the diagonal of `R`.
    InvalidBound,
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelError::TooManyInputs => f.write_str("more inputs than the model can hold"),
            ModelError::NoAxes => f.write_str("a model needs at least one axis"),
            ModelError::TooManyTerms => f.write_str("more terms than the model can hold"),
            ModelError::TermOutOfRange { term } => {
                write!(
                    f,
                    "term {term} names an axis or input the model does not have"
                )
            }
            ModelError::DegreeTooHigh { term } => write!(f, "term {term} has too high a power"),
            ModelError::NonFinite => f.write_str("a number in the model is not finite"),
            ModelError::InvalidScaling { input } => {
                write!(
                    f,
                    "input {input} has a scaling with a non-positive half range"
                )
            }
            ModelError::InvalidRange { input } => write!(f, "input {input} has min > max"),
            ModelError::FoldTooLarge { coefficients } => write!(
                f,
                "the terms' degrees need {coefficients} fast-path coefficients, more than a fold holds"
            ),
            ModelError::InvalidLag { lag } => {
                write!(f, "lag filter {lag} has an unknown sensor or τ ≤ 0")
            }
            ModelError::InvalidPlay { operator } => write!(
                f,
                "play operator {operator} has an unknown axis, a negative or non-finite threshold, \
                 or is out of order (grouped by axis, thresholds strictly ascending)"
            ),
            ModelError::InvalidPlayTerm { term } => write!(
                f,
                "term {term} uses a play operator with position powers, a direction or another \
                 axis' output"
            ),
            ModelError::BankNotMonotone { axis } => write!(
                f,
                "the play operators of axis {axis} make a branch of q(x) flat or falling \
                 (1 + partial sum of weights below the minimum slope)"
            ),
            ModelError::InvalidBound => f.write_str(
                "a prediction bound does not fit its axis' terms (count, positive s, t and \
                 scales, non-zero diagonal of R)",
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ModelError {}

/// The inverse map did not find a position for a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum InverseError {
    /// Newton's iteration did not converge within its iteration bound.
    NotConverged,
    /// The model's Jacobian is singular (or nearly) at the iterate: no unique position.
    Singular,
    /// The command or an iterate is NaN or infinite.
    NonFinite,
}

impl fmt::Display for InverseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InverseError::NotConverged => f.write_str("inverse did not converge"),
            InverseError::Singular => f.write_str("model is singular at this command"),
            InverseError::NonFinite => f.write_str("command or iterate is not finite"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for InverseError {}
