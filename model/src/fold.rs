//! The two speeds of evaluation, as ultra-precision robot controllers split them (paper 001
//! §VI: thermal terms "can be calculated in a non-real-time process each 5-10 seconds",
//! "variations due to external forces have imperatively to be compensated in real-time").
//!
//! - The slow path, [`Model::fold`], runs in f64 whenever temperatures change (every few seconds
//!   at most): it multiplies every slow factor (temperature, lagged temperature, slow aux input)
//!   into its term and merges terms with the same position monomial and multiplier channel,
//!   leaving polynomials in position.
//! - The fast path, [`Fold::correct`], runs per command in f32 and never touches temperature.
//!   It evaluates only the *deviation* `δ(x) = q(x) − x`, which is small (µm), and adds it to the
//!   target: so f32 rounding acts on δ, not on the whole command, and stays far below 0.05 nm.
//!   Per command it sees the targets, the direction of approach, the fast inputs
//!   ([`FastInputs`]) and the hysteresis state ([`HysteresisState`]), and treats them all alike:
//!   - one dense polynomial block per output axis and *multiplier channel*: the block's value is
//!     multiplied by the sign of approach of an axis, by a fast aux input, by both, or by 1;
//!   - one bank of play operators per axis, stepped and weighted. A play term
//!     `coeff·(y − c)/h` is split as `w·(y − x) + coeff·u` with `w = coeff/h`: the linear part
//!     folds into the axis' own block, so the bank only adds `Σ w·(y − x)`, small numbers
//!     bounded by the thresholds, like δ itself.

use crate::error::InverseError;
use crate::horner::{self, Dual, HornerNum};
use crate::hysteresis::{bank_starts, HysteresisState};
use crate::input::{FastInputs, Input, SlowInputs};
use crate::limits::{MAX_AUX, MAX_AXES, MAX_PLAY};
use crate::model::Model;
use crate::play::play;
use crate::term::{Factor, Term};

/// Coefficients a fold can hold over all its blocks (a power of two: masked indices need no
/// bounds check). [`Model`] validation refuses a model whose fold would not fit.
pub const FOLD_CAPACITY: usize = 512;
const POOL_MASK: usize = FOLD_CAPACITY - 1;
/// Multiplier channels besides the sign of approach: none, or fast aux input `n` (1 + n).
const CHANNELS: usize = 1 + MAX_AUX;
/// Blocks: one per output axis, sign channel (none, or the sign of approach of an axis) and
/// fast channel.
const MAX_BLOCKS: usize = MAX_AXES * (MAX_AXES + 1) * CHANNELS;
/// Bound on the inverse's Newton steps.
const MAX_NEWTON_STEPS: usize = 16;
/// Halvings of a Newton step that does not reduce the residual before it is taken anyway.
const MAX_BACKTRACKS: usize = 6;
/// Steps within this many tolerances are near the answer: taken in full, and the iteration
/// ends when they stop shrinking (the residual's rounding floor).
const NEAR: f32 = 64.0;

/// One dense polynomial of the fold: its output axis, the sign that multiplies it (0 none,
/// 1 + a the sign of approach of axis a), the fast input that multiplies it (0 none, 1 + n aux
/// input n), its total degree and where its coefficients start.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Block {
    output: u8,
    sign: u8,
    channel: u8,
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

/// Multiplier channel of a term: 1 + n for a fast aux input n, else 0 (play terms fold into
/// the plain block of their axis).
fn channel_of(term: &Term, fast_mask: u8) -> usize {
    match term.factor {
        Factor::Aux(n) if n < 8 && fast_mask & (1 << n) != 0 => 1 + (n as usize).min(MAX_AUX - 1),
        _ => 0,
    }
}

impl FoldShape {
    /// The blocks of a model with `axes` axes, these terms and these fast aux inputs: for each
    /// output the identity is subtracted (degree ≥ 1), and every sign × fast channel used gets a
    /// block of its own.
    pub(crate) fn of(axes: usize, terms: &[Term], fast_mask: u8) -> FoldShape {
        let mut degree = [[[None::<u8>; CHANNELS]; MAX_AXES + 1]; MAX_AXES];
        for o in 0..axes {
            degree[o][0][0] = Some(1);
        }
        for t in terms {
            let (o, s, c) = (
                (t.output as usize).min(MAX_AXES - 1),
                (t.direction as usize).min(MAX_AXES),
                channel_of(t, fast_mask),
            );
            degree[o][s][c] = Some(degree[o][s][c].unwrap_or(0).max(t.degree()));
        }
        let mut shape = FoldShape {
            blocks: [Block::default(); MAX_BLOCKS],
            len: 0,
            coefficients: 0,
        };
        for o in 0..axes {
            for s in 0..=MAX_AXES {
                for c in 0..CHANNELS {
                    if let Some(d) = degree[o][s][c] {
                        shape.blocks[shape.len] = Block {
                            output: o as u8,
                            sign: s as u8,
                            channel: c as u8,
                            degree: d,
                            start: shape.coefficients as u16,
                        };
                        shape.len += 1;
                        shape.coefficients += horner::block_len(axes, d as usize);
                    }
                }
            }
        }
        shape
    }

