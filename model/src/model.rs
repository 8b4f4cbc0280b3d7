//! The calibration model: terms, offsets, scalings, envelope, travel; its f64 reference evaluation.

use crate::bound::{AxisBound, MAX_BOUND_TERMS};
use crate::error::ModelError;
use crate::fold::{FoldShape, FOLD_CAPACITY};
use crate::hysteresis::{HysteresisState, PlaySpec, MIN_BANK_SLOPE};
use crate::input::{AuxKind, AuxSpec, EnvelopeFlags, Input, Range, Scaling, SlowInputs};
use crate::lag::LagSpec;
use crate::limits::{
    MAX_AUX, MAX_AXES, MAX_INPUTS, MAX_LAGS, MAX_PLAY, MAX_POWER, MAX_TEMPS, MAX_TERMS,
};
use crate::play::play;
use crate::provenance::Provenance;
use crate::term::{approach_sign, Factor, Term};

/// A calibration model mapping calibrated target positions `x` (µm) to the commands `q` (µm)
/// the stage controller must be sent:
///
/// `q_o = λ_o + λ_KMZ,o + Σ_terms coeff · Π_a u_a^p_a · factor · sign`
///
/// with every input centred and scaled (`u = (v − centre)/half_range`). A factor is a
/// temperature, a lagged temperature, an aux input (slow or fast, see [`AuxSpec`]) or the output
/// of a play operator (hysteresis, see [`crate::hysteresis`]). Fixed capacity, no heap.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    pub(crate) id: u32,
    pub(crate) axes: u8,
    pub(crate) temps: u8,
    pub(crate) aux: u8,
    pub(crate) lags: u8,
    pub(crate) plays: u8,
    /// Kind and speed of every aux input.
    pub(crate) aux_specs: [AuxSpec; MAX_AUX],
    /// Scaling of every input in flat order (axes, temperatures, aux).
    pub(crate) scaling: [Scaling; MAX_INPUTS],
    /// Training envelope of every input in flat order.
    pub(crate) envelope: [Range; MAX_INPUTS],
    pub(crate) travel_um: [Range; MAX_AXES],
    pub(crate) offset_um: [f64; MAX_AXES],
    pub(crate) kmz_offset_um: [f64; MAX_AXES],
    pub(crate) lag_specs: [LagSpec; MAX_LAGS],
    pub(crate) play_specs: [PlaySpec; MAX_PLAY],
    pub(crate) terms: [Term; MAX_TERMS],
    pub(crate) n_terms: u16,
    /// The prediction bound of each output axis, when the fit wrote one (blob version 3).
    pub(crate) bounds: [Option<AxisBound>; MAX_AXES],
    /// Where the model comes from (blob version 4; unknown for older blobs).
    pub(crate) provenance: Provenance,
}

/// Every input of one evaluation, already scaled, ready for [`Term::value`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaledInputs {
    /// Scaled axis positions.
    pub axes: [f64; MAX_AXES],
    /// Sign of approach per axis (+1, −1, 0).
    pub sign: [f64; MAX_AXES],
    /// Scaled temperatures.
    pub temps: [f64; MAX_TEMPS],
    /// Scaled aux channels.
    pub aux: [f64; MAX_AUX],
    /// Scaled lag-filter outputs (scaled like the sensor they follow).
    pub lagged: [f64; MAX_LAGS],
    /// Scaled play-operator outputs (scaled like the axis that feeds them).
    pub play: [f64; MAX_PLAY],
}

impl Term {
    /// The term's regressor (everything but the coefficient) at `inputs`.
    pub fn value(&self, inputs: &ScaledInputs) -> f64 {
        let mut v = self.factor_value(inputs);
        if self.direction > 0 {
            v *= inputs.sign[(self.direction - 1) as usize];
        }
        for (a, &p) in self.powers.iter().enumerate() {
            v *= powi(inputs.axes[a], p);
        }
        v
    }

