//! The virtual bench: what stands around the firmware when it runs under QEMU — the emulated
//! board as a process, a simulated stage controller on the stage link, simulated sensor chips on
//! the sensor bus. The end-to-end tests, the firmware benchmarks and `campaign --virtual`
//! ([`campaign_bench`]) share it.

pub mod bench;
pub mod board_first;
pub mod campaign_bench;
pub mod chips;
#[cfg(feature = "test-support")]
mod cli_relay;
pub mod controller;
pub mod core_split;
pub mod input_watch;
pub mod jitter;
pub mod link;
pub mod qemu;
pub mod sensors;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod twin_stage;

pub use controller::{
    AxisConfig, Clock, Config, Controller, Event, IdealPlant, ManualClock, Plant, Processed,
    StageSim, SystemClock, DEFAULT_SERIAL,
};
pub use link::{BenchClock, BenchLink};
pub use qemu::{bench_elf, have_qemu, qemu_elf, repo_root, Elf, Qemu, HANG};
pub use sensors::Buses;
#[cfg(feature = "test-support")]
pub use test_support::{qemu_or_skip, GcsHost, SensorSim};
