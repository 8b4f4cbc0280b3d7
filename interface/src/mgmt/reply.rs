//! Typed replies: what the device answers, encoded and decoded in one place.

use super::frame::{PayloadError, Reader, Writer};
use super::kind::Kind;
use super::refusal::{InputCode, Refusal};
use crate::identity::{ResetCause, MAX_SITE, UID_LEN};
use crate::settings::Settings;
use crate::status::Status;
use nanocal_model::MAX_AXES;

/// Result byte of a reply that succeeded.
const OK: u8 = 0;

/// Longest firmware version text in `HELLO` (its length is a u8).
pub const MAX_FIRMWARE: usize = u8::MAX as usize;

/// What `HELLO` tells.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hello {
    /// Management protocol version ([`crate::mgmt::PROTOCOL`]).
    pub protocol: u16,
    /// Blob format version the firmware reads.
    pub blob_format: u16,
    /// Largest upload chunk.
    pub max_chunk: u16,
    /// Firmware version (ASCII).
    pub firmware: heapless::String<MAX_FIRMWARE>,
    /// Chip unique ID.
    pub uid: [u8; UID_LEN],
    /// Why the device last reset.
    pub reset_cause: ResetCause,
    /// Where, when the firmware recorded it (a panic's `file:line`, an address as `0x…`;
    /// [`crate::identity::Site::text`]); empty otherwise.
    pub reset_site: heapless::String<MAX_SITE>,
}

/// A management reply's payload: the result byte and what follows it (the table in
/// [`crate::mgmt`] has the bytes). Every success is the reply to one request kind; a refusal
/// can answer any.
// No heap on the device: the settings (and the status) travel by value, not boxed.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// To `HELLO`.
    Hello(Hello),
    /// To `STATUS`.
    Status(Status),
    /// To `UPLOAD_BEGIN`: ready for chunks.
    UploadBegin,
    /// To `UPLOAD_CHUNK`: bytes received so far.
    UploadChunk {
        /// Bytes received so far.
        received: u32,
    },
    /// To `UPLOAD_COMMIT`: the model is stored and in service.
    UploadCommit {
        /// Id of the model now in service.
        model_id: u32,
        /// The CRC-32 its blob carries, as the device stored it (the content hash the status
        /// reports: [`crate::status::Status::model_crc32`]).
        model_crc32: u32,
        /// Uploads accepted since start-up.
        uploads_accepted: u32,
    },
    /// To `UPLOAD_ABORT`.
    UploadAbort,
    /// To `SET_KMZ`: the new λ_KMZ.
    SetKmz {
        /// λ_KMZ per axis, µm.
        kmz_um: [f64; MAX_AXES],
        /// Whether the change was stored in flash (else it holds until the next reset).
        stored: bool,
    },
    /// To `BYPASS`.
    Bypass,
    /// To `CONFIG_GET`: the settings.
    ConfigGet(Settings),
    /// To `CONFIG_SET`: stored and applied.
    ConfigSet,
    /// To `RESET`: the device resets next.
    Reset,
    /// The request was refused.
    Refused {
        /// Why.
        refusal: Refusal,
        /// With [`Refusal::Input`]: which input and why.
        input: Option<InputCode>,
    },
}

impl Reply {
    /// A refusal without detail.
    pub const fn refused(refusal: Refusal) -> Self {
        Reply::Refused {
            refusal,
            input: None,
        }
    }