    fn block_of(&self, output: u8, sign: u8, channel: u8) -> Option<&Block> {
        self.blocks[..self.len]
            .iter()
            .find(|b| b.output == output && b.sign == sign && b.channel == channel)
    }
}

/// A model with its slow inputs folded in: dense f32 polynomials in position, one block per
/// output axis and multiplier channel, the fast inputs' scalings and the play-operator banks.
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
    slow_flags: u32,
    /// Bit n: fast aux input n multiplies some block.
    fast_mask: u8,
    fast_centre: [f32; MAX_AUX],
    fast_inv_half_range: [f32; MAX_AUX],
    fast_min: [f32; MAX_AUX],
    fast_max: [f32; MAX_AUX],
    /// Operators of axis a are `bank_start[a]..bank_start[a + 1]`.
    bank_start: [u8; MAX_AXES + 1],
    play_threshold_um: [f32; MAX_PLAY],
    /// `w = coeff/h`: µm of command per µm of `y − x`.
    play_weight: [f32; MAX_PLAY],
}

/// Result of the fast path.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Correction {
    /// Commands for the stage controller, µm (`x + δ` rounded to f32).
    pub q_um: [f32; MAX_AXES],
    /// The deviation `δ = q − x`, µm. A caller that holds the target in f64 forms
    /// `q = x + δ` in f64: f32 commands round by half an ulp, 0.24 nm at 5 mm.
    pub delta_um: [f32; MAX_AXES],
    /// Bit `a` set when target axis `a` lies outside the training envelope.
    pub outside_envelope: u8,
    /// Bit `n` set when fast aux input `n`, which the model uses, is outside its training
    /// envelope or not supplied (NaN; the commands are NaN then too).
    pub fast_outside_envelope: u8,
}

