//! `nanocal campaign`: a whole calibration on a bench, through the compensator.
pub mod bench;
pub mod gcs;
pub mod recorder;
pub mod reference;
