//! Explain's error: a leaf every part of explain and every effect may import without
//! importing the engine (explain/mod.rs), which imports the effects.

use crate::data::recording::RecordingError;
use crate::numerics::linalg::LinalgError;

/// Errors of explain.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExplainError {
    /// The recording is not usable.
    #[error("{0}")]
    Input(String),
    /// Reading a recording failed.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A least-squares problem failed.
    #[error("least squares: {0}")]
    Linalg(#[from] LinalgError),
}
