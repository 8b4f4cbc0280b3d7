//! nanocal host library: recordings, fitting, validation, the digital twin, explain, device client.
#![warn(missing_docs)]
pub use nanocal_model as model;

pub mod cli;
pub mod effects;
pub mod twin;
pub mod linalg;
pub mod recording;
pub mod published;
pub mod explain;
