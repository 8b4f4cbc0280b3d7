//! nanocal-model: the calibration model shared by the firmware and the host tools.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "std")]
extern crate std;