    /// Encode the payload: the result byte, then the data.
    // Out of line: the firmware's management task would inline it (+650 B of STM32 flash).
    #[inline(never)]
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), PayloadError> {
        if let Reply::Refused { refusal, input } = self {
            w.u8(refusal.code())?;
            if let Some(i) = input {
                w.u8(i.code())?;
            }
            return Ok(());
        }
        w.u8(OK)?;
        match self {
            Reply::Hello(h) => {
                w.u16(h.protocol)?;
                w.u16(h.blob_format)?;
                w.u16(h.max_chunk)?;
                w.u8(h.firmware.len() as u8)?;
                w.bytes(h.firmware.as_bytes())?;
                w.bytes(&h.uid)?;
                w.u8(h.reset_cause.code())?;
                w.u8(h.reset_site.len() as u8)?;
                w.bytes(h.reset_site.as_bytes())
            }
            Reply::Status(s) => s.encode(w),
            Reply::UploadChunk { received } => w.u32(*received),
            Reply::UploadCommit {
                model_id,
                model_crc32,
                uploads_accepted,
            } => {
                w.u32(*model_id)?;
                w.u32(*model_crc32)?;
                w.u32(*uploads_accepted)
            }
            Reply::SetKmz { kmz_um, stored } => {
                for k in kmz_um {
                    w.f64(*k)?;
                }
                w.u8(u8::from(*stored))
            }
            Reply::ConfigGet(s) => w.bytes(&s.encode()),
            Reply::UploadBegin
            | Reply::UploadAbort
            | Reply::Bypass
            | Reply::ConfigSet
            | Reply::Reset
            | Reply::Refused { .. } => Ok(()),
        }
    }

    /// Decode the payload of the reply to a request of kind `kind`. Never panics.
    pub fn decode(kind: Kind, payload: &[u8]) -> Result<Self, PayloadError> {
        let mut r = Reader::new(payload);
        let code = r.u8()?;
        if code != OK {
            let refusal = Refusal::from_code(code).ok_or(PayloadError::Value {
                field: "result",
                value: code.into(),
            })?;
            let input = match (refusal, r.u8()) {
                (Refusal::Input, Ok(b)) => {
                    Some(InputCode::from_code(b).ok_or(PayloadError::Value {
                        field: "input",
                        value: b.into(),
                    })?)
                }
                _ => None,
            };
            return Ok(Reply::Refused { refusal, input });
        }
        Ok(match kind {
            Kind::Hello => {
                let (protocol, blob_format, max_chunk) = (r.u16()?, r.u16()?, r.u16()?);
                let n = r.u8()?;
                let text = core::str::from_utf8(r.bytes(usize::from(n))?)
                    .map_err(|_| PayloadError::Text)?;
                let mut firmware = heapless::String::new();
                firmware.push_str(text).map_err(|_| PayloadError::Text)?;
                let mut uid = [0u8; UID_LEN];
                uid.copy_from_slice(r.bytes(UID_LEN)?);
                let c = r.u8()?;
                let reset_cause = ResetCause::from_code(c).ok_or(PayloadError::Value {
                    field: "reset_cause",
                    value: c.into(),
                })?;
                let n = r.u8()?;
                let text = core::str::from_utf8(r.bytes(usize::from(n))?)
                    .map_err(|_| PayloadError::Text)?;
                let mut reset_site = heapless::String::new();
                reset_site.push_str(text).map_err(|_| PayloadError::Text)?;
                Reply::Hello(Hello {
                    protocol,
                    blob_format,
                    max_chunk,
                    firmware,
                    uid,
                    reset_cause,
                    reset_site,
                })
            }
            Kind::Status => Reply::Status(Status::decode(&mut r)?),
            Kind::UploadBegin => Reply::UploadBegin,
            Kind::UploadChunk => Reply::UploadChunk { received: r.u32()? },
            Kind::UploadCommit => Reply::UploadCommit {
                model_id: r.u32()?,
                model_crc32: r.u32()?,
                uploads_accepted: r.u32()?,
            },
            Kind::UploadAbort => Reply::UploadAbort,
            Kind::SetKmz => {
                let mut kmz_um = [0.0; MAX_AXES];
                for k in kmz_um.iter_mut() {
                    *k = r.f64()?;
                }
                Reply::SetKmz {
                    kmz_um,
                    stored: r.u8()? != 0,
                }
            }
            Kind::Bypass => Reply::Bypass,
            Kind::ConfigGet => {
                Reply::ConfigGet(Settings::decode(r.rest()).map_err(PayloadError::Settings)?)
            }
            Kind::ConfigSet => Reply::ConfigSet,
            Kind::Reset => Reply::Reset,
            // the device hangs instead of answering: there is no success reply
            Kind::DebugHang => {
                return Err(PayloadError::Value {
                    field: "result",
                    value: 0,
                })
            }
        })
    }
}
