//! nanocal-compensator: the inline compensator's device logic, pure and board-agnostic.
//!
//! The firmware only moves bytes between peripherals and these state machines; the host tests
//! drive the same code natively. The calibration model itself (terms, fold, blob) lives in
//! `nanocal-model`; this crate is what the device does with it:
//!
//! - [`gcs`]: GCS syntax: mnemonics, numbers in fixed point, axis/value lists, addresses;
//! - [`command`]: what each GCS command does to the stage (corrected, refused, forgets targets);
//! - [`proxy`]: the GCS proxy (targets corrected, position replies mapped back, refusals);
//! - [`sensor`] and [`fault`]: temperature amplifiers at register level and the fault policy;
//! - [`inputs`], [`settings`]: what the board supplies and how it is configured;
//! - [`slow_average`]: the slow path's clock: readings averaged over the fold period;
//! - [`mgmt`], [`upload`]: the management protocol and chunked upload;
//! - [`store`], [`l4flash`]: the persistent store on the L4's flash (and its simulation);
//! - [`identity`], [`clock`], [`led`], [`wire`]: reset cause and UID, clock rules, the status
//!   LED, the QEMU board's bus stand-in;
//! - [`bench_link`]: the QEMU board's link to its virtual bench (host-driven clock, bus mailbox).
//!
//! No heap, no `unsafe`, no panics on external input.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

#[cfg(any(test, feature = "std"))]
extern crate std;

pub mod bench_link;
pub mod clock;
pub mod command;
pub mod fault;
pub mod gcs;
pub mod identity;
pub mod inputs;
pub mod l4flash;
pub mod led;
pub mod lps22hb;
pub mod mgmt;
pub mod proxy;
pub mod sensor;
pub mod settings;
pub mod slow_average;
pub mod store;
pub mod upload;
pub mod wire;

/// CRC-32/ISO-HDLC (reflected, polynomial 0x04C11DB7, init and xorout !0: zlib's CRC, the one
/// the blob and the management frames carry), from the `crc` crate.
pub fn crc32(bytes: &[u8]) -> u32 {
    const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    CRC.checksum(bytes)
}
