//! nanocal host library: recordings, fitting, validation, the digital twin, explain, device client.
#![warn(missing_docs)]
pub use nanocal_model as model;

pub mod cli;
pub mod device;
pub mod effects;
pub mod linalg;
pub mod published;
pub mod recording;
pub mod stats;
pub mod stepwise;
pub mod twin;
