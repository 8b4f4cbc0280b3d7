//! A parameter's value with its 1σ ([`Estimate`]) and a nonlinear parameter a search found
//! ([`Theta`]): a leaf the search, the candidate contract and the effects share.

use serde::Serialize;

/// A parameter estimate with its 1σ uncertainty (NaN when not known).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Estimate {
    /// Name with unit suffix (`tau_s`, `half_width_nm`, …).
    pub name: String,
    /// Value.
    pub value: f64,
    /// 1σ uncertainty.
    pub sigma: f64,
}

impl Estimate {
    /// A named estimate.
    pub fn new(name: &str, value: f64, sigma: f64) -> Self {
        Self {
            name: name.into(),
            value,
            sigma,
        }
    }
}

/// A nonlinear parameter a candidate searched (τ, t0, a time scale), with its 1σ from the
/// profile of the residual sum of squares and the range it was searched in.
#[derive(Clone, Debug, PartialEq)]
pub struct Theta {
    /// Name with unit suffix (`tau_s`, `t0_s`, …).
    pub name: String,
    /// Best value.
    pub value: f64,
    /// 1σ (infinite when the profile is flat, NaN when not known).
    pub sigma: f64,
    /// Bottom of the searched range.
    pub lo: f64,
    /// Top of the searched range.
    pub hi: f64,
}

impl Theta {
    /// A sentence when the value sits on a bound of its searched range (within 3 %): then it
    /// is a bound, not an estimate.
    pub fn bound_note(&self) -> Option<String> {
        if self.value >= self.hi * 0.97 {
            Some(format!(
                "{} at the top of the searched range ({}): a lower bound",
                self.name,
                super::units::sig3(self.hi)
            ))
        } else if self.value <= self.lo * 1.03 {
            Some(format!(
                "{} at the bottom of the searched range ({}): an upper bound",
                self.name,
                super::units::sig3(self.lo)
            ))
        } else {
            None
        }
    }

    /// As an estimate (value ± σ); on a bound of the searched range it is a bound, not a
    /// value ± σ: its σ is then NaN (not known), and [`Theta::bound_note`] says which bound.
    pub fn estimate(&self) -> Estimate {
        Estimate::new(&self.name, self.value, self.sigma_unless_bound())
    }

    /// σ, or NaN when the value sits on a bound of its searched range.
    pub fn sigma_unless_bound(&self) -> f64 {
        if self.bound_note().is_some() {
            f64::NAN
        } else {
            self.sigma
        }
    }
}