impl Model {
    /// Slow path: folds temperatures, slow aux channels and lagged temperatures into the fast
    /// coefficients (computed in f64, stored in f32). Fast aux inputs stay symbolic (a block
    /// each) and play operators keep their thresholds and weights.
    pub fn fold(&self, slow: &SlowInputs) -> Fold {
        let axes = self.axes();
        let fast_mask = self.fast_aux_mask();
        let shape = FoldShape::of(axes, self.terms(), fast_mask);
        let scaled = self.scale(&[0.0; MAX_AXES], &[0; MAX_AXES], slow);
        // Accumulate in f64 at each coefficient's place; validation guarantees it fits.
        let mut acc = [0.0f64; FOLD_CAPACITY];
        let mut constant = [0.0f64; MAX_AXES];
        let mut add = |output: u8, sign: u8, channel: u8, powers: [u8; MAX_AXES], value: f64| {
            if powers == [0; MAX_AXES] && sign == 0 && channel == 0 {
                constant[(output as usize).min(MAX_AXES - 1)] += value;
            } else if let Some(b) = shape.block_of(output, sign, channel) {
                if let Some(pos) = horner::position(axes, b.degree as usize, powers) {
                    acc[(b.start as usize + pos) & POOL_MASK] += value;
                }
            }
        };
        let unit = |a: usize| {
            let mut p = [0; MAX_AXES];
            p[a.min(MAX_AXES - 1)] = 1;
            p
        };
        for a in 0..axes {
            let sc = self.scaling(Input::Axis(a as u8));
            // δ = q − x, and x = centre + half_range·u.
            add(
                a as u8,
                0,
                0,
                [0; MAX_AXES],
                self.offset_um[a] + self.kmz_offset_um[a] - sc.centre,
            );
            add(a as u8, 0, 0, unit(a), -sc.half_range);
        }
        for term in self.terms() {
            let channel = channel_of(term, fast_mask) as u8;
            match term.factor {
                // coeff·(y − c)/h = (coeff/h)·(y − x) + coeff·u: the linear part folds here.
                Factor::Play(k) => {
                    let a = self.play_operators()[k as usize].axis as usize;
                    add(term.output, 0, 0, unit(a), term.coeff);
                }
                _ if channel != 0 => add(
                    term.output,
                    term.direction,
                    channel,
                    term.powers,
                    term.coeff,
                ),
                _ => add(
                    term.output,
                    term.direction,
                    0,
                    term.powers,
                    term.coeff * term.factor_value(&scaled),
                ),
            }
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
            coefficients: [0.0; FOLD_CAPACITY],
            slow_flags: self.slow_envelope_flags(slow).0,
            fast_mask: 0,
            fast_centre: [0.0; MAX_AUX],
            fast_inv_half_range: [1.0; MAX_AUX],
            fast_min: [f32::NEG_INFINITY; MAX_AUX],
            fast_max: [f32::INFINITY; MAX_AUX],
            bank_start: bank_starts(self.play_operators()),
            play_threshold_um: [0.0; MAX_PLAY],
            play_weight: [0.0; MAX_PLAY],
        };
        // Only the coefficients the blocks use: f64 → f32 is a soft-float call on the M4.
        let used = shape.coefficients.min(FOLD_CAPACITY);
        for (c, &v) in fold.coefficients[..used].iter_mut().zip(&acc[..used]) {
            *c = v as f32;
        }
        for a in 0..axes {
            let sc = self.scaling(Input::Axis(a as u8));
            let (min, max) = self.envelope(Input::Axis(a as u8));
            fold.centre_um[a] = sc.centre as f32;
            fold.inv_half_range[a] = (1.0 / sc.half_range) as f32;
            fold.envelope_min_um[a] = min as f32;
            fold.envelope_max_um[a] = max as f32;
        }
        // Only the fast inputs some block uses are read (a declared but unused one is not).
        for b in &shape.blocks[..shape.len] {
            if b.channel > 0 {
                fold.fast_mask |= 1 << (b.channel - 1);
            }
        }
        for n in 0..self.aux() {
            let input = Input::Aux(n as u8);
            let sc = self.scaling(input);
            let (min, max) = self.envelope(input);
            fold.fast_centre[n] = sc.centre as f32;
            fold.fast_inv_half_range[n] = (1.0 / sc.half_range) as f32;
            fold.fast_min[n] = min as f32;
            fold.fast_max[n] = max as f32;
        }
        let weights = self.play_weights();
        for (k, spec) in self.play_operators().iter().enumerate() {
            fold.play_threshold_um[k] = spec.threshold_um as f32;
            fold.play_weight[k] = weights[k] as f32;
        }
        fold
    }
}

/// What multiplies the blocks for one command: the directions of approach and the fast
/// inputs (read only by the blocks that use them).
struct Multipliers<'a> {
    dir: &'a [i8; MAX_AXES],
    fast: &'a FastInputs,
}

/// How the fast path treats the play banks: a `&mut` state is stepped (and primed if fresh), a
/// `&` state is frozen (read, not changed; a fresh one adds nothing).
trait BankStep {
    fn step(self, fold: &Fold, v: &[f32; MAX_AXES], delta: &mut [f32; MAX_AXES]);
}

impl BankStep for &mut HysteresisState {
    #[inline(always)]
    fn step(self, fold: &Fold, v: &[f32; MAX_AXES], delta: &mut [f32; MAX_AXES]) {
        fold.prime(v, self);
        fold.banks::<true>(v, &mut self.outputs, delta, &mut [0.0; MAX_AXES]);
    }
}

impl BankStep for &HysteresisState {
    #[inline(always)]
    fn step(self, fold: &Fold, v: &[f32; MAX_AXES], delta: &mut [f32; MAX_AXES]) {
        if self.primed {
            let mut frozen = self.outputs;
            fold.banks::<false>(v, &mut frozen, delta, &mut [0.0; MAX_AXES]);
        }
    }
}

impl Fold {
    /// Number of axes.
    pub fn axes(&self) -> usize {
        self.axes as usize
    }

    /// Bits of the temperature and slow aux inputs that were outside the training envelope when
    /// this fold was made (bit numbering of [`crate::EnvelopeFlags`]).
    pub fn slow_outside_envelope(&self) -> u32 {
        self.slow_flags
    }

    /// Bit `n` set for every fast aux input the fast path reads (from [`FastInputs`]).
    pub fn fast_aux_mask(&self) -> u8 {
        self.fast_mask
    }

