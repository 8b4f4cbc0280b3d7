//! Framing: sync, header, CRC; the byte-wise decoder; little-endian payload readers/writers.

use crate::crc32;
use crate::settings::SettingsError;
use core::fmt;

/// Frame sync bytes.
pub const SYNC: [u8; 2] = [0xA7, 0x5C];
/// Largest payload.
pub const MAX_PAYLOAD: usize = 320;
/// Bytes around the payload (sync, kind, seq, len, crc).
pub const OVERHEAD: usize = 2 + 1 + 1 + 2 + 4;
/// Largest frame on the wire.
pub const MAX_FRAME: usize = MAX_PAYLOAD + OVERHEAD;

/// Framing errors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FrameError {
    /// The frame's CRC did not match (the decoder resynchronises).
    BadCrc,
    /// The length field exceeds [`MAX_PAYLOAD`].
    TooLong,
    /// The output buffer is too small.
    OutputFull,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::BadCrc => "management frame CRC mismatch",
            FrameError::TooLong => "management frame longer than the maximum payload",
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

/// Why a payload could not be read or written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PayloadError {
    /// The payload ends before a field its kind needs.
    Short,
    /// The output buffer is too small.
    OutputFull,
    /// A field holds a code no enum of this protocol has.
    Value {
        /// The field.
        field: &'static str,
        /// Its value.
        value: u32,
    },
    /// A number that must be finite is not (NaN or infinite).
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// A text field is not UTF-8.
    Text,
    /// The settings bytes were refused.
    Settings(SettingsError),
    /// A request kind this protocol does not have.
    UnknownKind(u8),
}

impl fmt::Display for PayloadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PayloadError::Short => f.write_str("management payload too short for its kind"),
            PayloadError::OutputFull => f.write_str("output buffer too small for the payload"),
            PayloadError::Value { field, value } => {
                write!(f, "management field {field} holds unknown code {value}")
            }
            PayloadError::NotFinite { field } => {
                write!(f, "management field {field} is not a finite number")
            }
            PayloadError::Text => f.write_str("management text field is not UTF-8"),
            PayloadError::Settings(e) => write!(f, "settings: {e}"),
            PayloadError::UnknownKind(k) => write!(f, "unknown request kind {k:#04x}"),
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
    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8], PayloadError> {
        if self.b.len() < n {
            return Err(PayloadError::Short);
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
    pub fn u8(&mut self) -> Result<u8, PayloadError> {
        Ok(self.bytes(1)?[0])
    }
    /// A u16.
    pub fn u16(&mut self) -> Result<u16, PayloadError> {
        let b = self.bytes(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    /// A u32.
    pub fn u32(&mut self) -> Result<u32, PayloadError> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    /// An i32.
    pub fn i32(&mut self) -> Result<i32, PayloadError> {
        Ok(self.u32()? as i32)
    }
    /// An f32.
    pub fn f32(&mut self) -> Result<f32, PayloadError> {
        Ok(f32::from_bits(self.u32()?))
    }
    /// An f64.
    pub fn f64(&mut self) -> Result<f64, PayloadError> {
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
    pub fn bytes(&mut self, v: &[u8]) -> Result<(), PayloadError> {
        let end = self.n + v.len();
        if end > self.b.len() {
            return Err(PayloadError::OutputFull);
        }
        self.b[self.n..end].copy_from_slice(v);
        self.n = end;
        Ok(())
    }
    /// Append a u8.
    pub fn u8(&mut self, v: u8) -> Result<(), PayloadError> {
        self.bytes(&[v])
    }
    /// Append a u16.
    pub fn u16(&mut self, v: u16) -> Result<(), PayloadError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append a u32.
    pub fn u32(&mut self, v: u32) -> Result<(), PayloadError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an i32.
    pub fn i32(&mut self, v: i32) -> Result<(), PayloadError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an f32.
    pub fn f32(&mut self, v: f32) -> Result<(), PayloadError> {
        self.bytes(&v.to_le_bytes())
    }
    /// Append an f64.
    pub fn f64(&mut self, v: f64) -> Result<(), PayloadError> {
        self.bytes(&v.to_le_bytes())
    }
}
