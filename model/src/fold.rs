//! The two speeds of evaluation, as ultra-precision robot controllers split them.
//!
//! - The slow path, [`Model::fold`], runs in f64 whenever temperatures change (every few seconds
//!   at most): it multiplies every slow factor into its term and merges terms with the same
//!   position monomial, leaving a pure polynomial in position.
//! - The fast path, [`Fold::correct`], runs per command in f32 and never touches temperature.
//!   It evaluates only the *deviation* `δ(x) = q(x) − x`, which is small (µm), and adds it to the
//!   target: so f32 rounding acts on δ, not on the whole command, and stays far below 0.05 nm.

use crate::error::InverseError;
use crate::horner::{self, Dual, HornerNum};
use crate::input::{Input, SlowInputs};
use crate::limits::MAX_AXES;
use crate::model::Model;
use crate::term::Term;

/// Coefficients a fold can hold over all its blocks (a power of two: masked indices need no
/// bounds check). [`Model`] validation refuses a model whose fold would not fit.
pub const FOLD_CAPACITY: usize = 512;
const POOL_MASK: usize = FOLD_CAPACITY - 1;
/// Blocks: one per output axis and sign channel (none, or the sign of approach of an axis).
const MAX_BLOCKS: usize = MAX_AXES * (MAX_AXES + 1);
const MAX_NEWTON_STEPS: usize = 24;

/// One dense polynomial of the fold: its output axis, the sign that multiplies it (0 none,
/// 1 + a the sign of approach of axis a), its total degree and where its coefficients start.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Block {
    output: u8,
    sign: u8,
    degree: u8,
    start: u16,
}

/// The blocks a model folds into, with their degrees: the fold's shape, which depends only on
/// the model's terms, not on the slow inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FoldShape {
    blocks: [Block; MAX_BLOCKS],
    len: usize,
    /// Coefficients all blocks need together.
    pub coefficients: usize,
}

impl FoldShape {
    /// The blocks of a model with `axes` axes and these terms: for each output the identity
    /// is subtracted (degree ≥ 1), and every sign channel used gets a block of its own.
    pub(crate) fn of(axes: usize, terms: &[Term]) -> FoldShape {
        let mut degree = [[None::<u8>; MAX_AXES + 1]; MAX_AXES];
        for o in 0..axes {
            degree[o][0] = Some(1);
        }
        for t in terms {
            let (o, s) = (
                (t.output as usize).min(MAX_AXES - 1),
                (t.direction as usize).min(MAX_AXES),
            );
            degree[o][s] = Some(degree[o][s].unwrap_or(0).max(t.degree()));
        }
        let mut shape = FoldShape {
            blocks: [Block::default(); MAX_BLOCKS],
            len: 0,
            coefficients: 0,
        };
        for o in 0..axes {
            for s in 0..=MAX_AXES {
                if let Some(d) = degree[o][s] {
                    shape.blocks[shape.len] = Block {
                        output: o as u8,
                        sign: s as u8,
                        degree: d,
                        start: shape.coefficients as u16,
                    };
                    shape.len += 1;
                    shape.coefficients += horner::block_len(axes, d as usize);
                }
            }
        }
        shape
    }

    fn block_of(&self, output: u8, sign: u8) -> Option<&Block> {
        self.blocks[..self.len]
            .iter()
            .find(|b| b.output == output && b.sign == sign)
    }
}

