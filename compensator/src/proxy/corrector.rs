//! The boundary between the proxy and the model: what the proxy asks of a calibration model.

use crate::gcs::MAP_AXES;
use nanocal_model::{FastInputs, Fold, HysteresisState, Model, SlowInputs, MAX_AXES};

/// Result of the model's fast path for one target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corrected {
    /// Commands for the controller, µm, per model axis.
    pub q_um: [f32; MAP_AXES],
    /// Bit per axis: the target is outside the training envelope.
    pub outside_envelope: u8,
}

/// What the proxy needs from a model: the fast path, its inverse and the stage travel.
///
/// The contract the proxy relies on (keep it when the model grows):
/// - [`correct`](Corrector::correct) is a pure function of its arguments and the corrector's
///   state. The proxy calls it for every forwarded target *and* for trial points: the inverse
///   of a position reply iterates on it (a chord method warm-started at the last target, see
///   `proxy::inverse`) and differentiates it by finite differences. A model with per-command
///   state (play operators of a hysteresis bank, fast inputs) must therefore not advance that
///   state inside `correct`; it advances it when a target is actually sent — the one place
///   that stores new targets, at the end of `ProxyState::rewrite_move` in `proxy/moves.rs`
///   ("the one place a corrected target goes out") — through a method to be added here then
///   (the proxy would then hold the corrector mutably).
/// - [`inverse`](Corrector::inverse) is the model's own inverse, the fallback when the proxy's
///   iteration does not converge.
/// - Positions are in the model's unit, µm; the proxy refuses to correct for a controller whose
///   position unit (`PUN?`) is not µm.
pub trait Corrector {
    /// Number of model axes (1..=3).
    fn axes(&self) -> usize;
    /// Fast path: commands for calibrated targets `x_um` approached in direction `dir`.
    fn correct(&self, x_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Corrected;
    /// Inverse: calibrated position for controller positions `q_um`; `None` if it fails.
    fn inverse(&self, q_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Option<[f32; MAP_AXES]>;
    /// Stage travel of a model axis in command space (min, max), µm.
    fn travel_um(&self, axis: usize) -> (f32, f32);
}

/// The model's fast path as the proxy uses it: a thermal fold and the stage travel.
#[derive(Debug, Clone, Copy)]
pub struct FoldCorrector {
    /// The current thermal fold.
    pub fold: Fold,
    /// Stage travel per axis in command space, µm.
    pub travel_um: [(f32, f32); MAX_AXES],
}

impl FoldCorrector {
    /// Fold `model` at `slow` (the slow path).
    pub fn new(model: &Model, slow: &SlowInputs) -> Self {
        let mut travel_um = [(0.0, 0.0); MAX_AXES];
        for (a, t) in travel_um.iter_mut().enumerate().take(model.axes()) {
            let (lo, hi) = model.travel_um(a);
            *t = (lo as f32, hi as f32);
        }
        Self {
            fold: model.fold(slow),
            travel_um,
        }
    }
}

impl Corrector for FoldCorrector {
    fn axes(&self) -> usize {
        self.fold.axes()
    }
    fn correct(&self, x_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Corrected {
        // Fast inputs and hysteresis state are not supplied by the device yet: a model that
        // uses a fast input yields NaN commands (refused), and play operators start fresh on
        // every command.
        let c = self
            .fold
            .correct(x_um, dir, &FastInputs::NONE, &mut HysteresisState::new());
        Corrected {
            q_um: c.q_um,
            outside_envelope: c.outside_envelope,
        }
    }
    fn inverse(&self, q_um: &[f32; MAP_AXES], dir: &[i8; MAP_AXES]) -> Option<[f32; MAP_AXES]> {
        self.fold
            .inverse(q_um, dir, &FastInputs::NONE, &HysteresisState::new())
            .ok()
    }
    fn travel_um(&self, axis: usize) -> (f32, f32) {
        self.travel_um.get(axis).copied().unwrap_or((0.0, 0.0))
    }
}
