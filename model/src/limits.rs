//! Fixed capacities of the model: everything is sized at compile time, nothing is allocated.

/// Axes a model can command (x, y, z).
pub const MAX_AXES: usize = 3;
/// Temperature channels a model can read (paper 001's robot has 10; the spindle recording in
/// `shared/data/spindle-thermal` has 16).
pub const MAX_TEMPS: usize = 16;
/// Auxiliary inputs (air pressure, force, …), slow or fast.
pub const MAX_AUX: usize = 4;
/// First-order lag filters (lagged temperatures) a model can declare: two time constants for
/// each of the 16 temperature channels.
pub const MAX_LAGS: usize = 32;
/// Play operators (hysteresis) a model can declare over all its axes: 16 on each of 3 axes.
pub const MAX_PLAY: usize = 48;
/// Terms a model can hold. Published 3-DoF delta-robot models use 78 parameters.
pub const MAX_TERMS: usize = 128;
/// Highest power of one axis in a term, and highest total degree of a term.
pub const MAX_POWER: u8 = 9;
/// Inputs that carry a scaling and a training envelope: axes, then temperatures, then aux.
pub const MAX_INPUTS: usize = MAX_AXES + MAX_TEMPS + MAX_AUX;

// Envelope bit masks ([`crate::EnvelopeFlags`]) hold one bit per input in a u32.
const _: () = assert!(MAX_INPUTS <= 32);
