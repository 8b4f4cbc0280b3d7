//! Management protocol: binary frames on a channel separate from the GCS stream (a second USB
//! CDC-ACM interface on the STM32 board, serial3 on the QEMU board).
//!
//! ```text
//! frame:  0xA7 0x5C | kind u8 | seq u8 | len u16 LE | payload (len ≤ MAX_PAYLOAD) | crc32 u32 LE
//!         crc32 (IEEE, as the blob's) covers kind, seq, len and payload
//! ```
//! The host sends a request; the device answers with `kind | 0x80`, the same `seq`, and a
//! payload whose first byte is a result code ([`RESULT_OK`] or an error code), then data.
//!
//! | kind | request payload | reply data |
//! |---|---|---|
//! | `HELLO` 0x01 | – | protocol u16, blob format u16, max chunk u16 |
//! | `STATUS` 0x02 | – | [`Status`] |
//! | `UPLOAD_BEGIN` 0x10 | total_len u32, crc32 u32, format u16 | – |
//! | `UPLOAD_CHUNK` 0x11 | offset u32, bytes | received u32 |
//! | `UPLOAD_COMMIT` 0x12 | – | model id u32, 0 u8 (was: slot), uploads accepted u32 |
//! | `UPLOAD_ABORT` 0x13 | – | – |
//! | `SET_KMZ` 0x20 | q_cmd f64×3, x_meas f64×3 | kmz f64×3, stored u8 (model re-committed) |
//! | `BYPASS` 0x21 | on u8 | – |
//! | `CONFIG_GET` 0x30 | – | settings ([`crate::settings`] bytes) |
//! | `CONFIG_SET` 0x31 | settings bytes | – (stored; applied at once, the baud rate at reset) |
//! | `RESET` 0x32 | – | – (the device resets after replying) |
//!
//! `HELLO` data, after the three u16: firmware version (len u8, ASCII), chip UID (12 bytes),
//! reset cause u8 ([`crate::identity::ResetCause::code`]).
//!
//! Result codes: 0 ok; 1..=9 [`crate::upload::UploadError::code`]; [`RESULT_STORAGE`];
//! [`RESULT_NO_MODEL`]; [`RESULT_BAD_REQUEST`]; [`RESULT_UNKNOWN_KIND`]; [`RESULT_INPUT`] (the
//! reply data carries [`crate::inputs::InputError::code`]); [`RESULT_SETTINGS`].

use crate::crc32;
use core::fmt;

/// Protocol version. 2: identity in HELLO/STATUS, settings, reset, input checks, and
/// [`Status::slow_outside`] widened from u16 to u32 (a model has up to 23 inputs with envelope
/// bits). 3: 16 temperatures in STATUS ([`STATUS_SENSORS`]), settings layout 2 (16
/// chip-selects). 4: [`Status::move_fold`] in the word that was the unused `slot_seq` (0), with
/// [`flags::MOVE_FOLD`]; the layout is unchanged. 5: settings layout 3 (the fold period), and
/// [`Status::temps_c`]/[`Status::aux`] are the last fold's inputs (the readings averaged over the
/// fold period); the layout is unchanged.
pub const PROTOCOL: u16 = 5;
/// Frame sync bytes.
pub const SYNC: [u8; 2] = [0xA7, 0x5C];
/// Largest payload.
pub const MAX_PAYLOAD: usize = 320;
/// Largest upload chunk (payload minus the offset).
pub const MAX_CHUNK: usize = 256;
/// Bytes around the payload (sync, kind, seq, len, crc).
pub const OVERHEAD: usize = 2 + 1 + 1 + 2 + 4;
/// Largest frame on the wire.
pub const MAX_FRAME: usize = MAX_PAYLOAD + OVERHEAD;

