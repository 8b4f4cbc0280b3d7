//! The two speeds of evaluation, as ultra-precision robot controllers split them.
//!
//! - The slow path, [`Model::fold`], runs in f64 whenever temperatures change (every few seconds
//!   at most): it multiplies every slow factor into its term and merges terms with the same
//!   position monomial, leaving a pure polynomial in position.
//! - The fast path, [`Fold::correct`], runs per command in f32 and never touches temperature.
//!   It evaluates only the *deviation* `δ(x) = q(x) − x`, which is small (µm), and adds it to the
//!   target: so f32 rounding acts on δ, not on the whole command, and stays far below 0.05 nm.

use crate::error::InverseError;
use crate::input::{Input, SlowInputs};
use crate::limits::{MAX_AXES, MAX_POWER, MAX_TERMS};
use crate::model::Model;

const FAST_CAPACITY: usize = MAX_TERMS + 2 * MAX_AXES;
const POWERS: usize = MAX_POWER as usize + 1;
const MAX_NEWTON_STEPS: usize = 24;

/// One monomial of the folded deviation polynomial.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FastTerm {
    output: u8,
    powers: [u8; MAX_AXES],
    direction: u8,
    coeff: f32,
}

/// A model with its slow inputs folded in: a pure f32 polynomial in position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fold {
    axes: u8,
    centre_um: [f32; MAX_AXES],
    inv_half_range: [f32; MAX_AXES],
    envelope_min_um: [f32; MAX_AXES],
    envelope_max_um: [f32; MAX_AXES],
    max_power: [u8; MAX_AXES],
    /// Constant part of δ per axis, added after the small terms: summing those onto a large
    /// constant would round each partial sum at the constant's magnitude.
    constant_um: [f32; MAX_AXES],
    terms: [FastTerm; FAST_CAPACITY],
    n_terms: u16,
    slow_flags: u16,
}

/// Result of the fast path.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Correction {
    /// Commands for the stage controller, µm.
    pub q_um: [f32; MAX_AXES],
    /// Bit `a` set when target axis `a` lies outside the training envelope.
    pub outside_envelope: u8,
}

impl Model {
    /// Slow path: folds temperatures, aux channels and lagged temperatures into the fast
    /// coefficients (computed in f64, stored in f32).
    pub fn fold(&self, slow: &SlowInputs) -> Fold {
        let scaled = self.scale(&[0.0; MAX_AXES], &[0; MAX_AXES], slow);
        let mut acc = FoldAccumulator::default();
        for a in 0..self.axes() {
            let sc = self.scaling(Input::Axis(a as u8));
            // δ = q − x, and x = centre + half_range·u.
            acc.add(
                a as u8,
                [0; MAX_AXES],
                0,
                self.offset_um[a] + self.kmz_offset_um[a] - sc.centre,
            );
            let mut unit = [0; MAX_AXES];
            unit[a] = 1;
            acc.add(a as u8, unit, 0, -sc.half_range);
        }
        for term in self.terms() {
            acc.add(
                term.output,
                term.powers,
                term.direction,
                term.coeff * term.slow_factor(&scaled),
            );
        }
        let mut fold = Fold {
            axes: self.axes,
            centre_um: [0.0; MAX_AXES],
            inv_half_range: [1.0; MAX_AXES],
            envelope_min_um: [f32::NEG_INFINITY; MAX_AXES],
            envelope_max_um: [f32::INFINITY; MAX_AXES],
            max_power: [0; MAX_AXES],
            constant_um: [0.0; MAX_AXES],
            terms: acc.terms,
            n_terms: 0,
            slow_flags: self.slow_envelope_flags(slow).0,
        };
        for a in 0..self.axes() {
            let sc = self.scaling(Input::Axis(a as u8));
            let (min, max) = self.envelope(Input::Axis(a as u8));
            fold.centre_um[a] = sc.centre as f32;
            fold.inv_half_range[a] = (1.0 / sc.half_range) as f32;
            fold.envelope_min_um[a] = min as f32;
            fold.envelope_max_um[a] = max as f32;
        }
        for (i, t) in acc.terms[..acc.len].iter().enumerate() {
            if t.powers == [0; MAX_AXES] && t.direction == 0 {
                fold.constant_um[t.output as usize] = acc.coeffs[i] as f32;
                continue;
            }
            fold.terms[fold.n_terms as usize] = *t;
            fold.n_terms += 1;
            for a in 0..MAX_AXES {
                fold.max_power[a] = fold.max_power[a].max(t.powers[a]);
            }
        }
        fold
    }
}