    /// The factor's scaled value (1 for [`Factor::None`]).
    pub(crate) fn factor_value(&self, inputs: &ScaledInputs) -> f64 {
        match self.factor {
            Factor::None => 1.0,
            Factor::Temp(n) => inputs.temps[n as usize],
            Factor::Aux(n) => inputs.aux[n as usize],
            Factor::Lagged(n) => inputs.lagged[n as usize],
            Factor::Play(n) => inputs.play[n as usize],
        }
    }
}

/// `x^p` by repeated multiplication (exact for small `p`, no libm call).
#[inline]
pub(crate) fn powi(x: f64, p: u8) -> f64 {
    let mut v = 1.0;
    for _ in 0..p {
        v *= x;
    }
    v
}

impl Model {
    /// Identifier chosen by whoever fitted the model.
    pub fn id(&self) -> u32 {
        self.id
    }
    /// Number of axes.
    pub fn axes(&self) -> usize {
        self.axes as usize
    }
    /// Number of temperature inputs.
    pub fn temps(&self) -> usize {
        self.temps as usize
    }
    /// Number of auxiliary inputs.
    pub fn aux(&self) -> usize {
        self.aux as usize
    }
    /// The declared lag filters.
    pub fn lags(&self) -> &[LagSpec] {
        &self.lag_specs[..self.lags as usize]
    }
    /// The declared play operators (hysteresis), grouped by axis, thresholds ascending.
    pub fn play_operators(&self) -> &[PlaySpec] {
        &self.play_specs[..self.plays as usize]
    }
    /// Whether the model has play operators: its fast path then carries state
    /// ([`HysteresisState`]) from command to command.
    pub fn has_hysteresis(&self) -> bool {
        self.plays > 0
    }
    /// Kind and speed of aux input `n`, `None` for an aux input the model does not have.
    pub fn aux_spec(&self, n: usize) -> Option<AuxSpec> {
        self.aux_specs[..self.aux()].get(n).copied()
    }
    /// What aux input `n` measures (its unit), `None` for an aux input the model does not have.
    /// A device checks it can supply every aux input of a model before putting it in service.
    pub fn aux_kind(&self, n: usize) -> Option<AuxKind> {
        self.aux_spec(n).map(|s| s.kind)
    }
    /// Whether aux input `n` is fast: supplied per command in [`crate::FastInputs`] and
    /// evaluated by the fast path, not folded.
    pub fn is_fast(&self, n: usize) -> bool {
        self.aux_spec(n).is_some_and(|s| s.fast)
    }
    /// Bit `n` set for every fast aux input.
    pub fn fast_aux_mask(&self) -> u8 {
        (0..self.aux()).fold(0, |m, n| if self.is_fast(n) { m | 1 << n } else { m })
    }
    /// The terms.
    pub fn terms(&self) -> &[Term] {
        &self.terms[..self.n_terms as usize]
    }
    /// Scaling of an input.
    pub fn scaling(&self, input: Input) -> Scaling {
        self.scaling[input.flat_index()]
    }
    /// Training envelope `(min, max)` of an input.
    pub fn envelope(&self, input: Input) -> (f64, f64) {
        let r = self.envelope[input.flat_index()];
        (r.min, r.max)
    }
    /// Stage travel `(min, max)` of an axis, in command space (µm).
    pub fn travel_um(&self, axis: usize) -> (f64, f64) {
        let r = self.travel_um[axis.min(MAX_AXES - 1)];
        (r.min, r.max)
    }
    /// Static offset λ of an axis, µm (the constant of the scaled model).
    pub fn offset_um(&self, axis: usize) -> f64 {
        self.offset_um[axis.min(MAX_AXES - 1)]
    }
    /// Adaptive offset λ_KMZ of an axis, µm.
    pub fn kmz_offset_um(&self, axis: usize) -> f64 {
        self.kmz_offset_um[axis.min(MAX_AXES - 1)]
    }
    /// The prediction bound of output axis `axis` ([`crate::bound`]), if the fit wrote one.
    pub fn bound(&self, axis: usize) -> Option<&AxisBound> {
        self.bounds.get(axis).and_then(|b| b.as_ref())
    }

