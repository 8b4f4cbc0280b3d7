//! Typed requests: what the host asks, encoded and decoded in one place.

use super::frame::{encode, FrameError, PayloadError, Reader, Writer, MAX_PAYLOAD};
use super::kind::Kind;
use super::refusal::Refusal;
use crate::settings::Settings;
use nanocal_model::MAX_AXES;

/// A management request (the table in [`crate::mgmt`] has the bytes).
// No heap on the device: the settings (and the status) travel by value, not boxed.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request<'a> {
    /// Identify.
    Hello,
    /// Status report.
    Status,
    /// Start an upload of `total_len` bytes whose CRC-32 is `crc32`, blob format
    /// `format_version`.
    UploadBegin {
        /// Blob length, bytes.
        total_len: u32,
        /// CRC-32 of the whole blob ([`crate::crc32`]).
        crc32: u32,
        /// Blob format version the host announces.
        format_version: u16,
    },
    /// Upload bytes at `offset`.
    UploadChunk {
        /// Where the bytes go in the blob.
        offset: u32,
        /// The bytes.
        bytes: &'a [u8],
    },
    /// Verify, store and activate the upload.
    UploadCommit,
    /// Drop the upload.
    UploadAbort,
    /// Set λ_KMZ so the model maps the measured reference `x_meas_um` to the command
    /// `q_cmd_um` that was sent (µm, finite).
    SetKmz {
        /// Command sent, per axis, µm.
        q_cmd_um: [f64; MAX_AXES],
        /// Reference measured, per axis, µm.
        x_meas_um: [f64; MAX_AXES],
    },
    /// Bypass compensation (`true`) or compensate (`false`).
    Bypass {
        /// Bypass on.
        on: bool,
    },
    /// Read the settings.
    ConfigGet,
    /// Store and apply settings.
    ConfigSet(Settings),
    /// Reset the device (after replying).
    Reset,
    /// QEMU board only: hang (the watchdog test).
    DebugHang,
}

impl<'a> Request<'a> {
    /// The request's kind.
    pub const fn kind(&self) -> Kind {
        match self {
            Request::Hello => Kind::Hello,
            Request::Status => Kind::Status,
            Request::UploadBegin { .. } => Kind::UploadBegin,
            Request::UploadChunk { .. } => Kind::UploadChunk,
            Request::UploadCommit => Kind::UploadCommit,
            Request::UploadAbort => Kind::UploadAbort,
            Request::SetKmz { .. } => Kind::SetKmz,
            Request::Bypass { .. } => Kind::Bypass,
            Request::ConfigGet => Kind::ConfigGet,
            Request::ConfigSet(_) => Kind::ConfigSet,
            Request::Reset => Kind::Reset,
            Request::DebugHang => Kind::DebugHang,
        }
    }

    /// Encode the payload.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), PayloadError> {
        match self {
            Request::UploadBegin {
                total_len,
                crc32,
                format_version,
            } => {
                w.u32(*total_len)?;
                w.u32(*crc32)?;
                w.u16(*format_version)
            }
            Request::UploadChunk { offset, bytes } => {
                w.u32(*offset)?;
                w.bytes(bytes)
            }
            Request::SetKmz {
                q_cmd_um,
                x_meas_um,
            } => {
                for v in q_cmd_um.iter().chain(x_meas_um) {
                    w.f64(*v)?;
                }
                Ok(())
            }
            Request::Bypass { on } => w.u8(u8::from(*on)),
            Request::ConfigSet(s) => w.bytes(&s.encode()),
            Request::Hello
            | Request::Status
            | Request::UploadCommit
            | Request::UploadAbort
            | Request::ConfigGet
            | Request::Reset
            | Request::DebugHang => Ok(()),
        }
    }

    /// The whole frame with sequence number `seq` into `out`; its length.
    pub fn frame(&self, seq: u8, out: &mut [u8]) -> Result<usize, FrameError> {
        let mut payload = [0u8; MAX_PAYLOAD];
        let mut w = Writer::new(&mut payload);
        self.encode(&mut w).map_err(|_| FrameError::TooLong)?;
        let n = w.len();
        encode(self.kind().code(), seq, &payload[..n], out)
    }

    /// Decode a request of kind byte `kind` (trailing bytes after the fields are ignored,
    /// except for settings, which are the whole payload). Never panics.
    // Out of line: the firmware's management task would inline it (+650 B of STM32 flash).
    #[inline(never)]
    pub fn decode(kind: u8, payload: &'a [u8]) -> Result<Self, PayloadError> {
        let k = Kind::from_code(kind).ok_or(PayloadError::UnknownKind(kind))?;
        let mut r = Reader::new(payload);
        Ok(match k {
            Kind::Hello => Request::Hello,
            Kind::Status => Request::Status,
            Kind::UploadBegin => Request::UploadBegin {
                total_len: r.u32()?,
                crc32: r.u32()?,
                format_version: r.u16()?,
            },
            Kind::UploadChunk => Request::UploadChunk {
                offset: r.u32()?,
                bytes: r.rest(),
            },
            Kind::UploadCommit => Request::UploadCommit,
            Kind::UploadAbort => Request::UploadAbort,
            Kind::SetKmz => {
                let mut v = [0.0; 2 * MAX_AXES];
                for (i, x) in v.iter_mut().enumerate() {
                    *x = r.f64()?;
                    if !x.is_finite() {
                        let field = if i < MAX_AXES {
                            "q_cmd_um"
                        } else {
                            "x_meas_um"
                        };
                        return Err(PayloadError::NotFinite { field });
                    }
                }
                Request::SetKmz {
                    q_cmd_um: core::array::from_fn(|a| v[a]),
                    x_meas_um: core::array::from_fn(|a| v[MAX_AXES + a]),
                }
            }
            Kind::Bypass => Request::Bypass { on: r.u8()? != 0 },
            Kind::ConfigGet => Request::ConfigGet,
            Kind::ConfigSet => {
                Request::ConfigSet(Settings::decode(payload).map_err(PayloadError::Settings)?)
            }
            Kind::Reset => Request::Reset,
            Kind::DebugHang => Request::DebugHang,
        })
    }
}

impl PayloadError {
    /// The result code a device answers a request it cannot decode with.
    pub const fn refusal(&self) -> Refusal {
        match self {
            PayloadError::UnknownKind(_) => Refusal::UnknownKind,
            PayloadError::Settings(_) => Refusal::Settings,
            _ => Refusal::BadRequest,
        }
    }
}