    /// Number of play operators the fast path steps per command.
    pub fn play_operators(&self) -> usize {
        self.bank_start[MAX_AXES] as usize
    }

    /// Number of coefficients the fast path reads per correction.
    pub fn fast_coefficients(&self) -> usize {
        self.blocks()
            .iter()
            .map(|b| horner::block_len(self.axes(), b.degree as usize))
            .sum()
    }

    fn blocks(&self) -> &[Block] {
        &self.blocks[..(self.n_blocks as usize).min(MAX_BLOCKS)]
    }

    /// The factor block `b`'s value is multiplied with (1 for a plain block).
    #[inline(always)]
    fn multiplier(&self, b: &Block, m: &Multipliers) -> f32 {
        let mut k = 1.0;
        if b.sign != 0 {
            let a = (b.sign as usize - 1).min(MAX_AXES - 1);
            k = crate::term::approach_sign(m.dir[a]) as f32;
        }
        if b.channel != 0 {
            let n = (b.channel as usize - 1).min(MAX_AUX - 1);
            k *= (m.fast.aux[n] - self.fast_centre[n]) * self.fast_inv_half_range[n];
        }
        k
    }

    /// Bit n set for every fast input the blocks use that is outside its training envelope
    /// or not supplied.
    #[inline(always)]
    fn fast_outside(&self, fast: &FastInputs) -> u8 {
        if self.fast_mask == 0 {
            0
        } else {
            self.fast_inputs_outside(fast)
        }
    }

    #[inline(never)]
    fn fast_inputs_outside(&self, fast: &FastInputs) -> u8 {
        let mut outside = 0;
        for n in 0..MAX_AUX {
            let v = fast.aux[n];
            if self.fast_mask & (1 << n) != 0 && !(v >= self.fast_min[n] && v <= self.fast_max[n]) {
                outside |= 1 << n;
            }
        }
        outside
    }

    /// δ without its constant and play parts: every block at scaled positions `u`, times its
    /// multipliers.
    #[inline(always)]
    fn polynomial(&self, u: [f32; MAX_AXES], m: &Multipliers) -> [f32; MAX_AXES] {
        let axes = self.axes();
        let mut delta = [0.0f32; MAX_AXES];
        for b in self.blocks() {
            let mut value = horner::evaluate(axes, b.degree as usize, u, |k| {
                self.coefficients[(b.start as usize + k) & POOL_MASK]
            });
            if b.sign | b.channel != 0 {
                value *= self.multiplier(b, m);
            }
            delta[(b.output as usize).min(MAX_AXES - 1)] += value;
        }
        delta
    }

    /// Steps every axis' bank from `outputs` at centred targets `v` (µm) and adds each axis'
    /// contribution `Σ w·(y − v)` to `delta`. Writes the new outputs back when `COMMIT`;
    /// otherwise adds the contribution's slope in `v` to `slope` (`−Σ w` over the operators
    /// inside their dead band).
    #[inline(always)]
    fn banks<const COMMIT: bool>(
        &self,
        v: &[f32; MAX_AXES],
        outputs: &mut [f32; MAX_PLAY],
        delta: &mut [f32; MAX_AXES],
        slope: &mut [f32; MAX_AXES],
    ) {
        for a in 0..self.axes() {
            let range = self.bank_start[a] as usize..self.bank_start[a + 1] as usize;
            let (Some(ys), Some(rs), Some(ws)) = (
                outputs.get_mut(range.clone()),
                self.play_threshold_um.get(range.clone()),
                self.play_weight.get(range),
            ) else {
                continue;
            };
            let va = v[a];
            let (mut acc, mut inside) = (0.0f32, 0.0f32);
            for ((y, &r), &w) in ys.iter_mut().zip(rs).zip(ws) {
                let next = play(*y, va, r);
                if COMMIT {
                    *y = next;
                } else if next == *y {
                    inside += w;
                }
                acc += w * (next - va);
            }
            delta[a] += acc;
            slope[a] -= inside;
        }
    }

    /// Centred targets `x − centre` (µm) and scaled ones `u` of the model's axes, and the bit of
    /// every axis whose target is outside the training envelope.
    #[inline(always)]
    fn centred(&self, x_um: &[f32; MAX_AXES]) -> ([f32; MAX_AXES], [f32; MAX_AXES], u8) {
        let mut outside = 0u8;
        let mut v = [0.0f32; MAX_AXES];
        let mut u = [0.0f32; MAX_AXES];
        for a in 0..self.axes() {
            if !(x_um[a] >= self.envelope_min_um[a] && x_um[a] <= self.envelope_max_um[a]) {
                outside |= 1 << a;
            }
            v[a] = x_um[a] - self.centre_um[a];
            u[a] = v[a] * self.inv_half_range[a];
        }
        (v, u, outside)
    }

