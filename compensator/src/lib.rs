//! nanocal-compensator: the inline compensator's device logic, pure and board-agnostic.
//!
//! The firmware only moves bytes between peripherals and these state machines; the host tests
//! drive the same code natively. The calibration model itself (terms, fold, blob) lives in
//! `nanocal-model`; this crate is what the device does with it:
//!
//! - [`gcs`]: GCS syntax: mnemonics, numbers in fixed point, axis/value lists, addresses;
//! - [`command`]: what each GCS command does to the stage (corrected, refused, forgets targets);
//! - [`proxy`]: the GCS proxy (targets corrected, position replies mapped back, refusals);
//! - [`sensor`] and [`fault`]: temperature-amplifier frames and the sensor fault policy;
//! - [`mgmt`], [`upload`], [`slots`]: the management protocol, chunked upload, model storage.
//!
//! No heap, no `unsafe`, no panics on external input.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

#[cfg(any(test, feature = "std"))]
extern crate std;

pub mod command;
pub mod fault;
pub mod gcs;
pub mod mgmt;
pub mod proxy;
pub mod sensor;
pub mod slots;
pub mod upload;