    /// Where the model comes from: the stage, axes and unit it was fitted on, the fit's date
    /// and the hash of its data ([`crate::provenance`]; all unknown for a version 1–3 blob).
    pub fn provenance(&self) -> &Provenance {
        &self.provenance
    }

    /// Records where the model comes from. Axis names past the model's axes are dropped (the
    /// blob has no place for them).
    pub fn set_provenance(&mut self, mut provenance: Provenance) {
        for name in provenance.axes.iter_mut().skip(self.axes()) {
            *name = None;
        }
        self.provenance = provenance;
    }

    /// Terms of output axis `axis` (the regressors of its bound).
    pub fn axis_terms(&self, axis: usize) -> usize {
        self.terms()
            .iter()
            .filter(|t| t.output as usize == axis)
            .count()
    }

    /// Attaches the prediction bound of output axis `axis` (`None` removes it). The bound must
    /// cover exactly the axis' terms ([`ModelError::InvalidBound`]).
    pub fn set_bound(&mut self, axis: usize, bound: Option<AxisBound>) -> Result<(), ModelError> {
        if axis >= self.axes() {
            return Err(ModelError::InvalidBound);
        }
        if let Some(b) = &bound {
            if b.regressors() != self.axis_terms(axis) {
                return Err(ModelError::InvalidBound);
            }
        }
        self.bounds[axis] = bound;
        Ok(())
    }

    /// The regressors of output axis `axis`'s bound at `inputs` — its term values in term
    /// order, in f32 — into `out`; how many (0 beyond the capacity of a bound).
    pub fn bound_regressors(
        &self,
        axis: usize,
        inputs: &ScaledInputs,
        out: &mut [f32; MAX_BOUND_TERMS],
    ) -> usize {
        let mut n = 0;
        for t in self.terms().iter().filter(|t| t.output as usize == axis) {
            if n == MAX_BOUND_TERMS {
                return 0;
            }
            out[n] = t.value(inputs) as f32;
            n += 1;
        }
        n
    }

    /// The half-width of the interval `k` standard errors of prediction wide of output axis
    /// `axis` at `inputs`, µm, in f32 (`k = bound.t95()` gives the 95 % prediction interval);
    /// `None` when the axis has no bound.
    pub fn prediction_half_width_um(
        &self,
        axis: usize,
        inputs: &ScaledInputs,
        k: f32,
    ) -> Option<f32> {
        let b = self.bound(axis)?;
        let mut x0 = [0.0f32; MAX_BOUND_TERMS];
        let n = self.bound_regressors(axis, inputs, &mut x0);
        Some(b.half_width_um(k, &x0[..n]))
    }

    /// Sets the adaptive offset λ_KMZ of an axis (ignored for an axis the model lacks or a
    /// non-finite value).
    pub fn set_kmz_offset_um(&mut self, axis: usize, value_um: f64) {
        if axis < self.axes() && value_um.is_finite() {
            self.kmz_offset_um[axis] = value_um;
        }
    }

    /// Scales raw inputs for evaluation, with the play operators as a fresh hysteresis state
    /// leaves them after this command (each at its input: see [`Model::scale_with_state`]).
    pub fn scale(
        &self,
        x_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
    ) -> ScaledInputs {
        let mut s = ScaledInputs {
            axes: [0.0; MAX_AXES],
            sign: [0.0; MAX_AXES],
            temps: [0.0; MAX_TEMPS],
            aux: [0.0; MAX_AUX],
            lagged: [0.0; MAX_LAGS],
            play: [0.0; MAX_PLAY],
        };
        for a in 0..self.axes() {
            s.axes[a] = self.scaling(Input::Axis(a as u8)).apply(x_um[a]);
            s.sign[a] = approach_sign(dir[a]);
        }
        for t in 0..self.temps() {
            s.temps[t] = self.scaling(Input::Temp(t as u8)).apply(slow.temps_c[t]);
        }
        for n in 0..self.aux() {
            s.aux[n] = self.scaling(Input::Aux(n as u8)).apply(slow.aux[n]);
        }
        for (k, spec) in self.lags().iter().enumerate() {
            s.lagged[k] = self
                .scaling(Input::Temp(spec.sensor))
                .apply(slow.lagged_c[k]);
        }
        for (k, spec) in self.play_operators().iter().enumerate() {
            s.play[k] = s.axes[(spec.axis as usize).min(MAX_AXES - 1)];
        }
        s
    }