    /// Primes an unprimed state: every operator at its axis' centred target `v`.
    #[inline(always)]
    fn prime(&self, v: &[f32; MAX_AXES], state: &mut HysteresisState) {
        if !state.primed {
            for a in 0..self.axes() {
                let range = self.bank_start[a] as usize..self.bank_start[a + 1] as usize;
                if let Some(ys) = state.outputs.get_mut(range) {
                    ys.fill(v[a]);
                }
            }
            state.primed = true;
        }
    }

    /// The fast path for one command, the play banks handled by `bank` (stepped in place, or
    /// frozen): one body for [`Fold::correct`] and [`Fold::evaluate`].
    #[inline(always)]
    fn fast_path<B: BankStep>(
        &self,
        x_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        bank: B,
    ) -> Correction {
        let axes = self.axes();
        let mut outside = 0u8;
        let mut v = [0.0f32; MAX_AXES];
        let mut u = [0.0f32; MAX_AXES];
        for a in 0..axes {
            if !(x_um[a] >= self.envelope_min_um[a] && x_um[a] <= self.envelope_max_um[a]) {
                outside |= 1 << a;
            }
            v[a] = x_um[a] - self.centre_um[a];
            u[a] = v[a] * self.inv_half_range[a];
        }
        let m = Multipliers { dir, fast };
        let mut delta = self.polynomial(u, &m);
        if self.play_operators() > 0 {
            bank.step(self, &v, &mut delta);
        }
        let mut q_um = [0.0f32; MAX_AXES];
        for a in 0..axes {
            delta[a] += self.constant_um[a];
            q_um[a] = delta[a] + x_um[a];
        }
        Correction {
            q_um,
            delta_um: delta,
            outside_envelope: outside,
            fast_outside_envelope: self.fast_outside(fast),
        }
    }

    /// Fast path: commands for calibrated targets `x_um`, approached in direction `dir`
    /// (+1 forward, −1 backward, 0 unknown), with this command's fast inputs; steps the play
    /// operators of `state` (primed with these targets if it is fresh or was reset).
    ///
    /// A model without fast inputs never reads `fast` (pass [`FastInputs::NONE`]); a model
    /// without play operators never touches `state`.
    pub fn correct(
        &self,
        x_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        state: &mut HysteresisState,
    ) -> Correction {
        self.fast_path(x_um, dir, fast, state)
    }

    /// What [`Fold::correct`] returns for these targets, with `state` left as it is: each play
    /// operator is stepped from its output in `state` to this target, and the step is not kept
    /// (a fresh or reset state adds nothing, as it would be primed at the target itself). For a
    /// caller that sends the command only if it passes its checks, or that evaluates trial
    /// points (an inverse): it advances the state with [`Fold::step`] for the commands it sends.
    /// `evaluate` then `step` leave the same commands and state as `correct`.
    ///
    /// Always inlined: the device calls it per command (the MOV line) and once per mapped
    /// reply; called out of line, every MOV line pays the call (+17 guest instructions).
    #[inline(always)]
    pub fn evaluate(
        &self,
        x_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        state: &HysteresisState,
    ) -> Correction {
        self.fast_path(x_um, dir, fast, state)
    }

    /// Steps the play operators of `state` to targets `x_um` (primes a fresh or reset state),
    /// as [`Fold::correct`] does, without evaluating anything: a command was sent for them.
    #[inline]
    pub fn step(&self, x_um: &[f32; MAX_AXES], state: &mut HysteresisState) {
        if self.play_operators() > 0 {
            self.step_banks(x_um, state);
        }
    }

    #[inline(never)]
    fn step_banks(&self, x_um: &[f32; MAX_AXES], state: &mut HysteresisState) {
        let (v, _, _) = self.centred(x_um);
        self.prime(&v, state);
        for a in 0..self.axes() {
            let range = self.bank_start[a] as usize..self.bank_start[a + 1] as usize;
            if let (Some(ys), Some(rs)) = (
                state.outputs.get_mut(range.clone()),
                self.play_threshold_um.get(range),
            ) {
                for (y, &r) in ys.iter_mut().zip(rs) {
                    *y = play(*y, v[a], r);
                }
            }
        }
    }

