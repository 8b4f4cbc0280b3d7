//! The management protocol: binary frames on a channel separate from the GCS stream (a second
//! USB CDC-ACM interface on the STM32 board, serial3 on the QEMU board).
//!
//! ```text
//! frame:  A7 5C | kind u8 | seq u8 | len u16 LE | payload (len ≤ MAX_PAYLOAD) | crc32 u32 LE
//!         crc32 (CRC-32/ISO-HDLC, the blob's: crate::crc32) covers kind, seq, len and payload
//! ```
//! The host sends a request ([`Request`]); the device answers with kind `kind | 0x80`
//! ([`REPLY`]), the same `seq`, and a payload whose first byte is the result: 0 for success,
//! then the reply's data ([`Reply`]), or a [`Refusal`] code (with one more byte, an
//! [`InputCode`], for [`Refusal::Input`]).
//!
//! | kind | request payload | reply data |
//! |---|---|---|
//! | `HELLO` 0x01 | – | protocol u16, blob format u16, max chunk u16, firmware (len u8, ASCII), chip UID (12 bytes), reset cause u8, reset site (len u8, ASCII, empty when none) |
//! | `STATUS` 0x02 | – | [`Status`] ([`crate::status`] has the layout) |
//! | `UPLOAD_BEGIN` 0x10 | total_len u32, crc32 u32, format u16 | – |
//! | `UPLOAD_CHUNK` 0x11 | offset u32, bytes (≤ [`MAX_CHUNK`]) | received u32 |
//! | `UPLOAD_COMMIT` 0x12 | – | model id u32, model CRC-32 u32 (the stored blob's own), uploads accepted u32 |
//! | `UPLOAD_ABORT` 0x13 | – | – |
//! | `SET_KMZ` 0x20 | q_cmd f64×3, x_meas f64×3 (µm, finite) | kmz f64×3, stored u8 (0/1) |
//! | `BYPASS` 0x21 | on u8 (0 off, else on) | – |
//! | `CONFIG_GET` 0x30 | – | settings ([`crate::settings`] layout) |
//! | `CONFIG_SET` 0x31 | settings ([`crate::settings`] layout) | – (stored; applied at once, the baud rate at reset) |
//! | `RESET` 0x32 | – | – (the device resets after replying) |
//! | `DEBUG_HANG` 0x7E | – | none: the QEMU board hangs (the watchdog test); other boards refuse it as unknown |
//!
//! All little-endian. Trailing bytes after a request's fields are ignored. The golden bytes of
//! every request and reply are in this crate's tests.
//!
//! `HELLO`'s request and the first field of its reply (the protocol version, after the result
//! byte) are the same in every version: a host reads them first and refuses to go on with a
//! device of another version (naming both) instead of misreading its bytes.
//!
//! The decoder ([`Decoder`]) resynchronises on the sync bytes and drops a frame that is still
//! incomplete [`FRAME_TIMEOUT_MS`] after its first byte (a connection closed mid-frame): the
//! requests after it are answered, not swallowed.

mod frame;
mod kind;
mod refusal;
mod reply;
mod request;

#[cfg(doc)]
use crate::status::Status;
pub use frame::{
    encode, seal, Decoder, Frame, FrameError, PayloadError, Reader, Writer, FRAME_TIMEOUT_MS,
    MAX_FRAME, MAX_PAYLOAD, OVERHEAD, PAYLOAD_AT, SYNC,
};
pub use kind::{Kind, REPLY};
pub use refusal::{InputCode, InputWhy, Refusal};
pub use reply::{Hello, Reply};
pub use request::Request;

/// Protocol version. 2: identity in HELLO/STATUS, settings, reset, input checks, and
/// `Status::slow_outside` widened from u16 to u32 (a model has up to 23 inputs with envelope
/// bits). 3: 16 temperatures in STATUS, settings layout 2 (16 chip-selects). 4:
/// `Status::move_fold` in the word that was the unused `slot_seq` (0), with `MOVE_FOLD`; the
/// layout is unchanged. (Version 4 is also the first whose facts live in this crate; the
/// bytes did not change with the move.) 5: the model's content hash — the CRC-32 its blob
/// carries — in `STATUS` (`Status::model_crc32`, in place of the reserved byte at offset 6:
/// every later field moved by 3 bytes) and in `UPLOAD_COMMIT`'s reply (in place of its
/// reserved byte); the model id alone did not tell two models apart (issue 21). Also in 5 (the
/// changes met before any was released): HELLO ends with the reset site, reset causes 8
/// (panic), 9 (double ECC error outside the store), 10 (CPU fault) (issue 16); settings layout 3
/// (the fold period, 2 bytes more in CONFIG_GET/CONFIG_SET), and `Status::temps_c`/`Status::aux`
/// are the last fold's inputs (the readings averaged over the fold period) (issue 18). 6: the
/// model-stale check (issue 19): `STATUS` grows by 33 bytes at its end (`Status::stale` …
/// `Status::envelope_excess_c`, flag `MODEL_STALE`), LED state 5 (model stale), settings
/// layout 4 (the check's `k` and extrapolation margin, 8 bytes more in CONFIG_GET/CONFIG_SET).
/// 7: the provenance check (issue 19): `STATUS` grows by 51 bytes at its end (`Status::stage`,
/// `Status::model_serial`, `Status::controller_serial`), flag `STAGE_MISMATCH`, GCS error 9015,
/// settings layout 5 (`allow_other_stage`, 1 byte more in CONFIG_GET/CONFIG_SET), and HELLO's
/// blob format is 4 (the provenance section). 8: following's counters (issue 21, held targets
/// that follow the model): `STATUS` grows by 8 bytes at its end (`Status::follow_reissues`,
/// `Status::follow_refused`); a lab could not tell from the status whether following acted, or
/// whether the controller refused its re-issues. 9: `Status::pending_error` may carry two new
/// codes, 22 (an axis named twice, PI's own code) and 9016 (a relative move mixing model and
/// other axes, refused rather than split); the bytes are unchanged, but a protocol-8 host's
/// decoder refuses those values, so it must be told to update rather than fail on a status.
pub const PROTOCOL: u16 = 9;
/// Largest upload chunk (payload minus the offset).
pub const MAX_CHUNK: usize = 256;
