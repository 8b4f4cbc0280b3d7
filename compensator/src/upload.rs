//! Chunked model upload: the state machine the management channel drives.
//!
//! `begin(total_len, crc32, format_version)` → `chunk(offset, bytes)`… in order (a repeated
//! chunk with identical bytes is acknowledged again, so the host may retry) → `finish`, which
//! verifies the length, the whole-blob CRC-32 and decodes the blob completely in RAM (the
//! decoder checks magic, format version, its own CRC and every field). Only a model that passed
//! all of that is returned; any failure leaves the model in service untouched.

use core::fmt;
use nanocal_interface::mgmt::Refusal;
use nanocal_model::blob::{self, BlobError};
use nanocal_model::Model;

/// Why an upload step was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum UploadError {
    /// A chunk or finish arrived without a `begin`.
    NotStarted,
    /// The host announced a blob format this firmware does not read.
    VersionMismatch {
        /// Version the host announced.
        found: u16,
        /// Version this firmware reads.
        expected: u16,
    },
    /// The announced length is zero or larger than the receive buffer.
    BadLength {
        /// Announced length.
        len: u32,
        /// Largest accepted length.
        max: u32,
    },
    /// A chunk did not start where the previous one ended.
    OutOfOrder {
        /// Offset expected next.
        expected: u32,
        /// Offset received.
        found: u32,
    },
    /// A chunk would run past the announced length.
    Overrun,
    /// A repeated chunk differs from what was received before at that offset.
    ChunkMismatch,
    /// `finish` before all bytes arrived.
    Incomplete {
        /// Bytes announced.
        expected: u32,
        /// Bytes received.
        received: u32,
    },
    /// The whole-blob CRC-32 differs from the announced one.
    CrcMismatch {
        /// CRC announced by the host.
        expected: u32,
        /// CRC computed over the received bytes.
        computed: u32,
    },
    /// The blob itself is invalid.
    Blob(BlobError),
}

impl fmt::Display for UploadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UploadError::NotStarted => f.write_str("upload step without a begin"),
            UploadError::VersionMismatch { found, expected } => write!(
                f,
                "blob format version {found} announced, this firmware reads {expected}"
            ),
            UploadError::BadLength { len, max } => {
                write!(f, "announced length {len} bytes, expected 1..={max}")
            }
            UploadError::OutOfOrder { expected, found } => {
                write!(f, "chunk at offset {found}, expected offset {expected}")
            }
            UploadError::Overrun => f.write_str("chunk runs past the announced length"),
            UploadError::ChunkMismatch => {
                f.write_str("repeated chunk differs from the bytes received before")
            }
            UploadError::Incomplete { expected, received } => {
                write!(f, "finish after {received} of {expected} bytes")
            }
            UploadError::CrcMismatch { expected, computed } => write!(
                f,
                "CRC-32 {computed:#010x} computed, {expected:#010x} announced"
            ),
            UploadError::Blob(e) => write!(f, "invalid blob: {e}"),
        }
    }
}

impl UploadError {
    /// The management protocol's result code for it.
    pub fn code(&self) -> Refusal {
        match self {
            UploadError::NotStarted => Refusal::UploadNotStarted,
            UploadError::VersionMismatch { .. } => Refusal::UploadVersion,
            UploadError::BadLength { .. } => Refusal::UploadLength,
            UploadError::OutOfOrder { .. } => Refusal::UploadOutOfOrder,
            UploadError::Overrun => Refusal::UploadOverrun,
            UploadError::ChunkMismatch => Refusal::UploadChunkMismatch,
            UploadError::Incomplete { .. } => Refusal::UploadIncomplete,
            UploadError::CrcMismatch { .. } => Refusal::UploadCrc,
            UploadError::Blob(_) => Refusal::UploadBlob,
        }
    }
}

/// Upload progress; the bytes live in a caller-provided buffer.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Upload {
    active: bool,
    total: u32,
    crc: u32,
    received: u32,
}

impl Upload {
    /// No upload in progress.
    pub const fn new() -> Self {
        Self {
            active: false,
            total: 0,
            crc: 0,
            received: 0,
        }
    }

    /// True while an upload is in progress.
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Bytes received so far.
    pub fn received(&self) -> u32 {
        self.received
    }

    /// Start an upload of `total_len` bytes with whole-blob CRC `crc32` into a buffer of
    /// `capacity` bytes. A previous unfinished upload is dropped.
    pub fn begin(
        &mut self,
        total_len: u32,
        crc32: u32,
        format_version: u16,
        capacity: usize,
    ) -> Result<(), UploadError> {
        self.active = false;
        if format_version != blob::FORMAT_VERSION {
            return Err(UploadError::VersionMismatch {
                found: format_version,
                expected: blob::FORMAT_VERSION,
            });
        }
        let max = capacity.min(blob::MAX_BLOB_LEN) as u32;
        if total_len == 0 || total_len > max {
            return Err(UploadError::BadLength {
                len: total_len,
                max,
            });
        }
        *self = Self {
            active: true,
            total: total_len,
            crc: crc32,
            received: 0,
        };
        Ok(())
    }

    /// Store a chunk; returns the bytes received so far.
    pub fn chunk(&mut self, buf: &mut [u8], offset: u32, data: &[u8]) -> Result<u32, UploadError> {
        if !self.active {
            return Err(UploadError::NotStarted);
        }
        let end = u64::from(offset) + data.len() as u64;
        if end > u64::from(self.total) || end > buf.len() as u64 {
            return Err(UploadError::Overrun);
        }
        let (o, e) = (offset as usize, end as usize);
        if offset == self.received {
            buf[o..e].copy_from_slice(data);
            self.received = end as u32;
            Ok(self.received)
        } else if end <= u64::from(self.received) {
            // a retransmission of something already stored
            if &buf[o..e] == data {
                Ok(self.received)
            } else {
                Err(UploadError::ChunkMismatch)
            }
        } else {
            Err(UploadError::OutOfOrder {
                expected: self.received,
                found: offset,
            })
        }
    }

    /// Verify everything and decode. The upload ends either way. On success returns the model
    /// and the blob's length (the blob is `buf[..len]`, ready to be committed to storage).
    pub fn finish(&mut self, buf: &[u8]) -> Result<(Model, usize), UploadError> {
        if !self.active {
            return Err(UploadError::NotStarted);
        }
        self.active = false;
        if self.received != self.total {
            return Err(UploadError::Incomplete {
                expected: self.total,
                received: self.received,
            });
        }
        let bytes = &buf[..self.total as usize];
        let computed = nanocal_interface::crc32(bytes);
        if computed != self.crc {
            return Err(UploadError::CrcMismatch {
                expected: self.crc,
                computed,
            });
        }
        let model = blob::decode(bytes).map_err(UploadError::Blob)?;
        Ok((model, bytes.len()))
    }

    /// Drop the upload in progress.
    pub fn abort(&mut self) {
        self.active = false;
    }
}
