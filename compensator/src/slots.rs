//! Two-slot model storage: power loss at any moment leaves a valid model.
//!
//! Each slot holds one blob:
//! ```text
//! offset 0   magic "NCSL" | seq u32 LE | len u32 LE | crc32(blob) u32 LE   (16-byte header)
//! offset 16  blob bytes (len), padded with 0xFF to the write granularity
//! ```
//! A commit goes to the slot that does *not* hold the newest valid model: erase it, write the
//! blob, then write the header last (with `seq` = newest + 1), then read everything back. A slot
//! whose erase, body or header write was interrupted has no valid header or a CRC mismatch and
//! is ignored at start-up, so the previous model stays in service. At start-up both slots are
//! checked (header, CRC, and the caller decodes the blob) and the valid one with the newer
//! sequence number (wrapping comparison) wins.

use core::fmt;
use nanocal_model::blob;

/// Header length, bytes.
pub const HEADER_LEN: usize = 16;
/// Slot magic.
pub const MAGIC: [u8; 4] = *b"NCSL";
/// Write granularity the storage needs (STM32L4 flash: a double word).
pub const WRITE_ALIGN: usize = 8;

/// Storage failures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum StorageError {
    /// The device reported an erase/program/read error.
    Device,
    /// Offset or length outside the slot.
    OutOfBounds,
    /// The blob does not fit a slot.
    TooLarge,
    /// Read-back after writing differed from what was written.
    VerifyFailed,
}

impl fmt::Display for StorageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            StorageError::Device => "storage device error",
            StorageError::OutOfBounds => "access outside the slot",
            StorageError::TooLarge => "blob larger than a slot",
            StorageError::VerifyFailed => "read-back differs from the data written",
        })
    }
}

/// Two equal slots of erasable storage (blocking; flash programming stalls the CPU anyway).
pub trait SlotStorage {
    /// Bytes per slot.
    fn slot_size(&self) -> usize;
    /// Read `buf.len()` bytes at `offset` of `slot` (0 or 1).
    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), StorageError>;
    /// Erase a whole slot (to 0xFF).
    fn erase(&mut self, slot: usize) -> Result<(), StorageError>;
    /// Program `data` at `offset` (both multiples of [`WRITE_ALIGN`]) of an erased area.
    fn write(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), StorageError>;
}

/// A slot that holds a valid blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Active {
    /// Slot index (0 or 1).
    pub slot: usize,
    /// Sequence number of the commit.
    pub seq: u32,
    /// Blob length, bytes.
    pub len: usize,
}

/// A parsed slot header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Sequence number.
    pub seq: u32,
    /// Blob length.
    pub len: u32,
    /// CRC-32 of the blob.
    pub crc: u32,
}

impl Header {
    /// Encode.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut h = [0u8; HEADER_LEN];
        h[0..4].copy_from_slice(&MAGIC);
        h[4..8].copy_from_slice(&self.seq.to_le_bytes());
        h[8..12].copy_from_slice(&self.len.to_le_bytes());
        h[12..16].copy_from_slice(&self.crc.to_le_bytes());
        h
    }
    /// Parse; `None` for an erased or foreign header.
    pub fn parse(h: &[u8; HEADER_LEN]) -> Option<Self> {
        if h[0..4] != MAGIC {
            return None;
        }
        let w = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        Some(Self {
            seq: w(4),
            len: w(8),
            crc: w(12),
        })
    }
}

/// True when sequence `a` is newer than `b` (wrapping).
pub fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// Check one slot: read its blob into `buf` and verify length and CRC.
pub fn check_slot<S: SlotStorage>(s: &mut S, slot: usize, buf: &mut [u8]) -> Option<Active> {
    let mut h = [0u8; HEADER_LEN];
    s.read(slot, 0, &mut h).ok()?;
    let h = Header::parse(&h)?;
    let len = h.len as usize;
    if len == 0 || len > buf.len() || len > blob::MAX_BLOB_LEN || HEADER_LEN + len > s.slot_size() {
        return None;
    }
    s.read(slot, HEADER_LEN, &mut buf[..len]).ok()?;
    if blob::crc32(&buf[..len]) != h.crc {
        return None;
    }
    Some(Active {
        slot,
        seq: h.seq,
        len,
    })
}

/// Find the newest slot whose blob passes `accept` (e.g. decodes); its blob is left in
/// `buf[..len]`. `None` when neither slot holds an acceptable blob.
pub fn load_newest<S: SlotStorage>(
    s: &mut S,
    buf: &mut [u8],
    mut accept: impl FnMut(&[u8]) -> bool,
) -> Option<Active> {
    let mut best: Option<Active> = None;
    for slot in 0..2 {
        if let Some(a) = check_slot(s, slot, buf) {
            if accept(&buf[..a.len]) && best.map(|b| newer(a.seq, b.seq)).unwrap_or(true) {
                best = Some(a);
            }
        }
    }
    let b = best?;
    // the buffer holds whichever slot was checked last: re-read the winner
    check_slot(s, b.slot, buf)
}

