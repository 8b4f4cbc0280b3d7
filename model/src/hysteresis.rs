//! Deployable hysteresis: per-axis banks of play operators, a Prandtl–Ishlinskii model that the
//! fast path runs per command.
//!
//! A Prandtl–Ishlinskii operator is a weighted sum of play operators with thresholds spread over
//! the stroke, `H[v] = Σ_k w_k · F_{r_k}[v]` (K. Kuhnen, "Modeling, Identification and
//! Compensation of Complex Hysteretic Nonlinearities: A Modified Prandtl–Ishlinskii Approach",
//! European Journal of Control 9(4), 2003, pp. 407–418). It is rate independent and remembers
//! its reversal points, so it reproduces minor loops and changing amplitudes, not one fixed loop.
//!
//! ## What the model declares, precisely
//! - **Operator `k`** ([`PlaySpec`]): an axis `a` and a threshold `r_k ≥ 0` in µm (the half
//!   width of its dead band, over the stroke). Operators are declared grouped by axis in axis
//!   order, thresholds strictly ascending within an axis: that order is the bank of axis `a`.
//! - **Input**: the calibrated target `x_a` of that axis, in µm — the same value the position
//!   polynomial sees, before any correction.
//! - **State**: the operators' outputs `y_k` (µm), held in a [`HysteresisState`] outside the
//!   model; every command steps them, `y_k ← play(y_k, x_a, r_k)` ([`crate::play::play`]).
//! - **Output**: a term `coeff · Factor::Play(k)` adds to the command of axis `a` itself
//!   (validation refuses any other output, position powers or a direction on such a term).
//!   Like every factor it is scaled like its input, `coeff · (y_k − c_a)/h_a`, so in raw units
//!   the term adds `w_k · y_k` with the dimensionless weight `w_k = coeff/h_a` (µm per µm).
//! - **Initial state and reset**: a fresh or reset state is *unprimed*; the first command then
//!   sets every `y_k = x_a` (each operator at the centre of its dead band, no hysteresis offset)
//!   and steps from there. Reset whenever the stage's own hysteretic memory is unknown to the
//!   compensator: a new model, power-up, anything that moved the stage without the compensator
//!   seeing the targets.
//! - **Sign of the weights**: while operator `k` follows a rising target its output is
//!   `x_a − r_k`, on a falling one `x_a + r_k`, so it adds `−w_k·r_k` going up and `+w_k·r_k`
//!   coming down. A positive weight puts the rising branch of `q(x)` below the falling one (the
//!   command lags the target); a negative weight puts it above (the command leads the target),
//!   which is what an actuator whose position lags its command — a piezo stack — needs: the
//!   inverse of a Prandtl–Ishlinskii operator with positive weights has negative weights on its
//!   higher thresholds (Kuhnen 2003, the inverse operator).
//! - **Well-posed inverse**: after a reversal the operators start to follow in threshold order,
//!   so along a branch the bank's slope is `Σ_{i ≤ j} w_i` for the first `j` thresholds passed
//!   (for any state a history can reach: an operator's output moves by at most the change of
//!   its threshold, `|y_i − y_j| ≤ |r_i − r_j|`). With the identity `q = x` this is Kuhnen's
//!   initial loading curve, which must be strictly increasing for the operator to be
//!   invertible. Validation demands `1 + Σ_{i ≤ j} w_i ≥` [`MIN_BANK_SLOPE`] for every `j`:
//!   the bank alone never flattens or reverses a branch. The position polynomial's own slope
//!   comes on top; where it breaks monotonicity the inverse says so
//!   ([`crate::InverseError`]), as without hysteresis.
//! - **Position replies**: [`crate::Fold::inverse`] solves `q(x) = q` with the state *frozen*
//!   (a query does not move the stage): right after commanding `x` it returns `x` again.

use crate::limits::{MAX_AXES, MAX_PLAY};

/// Smallest slope `1 + Σ_{i ≤ j} w_i` the identity and a bank may have along a branch: below
/// it the inverse would amplify a reply's error more than twentyfold.
pub const MIN_BANK_SLOPE: f64 = 0.05;

/// A declared play operator: the axis whose target feeds it, and its threshold.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlaySpec {
    /// Axis whose calibrated target is the input, and whose command the weighted output joins.
    pub axis: u8,
    /// Threshold (half width of the dead band) r, µm (≥ 0, finite).
    pub threshold_um: f64,
}

/// The outputs of every play operator of a model, stepped once per command. `f32` on the
/// device's fast path, `f64` for the host's reference ([`crate::Model::eval_f64_with_state`]).
///
/// Outputs are kept relative to their axis' scaling centre (µm), where f32 has the most
/// digits. A state belongs to one model: reset it when the model changes.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HysteresisState<T = f32> {
    pub(crate) outputs: [T; MAX_PLAY],
    pub(crate) primed: bool,
}

impl<T: Copy + Default> HysteresisState<T> {
    /// An unprimed state: the next command initialises every operator at its input.
    pub fn new() -> Self {
        HysteresisState {
            outputs: [T::default(); MAX_PLAY],
            primed: false,
        }
    }

    /// Forgets the history: the next command initialises every operator at its input.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Whether a command has set the operators since the last reset.
    pub fn is_primed(&self) -> bool {
        self.primed
    }

    /// Operator outputs by operator index, relative to their axis' scaling centre, µm
    /// (meaningful once primed).
    pub fn outputs(&self) -> &[T; MAX_PLAY] {
        &self.outputs
    }
}

/// The device's f32 memory as the f64 reference evaluation's ([`crate::Model::eval_f64_with_state`])
/// starting point: a host that mirrors the device steps an f32 state and evaluates from it in f64.
impl From<HysteresisState<f32>> for HysteresisState<f64> {
    fn from(s: HysteresisState<f32>) -> Self {
        HysteresisState {
            outputs: s.outputs.map(f64::from),
            primed: s.primed,
        }
    }
}

impl<T: Copy + Default> Default for HysteresisState<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Index ranges of each axis' bank in a list of operators already validated as grouped by axis:
/// the operators of axis `a` are `start[a]..start[a + 1]`.
pub(crate) fn bank_starts(specs: &[PlaySpec]) -> [u8; MAX_AXES + 1] {
    let mut start = [0u8; MAX_AXES + 1];
    for a in 0..MAX_AXES {
        let before = specs.iter().filter(|s| (s.axis as usize) <= a).count();
        start[a + 1] = before.min(MAX_PLAY) as u8;
    }
    start
}
