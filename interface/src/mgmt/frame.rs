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
    /// The frame was still incomplete [`FRAME_TIMEOUT_MS`] after its first byte (cut off);
    /// the decoder resynchronises on the bytes that followed it.
    Timeout,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::BadCrc => "management frame CRC mismatch",
            FrameError::TooLong => "management frame longer than the maximum payload",
            FrameError::OutputFull => "output buffer too small for the frame",
            FrameError::Timeout => "management frame incomplete when its time was up (dropped)",
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

/// How long a frame may take to arrive, from its first sync byte to its last CRC byte, ms.
///
/// The host writes a whole frame at once: the largest ([`MAX_FRAME`] bytes) takes 30 ms at
/// 115 200 baud and less than 1 ms over USB. A frame still incomplete after this long was cut
/// off (a connection closed mid-frame, bytes lost): the decoder drops it and looks for the
/// next sync in what followed, so a request sent after the cut is answered this much later
/// instead of being swallowed. A tenth of the host client's 5 s reply timeout.
pub const FRAME_TIMEOUT_MS: u32 = 500;

/// Byte-wise frame decoder. It resynchronises on the sync bytes: a frame that fails (bad CRC,
/// a length beyond [`MAX_PAYLOAD`], or [`FRAME_TIMEOUT_MS`] passed before it was complete) is
/// dropped from its first byte only, and the bytes after that byte are searched again for a
/// sync — a false sync (in garbage, or a cut frame's header) never swallows the frames that
/// follow it.
///
/// Time is an argument (ms on any clock that wraps at `u32`): the firmware passes its clock,
/// tests pass what they like.
///
/// Use: [`Decoder::feed`] each byte received, then call [`Decoder::next`] until it returns
/// `None` (one byte can complete a frame and leave bytes to look at again); when no byte
/// arrives, call [`Decoder::next`] again after [`Decoder::wait_ms`] (a frame that stopped
/// arriving is dropped then). [`Decoder::clear`] starts afresh (a new connection).
pub struct Decoder {
    /// Bytes held: a candidate frame from `buf[0]` (a sync byte), then bytes not yet looked at.
    buf: [u8; MAX_FRAME],
    /// Bytes held.
    held: usize,
    /// Bytes of the candidate checked so far (`scanned <= held`).
    scanned: usize,
    /// `buf[..frame_len]` is a complete frame not yet read past.
    ready: bool,
    /// When the candidate started (its first byte arrived, or the bytes were searched again).
    started_ms: u32,
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
            buf: [0; MAX_FRAME],
            held: 0,
            scanned: 0,
            ready: false,
            started_ms: 0,
        }
    }

    /// Forget every byte held (a new connection: nothing of the previous one carries over).
    pub fn clear(&mut self) {
        self.held = 0;
        self.scanned = 0;
        self.ready = false;
    }

    /// The connection ended at `now_ms`: a frame still arriving is dropped by the next
    /// [`Decoder::next`] as if its time were up (the bytes after its first are searched again:
    /// the next connection's may already have followed it).
    pub fn cut(&mut self, now_ms: u32) {
        if self.held > 0 && !self.ready {
            self.started_ms = now_ms.wrapping_sub(FRAME_TIMEOUT_MS);
        }
    }

    /// Feed one byte received at `now_ms`; the first event it causes, as [`Decoder::next`].
    /// Call [`Decoder::next`] until `None` before the next `feed` (events left are dropped).
    pub fn feed(&mut self, b: u8, now_ms: u32) -> Option<Result<(), FrameError>> {
        while self.ready || self.scanned < self.held {
            // the caller did not drain: what it left is dropped (room for the byte)
            let _ = self.next(now_ms);
        }
        // a candidate that timed out before this byte arrived does not take it
        let expired = self.expire(now_ms);
        if self.held == 0 {
            self.started_ms = now_ms;
        }
        // a drained candidate is shorter than its frame, so there is room
        if self.held < MAX_FRAME {
            self.buf[self.held] = b;
            self.held += 1;
        }
        if expired.is_some() {
            return expired;
        }
        self.next(now_ms)
    }

    /// The next event from the bytes held: `Some(Ok(()))` when a frame is complete (read it
    /// with [`Decoder::frame`] before calling `feed` or `next` again), `Some(Err(_))` when a
    /// frame was dropped (the decoder resynchronises: call `next` again), `None` when the
    /// bytes held are a frame still arriving (or none).
    pub fn next(&mut self, now_ms: u32) -> Option<Result<(), FrameError>> {
        if self.ready {
            self.ready = false;
            let n = self.frame_len();
            self.discard(n, now_ms);
        }
        while self.scanned < self.held {
            let i = self.scanned;
            if (i == 0 && self.buf[0] != SYNC[0]) || (i == 1 && self.buf[1] != SYNC[1]) {
                self.discard(1, now_ms);
                continue;
            }
            self.scanned += 1;
            if self.scanned == PAYLOAD_AT && self.payload_len() > MAX_PAYLOAD {
                self.discard(1, now_ms);
                return Some(Err(FrameError::TooLong));
            }
            let n = self.scanned;
            if n >= PAYLOAD_AT && n == self.frame_len() {
                let crc = u32::from_le_bytes([
                    self.buf[n - 4],
                    self.buf[n - 3],
                    self.buf[n - 2],
                    self.buf[n - 1],
                ]);
                if crc32(&self.buf[2..n - 4]) != crc {
                    self.discard(1, now_ms);
                    return Some(Err(FrameError::BadCrc));
                }
                self.ready = true;
                return Some(Ok(()));
            }
        }
        self.expire(now_ms)
    }

    /// How long until the frame still arriving is dropped, ms (0: due now); `None` when no
    /// frame is arriving.
    pub fn wait_ms(&self, now_ms: u32) -> Option<u32> {
        if self.held == 0 || self.ready {
            return None;
        }
        let age = now_ms.wrapping_sub(self.started_ms);
        Some(FRAME_TIMEOUT_MS.saturating_sub(age))
    }

    /// Drop the candidate when its time is up (all its bytes looked at, still incomplete).
    fn expire(&mut self, now_ms: u32) -> Option<Result<(), FrameError>> {
        if self.held > 0
            && !self.ready
            && self.scanned == self.held
            && self.wait_ms(now_ms) == Some(0)
        {
            self.discard(1, now_ms);
            return Some(Err(FrameError::Timeout));
        }
        None
    }

    /// Drop the first `n` bytes held and whatever follows up to the next possible sync; the
    /// rest is looked at again from its start.
    fn discard(&mut self, n: usize, now_ms: u32) {
        let n = n.min(self.held);
        let skip = self.buf[n..self.held]
            .iter()
            .position(|&b| b == SYNC[0])
            .map_or(self.held, |p| n + p);
        self.buf.copy_within(skip..self.held, 0);
        self.held -= skip;
        self.scanned = 0;
        self.started_ms = now_ms;
    }

    fn payload_len(&self) -> usize {
        if self.scanned < PAYLOAD_AT {
            return 0;
        }
        usize::from(u16::from_le_bytes([self.buf[4], self.buf[5]]))
    }

    fn frame_len(&self) -> usize {
        self.payload_len() + OVERHEAD
    }

    /// The frame completed by the last `feed` or `next` (valid until the next call of
    /// either; empty kind, seq and payload when none is complete).
    pub fn frame(&self) -> Frame<'_> {
        if !self.ready {
            return Frame {
                kind: 0,
                seq: 0,
                payload: &[],
            };
        }
        let n = self.payload_len().min(MAX_PAYLOAD);
        Frame {
            kind: self.buf[2],
            seq: self.buf[3],
            payload: &self.buf[PAYLOAD_AT..PAYLOAD_AT + n],
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
    /// Append `N` bytes known at compile time: stores of the width, where [`Self::bytes`]
    /// copies through `memcpy` (≈ 100 guest instructions a field on the firmware, whose
    /// status reply has 80-odd fields; issue 20 §5). The same bytes and errors as `bytes`.
    fn array<const N: usize>(&mut self, v: [u8; N]) -> Result<(), PayloadError> {
        let end = self.n + N;
        let out: &mut [u8; N] = self
            .b
            .get_mut(self.n..end)
            .and_then(|out| out.try_into().ok())
            .ok_or(PayloadError::OutputFull)?;
        *out = v;
        self.n = end;
        Ok(())
    }
    /// Append a u8.
    pub fn u8(&mut self, v: u8) -> Result<(), PayloadError> {
        self.array([v])
    }
    /// Append a u16.
    pub fn u16(&mut self, v: u16) -> Result<(), PayloadError> {
        self.array(v.to_le_bytes())
    }
    /// Append a u32.
    pub fn u32(&mut self, v: u32) -> Result<(), PayloadError> {
        self.array(v.to_le_bytes())
    }
    /// Append an i32.
    pub fn i32(&mut self, v: i32) -> Result<(), PayloadError> {
        self.array(v.to_le_bytes())
    }
    /// Append an f32.
    pub fn f32(&mut self, v: f32) -> Result<(), PayloadError> {
        self.array(v.to_le_bytes())
    }
    /// Append an f64.
    pub fn f64(&mut self, v: f64) -> Result<(), PayloadError> {
        self.array(v.to_le_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::{PayloadError, Writer};

    /// Every fixed-width write through `array` leaves what `bytes` of the same little-endian
    /// bytes leaves, and refuses a field that does not fit whole exactly as `bytes` does,
    /// at every fill of the buffer.
    #[test]
    fn fixed_width_fields_write_and_refuse_as_bytes_does() {
        type Put = fn(&mut Writer<'_>) -> Result<(), PayloadError>;
        let fields: [(Put, &[u8]); 6] = [
            (|w| w.u8(0xA7), &[0xA7]),
            (|w| w.u16(0xBEEF), &0xBEEFu16.to_le_bytes()),
            (|w| w.u32(0xDEAD_BEEF), &0xDEAD_BEEFu32.to_le_bytes()),
            (|w| w.i32(-5), &(-5i32).to_le_bytes()),
            (|w| w.f32(-1.25), &(-1.25f32).to_le_bytes()),
            (|w| w.f64(3.5e-7), &3.5e-7f64.to_le_bytes()),
        ];
        for (put, le) in fields {
            for room in 0..12 {
                for used in 0..=room {
                    let (mut a, mut b) = ([0x55u8; 12], [0x55u8; 12]);
                    let mut wa = Writer::new(&mut a[..room]);
                    let mut wb = Writer::new(&mut b[..room]);
                    wa.bytes(&[1; 12][..used]).unwrap();
                    wb.bytes(&[1; 12][..used]).unwrap();
                    assert_eq!(put(&mut wa), wb.bytes(le), "room {room}, used {used}");
                    assert_eq!(wa.len(), wb.len());
                    assert_eq!(a, b);
                }
            }
        }
    }
}
