//! The QEMU board's stand-in for its peripheral buses: one mailbox (in the bench link's page,
//! [`crate::bench_link`]) carries byte-exact bus transactions to simulated chips on the host
//! (`nanocal::virtual_bench`), because QEMU's `mps2-an386` has no SPI controller, no I2C the
//! firmware could use and no ADC.
//!
//! ```text
//! request  (firmware → chips): A5 | op u8 | target u8 | n_out u8 | n_in u8 | n_out bytes
//! reply    (chips → firmware): 5A | op u8 | target u8 | status u8 | n_in u8 | n_in bytes
//! ```
//! - op [`BusOp::Spi`]: one chip-select-low transaction on chip-select `target`: the `n_out`
//!   bytes are clocked out on MOSI, and the reply carries the `n_in` (= `n_out`) bytes clocked
//!   in on MISO in the same clocks. A chip-select with no chip answers FFh for every byte (MISO
//!   pull-up).
//! - op [`BusOp::I2c`]: a write of `n_out` bytes to 7-bit address `target`, then (with a
//!   repeated start) a read of `n_in` bytes; status [`BusStatus::Nack`] when the address was
//!   not acknowledged.
//! - op [`BusOp::Adc`]: one conversion of ADC channel `target`: `n_in` = 2, the 12-bit code LE.
//!
//! `n_out`, `n_in` ≤ [`MAX_DATA`]. A reply of status [`BusStatus::NoAnswer`] (nothing answered:
//! a dead bus) makes the board wait for its own timeout, as a real board waits on a dead bus.

/// Request start byte.
pub const REQ: u8 = 0xA5;
/// Reply start byte.
pub const REP: u8 = 0x5A;
/// Request/reply header length.
pub const HEADER: usize = 5;
/// Longest payload either way.
pub const MAX_DATA: usize = 32;
/// Longest frame (header + data).
pub const FRAME_LEN: usize = HEADER + MAX_DATA;

code_enum! {
    /// A bus transaction's kind.
    pub enum BusOp: u8 {
        /// SPI: one chip-select-low transaction.
        Spi = 1 => "SPI transaction",
        /// I2C: write, then read with a repeated start.
        I2c = 2 => "I2C write-then-read",
        /// ADC: one conversion.
        Adc = 3 => "ADC conversion",
    }
}

code_enum! {
    /// How a transaction ended.
    pub enum BusStatus: u8 {
        /// Done: the reply carries the data read.
        Ok = 0 => "done",
        /// I2C: the address was not acknowledged.
        Nack = 1 => "I2C address not acknowledged",
        /// Nothing answered at all (the board waits for its timeout).
        NoAnswer = 0xFF => "no answer (dead bus)",
    }
}

/// Why bus bytes were refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BusError {
    /// The frame does not start with [`REQ`] / [`REP`].
    Start(u8),
    /// Unknown op code.
    Op(u8),
    /// Unknown reply status.
    Status(u8),
    /// A length above [`MAX_DATA`], or more data than the buffer holds.
    Length(usize),
}

impl core::fmt::Display for BusError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            BusError::Start(b) => write!(f, "bus frame starts with {b:#04x}"),
            BusError::Op(b) => write!(f, "unknown bus op {b}"),
            BusError::Status(b) => write!(f, "unknown bus reply status {b:#04x}"),
            BusError::Length(n) => write!(f, "bus frame data of {n} bytes does not fit"),
        }
    }
}

/// A transaction request (firmware → chips).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusRequest<'a> {
    /// What kind of transaction.
    pub op: BusOp,
    /// Chip-select, I2C address or ADC channel.
    pub target: u8,
    /// Bytes written.
    pub data_out: &'a [u8],
    /// Bytes to read.
    pub n_in: usize,
}

impl<'a> BusRequest<'a> {
    /// Encode into `out`; the frame's length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, BusError> {
        let n = self.data_out.len();
        if n > MAX_DATA || self.n_in > MAX_DATA {
            return Err(BusError::Length(n.max(self.n_in)));
        }
        if out.len() < HEADER + n {
            return Err(BusError::Length(n));
        }
        out[..HEADER].copy_from_slice(&[
            REQ,
            self.op.code(),
            self.target,
            n as u8,
            self.n_in as u8,
        ]);
        out[HEADER..HEADER + n].copy_from_slice(self.data_out);
        Ok(HEADER + n)
    }

    /// Decode a request frame (trailing bytes ignored).
    pub fn decode(b: &'a [u8]) -> Result<Self, BusError> {
        let h = header(b, REQ)?;
        let op = BusOp::from_code(h[1]).ok_or(BusError::Op(h[1]))?;
        let (n_out, n_in) = (usize::from(h[3]), usize::from(h[4]));
        if n_in > MAX_DATA {
            return Err(BusError::Length(n_in));
        }
        Ok(BusRequest {
            op,
            target: h[2],
            data_out: data(b, n_out)?,
            n_in,
        })
    }
}

/// A transaction reply (chips → firmware).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusReply<'a> {
    /// The request's op.
    pub op: BusOp,
    /// The request's target.
    pub target: u8,
    /// How it ended.
    pub status: BusStatus,
    /// Bytes read.
    pub data_in: &'a [u8],
}

impl<'a> BusReply<'a> {
    /// Encode into `out`; the frame's length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, BusError> {
        let n = self.data_in.len();
        if n > MAX_DATA || out.len() < HEADER + n {
            return Err(BusError::Length(n));
        }
        out[..HEADER].copy_from_slice(&[
            REP,
            self.op.code(),
            self.target,
            self.status.code(),
            n as u8,
        ]);
        out[HEADER..HEADER + n].copy_from_slice(self.data_in);
        Ok(HEADER + n)
    }

    /// Decode a reply frame (trailing bytes ignored).
    pub fn decode(b: &'a [u8]) -> Result<Self, BusError> {
        let h = header(b, REP)?;
        Ok(BusReply {
            op: BusOp::from_code(h[1]).ok_or(BusError::Op(h[1]))?,
            target: h[2],
            status: BusStatus::from_code(h[3]).ok_or(BusError::Status(h[3]))?,
            data_in: data(b, usize::from(h[4]))?,
        })
    }
}

fn header(b: &[u8], start: u8) -> Result<&[u8], BusError> {
    let h = b.get(..HEADER).ok_or(BusError::Length(b.len()))?;
    if h[0] != start {
        return Err(BusError::Start(h[0]));
    }
    Ok(h)
}

fn data(b: &[u8], n: usize) -> Result<&[u8], BusError> {
    if n > MAX_DATA {
        return Err(BusError::Length(n));
    }
    b.get(HEADER..HEADER + n).ok_or(BusError::Length(n))
}
