//! The boundary between the proxy and the model: what the proxy asks of a calibration model.

use crate::gcs::MAP_AXES;
use nanocal_model::{FastInputs, Fold, HysteresisState, Model, SlowInputs, MAX_AXES};

/// Result of the model's fast path for one target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corrected {
    /// Commands for the controller, µm, per model axis (`x + δ` in f32: for limits and trial
    /// evaluations; the command sent is formed exactly from `delta_um`).
    pub q_um: [f32; MAP_AXES],
    /// The deviation `δ = q − x`, µm, per model axis. The proxy holds targets as integers in
    /// millionths of a µm and forms the command as `x + δ` there: an f32 command would round by
    /// up to half an ulp of the position (0.24 nm at 5 mm), δ alone by far less.
    pub delta_um: [f32; MAP_AXES],
    /// Bit per axis: the target is outside the training envelope.
    pub outside_envelope: u8,
    /// A fast input the model uses is outside its training envelope.
    pub fast_outside: bool,
    /// A fast input the model uses has no sample recent enough for a command (stale, failed,
    /// never sampled): the command must be refused, never evaluated with a default.
    pub fast_missing: bool,
}

/// What the proxy needs from a model: the fast path and the stage travel.
///
/// The contract the proxy relies on (keep it when the model grows):
/// - [`correct`](Corrector::correct) is a pure function of its arguments and the corrector's
///   state: it evaluates the command for a target from the hysteresis state as it stands,
///   without advancing it. The proxy calls it for every target it may forward.
/// - [`inverse`](Corrector::inverse) maps a reported position back, with the state *frozen*
///   where the last command left it (a query does not move the stage), and gives δ at the
///   answer: the proxy forms the calibrated position as `q − δ` in integer micros, which keeps
///   the resolution an f32 position lacks on a long stroke.
/// - [`sent`](Corrector::sent) advances the hysteresis state for targets whose command went
///   out. The proxy calls it in exactly one place: where it records the targets it sent, at the
///   end of `ProxyState::rewrite_move` in `proxy/moves.rs`.
/// - Fast inputs (a force, …) are the corrector's own: the firmware sets this command's
///   samples before it hands the proxy a line ([`FoldCorrector::fast`]).
/// - Positions are in the model's unit, µm; the proxy refuses to correct for a controller whose
///   position unit (`PUN?`) is not µm.
pub trait Corrector {
    /// Number of model axes (1..=3).
    fn axes(&self) -> usize;
    /// Fast path: commands for calibrated targets `x_um` approached in direction `dir`, the
    /// play operators stepped from `state` to the targets but `state` left as it is.
    fn correct(
        &self,
        x_um: &[f32; MAP_AXES],
        dir: &[i8; MAP_AXES],
        state: &HysteresisState,
    ) -> Corrected;
    /// The calibrated targets whose commands are `q_um` (model axes `0..axes()`), approached
    /// in direction `dir`, the play operators frozen in `state`, starting at `start_um` (the
    /// last targets) when known, else at `q_um`; and δ there. `None` when the model cannot be
    /// inverted there (it folds back or is flat, or a value is not finite).
    fn inverse(
        &self,
        q_um: &[f32; MAP_AXES],
        dir: &[i8; MAP_AXES],
        state: &HysteresisState,
        start_um: Option<&[f32; MAP_AXES]>,
    ) -> Option<([f32; MAP_AXES], [f32; MAP_AXES])>;
    /// The command for targets `x_um` went out: advance `state` (the play operators follow).
    fn sent(&self, x_um: &[f32; MAP_AXES], state: &mut HysteresisState);
    /// Stage travel of a model axis in command space (min, max), µm.
    fn travel_um(&self, axis: usize) -> (f32, f32);
}

/// The model's fast path as the proxy uses it: a thermal fold, the stage travel and this
/// command's fast inputs.
#[derive(Debug, Clone, Copy)]
pub struct FoldCorrector {
    /// The current thermal fold.
    pub fold: Fold,
    /// Stage travel per axis in command space, µm.
    pub travel_um: [(f32, f32); MAX_AXES],
    /// The latest valid sample of every fast input (NaN: none yet), set by the firmware before
    /// each call into the proxy. Position replies are mapped with these.
    pub fast: FastInputs,
    /// Bit `n`: fast input `n`'s sample is recent enough to correct a command with. A command
    /// that needs a fast input without its bit is refused.
    pub fast_fresh: u8,
}

impl FoldCorrector {
    /// Fold `model` at `slow` (the slow path); no fast input sampled yet.
    pub fn new(model: &Model, slow: &SlowInputs) -> Self {
        let mut travel_um = [(0.0, 0.0); MAX_AXES];
        for (a, t) in travel_um.iter_mut().enumerate().take(model.axes()) {
            let (lo, hi) = model.travel_um(a);
            *t = (lo as f32, hi as f32);
        }
        Self {
            fold: model.fold(slow),
            travel_um,
            fast: FastInputs::NONE,
            fast_fresh: 0,
        }
    }
}

impl Corrector for FoldCorrector {
    fn axes(&self) -> usize {
        self.fold.axes()
    }
    fn correct(
        &self,
        x_um: &[f32; MAP_AXES],
        dir: &[i8; MAP_AXES],
        state: &HysteresisState,
    ) -> Corrected {
        let c = self.fold.evaluate(x_um, dir, &self.fast, state);
        let missing = self.fold.fast_aux_mask() & !self.fast_fresh;
        Corrected {
            q_um: c.q_um,
            delta_um: c.delta_um,
            outside_envelope: c.outside_envelope,
            fast_outside: c.fast_outside_envelope & !missing != 0,
            fast_missing: missing != 0,
        }
    }
    /// The model's own inverse, [`Fold::inverse_from`] (the one the host's validation uses
    /// too), then δ evaluated once at the answer.
    fn inverse(
        &self,
        q_um: &[f32; MAP_AXES],
        dir: &[i8; MAP_AXES],
        state: &HysteresisState,
        start_um: Option<&[f32; MAP_AXES]>,
    ) -> Option<([f32; MAP_AXES], [f32; MAP_AXES])> {
        let x = self
            .fold
            .inverse_from(q_um, dir, &self.fast, state, start_um.unwrap_or(q_um))
            .ok()?;
        let c = self.fold.evaluate(&x, dir, &self.fast, state);
        Some((x, c.delta_um))
    }
    fn sent(&self, x_um: &[f32; MAP_AXES], state: &mut HysteresisState) {
        self.fold.step(x_um, state);
    }
    fn travel_um(&self, axis: usize) -> (f32, f32) {
        self.travel_um.get(axis).copied().unwrap_or((0.0, 0.0))
    }
}