/// Request kinds.
pub mod kind {
    /// Identify.
    pub const HELLO: u8 = 0x01;
    /// Status report.
    pub const STATUS: u8 = 0x02;
    /// Start an upload.
    pub const UPLOAD_BEGIN: u8 = 0x10;
    /// One chunk of an upload.
    pub const UPLOAD_CHUNK: u8 = 0x11;
    /// Verify, store and activate the upload.
    pub const UPLOAD_COMMIT: u8 = 0x12;
    /// Drop the upload.
    pub const UPLOAD_ABORT: u8 = 0x13;
    /// Set λ_KMZ from a measured reference.
    pub const SET_KMZ: u8 = 0x20;
    /// Bypass (1) or enable (0) compensation.
    pub const BYPASS: u8 = 0x21;
    /// Read the settings.
    pub const CONFIG_GET: u8 = 0x30;
    /// Store and apply settings.
    pub const CONFIG_SET: u8 = 0x31;
    /// Reset the device.
    pub const RESET: u8 = 0x32;
    /// QEMU board only: the firmware hangs in a busy loop (the watchdog test's hung firmware).
    pub const DEBUG_HANG: u8 = 0x7E;
    /// Bit set in reply kinds.
    pub const REPLY: u8 = 0x80;
}

/// Result: success.
pub const RESULT_OK: u8 = 0;
/// Result: storage failure (the old model stays in service).
pub const RESULT_STORAGE: u8 = 20;
/// Result: the request needs a model and none is loaded.
pub const RESULT_NO_MODEL: u8 = 21;
/// Result: malformed request payload.
pub const RESULT_BAD_REQUEST: u8 = 22;
/// Result: unknown request kind.
pub const RESULT_UNKNOWN_KIND: u8 = 23;
/// Result: the model uses an input this board cannot supply (nothing stored).
pub const RESULT_INPUT: u8 = 24;
/// Result: settings rejected (malformed or out of range).
pub const RESULT_SETTINGS: u8 = 25;

/// What a result code means (for people: CLI output, logs).
pub fn result_meaning(code: u8) -> &'static str {
    match code {
        RESULT_OK => "ok",
        1 => "upload step without a begin",
        2 => "blob format version not supported by the firmware",
        3 => "announced length out of range",
        4 => "chunk out of order",
        5 => "chunk past the announced length",
        6 => "repeated chunk differs",
        7 => "upload incomplete",
        8 => "whole-blob CRC mismatch",
        9 => "invalid blob",
        RESULT_STORAGE => "storage (flash) failure; old model kept",
        RESULT_NO_MODEL => "no model loaded",
        RESULT_BAD_REQUEST => "malformed request",
        RESULT_UNKNOWN_KIND => "unknown request",
        RESULT_INPUT => "model uses an input this board cannot supply (see `nanocal device config`); nothing stored",
        RESULT_SETTINGS => "settings rejected (malformed or out of range)",
        _ => "unknown code",
    }
}

/// Framing errors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum FrameError {
    /// The frame's CRC did not match (the decoder resynchronises).
    BadCrc,
    /// The length field exceeds [`MAX_PAYLOAD`].
    TooLong,
    /// A payload was too short for its kind.
    Short,
    /// The output buffer is too small.
    OutputFull,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::BadCrc => "management frame CRC mismatch",
            FrameError::TooLong => "management frame longer than the maximum payload",
            FrameError::Short => "management payload too short for its kind",
            FrameError::OutputFull => "output buffer too small for the frame",
        })
    }
}

/// A decoded frame (payload borrowed from the decoder).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Kind.
    pub kind: u8,
    /// Sequence number (echoed in the reply).
    pub seq: u8,
    /// Payload.
    pub payload: &'a [u8],
}

/// Where a frame's payload starts.
pub const PAYLOAD_AT: usize = 6;

/// Encode a frame into `out`; returns its length.
pub fn encode(kind: u8, seq: u8, payload: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    if payload.len() > MAX_PAYLOAD {
        return Err(FrameError::TooLong);
    }
    if out.len() < payload.len() + OVERHEAD {
        return Err(FrameError::OutputFull);
    }
    out[PAYLOAD_AT..PAYLOAD_AT + payload.len()].copy_from_slice(payload);
    seal(kind, seq, payload.len(), out)
}

/// Complete a frame whose `len` payload bytes were written in place at
/// `out[PAYLOAD_AT..]` (no second buffer): sync, header and CRC; returns the frame's length.
pub fn seal(kind: u8, seq: u8, len: usize, out: &mut [u8]) -> Result<usize, FrameError> {
    if len > MAX_PAYLOAD {
        return Err(FrameError::TooLong);
    }
    let n = len + OVERHEAD;
    if out.len() < n {
        return Err(FrameError::OutputFull);
    }
    out[0..2].copy_from_slice(&SYNC);
    out[2] = kind;
    out[3] = seq;
    out[4..6].copy_from_slice(&(len as u16).to_le_bytes());
    let crc = crc32(&out[2..PAYLOAD_AT + len]);
    out[PAYLOAD_AT + len..n].copy_from_slice(&crc.to_le_bytes());
    Ok(n)
}