    /// Scales raw inputs for evaluation, stepping the play operators of `state` with this
    /// command first (the f64 reference of what [`crate::Fold::correct`] does with its state).
    pub fn scale_with_state(
        &self,
        x_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
        state: &mut HysteresisState<f64>,
    ) -> ScaledInputs {
        let mut s = self.scale(x_um, dir, slow);
        let mut v = [0.0; MAX_AXES];
        for a in 0..self.axes() {
            v[a] = x_um[a] - self.scaling[a].centre;
        }
        let ops = self.play_operators();
        for (k, spec) in ops.iter().enumerate() {
            let a = (spec.axis as usize).min(MAX_AXES - 1);
            let y = if state.primed {
                play(state.outputs[k], v[a], spec.threshold_um)
            } else {
                v[a]
            };
            state.outputs[k] = y;
            s.play[k] = y / self.scaling[a].half_range;
        }
        state.primed |= !ops.is_empty();
        s
    }

    /// Reference evaluation in f64: the commands `q` (µm) for calibrated targets `x` (µm).
    /// Outputs beyond [`Model::axes`] are 0. Every aux input, fast ones included, is read from
    /// `slow.aux`; play operators are as a fresh state leaves them (the first command after a
    /// reset): use [`Model::eval_f64_with_state`] along a sequence of commands.
    pub fn eval_f64(
        &self,
        x_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
    ) -> [f64; MAX_AXES] {
        self.eval_scaled(&self.scale(x_um, dir, slow))
    }

    /// Reference evaluation in f64 of one command of a sequence: steps the play operators of
    /// `state` with the targets, then evaluates (as [`crate::Fold::correct`] does in f32).
    pub fn eval_f64_with_state(
        &self,
        x_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
        state: &mut HysteresisState<f64>,
    ) -> [f64; MAX_AXES] {
        self.eval_scaled(&self.scale_with_state(x_um, dir, slow, state))
    }

    /// Evaluation on inputs already scaled by [`Model::scale`].
    pub fn eval_scaled(&self, inputs: &ScaledInputs) -> [f64; MAX_AXES] {
        let mut q = [0.0; MAX_AXES];
        for a in 0..self.axes() {
            q[a] = self.offset_um[a] + self.kmz_offset_um[a];
        }
        for term in self.terms() {
            q[term.output as usize] += term.coeff * term.value(inputs);
        }
        q
    }

    /// Which inputs lie outside the training envelope (axes of `x_um`, temperatures and every
    /// aux input, fast ones included, from `slow.aux`).
    pub fn check_envelope(&self, x_um: &[f64; MAX_AXES], slow: &SlowInputs) -> EnvelopeFlags {
        let mut flags = self.slow_envelope_flags(slow).0;
        let axes = (0..self.axes).map(|a| (Input::Axis(a), x_um[a as usize]));
        let fast = (0..self.aux)
            .filter(|&n| self.is_fast(n as usize))
            .map(|n| (Input::Aux(n), slow.aux[n as usize]));
        for (input, v) in axes.chain(fast) {
            if !self.envelope[input.flat_index()].contains(v) {
                flags |= 1 << input.flat_index();
            }
        }
        EnvelopeFlags(flags)
    }