    /// Inverse map: the calibrated position whose command is `q_um` (e.g. a position the
    /// controller reports), with the same fast inputs and the play operators *frozen* in
    /// `state` (a query does not move the stage). Starts from `q_um`; see
    /// [`Fold::inverse_from`].
    pub fn inverse(
        &self,
        q_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        state: &HysteresisState,
    ) -> Result<[f32; MAX_AXES], InverseError> {
        self.inverse_from(q_um, dir, fast, state, q_um)
    }

    /// [`Fold::inverse`] starting from `start_um` (e.g. the last target, when the reply is
    /// expected near the last command): a Newton-type iteration on `x + δ(x) = q`.
    ///
    /// The residual is the fast path's own f32 evaluation, which also gives the play banks'
    /// slope (piecewise constant). The polynomial part of the Jacobian starts as its linear
    /// part — exact at the envelope's centre and, for a calibration model (a small, smooth
    /// deviation from `q = x`), close enough everywhere that each step gains several digits
    /// without any derivative evaluation. Only when a step reduces the residual less than
    /// fourfold is the full Jacobian computed (dual numbers over the model's axes), at that
    /// point and again whenever progress is slow. A step that does not reduce the residual is
    /// halved (up to six times; residuals measured per axis in units of its tolerance). The
    /// iteration stops when a step is at the rounding of the residual (`4·ε·(|x| + |q| + 1)`
    /// per axis), or, within 64 such tolerances of the answer, when steps stop halving: the
    /// residual's own rounding, which grows with the polynomial's terms, is then reached (the
    /// answer is good to about that step). A Jacobian whose determinant is not positive
    /// (the model folds back, or is flat, at the iterate) is [`InverseError::Singular`].
    pub fn inverse_from(
        &self,
        q_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        state: &HysteresisState,
        start_um: &[f32; MAX_AXES],
    ) -> Result<[f32; MAX_AXES], InverseError> {
        let n = self.axes();
        if q_um[..n]
            .iter()
            .chain(&start_um[..n])
            .any(|v| !v.is_finite())
        {
            return Err(InverseError::NonFinite);
        }
        let m = Multipliers { dir, fast };
        // A fresh state would be primed at the answer itself, where the banks add nothing.
        if state.primed && self.play_operators() > 0 {
            let mut frozen = state.outputs;
            self.newton(q_um, start_um, &m, |x| {
                self.deviation_at(x, &m, Some(&mut frozen))
            })
        } else {
            self.newton(q_um, start_um, &m, |x| self.deviation_at(x, &m, None))
        }
    }

