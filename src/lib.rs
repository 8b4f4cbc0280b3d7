//! nanocal inline compensator firmware: a board-agnostic embassy application ([`app`]) and the
//! drivers of the QEMU board ([`qemu`]). The STM32 board's glue lives in `src/bin/stm32.rs`,
//! the QEMU board's in `src/bin/qemu.rs`. All pure logic (GCS proxy, sensor frames, fault
//! policy, management protocol, upload, settings, the flash store) lives in `nanocal-compensator`.
#![no_std]
#![warn(missing_docs)]

#[macro_use]
mod fmt;

pub mod app;
#[cfg(feature = "qemu")]
pub mod qemu;

#[cfg(all(feature = "stm32", feature = "qemu"))]
compile_error!(
    "choose one board: feature `stm32` (default) or `qemu` (with --no-default-features)"
);