    /// Which temperature and slow aux inputs lie outside the training envelope (what a fold
    /// knows; fast aux inputs are checked per command by [`crate::Fold::correct`]).
    pub fn slow_envelope_flags(&self, slow: &SlowInputs) -> EnvelopeFlags {
        let mut flags = 0u32;
        let temps = (0..self.temps).map(|t| (Input::Temp(t), slow.temps_c[t as usize]));
        let aux = (0..self.aux)
            .filter(|&n| !self.is_fast(n as usize))
            .map(|n| (Input::Aux(n), slow.aux[n as usize]));
        for (input, v) in temps.chain(aux) {
            if !self.envelope[input.flat_index()].contains(v) {
                flags |= 1 << input.flat_index();
            }
        }
        EnvelopeFlags(flags)
    }

    /// Re-measures the adaptive offset at a reference pose ("KiloMeter-Zero"): command `q_cmd_um`
    /// was sent and the external reference measured `x_meas_um`; λ_KMZ moves so that the model
    /// maps `x_meas_um` to `q_cmd_um` again.
    pub fn set_kmz_from_reference(
        &mut self,
        q_cmd_um: &[f64; MAX_AXES],
        x_meas_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
    ) {
        let predicted = self.eval_f64(x_meas_um, dir, slow);
        self.move_kmz_offset(q_cmd_um, &predicted);
    }

    /// [`Model::set_kmz_from_reference`] for a model with play operators: the model maps
    /// `x_meas_um` to `q_cmd_um` with its operators stepped from `state`, the memory they had
    /// before the reference move (`state` itself is not changed).
    pub fn set_kmz_from_reference_with_state(
        &mut self,
        q_cmd_um: &[f64; MAX_AXES],
        x_meas_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
        state: &HysteresisState<f64>,
    ) {
        let predicted = self.eval_f64_with_state(x_meas_um, dir, slow, &mut state.clone());
        self.move_kmz_offset(q_cmd_um, &predicted);
    }

    /// λ_KMZ moves by the command minus what the model predicted for the measured position.
    fn move_kmz_offset(&mut self, q_cmd_um: &[f64; MAX_AXES], predicted: &[f64; MAX_AXES]) {
        for a in 0..self.axes() {
            let v = self.kmz_offset_um[a] + (q_cmd_um[a] - predicted[a]);
            self.set_kmz_offset_um(a, v);
        }
    }

    /// Checks every rule of the format; the builder and the blob decoder both call it.
    pub(crate) fn validate(&self) -> Result<(), ModelError> {
        let (axes, temps, aux) = (self.axes(), self.temps(), self.aux());
        if axes == 0 {
            return Err(ModelError::NoAxes);
        }
        if axes > MAX_AXES
            || temps > MAX_TEMPS
            || aux > MAX_AUX
            || self.lags as usize > MAX_LAGS
            || self.plays as usize > MAX_PLAY
        {
            return Err(ModelError::TooManyInputs);
        }
        if self.n_terms as usize > MAX_TERMS {
            return Err(ModelError::TooManyTerms);
        }
        for i in self.used_inputs() {
            let flat = i.flat_index();
            if !self.scaling[flat].is_valid() {
                return Err(ModelError::InvalidScaling { input: flat as u8 });
            }
            if !self.envelope[flat].is_valid() {
                return Err(ModelError::InvalidRange { input: flat as u8 });
            }
        }
        for a in 0..axes {
            if !self.travel_um[a].is_valid() {
                return Err(ModelError::InvalidRange { input: a as u8 });
            }
            if !self.offset_um[a].is_finite() || !self.kmz_offset_um[a].is_finite() {
                return Err(ModelError::NonFinite);
            }
        }
        for (k, spec) in self.lags().iter().enumerate() {
            if spec.sensor as usize >= temps || !(spec.tau_s > 0.0 && spec.tau_s.is_finite()) {
                return Err(ModelError::InvalidLag { lag: k as u8 });
            }
        }
        self.validate_play_operators()?;
        for (i, term) in self.terms().iter().enumerate() {
            self.validate_term(term, i as u16)?;
        }
        self.validate_bank_slopes()?;
        let fold = FoldShape::of(axes, self.terms(), self.fast_aux_mask());
        if fold.coefficients > FOLD_CAPACITY {
            return Err(ModelError::FoldTooLarge {
                coefficients: fold.coefficients as u16,
            });
        }
        Ok(())
    }