/// Byte-wise frame decoder with resynchronisation on the sync bytes.
pub struct Decoder {
    buf: heapless::Vec<u8, MAX_FRAME>,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// Empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
        }
    }

    /// Feed one byte. `Some(Ok(()))` when a frame is complete: read it with [`Decoder::frame`]
    /// before the next `feed`. `Some(Err(_))` for a corrupt frame (already discarded).
    pub fn feed(&mut self, b: u8) -> Option<Result<(), FrameError>> {
        if self.buf.len() >= 6 && self.buf.len() == self.frame_len() {
            self.buf.clear(); // the previous frame was consumed
        }
        match self.buf.len() {
            0 if b != SYNC[0] => return None,
            1 if b != SYNC[1] => {
                self.buf.clear();
                if b == SYNC[0] {
                    let _ = self.buf.push(b);
                }
                return None;
            }
            _ => {}
        }
        if self.buf.push(b).is_err() {
            self.buf.clear();
            return Some(Err(FrameError::TooLong));
        }
        let n = self.buf.len();
        if n == 6 && self.payload_len() > MAX_PAYLOAD {
            self.buf.clear();
            return Some(Err(FrameError::TooLong));
        }
        if n >= 6 && n == self.frame_len() {
            let crc = u32::from_le_bytes([
                self.buf[n - 4],
                self.buf[n - 3],
                self.buf[n - 2],
                self.buf[n - 1],
            ]);
            if crc32(&self.buf[2..n - 4]) != crc {
                self.buf.clear();
                return Some(Err(FrameError::BadCrc));
            }
            return Some(Ok(()));
        }
        None
    }

    fn payload_len(&self) -> usize {
        if self.buf.len() < 6 {
            return 0;
        }
        usize::from(u16::from_le_bytes([self.buf[4], self.buf[5]]))
    }

    fn frame_len(&self) -> usize {
        self.payload_len() + OVERHEAD
    }

    /// The frame completed by the last `feed`.
    pub fn frame(&self) -> Frame<'_> {
        let n = self
            .payload_len()
            .min(MAX_PAYLOAD)
            .min(self.buf.len().saturating_sub(6));
        Frame {
            kind: self.buf[2],
            seq: self.buf[3],
            payload: &self.buf[6..6 + n],
        }
    }
}

/// Little-endian reader over a payload.
pub struct Reader<'a> {
    b: &'a [u8],
}

