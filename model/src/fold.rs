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
/// Flat power table: axis `a`'s power `p` sits at `a·POWERS + p`; a power of two in size so a
/// masked index needs no bounds check on the fast path.
const TABLE: usize = 32;
const TABLE_MASK: usize = TABLE - 1;
const MAX_NEWTON_STEPS: usize = 24;

// The flat power table must hold every axis' powers.
const _: () = assert!(MAX_AXES * POWERS <= TABLE);

/// One monomial of the folded deviation polynomial, laid out for the fast path: its
/// coefficient, where its three powers sit in the flat power table, and which sign multiplies
/// it (slot 0 holds 1, slot 1 + a the sign of approach of axis a).
#[derive(Clone, Copy, Debug, PartialEq)]
struct FastTerm {
    coeff: f32,
    index: [u8; 4],
}

impl FastTerm {
    fn new(powers: [u8; MAX_AXES], direction: u8, coeff: f32) -> Self {
        let mut index = [0u8; 4];
        for a in 0..MAX_AXES {
            index[a] = (a * POWERS) as u8 + powers[a];
        }
        index[3] = direction;
        FastTerm { coeff, index }
    }

    fn power(&self, axis: usize) -> usize {
        self.index[axis] as usize - axis * POWERS
    }

    #[inline(always)]
    fn monomial(&self, pows: &PowerTable) -> f32 {
        pows[self.index[0] as usize & TABLE_MASK]
            * pows[self.index[1] as usize & TABLE_MASK]
            * pows[self.index[2] as usize & TABLE_MASK]
    }

    #[inline(always)]
    fn sign(&self, signs: &[f32; 4]) -> f32 {
        signs[self.index[3] as usize & 3]
    }
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
    /// Non-constant monomials, grouped by output axis: output `o` owns
    /// `terms[output_end[o−1]..output_end[o]]`.
    terms: [FastTerm; FAST_CAPACITY],
    output_end: [u16; MAX_AXES],
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
            terms: [FastTerm {
                coeff: 0.0,
                index: [0; 4],
            }; FAST_CAPACITY],
            output_end: [0; MAX_AXES],
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
        let mut n = 0;
        for output in 0..MAX_AXES as u8 {
            for (shape, &coeff) in acc.shapes[..acc.len].iter().zip(&acc.coeffs) {
                if shape.output != output {
                    continue;
                }
                if shape.powers == [0; MAX_AXES] && shape.direction == 0 {
                    fold.constant_um[output as usize] = coeff as f32;
                    continue;
                }
                fold.terms[n] = FastTerm::new(shape.powers, shape.direction, coeff as f32);
                n += 1;
                for a in 0..MAX_AXES {
                    fold.max_power[a] = fold.max_power[a].max(shape.powers[a]);
                }
            }
            fold.output_end[output as usize] = n as u16;
        }
        fold
    }
}

/// Shape of a folded monomial: output axis, powers, direction.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Shape {
    output: u8,
    powers: [u8; MAX_AXES],
    direction: u8,
}

/// Merges folded coefficients of equal monomials, in f64 until stored.
struct FoldAccumulator {
    coeffs: [f64; FAST_CAPACITY],
    shapes: [Shape; FAST_CAPACITY],
    len: usize,
}

impl Default for FoldAccumulator {
    fn default() -> Self {
        let empty = Shape {
            output: 0,
            powers: [0; MAX_AXES],
            direction: 0,
        };
        FoldAccumulator {
            coeffs: [0.0; FAST_CAPACITY],
            shapes: [empty; FAST_CAPACITY],
            len: 0,
        }
    }
}

impl FoldAccumulator {
    fn add(&mut self, output: u8, powers: [u8; MAX_AXES], direction: u8, coeff: f64) {
        let shape = Shape {
            output,
            powers,
            direction,
        };
        let slot = match self.shapes[..self.len].iter().position(|s| *s == shape) {
            Some(i) => i,
            // A validated model has at most MAX_TERMS shapes plus the 2·axes identity ones.
            None if self.len < FAST_CAPACITY => {
                self.shapes[self.len] = shape;
                self.len += 1;
                self.len - 1
            }
            None => return,
        };
        self.coeffs[slot] += coeff;
    }
}

/// Powers 0..=MAX_POWER of each scaled axis position, flat (see [`TABLE`]).
type PowerTable = [f32; TABLE];

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
        self.output_end[MAX_AXES - 1] as usize
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
        let signs = signs(dir);
        let mut q_um = [0.0f32; MAX_AXES];
        let mut start = 0;
        for o in 0..self.axes() {
            let end = self.output_end[o] as usize;
            let mut delta = 0.0f32;
            for t in self.terms.get(start..end).unwrap_or(&[]) {
                delta += t.coeff * t.monomial(&pows) * t.sign(&signs);
            }
            q_um[o] = (delta + self.constant_um[o]) + x_um[o];
            start = end;
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
        let signs = signs(dir);
        let mut x = *q_um;
        for _ in 0..MAX_NEWTON_STEPS {
            let pows = self.power_table(&x);
            let mut residual = [0.0f32; MAX_AXES];
            let mut jacobian = [[0.0f32; MAX_AXES]; MAX_AXES];
            let mut start = 0;
            for o in 0..n {
                residual[o] = (x[o] - q_um[o]) + self.constant_um[o];
                jacobian[o][o] = 1.0;
                let end = self.output_end[o] as usize;
                for t in self.terms.get(start..end).unwrap_or(&[]) {
                    let c = t.coeff * t.sign(&signs);
                    residual[o] += c * t.monomial(&pows);
                    for a in 0..n {
                        let p = t.power(a);
                        if p > 0 {
                            // d/du_a of u_a^p is p·u_a^(p−1); the other axes' powers stay.
                            let mut lowered = *t;
                            lowered.index[a] -= 1;
                            let d = p as f32 * lowered.monomial(&pows) * self.inv_half_range[a];
                            jacobian[o][a] += c * d;
                        }
                    }
                }
                start = end;
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

    #[inline(always)]
    fn power_table(&self, x_um: &[f32; MAX_AXES]) -> PowerTable {
        let mut pows = [1.0f32; TABLE];
        for a in 0..self.axes() {
            let u = (x_um[a] - self.centre_um[a]) * self.inv_half_range[a];
            let base = a * POWERS;
            for k in 1..=self.max_power[a] as usize {
                pows[(base + k) & TABLE_MASK] = pows[(base + k - 1) & TABLE_MASK] * u;
            }
        }
        pows
    }
}

#[inline(always)]
fn signs(dir: &[i8; MAX_AXES]) -> [f32; 4] {
    let mut s = [1.0f32; 4];
    for a in 0..MAX_AXES {
        s[a + 1] = crate::term::approach_sign(dir[a]) as f32;
    }
    s
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