/// A model with its slow inputs folded in: dense f32 polynomials in position, one block per
/// output axis and sign channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fold {
    axes: u8,
    centre_um: [f32; MAX_AXES],
    inv_half_range: [f32; MAX_AXES],
    envelope_min_um: [f32; MAX_AXES],
    envelope_max_um: [f32; MAX_AXES],
    /// Constant part of δ per axis, added after the rest: summing small terms onto a large
    /// constant would round each partial sum at the constant's magnitude.
    constant_um: [f32; MAX_AXES],
    blocks: [Block; MAX_BLOCKS],
    n_blocks: u8,
    coefficients: [f32; FOLD_CAPACITY],
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
        let axes = self.axes();
        let shape = FoldShape::of(axes, self.terms());
        let scaled = self.scale(&[0.0; MAX_AXES], &[0; MAX_AXES], slow);
        // Accumulate in f64 at each coefficient's place; validation guarantees it fits.
        let mut acc = [0.0f64; FOLD_CAPACITY];
        let mut constant = [0.0f64; MAX_AXES];
        let mut add = |output: u8, sign: u8, powers: [u8; MAX_AXES], value: f64| {
            if powers == [0; MAX_AXES] && sign == 0 {
                constant[output as usize] += value;
            } else if let Some(b) = shape.block_of(output, sign) {
                if let Some(pos) = horner::position(axes, b.degree as usize, powers) {
                    acc[(b.start as usize + pos) & POOL_MASK] += value;
                }
            }
        };
        for a in 0..axes {
            let sc = self.scaling(Input::Axis(a as u8));
            // δ = q − x, and x = centre + half_range·u.
            add(
                a as u8,
                0,
                [0; MAX_AXES],
                self.offset_um[a] + self.kmz_offset_um[a] - sc.centre,
            );
            let mut unit = [0; MAX_AXES];
            unit[a] = 1;
            add(a as u8, 0, unit, -sc.half_range);
        }
        for term in self.terms() {
            add(
                term.output,
                term.direction,
                term.powers,
                term.coeff * term.slow_factor(&scaled),
            );
        }
        let mut fold = Fold {
            axes: self.axes,
            centre_um: [0.0; MAX_AXES],
            inv_half_range: [1.0; MAX_AXES],
            envelope_min_um: [f32::NEG_INFINITY; MAX_AXES],
            envelope_max_um: [f32::INFINITY; MAX_AXES],
            constant_um: constant.map(|c| c as f32),
            blocks: shape.blocks,
            n_blocks: shape.len as u8,
            coefficients: acc.map(|c| c as f32),
            slow_flags: self.slow_envelope_flags(slow).0,
        };
        for a in 0..axes {
            let sc = self.scaling(Input::Axis(a as u8));
            let (min, max) = self.envelope(Input::Axis(a as u8));
            fold.centre_um[a] = sc.centre as f32;
            fold.inv_half_range[a] = (1.0 / sc.half_range) as f32;
            fold.envelope_min_um[a] = min as f32;
            fold.envelope_max_um[a] = max as f32;
        }
        fold
    }
}

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

    /// Number of coefficients the fast path reads per correction.
    pub fn fast_coefficients(&self) -> usize {
        self.blocks[..self.n_blocks as usize]
            .iter()
            .map(|b| horner::block_len(self.axes(), b.degree as usize))
            .sum()
    }

    /// Fast path: commands for calibrated targets `x_um`, approached in direction `dir`
    /// (+1 forward, −1 backward, 0 unknown).
    pub fn correct(&self, x_um: &[f32; MAX_AXES], dir: &[i8; MAX_AXES]) -> Correction {
        let axes = self.axes();
        let mut outside = 0u8;
        let mut u = [0.0f32; MAX_AXES];
        for a in 0..axes {
            if !(x_um[a] >= self.envelope_min_um[a] && x_um[a] <= self.envelope_max_um[a]) {
                outside |= 1 << a;
            }
            u[a] = (x_um[a] - self.centre_um[a]) * self.inv_half_range[a];
        }
        let mut delta = [0.0f32; MAX_AXES];
        for b in &self.blocks[..(self.n_blocks as usize).min(MAX_BLOCKS)] {
            let value = horner::evaluate(axes, b.degree as usize, u, |k| {
                self.coefficients[(b.start as usize + k) & POOL_MASK]
            });
            delta[(b.output as usize).min(MAX_AXES - 1)] += if b.sign == 0 {
                value
            } else {
                value * sign(dir, b.sign)
            };
        }
        let mut q_um = [0.0f32; MAX_AXES];
        for a in 0..axes {
            q_um[a] = (delta[a] + self.constant_um[a]) + x_um[a];
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
        let mut x = *q_um;
        for _ in 0..MAX_NEWTON_STEPS {
            let mut residual = [0.0f32; MAX_AXES];
            let mut jacobian = [[0.0f32; MAX_AXES]; MAX_AXES];
            let mut u = [<Dual as HornerNum>::ZERO; MAX_AXES];
            for a in 0..n {
                residual[a] = (x[a] - q_um[a]) + self.constant_um[a];
                jacobian[a][a] = 1.0;
                u[a] = Dual::variable(a, (x[a] - self.centre_um[a]) * self.inv_half_range[a]);
            }
            for b in &self.blocks[..(self.n_blocks as usize).min(MAX_BLOCKS)] {
                let d = horner::evaluate(n, b.degree as usize, u, |k| {
                    self.coefficients[(b.start as usize + k) & POOL_MASK]
                });
                let s = if b.sign == 0 { 1.0 } else { sign(dir, b.sign) };
                let o = (b.output as usize).min(MAX_AXES - 1);
                residual[o] += s * d.value;
                for a in 0..n {
                    // Chain rule: du_a/dx_a = 1/half_range_a.
                    jacobian[o][a] += s * d.grad[a] * self.inv_half_range[a];
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
}

/// Sign of approach for a block's sign channel `1 + axis`: +1, −1, or 0 when unknown.
#[inline(always)]
fn sign(dir: &[i8; MAX_AXES], channel: u8) -> f32 {
    crate::term::approach_sign(dir[(channel as usize - 1).min(MAX_AXES - 1)]) as f32
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
