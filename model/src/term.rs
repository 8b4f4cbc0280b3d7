//! A term of the model: coefficient × position monomial × optional factor × optional sign of
//! approach, contributing to one output axis.

use crate::limits::MAX_AXES;

/// What a term multiplies its position monomial with, scaled like the input it comes from.
/// Temperatures, lagged temperatures and slow aux inputs are folded by [`crate::Model::fold`];
/// fast aux inputs and play operators are evaluated per command by [`crate::Fold::correct`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Factor {
    /// Nothing: a pure position polynomial term.
    None,
    /// Temperature sensor `n`.
    Temp(u8),
    /// Auxiliary channel `n`.
    Aux(u8),
    /// Output of lag filter `n` (a lagged copy of one temperature sensor).
    Lagged(u8),
    /// Output of play operator `n` (hysteresis, see [`crate::hysteresis`]), scaled like the
    /// axis that feeds it. Only alone on its axis' own output: no powers, no direction.
    Play(u8),
}

/// One term: `coeff × Π_a u_a^powers[a] × factor × sign(approach on axis direction−1)`.
///
/// All inputs are the *scaled* ones (see [`crate::Scaling`]); `coeff` is in µm of the output axis.
/// `direction` is 0 for none, or `k` in 1..=3 to multiply by the sign of approach (+1 forward,
/// −1 backward, 0 unknown) of axis `k − 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Term {
    /// Output axis the term contributes to.
    pub output: u8,
    /// Power of each scaled axis position.
    pub powers: [u8; MAX_AXES],
    /// Slow factor.
    pub factor: Factor,
    /// 0, or 1 + the axis whose sign of approach multiplies the term.
    pub direction: u8,
    /// Coefficient, µm.
    pub coeff: f64,
}

impl Term {
    /// Total degree of the position monomial, saturating at 255: the powers come from outside
    /// (a blob), and validation compares the degree with the limit before anything else bounds
    /// the powers, so a sum that wrapped could make a too-high degree look like 0.
    pub fn degree(&self) -> u8 {
        self.powers.iter().fold(0u8, |d, &p| d.saturating_add(p))
    }

    /// Whether two terms differ only by their coefficient.
    pub fn same_shape(&self, other: &Term) -> bool {
        self.output == other.output
            && self.powers == other.powers
            && self.factor == other.factor
            && self.direction == other.direction
    }
}

/// Sign of approach as a factor: +1 forward, −1 backward, 0 unknown (the middle of the loop).
#[inline]
pub fn approach_sign(dir: i8) -> f64 {
    match dir {
        d if d > 0 => 1.0,
        d if d < 0 => -1.0,
        _ => 0.0,
    }
}
