//! nanocal-model: the calibration model shared by the firmware and the host tools.
//!
//! A [`Model`] maps calibrated target positions to the commands a stage controller must be sent:
//! a polynomial in the commanded position(s) with cross-axis coupling, linear terms in several
//! temperatures and auxiliary channels (directly or through first-order lags), position ×
//! temperature interactions, direction-of-approach terms, fast (real-time) aux inputs such as a
//! force, rate-independent hysteresis as per-axis banks of play operators ([`hysteresis`]), a
//! static offset λ and an adaptive offset λ_KMZ. Inputs are centred and scaled with constants
//! stored in the model.
//!
//! Evaluation has two speeds: [`Model::fold`] (slow path, f64, when temperatures change) and
//! [`Fold::correct`] / [`Fold::inverse`] (fast path, f32, per command, with the command's
//! [`FastInputs`] and the [`HysteresisState`] it steps). [`Model::eval_f64`] and
//! [`Model::eval_f64_with_state`] are the references the host checks the fast path against.
//! [`blob`] is the stored byte format.
//!
//! No heap, no `unsafe`, no panics on external input.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Index loops over axes read like the maths they implement.
#![allow(clippy::needless_range_loop)]

#[cfg(any(test, feature = "std"))]
extern crate std;

pub mod blob;
pub mod bound;
mod builder;
mod error;
mod fold;
mod horner;
pub mod hysteresis;
mod input;
mod lag;
pub mod limits;
mod model;
pub mod play;
pub mod provenance;
pub mod reference;
mod term;

pub use bound::{AxisBound, MAX_BOUND_TERMS};
pub use builder::ModelBuilder;
pub use error::{InverseError, ModelError};
pub use fold::{Correction, Fold, FOLD_CAPACITY};
pub use hysteresis::{HysteresisState, PlaySpec};
pub use input::{AuxKind, AuxSpec, EnvelopeFlags, FastInputs, Input, Range, Scaling, SlowInputs};
pub use lag::{LagBank, LagFilter, LagSpec};
pub use limits::{MAX_AUX, MAX_AXES, MAX_LAGS, MAX_PLAY, MAX_TEMPS, MAX_TERMS};
pub use model::{Model, ScaledInputs};
pub use provenance::{Provenance, StageSerial};
pub use term::{approach_sign, Factor, Term};
