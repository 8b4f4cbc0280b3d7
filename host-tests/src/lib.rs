//! nanocal host library: recordings, fitting, validation, the digital twin, explain, device client.
#![warn(missing_docs)]
pub use nanocal_model as model;

pub mod cli;
pub mod device;
pub mod published;
