//! nanocal-compensator: the inline compensator's device logic, pure and board-agnostic.
//!
//! The firmware only moves bytes between peripherals and these state machines; the host tests
//! drive the same code natively. The calibration model itself (terms, fold, blob) lives in
//! `nanocal-model`; this crate is what the device does with it:
//!
//! - [`gcs`]: GCS syntax: mnemonics, numbers in fixed point, axis/value lists, addresses;
//! - [`command`]: what each GCS command does to the stage (corrected, refused, forgets targets);
//! - [`proxy`]: the GCS proxy (targets corrected, position replies mapped back, refusals);
//! - [`sensor`] and [`fault`]: temperature amplifiers at register level and the fault policy;
//! - [`inputs`]: which model inputs the board supplies;
//! - [`slow_average`]: the slow path's clock: readings averaged over the fold period;
//! - [`stale`]: whether the model in service still holds (KMZ residual, envelope);
//! - [`upload`]: the chunked upload's state machine;
//! - [`store`], [`l4flash`]: the persistent store on the L4's flash (and its simulation);
//! - [`clock`], [`lps22hb`]: clock rules, the barometer;
//! - [`line_state`]: a USB CDC port's DTR as the application must see it (falls counted).
//!
//! What the device and the host must agree on — management frames, status, settings layout,
//! GCS error codes, the QEMU board's bus and bench page — is `nanocal-interface`'s.
//!
//! No heap, no `unsafe`, no panics on external input.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

#[cfg(any(test, feature = "std"))]
extern crate std;

pub mod clock;
pub mod command;
pub mod fault;
pub mod gcs;
pub mod inputs;
pub mod l4flash;
pub mod line_state;
pub mod lps22hb;
pub mod proxy;
pub mod sensor;
pub mod slow_average;
pub mod stale;
pub mod store;
pub mod upload;