/// Merges folded coefficients of equal monomials (f64 until stored).
struct FoldAccumulator {
    coeffs: [f64; FAST_CAPACITY],
    terms: [FastTerm; FAST_CAPACITY],
    len: usize,
}

impl Default for FoldAccumulator {
    fn default() -> Self {
        let empty = FastTerm {
            output: 0,
            powers: [0; MAX_AXES],
            direction: 0,
            coeff: 0.0,
        };
        FoldAccumulator {
            coeffs: [0.0; FAST_CAPACITY],
            terms: [empty; FAST_CAPACITY],
            len: 0,
        }
    }
}

impl FoldAccumulator {
    fn add(&mut self, output: u8, powers: [u8; MAX_AXES], direction: u8, coeff: f64) {
        let shape =
            |t: &FastTerm| t.output == output && t.powers == powers && t.direction == direction;
        let slot = match self.terms[..self.len].iter().position(shape) {
            Some(i) => i,
            // A validated model has at most MAX_TERMS shapes plus the 2·axes identity ones.
            None if self.len < FAST_CAPACITY => {
                self.terms[self.len] = FastTerm {
                    output,
                    powers,
                    direction,
                    coeff: 0.0,
                };
                self.len += 1;
                self.len - 1
            }
            None => return,
        };
        self.coeffs[slot] += coeff;
        self.terms[slot].coeff = self.coeffs[slot] as f32;
    }
}

/// Powers 0..=MAX_POWER of each scaled axis position.
type PowerTable = [[f32; POWERS]; MAX_AXES];

impl Fold {
    /// Number of axes.
    pub fn axes(&self) -> usize {
        self.axes as usize
    }

    /// Bits of the temperature and aux inputs that were outside the training envelope when
    /// this fold was made (bit numbering of [`crate::EnvelopeFlags`]).
    pub fn slow_outside_envelope(&self) -> u16 {
        self.slow_flags
    }

    /// Number of non-constant monomials the fast path evaluates.
    pub fn fast_terms(&self) -> usize {
        self.n_terms as usize
    }

    /// Fast path: commands for calibrated targets `x_um`, approached in direction `dir`
    /// (+1 forward, −1 backward, 0 unknown).
    pub fn correct(&self, x_um: &[f32; MAX_AXES], dir: &[i8; MAX_AXES]) -> Correction {
        let mut outside = 0u8;
        for a in 0..self.axes() {
            if !(x_um[a] >= self.envelope_min_um[a] && x_um[a] <= self.envelope_max_um[a]) {
                outside |= 1 << a;
            }
        }
        let pows = self.power_table(x_um);
        let sign = signs(dir);
        let mut q_um = [0.0f32; MAX_AXES];
        for t in &self.terms[..self.n_terms as usize] {
            q_um[t.output as usize] +=
                t.coeff * monomial(&pows, t.powers) * sign_of(&sign, t.direction);
        }
        for a in 0..self.axes() {
            q_um[a] = (q_um[a] + self.constant_um[a]) + x_um[a];
        }
        Correction {
            q_um,
            outside_envelope: outside,
        }
    }

