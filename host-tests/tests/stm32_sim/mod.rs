//! The rig for the shipped STM32 image on the emulated B-L475E-IOT01A: it lives in the
//! `nanocal-stm32-bench` crate (`stm32-bench/src/rig.rs`), which the `stm32-bench` binary's
//! campaigns share; the tests reach it here.
#![allow(unused_imports)]

pub use nanocal_stm32_bench::rig::*;
