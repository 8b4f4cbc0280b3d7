//! nanocal host library.
#![warn(missing_docs)]
pub use nanocal_model as model;
