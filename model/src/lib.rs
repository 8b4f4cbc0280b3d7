//! nanocal-model: the calibration model shared by the firmware and the host tools.
//!
//! A [`Model`] maps calibrated target positions to the commands a stage controller must be sent:
//! a polynomial in the commanded position(s) with cross-axis coupling, linear terms in several
//! temperatures and auxiliary channels (directly or through first-order lags), position ×
//! temperature interactions, direction-of-approach terms, a static offset λ and an adaptive
//! offset λ_KMZ. Inputs are centred and scaled with constants stored in the model.
//!
//! Evaluation has two speeds: [`Model::fold`] (slow path, f64, when temperatures change) and
//! [`Fold::correct`] / [`Fold::inverse`] (fast path, f32, per command). [`Model::eval_f64`] is
//! the reference the host checks the fast path against. [`blob`] is the stored byte format.
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
mod builder;
mod error;
mod fold;
mod horner;
mod input;
mod lag;
pub mod limits;
mod model;
pub mod play;
mod term;

pub use builder::ModelBuilder;
pub use error::{InverseError, ModelError};
pub use fold::{Correction, Fold, FOLD_CAPACITY};
pub use input::{EnvelopeFlags, Input, Range, Scaling, SlowInputs};
pub use lag::{LagBank, LagFilter, LagSpec};
pub use limits::{MAX_AUX, MAX_AXES, MAX_LAGS, MAX_TEMPS, MAX_TERMS};
pub use model::{Model, ScaledInputs};
pub use term::{approach_sign, Factor, Term};