impl<'a> Reader<'a> {
    /// Read from `b`.
    pub fn new(b: &'a [u8]) -> Self {
        Self { b }
    }
    /// Take `n` bytes.
    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8], FrameError> {
        if self.b.len() < n {
            return Err(FrameError::Short);
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    /// The rest.
    pub fn rest(&mut self) -> &'a [u8] {
        core::mem::take(&mut self.b)
    }
    /// A u8.
    pub fn u8(&mut self) -> Result<u8, FrameError> {
        Ok(self.bytes(1)?[0])
    }
    /// A u16.
    pub fn u16(&mut self) -> Result<u16, FrameError> {
        let b = self.bytes(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    /// A u32.
    pub fn u32(&mut self) -> Result<u32, FrameError> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    /// An i32.
    pub fn i32(&mut self) -> Result<i32, FrameError> {
        Ok(self.u32()? as i32)
    }
    /// An f32.
    pub fn f32(&mut self) -> Result<f32, FrameError> {
        Ok(f32::from_bits(self.u32()?))
    }
    /// An f64.
    pub fn f64(&mut self) -> Result<f64, FrameError> {
        let b = self.bytes(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }
}

/// Little-endian writer into a buffer.
pub struct Writer<'a> {
    b: &'a mut [u8],
    n: usize,
}

impl<'a> Writer<'a> {
    /// Write into `b`.
    pub fn new(b: &'a mut [u8]) -> Self {
        Self { b, n: 0 }
    }
    /// Bytes written.
    pub fn len(&self) -> usize {
        self.n
    }
    /// True when nothing was written.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// Append bytes.
    pub fn bytes(&mut self, v: &[u8]) -> Result<(), FrameError> {
        let end = self.n + v.len();
        if end > self.b.len() {
            return Err(FrameError::OutputFull);
        }
        self.b[self.n..end].copy_from_slice(v);
        self.n = end;
        Ok(())
    }
    /// Append a u8.
    pub fn u8(&mut self, v: u8) -> Result<(), FrameError> {
        self.bytes(&[v])
    }
    /// Append a u16.
    pub fn u16(&mut self, v: u16) -> Result<(), FrameError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append a u32.
    pub fn u32(&mut self, v: u32) -> Result<(), FrameError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an i32.
    pub fn i32(&mut self, v: i32) -> Result<(), FrameError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an f32.
    pub fn f32(&mut self, v: f32) -> Result<(), FrameError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an f64.
    pub fn f64(&mut self, v: f64) -> Result<(), FrameError> {
        self.bytes(&v.to_le_bytes())
    }
}

/// Sensors in a status report (every temperature a model can read).
pub const STATUS_SENSORS: usize = nanocal_model::MAX_TEMPS;

/// Status flags (bit set = condition present).
pub mod flags {
    /// A model is loaded.
    pub const MODEL: u16 = 1 << 0;
    /// Compensation is bypassed.
    pub const BYPASS: u16 = 1 << 1;
    /// Moves are refused because a sensor failed.
    pub const SENSOR_BLOCK: u16 = 1 << 2;
    /// A temperature/aux input is outside the training envelope (extrapolation).
    pub const EXTRAPOLATING: u16 = 1 << 3;
    /// An upload is in progress.
    pub const UPLOADING: u16 = 1 << 4;
    /// Moves are refused: the controller's position unit (`PUN?`) is not the model's µm, or
    /// the controller did not tell it (GCS error 9007 on the host's `ERR?`).
    pub const UNIT_MISMATCH: u16 = 1 << 5;
    /// The thermal fold is older than the sensor hold time (sensor task stalled): moves refused.
    pub const FOLD_STALE: u16 = 1 << 8;
    /// A host has the GCS port open (USB DTR set).
    pub const HOST_CONNECTED: u16 = 1 << 9;
    /// Sensors are warming up: a sensor the model uses has no valid reading yet.
    pub const WARMING_UP: u16 = 1 << 10;
    /// [`super::Status::move_fold`] is reported (always set by firmware that knows the field).
    pub const MOVE_FOLD: u16 = 1 << 11;
}

/// The device's status report.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Status {
    /// Flags, see [`flags`].
    pub flags: u16,
    /// Model id (0 without a model).
    pub model_id: u32,
    /// Unused since the store replaced the two slots (always 0xFF); kept for the layout.
    pub slot: u8,
    /// The fold (the value [`Status::folds`] had) that corrected the last move forwarded to the
    /// controller; 0: no move since start-up. With [`flags::MOVE_FOLD`] (firmware that reports
    /// it; the field was an unused 0 before). A host that reads `move_fold == folds` knows the
    /// temperatures in this report are the ones its last move was corrected with.
    pub move_fold: u32,
    /// Temperatures in use — the last fold's inputs, the readings averaged over the fold period
    /// — °C (NaN when unusable or not folded yet).
    pub temps_c: [f32; STATUS_SENSORS],
    /// Per-sensor status bits ([`crate::fault::Channel::status_bits`]).
    pub sensor_bits: [u8; STATUS_SENSORS],
    /// Sensors configured.
    pub sensors: u8,
    /// Slow inputs outside the training envelope at the last fold (model input bits,
    /// [`nanocal_model::EnvelopeFlags`]: 3 axes, 16 temperatures, 4 aux need a u32).
    pub slow_outside: u32,
    /// λ_KMZ per axis, µm.
    pub kmz_um: [f64; 3],
    /// Host lines seen.
    pub host_lines: u32,
    /// Moves corrected and forwarded.
    pub moves: u32,
    /// Moves refused.
    pub refused: u32,
    /// Replies mapped through the inverse.
    pub mapped_replies: u32,
    /// Uploads accepted.
    pub uploads_ok: u32,
    /// Uploads rejected.
    pub uploads_rejected: u32,
    /// Folds computed (slow path runs).
    pub folds: u32,
    /// Error waiting for the host's next `ERR?` (0 = none).
    pub pending_error: i32,
    /// Result code of the last rejected upload (0 = none).
    pub last_upload_error: u8,
    /// Uptime, ms.
    pub uptime_ms: u32,
    /// Chip unique ID (96 bits).
    pub uid: [u8; 12],
    /// Why the device last reset ([`crate::identity::ResetCause::code`]).
    pub reset_cause: u8,
    /// What the status LED shows ([`crate::led::LedState::code`]).
    pub led: u8,
    /// Age of the thermal fold in use, ms.
    pub fold_age_ms: u32,
    /// Flash double words that failed ECC on read since start-up.
    pub flash_ecc_errors: u32,
    /// Times a sensor was found without its configuration and reconfigured.
    pub sensor_reconfigs: u32,
    /// Auxiliary inputs in use, in their units (NaN when unusable).
    pub aux: [f32; STATUS_AUX],
    /// Per-aux status bits (as [`Status::sensor_bits`]).
    pub aux_bits: [u8; STATUS_AUX],
}

/// Auxiliary inputs in a status report.
pub const STATUS_AUX: usize = 4;

impl Status {
    /// Encoded length.
    pub const LEN: usize = 2
        + 4
        + 1
        + 4
        + 4 * STATUS_SENSORS
        + STATUS_SENSORS
        + 1
        + 4
        + 24
        + 7 * 4
        + 4
        + 1
        + 4
        + 12
        + 1
        + 1
        + 4 * 3
        + 5 * STATUS_AUX;

    /// Encode.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), FrameError> {
        w.u16(self.flags)?;
        w.u32(self.model_id)?;
        w.u8(self.slot)?;
        w.u32(self.move_fold)?;
        for t in self.temps_c {
            w.f32(t)?;
        }
        w.bytes(&self.sensor_bits)?;
        w.u8(self.sensors)?;
        w.u32(self.slow_outside)?;
        for k in self.kmz_um {
            w.f64(k)?;
        }
        for c in [
            self.host_lines,
            self.moves,
            self.refused,
            self.mapped_replies,
            self.uploads_ok,
            self.uploads_rejected,
            self.folds,
        ] {
            w.u32(c)?;
        }
        w.i32(self.pending_error)?;
        w.u8(self.last_upload_error)?;
        w.u32(self.uptime_ms)?;
        w.bytes(&self.uid)?;
        w.u8(self.reset_cause)?;
        w.u8(self.led)?;
        w.u32(self.fold_age_ms)?;
        w.u32(self.flash_ecc_errors)?;
        w.u32(self.sensor_reconfigs)?;
        for a in self.aux {
            w.f32(a)?;
        }
        w.bytes(&self.aux_bits)
    }

    /// Decode.
    pub fn decode(r: &mut Reader<'_>) -> Result<Self, FrameError> {
        let mut s = Status {
            flags: r.u16()?,
            model_id: r.u32()?,
            slot: r.u8()?,
            move_fold: r.u32()?,
            ..Default::default()
        };
        for t in s.temps_c.iter_mut() {
            *t = r.f32()?;
        }
        s.sensor_bits.copy_from_slice(r.bytes(STATUS_SENSORS)?);
        s.sensors = r.u8()?;
        s.slow_outside = r.u32()?;
        for k in s.kmz_um.iter_mut() {
            *k = r.f64()?;
        }
        s.host_lines = r.u32()?;
        s.moves = r.u32()?;
        s.refused = r.u32()?;
        s.mapped_replies = r.u32()?;
        s.uploads_ok = r.u32()?;
        s.uploads_rejected = r.u32()?;
        s.folds = r.u32()?;
        s.pending_error = r.i32()?;
        s.last_upload_error = r.u8()?;
        s.uptime_ms = r.u32()?;
        s.uid.copy_from_slice(r.bytes(12)?);
        s.reset_cause = r.u8()?;
        s.led = r.u8()?;
        s.fold_age_ms = r.u32()?;
        s.flash_ecc_errors = r.u32()?;
        s.sensor_reconfigs = r.u32()?;
        for a in s.aux.iter_mut() {
            *a = r.f32()?;
        }
        s.aux_bits.copy_from_slice(r.bytes(STATUS_AUX)?);
        Ok(s)
    }
}
