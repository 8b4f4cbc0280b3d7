//! nanocal-interface: every fact the device and the host must agree on, written once.
//!
//! The firmware (`src/`, through `nanocal-compensator`) and the host (`nanocal`: the device
//! client, the campaign, the virtual bench) both read and write these bytes and codes through
//! this crate, so a change shows on both sides at once and the golden-byte tests
//! (`tests/golden.rs`) catch any change of the bytes themselves.
//!
//! - [`mgmt`]: the management protocol — framing (sync, header, CRC), request kinds, typed
//!   [`mgmt::Request`]s and [`mgmt::Reply`]s, result codes ([`mgmt::Refusal`], the upload's
//!   among them), the protocol version;
//! - [`status`]: the status report's layout, its [`status::Flags`], per-channel
//!   [`status::ChannelBits`] and [`status::SensorFault`] codes;
//! - [`led`], [`identity`]: the status LED's states and patterns, reset causes, the USB serial;
//! - [`gcs_error`]: the GCS error codes the compensator answers on `ERR?` (9001–9009 and the
//!   three PI codes it raises itself);
//! - [`settings`]: the settings layout (chip-selects, amplifiers, axes, aux sources);
//! - [`bus`], [`bench_link`]: the QEMU board's bus framing and its shared page with the
//!   virtual bench.
//!
//! [`crc32`] is the project's one CRC-32 (the model's, which the blob uses): frames and settings
//! carry it too.
//!
//! Coded enums are generated from one table each (code, variant, meaning): adding a GCS error,
//! a result code, an LED state or a request kind is one line. When bytes on the wire change,
//! [`mgmt::PROTOCOL`] (or the settings' [`settings::VERSION`], the bench page's
//! [`bench_link::VERSION_VALUE`]) is bumped and the golden bytes are updated with it.
//!
//! No heap, no `unsafe`, no panics on any input.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(any(test, feature = "std"))]
extern crate std;

#[macro_use]
mod code_enum;

pub mod bench_link;
pub mod bus;
pub mod gcs_error;
pub mod identity;
pub mod led;
pub mod mgmt;
pub mod settings;
pub mod status;

pub use gcs_error::GcsErrorCode;
/// The fixed-capacity containers in this crate's types (e.g. [`mgmt::Hello::firmware`]).
pub use heapless;
/// CRC-32/ISO-HDLC (reflected, polynomial 0x04C11DB7, init and xorout all ones: zlib's CRC) —
/// the project's one implementation, the model's ([`nanocal_model::blob::crc32`]).
pub use nanocal_model::blob::crc32;
