//! Fixed capacities of the model: everything is sized at compile time, nothing is allocated.

/// Axes a model can command (x, y, z).
pub const MAX_AXES: usize = 3;
/// Temperature channels a model can read.
pub const MAX_TEMPS: usize = 8;
/// Auxiliary inputs (air pressure, force, …).
pub const MAX_AUX: usize = 4;
/// First-order lag filters (lagged temperatures) a model can declare.
pub const MAX_LAGS: usize = 8;
/// Terms a model can hold. Published 3-DoF delta-robot models use 78 parameters.
pub const MAX_TERMS: usize = 128;
/// Highest power of one axis in a term, and highest total degree of a term.
pub const MAX_POWER: u8 = 9;
/// Inputs that carry a scaling and a training envelope: axes, then temperatures, then aux.
pub const MAX_INPUTS: usize = MAX_AXES + MAX_TEMPS + MAX_AUX;