/// Commit `blob` to the slot not holding `current` (the model in service), header last, and
/// verify by reading back. Returns the new active slot.
pub fn commit<S: SlotStorage>(
    s: &mut S,
    current: Option<Active>,
    blob_bytes: &[u8],
) -> Result<Active, StorageError> {
    let len = blob_bytes.len();
    if len == 0 || HEADER_LEN + len.div_ceil(WRITE_ALIGN) * WRITE_ALIGN > s.slot_size() {
        return Err(StorageError::TooLarge);
    }
    let (slot, seq) = match current {
        Some(a) => (1 - a.slot.min(1), a.seq.wrapping_add(1)),
        None => (0, 1),
    };
    s.erase(slot)?;
    // body: whole aligned blocks, then the padded tail
    let whole = len / WRITE_ALIGN * WRITE_ALIGN;
    if whole > 0 {
        s.write(slot, HEADER_LEN, &blob_bytes[..whole])?;
    }
    if whole < len {
        let mut tail = [0xFFu8; WRITE_ALIGN];
        tail[..len - whole].copy_from_slice(&blob_bytes[whole..]);
        s.write(slot, HEADER_LEN + whole, &tail)?;
    }
    let header = Header {
        seq,
        len: len as u32,
        crc: blob::crc32(blob_bytes),
    };
    s.write(slot, 0, &header.encode())?;
    // verify in small pieces (no second blob-sized buffer needed)
    let mut chunk = [0u8; 64];
    let mut off = 0;
    while off < len {
        let n = (len - off).min(chunk.len());
        s.read(slot, HEADER_LEN + off, &mut chunk[..n])?;
        if chunk[..n] != blob_bytes[off..off + n] {
            return Err(StorageError::VerifyFailed);
        }
        off += n;
    }
    let mut h = [0u8; HEADER_LEN];
    s.read(slot, 0, &mut h)?;
    if Header::parse(&h) != Some(header) {
        return Err(StorageError::VerifyFailed);
    }
    Ok(Active { slot, seq, len })
}

/// A RAM-backed [`SlotStorage`] with flash semantics (erase to 0xFF, programming can only clear
/// bits, aligned writes): the QEMU board's storage and the tests' power-loss simulator. With
/// `budget` set, programming stops silently after that many more bytes (a power cut).
pub struct RamFlash<const SLOT: usize> {
    /// Slot contents.
    pub slots: [[u8; SLOT]; 2],
    /// Remaining bytes that may still be programmed (`None` = unlimited).
    pub budget: Option<usize>,
}

impl<const SLOT: usize> Default for RamFlash<SLOT> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const SLOT: usize> RamFlash<SLOT> {
    /// Both slots erased.
    pub const fn new() -> Self {
        Self {
            slots: [[0xFF; SLOT]; 2],
            budget: None,
        }
    }

    fn take_budget(&mut self) -> bool {
        match &mut self.budget {
            None => true,
            Some(0) => false,
            Some(n) => {
                *n -= 1;
                true
            }
        }
    }
}

impl<const SLOT: usize> SlotStorage for RamFlash<SLOT> {
    fn slot_size(&self) -> usize {
        SLOT
    }
    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        let src = self
            .slots
            .get(slot)
            .and_then(|s| s.get(offset..offset + buf.len()))
            .ok_or(StorageError::OutOfBounds)?;
        buf.copy_from_slice(src);
        Ok(())
    }
    fn erase(&mut self, slot: usize) -> Result<(), StorageError> {
        if slot > 1 {
            return Err(StorageError::OutOfBounds);
        }
        // an interrupted erase leaves a prefix erased (each byte costs one unit of budget)
        for i in 0..SLOT {
            if !self.take_budget() {
                return Ok(());
            }
            self.slots[slot][i] = 0xFF;
        }
        Ok(())
    }
    fn write(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        if slot > 1
            || !offset.is_multiple_of(WRITE_ALIGN)
            || !data.len().is_multiple_of(WRITE_ALIGN)
        {
            return Err(StorageError::OutOfBounds);
        }
        if offset + data.len() > SLOT {
            return Err(StorageError::OutOfBounds);
        }
        for (i, &b) in data.iter().enumerate() {
            if !self.take_budget() {
                return Ok(());
            }
            self.slots[slot][offset + i] &= b;
        }
        Ok(())
    }
}

impl<S: SlotStorage + ?Sized> SlotStorage for &mut S {
    fn slot_size(&self) -> usize {
        (**self).slot_size()
    }
    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        (**self).read(slot, offset, buf)
    }
    fn erase(&mut self, slot: usize) -> Result<(), StorageError> {
        (**self).erase(slot)
    }
    fn write(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        (**self).write(slot, offset, data)
    }
}
