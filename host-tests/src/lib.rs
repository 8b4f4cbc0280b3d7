//! nanocal host library: recordings, fitting, validation, the digital twin, explain, device client.
#![warn(missing_docs)]
pub use nanocal_model as model;

pub mod campaign;
pub mod cli;
pub mod data;
pub mod device;
pub mod effects;
pub mod explain;
pub mod fit;
pub mod numerics;
pub mod papers;
#[cfg(feature = "test-support")]
pub mod proxy_fuzz;
pub mod report;
pub mod twin;
pub mod validate;
pub mod virtual_bench;