    /// The iteration of [`Fold::inverse_from`] on `x + δ(x) = q`, with `deviation` giving δ and
    /// the banks' slope at `x`.
    #[inline(always)]
    fn newton(
        &self,
        q_um: &[f32; MAX_AXES],
        start_um: &[f32; MAX_AXES],
        m: &Multipliers,
        mut deviation: impl FnMut(&[f32; MAX_AXES]) -> ([f32; MAX_AXES], [f32; MAX_AXES]),
    ) -> Result<[f32; MAX_AXES], InverseError> {
        let n = self.axes();
        // Steps this small are at the rounding of `x − q + δ` in f32.
        let tolerance =
            |x: &[f32; MAX_AXES], a: usize| 4.0 * f32::EPSILON * (x[a].abs() + q_um[a].abs() + 1.0);
        // Residuals are compared in units of each axis' tolerance: an axis at its rounding
        // floor must not hold back one that still has digits to gain.
        let mut per_tolerance = [0.0f32; MAX_AXES];
        for a in 0..n {
            per_tolerance[a] = 1.0 / tolerance(q_um, a);
        }
        let mut residual = |x: &[f32; MAX_AXES]| {
            let (mut r, slope) = deviation(x);
            let mut norm = 0.0f32;
            for a in 0..n {
                r[a] += x[a] - q_um[a];
                // Not f32::max, a libm call on the M4; NaN propagates.
                let scaled = r[a].abs() * per_tolerance[a];
                if scaled > norm || scaled.is_nan() {
                    norm = scaled;
                }
            }
            (r, slope, norm)
        };
        let mut x = *start_um;
        let (mut r, mut bank_slope, mut norm) = residual(&x);
        let mut jacobian = self.linear_jacobian(m);
        // The last step's length in tolerances, once steps are within `NEAR` tolerances.
        let mut last_near: Option<f32> = None;
        for _ in 0..MAX_NEWTON_STEPS {
            let mut j = jacobian;
            for a in 0..n {
                j[a][a] += bank_slope[a];
            }
            let step = solve(j, r, n)?;
            let mut length = 0.0f32;
            for a in 0..n {
                let scaled = step[a].abs() / tolerance(&x, a);
                if scaled > length || scaled.is_nan() {
                    length = scaled;
                }
            }
            // Converged, or at the rounding floor of the residual: near the answer, a step
            // that is not at least halving the last one is made of rounding, not of distance.
            let stalled = last_near.is_some_and(|last| length > 0.5 * last);
            if length <= 1.0 || (length <= NEAR && stalled) {
                for a in 0..n {
                    x[a] -= step[a];
                }
                return Ok(x);
            }
            if length <= NEAR {
                // Near the answer the residual is partly rounding: take full steps.
                last_near = Some(length);
                for a in 0..n {
                    x[a] -= step[a];
                }
                (r, bank_slope, norm) = residual(&x);
                continue;
            }
            let mut t = 1.0f32;
            let mut backtracks = 0;
            loop {
                let mut trial = x;
                for a in 0..n {
                    trial[a] -= t * step[a];
                    if !trial[a].is_finite() {
                        return Err(InverseError::NonFinite);
                    }
                }
                let next = residual(&trial);
                if next.2 < norm || backtracks == MAX_BACKTRACKS {
                    if next.2 > 0.25 * norm {
                        jacobian = self.polynomial_jacobian(&trial, m);
                    }
                    (r, bank_slope, norm) = next;
                    x = trial;
                    break;
                }
                t *= 0.5;
                backtracks += 1;
            }
        }
        Err(InverseError::NotConverged)
    }

    /// The deviation `δ(x) = q(x) − x` (µm) with the play operators frozen in `state`, as the
    /// inverse sees them: with `x` from [`Fold::inverse`] and `q` held in f64, `x = q − δ(x)` in
    /// f64 keeps the sub-ulp resolution that f32 positions lose on long strokes.
    pub fn deviation(
        &self,
        x_um: &[f32; MAX_AXES],
        dir: &[i8; MAX_AXES],
        fast: &FastInputs,
        state: &HysteresisState,
    ) -> [f32; MAX_AXES] {
        let m = Multipliers { dir, fast };
        if state.primed && self.play_operators() > 0 {
            let mut frozen = state.outputs;
            self.deviation_at(x_um, &m, Some(&mut frozen)).0
        } else {
            self.deviation_at(x_um, &m, None).0
        }
    }

    /// δ at `x_um` with the banks frozen at `outputs` (none: no banks, or a fresh state, which
    /// would be primed at `x` itself where they add nothing), and the banks' slope.
    #[inline(always)]
    fn deviation_at(
        &self,
        x_um: &[f32; MAX_AXES],
        m: &Multipliers,
        outputs: Option<&mut [f32; MAX_PLAY]>,
    ) -> ([f32; MAX_AXES], [f32; MAX_AXES]) {
        let (v, u, _) = self.centred(x_um);
        let mut delta = self.polynomial(u, m);
        let mut slope = [0.0; MAX_AXES];
        if let Some(outputs) = outputs {
            self.banks::<false>(&v, outputs, &mut delta, &mut slope);
        }
        for a in 0..self.axes() {
            delta[a] += self.constant_um[a];
        }
        (delta, slope)
    }

    /// Jacobian of `x + δ(x)` without the play banks at the envelope's centre (`u = 0`): the
    /// identity plus every block's linear coefficients, times its multiplier.
    fn linear_jacobian(&self, m: &Multipliers) -> [[f32; MAX_AXES]; MAX_AXES] {
        let n = self.axes();
        let mut jacobian = [[0.0f32; MAX_AXES]; MAX_AXES];
        for a in 0..n {
            jacobian[a][a] = 1.0;
        }
        for b in self.blocks() {
            let k = self.multiplier(b, m);
            let o = (b.output as usize).min(MAX_AXES - 1);
            for a in 0..n {
                let mut unit = [0u8; MAX_AXES];
                unit[a] = 1;
                if let Some(pos) = horner::position(n, b.degree as usize, unit) {
                    let c = self.coefficients[(b.start as usize + pos) & POOL_MASK];
                    jacobian[o][a] += k * c * self.inv_half_range[a];
                }
            }
        }
        jacobian
    }

