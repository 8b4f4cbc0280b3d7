//! nanocal inline compensator firmware: a board-agnostic embassy application ([`app`]), the
//! STM32 board's drivers ([`stm32`]) and the QEMU board's ([`qemu`]). Each board's wiring is in
//! `src/bin/stm32.rs` and `src/bin/qemu.rs`. All pure logic (GCS proxy, sensor frames, fault
//! policy, management protocol, upload, settings, the flash store) lives in `nanocal-compensator`.
#![no_std]
#![warn(missing_docs)]

#[macro_use]
mod fmt;

pub mod app;
#[cfg(feature = "qemu")]
pub mod qemu;
#[cfg(feature = "stm32")]
pub mod stm32;

#[cfg(all(feature = "stm32", feature = "qemu"))]
compile_error!(
    "choose one board: feature `stm32` (default) or `qemu` (with --no-default-features)"
);