    /// Inverse map: the calibrated position whose command is `q_um` (e.g. a position the
    /// controller reports). Bounded Newton iteration on `x + δ(x) = q`.
    pub fn inverse(
        &self,
        q_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
    ) -> Result<[f32; MAX_AXES], InverseError> {
        let n = self.axes();
        if q_um[..n].iter().any(|v| !v.is_finite()) {
            return Err(InverseError::NonFinite);
        }
        let sign = signs(dir);
        let mut x = *q_um;
        for _ in 0..MAX_NEWTON_STEPS {
            let pows = self.power_table(&x);
            let mut residual = [0.0f32; MAX_AXES];
            let mut jacobian = [[0.0f32; MAX_AXES]; MAX_AXES];
            for a in 0..n {
                residual[a] = (x[a] - q_um[a]) + self.constant_um[a];
                jacobian[a][a] = 1.0;
            }
            for t in &self.terms[..self.n_terms as usize] {
                let c = t.coeff * sign_of(&sign, t.direction);
                let o = t.output as usize;
                residual[o] += c * monomial(&pows, t.powers);
                for a in 0..n {
                    let p = t.powers[a];
                    if p > 0 {
                        let mut lowered = t.powers;
                        lowered[a] -= 1;
                        let d = p as f32 * monomial(&pows, lowered) * self.inv_half_range[a];
                        jacobian[o][a] += c * d;
                    }
                }
            }
            let step = solve(jacobian, residual, n)?;
            let mut converged = true;
            for a in 0..n {
                x[a] -= step[a];
                if !x[a].is_finite() {
                    return Err(InverseError::NonFinite);
                }
                let tolerance = 8.0 * f32::EPSILON * (x[a].abs() + q_um[a].abs() + 1.0);
                converged &= step[a].abs() <= tolerance;
            }
            if converged {
                return Ok(x);
            }
        }
        Err(InverseError::NotConverged)
    }

    fn power_table(&self, x_um: &[f32; MAX_AXES]) -> PowerTable {
        let mut pows = [[0.0f32; POWERS]; MAX_AXES];
        for a in 0..MAX_AXES {
            pows[a][0] = 1.0;
            if a < self.axes() {
                let u = (x_um[a] - self.centre_um[a]) * self.inv_half_range[a];
                for k in 1..=self.max_power[a] as usize {
                    pows[a][k] = pows[a][k - 1] * u;
                }
            }
        }
        pows
    }
}

#[inline]
fn monomial(pows: &PowerTable, powers: [u8; MAX_AXES]) -> f32 {
    pows[0][powers[0] as usize] * pows[1][powers[1] as usize] * pows[2][powers[2] as usize]
}

#[inline]
fn signs(dir: &[i8; MAX_AXES]) -> [f32; MAX_AXES + 1] {
    let mut s = [1.0f32; MAX_AXES + 1];
    for a in 0..MAX_AXES {
        s[a + 1] = crate::term::approach_sign(dir[a]) as f32;
    }
    s
}

/// Factor of a term's direction field: 1 for none, else the sign of that axis (index 0 is 1).
#[inline]
fn sign_of(signs: &[f32; MAX_AXES + 1], direction: u8) -> f32 {
    signs[(direction as usize).min(MAX_AXES)]
}

/// Solves `J·s = r` for n ≤ 3 by Gaussian elimination with partial pivoting.
fn solve(
    mut j: [[f32; MAX_AXES]; MAX_AXES],
    mut r: [f32; MAX_AXES],
    n: usize,
) -> Result<[f32; MAX_AXES], InverseError> {
    for col in 0..n {
        let pivot = (col..n)
            .max_by(|&a, &b| j[a][col].abs().total_cmp(&j[b][col].abs()))
            .unwrap_or(col);
        if j[pivot][col].abs().partial_cmp(&1e-6) != Some(core::cmp::Ordering::Greater) {
            return Err(InverseError::Singular);
        }
        j.swap(col, pivot);
        r.swap(col, pivot);
        for row in col + 1..n {
            let f = j[row][col] / j[col][col];
            for k in col..n {
                j[row][k] -= f * j[col][k];
            }
            r[row] -= f * r[col];
        }
    }
    let mut s = [0.0f32; MAX_AXES];
    for row in (0..n).rev() {
        let mut v = r[row];
        for k in row + 1..n {
            v -= j[row][k] * s[k];
        }
        s[row] = v / j[row][row];
    }
    Ok(s)
}