    pub(crate) fn validate_term(&self, term: &Term, index: u16) -> Result<(), ModelError> {
        let out_of_range = ModelError::TermOutOfRange { term: index };
        if term.output as usize >= self.axes() || term.direction as usize > self.axes() {
            return Err(out_of_range);
        }
        let factor_ok = match term.factor {
            Factor::None => true,
            Factor::Temp(n) => (n as usize) < self.temps(),
            Factor::Aux(n) => (n as usize) < self.aux(),
            Factor::Lagged(n) => n < self.lags,
            Factor::Play(n) => n < self.plays,
        };
        if !factor_ok {
            return Err(out_of_range);
        }
        if let Factor::Play(n) = term.factor {
            let own_axis = self.play_specs[n as usize].axis;
            if term.output != own_axis || term.degree() > 0 || term.direction != 0 {
                return Err(ModelError::InvalidPlayTerm { term: index });
            }
        }
        for (a, &p) in term.powers.iter().enumerate() {
            if p > 0 && a >= self.axes() {
                return Err(out_of_range);
            }
        }
        if term.powers.iter().any(|&p| p > MAX_POWER) || term.degree() > MAX_POWER {
            return Err(ModelError::DegreeTooHigh { term: index });
        }
        if !term.coeff.is_finite() {
            return Err(ModelError::NonFinite);
        }
        Ok(())
    }

    /// Play operators: each on an axis of the model, threshold finite and ≥ 0, grouped by axis
    /// in axis order with thresholds strictly ascending within an axis.
    pub(crate) fn validate_play_operators(&self) -> Result<(), ModelError> {
        let ops = self.play_operators();
        for (k, spec) in ops.iter().enumerate() {
            let valid = (spec.axis as usize) < self.axes()
                && spec.threshold_um.is_finite()
                && spec.threshold_um >= 0.0;
            let ordered = match k.checked_sub(1).map(|p| ops[p]) {
                None => true,
                Some(prev) => {
                    prev.axis < spec.axis
                        || (prev.axis == spec.axis && prev.threshold_um < spec.threshold_um)
                }
            };
            if !(valid && ordered) {
                return Err(ModelError::InvalidPlay { operator: k as u8 });
            }
        }
        Ok(())
    }

    /// The weights `w_k = coeff/h_a` of each play operator (terms validated).
    pub(crate) fn play_weights(&self) -> [f64; MAX_PLAY] {
        let mut w = [0.0; MAX_PLAY];
        for term in self.terms() {
            if let Factor::Play(k) = term.factor {
                let k = (k as usize).min(MAX_PLAY - 1);
                let a = (self.play_specs[k].axis as usize).min(MAX_AXES - 1);
                w[k] += term.coeff / self.scaling[a].half_range;
            }
        }
        w
    }

    /// Every axis' bank keeps `1 + Σ_{i ≤ j} w_i ≥ MIN_BANK_SLOPE` (see [`crate::hysteresis`]).
    fn validate_bank_slopes(&self) -> Result<(), ModelError> {
        let w = self.play_weights();
        let mut slope = [1.0f64; MAX_AXES];
        for (k, spec) in self.play_operators().iter().enumerate() {
            let a = (spec.axis as usize).min(MAX_AXES - 1);
            slope[a] += w[k];
            if slope[a].is_nan() || slope[a] < MIN_BANK_SLOPE {
                return Err(ModelError::BankNotMonotone { axis: a as u8 });
            }
        }
        Ok(())
    }

    /// The inputs this model uses, in flat order.
    pub(crate) fn used_inputs(&self) -> impl Iterator<Item = Input> + '_ {
        let axes = (0..self.axes).map(Input::Axis);
        let temps = (0..self.temps).map(Input::Temp);
        let aux = (0..self.aux).map(Input::Aux);
        axes.chain(temps).chain(aux)
    }
}
