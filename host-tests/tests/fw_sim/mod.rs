//! Test rig for the QEMU firmware: the library's virtual bench (QEMU process, simulated stage
//! controller and sensor chips), shared by the e2e tests and benchmarks.
#![allow(unused_imports)]

pub use nanocal::virtual_bench::*;