    /// Jacobian of `x + δ(x)` without the play banks, at `x_um`.
    fn polynomial_jacobian(
        &self,
        x_um: &[f32; MAX_AXES],
        m: &Multipliers,
    ) -> [[f32; MAX_AXES]; MAX_AXES] {
        match self.axes() {
            1 => self.jacobian_n::<1>(x_um, m),
            2 => self.jacobian_n::<2>(x_um, m),
            _ => self.jacobian_n::<3>(x_um, m),
        }
    }

    fn jacobian_n<const N: usize>(
        &self,
        x_um: &[f32; MAX_AXES],
        m: &Multipliers,
    ) -> [[f32; MAX_AXES]; MAX_AXES] {
        let mut jacobian = [[0.0f32; MAX_AXES]; MAX_AXES];
        let mut u = [<Dual<N> as HornerNum>::ZERO; MAX_AXES];
        for a in 0..N.min(MAX_AXES) {
            jacobian[a][a] = 1.0;
            u[a] = Dual::variable(a, (x_um[a] - self.centre_um[a]) * self.inv_half_range[a]);
        }
        for b in self.blocks() {
            let d = horner::evaluate(N, b.degree as usize, u, |k| {
                self.coefficients[(b.start as usize + k) & POOL_MASK]
            });
            let s = self.multiplier(b, m);
            let o = (b.output as usize).min(MAX_AXES - 1);
            for a in 0..N.min(MAX_AXES) {
                // Chain rule: du_a/dx_a = 1/half_range_a.
                jacobian[o][a] += s * d.grad[a] * self.inv_half_range[a];
            }
        }
        jacobian
    }
}

/// Smallest Jacobian determinant the inverse accepts (the map is near `q = x`, det ≈ 1).
const MIN_DETERMINANT: f32 = 1e-6;

/// Solves `J·s = r` for n ≤ 3 by Cramer's rule (the Jacobian of a calibration model is near
/// the identity, so this is well conditioned); a determinant at or below `MIN_DETERMINANT` —
/// the map is flat or folds back — is [`InverseError::Singular`]. (Inlined: returning the
/// `Result` through memory costs more than solving.)
#[inline(always)]
fn solve(
    j: [[f32; MAX_AXES]; MAX_AXES],
    r: [f32; MAX_AXES],
    n: usize,
) -> Result<[f32; MAX_AXES], InverseError> {
    let det2 = |a: f32, b: f32, c: f32, d: f32| a * d - b * c;
    match n {
        1 => {
            if j[0][0].is_nan() || j[0][0] <= MIN_DETERMINANT {
                return Err(InverseError::Singular);
            }
            Ok([r[0] / j[0][0], 0.0, 0.0])
        }
        2 => {
            let det = det2(j[0][0], j[0][1], j[1][0], j[1][1]);
            if det.is_nan() || det <= MIN_DETERMINANT {
                return Err(InverseError::Singular);
            }
            let s0 = det2(r[0], j[0][1], r[1], j[1][1]) / det;
            let s1 = det2(j[0][0], r[0], j[1][0], r[1]) / det;
            Ok([s0, s1, 0.0])
        }
        _ => {
            // Cofactors of the first row, then the adjugate's rows times r.
            let c00 = det2(j[1][1], j[1][2], j[2][1], j[2][2]);
            let c01 = -det2(j[1][0], j[1][2], j[2][0], j[2][2]);
            let c02 = det2(j[1][0], j[1][1], j[2][0], j[2][1]);
            let det = j[0][0] * c00 + j[0][1] * c01 + j[0][2] * c02;
            if det.is_nan() || det <= MIN_DETERMINANT {
                return Err(InverseError::Singular);
            }
            let c10 = -det2(j[0][1], j[0][2], j[2][1], j[2][2]);
            let c11 = det2(j[0][0], j[0][2], j[2][0], j[2][2]);
            let c12 = -det2(j[0][0], j[0][1], j[2][0], j[2][1]);
            let c20 = det2(j[0][1], j[0][2], j[1][1], j[1][2]);
            let c21 = -det2(j[0][0], j[0][2], j[1][0], j[1][2]);
            let c22 = det2(j[0][0], j[0][1], j[1][0], j[1][1]);
            Ok([
                (c00 * r[0] + c10 * r[1] + c20 * r[2]) / det,
                (c01 * r[0] + c11 * r[1] + c21 * r[2]) / det,
                (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det,
            ])
        }
    }
}
