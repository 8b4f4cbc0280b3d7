//! A simulated PI stage controller (E-727 or C-867), for the firmware's stage link and for
//! `campaign --virtual`: a GCS 2.0 interpreter ([`Controller`]) over a pluggable stage
//! ([`Plant`], default [`IdealPlant`]) and clock ([`Clock`]: [`SystemClock`] or [`ManualClock`]),
//! served on a socket by [`StageSim`]. See [`device`] for what each command does and where that
//! comes from.

pub mod device;
pub mod plant;
mod tcp;

pub use device::{AxisConfig, Config, Controller, Event, Processed, DEFAULT_SERIAL};
pub use plant::{Clock, IdealPlant, ManualClock, Plant, SystemClock};
pub use tcp::StageSim;
