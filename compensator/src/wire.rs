//! The QEMU board's stand-in for its peripheral buses: one serial port carries byte-exact bus
//! transactions to simulated chips on the host (`nanocal::virtual_bench`), because QEMU's
//! `mps2-an386` has no SPI controller, no I2C the firmware could use and no ADC.
//!
//! ```text
//! request  (firmware → chips): A5 | op | target | n_out | n_in | n_out bytes
//! reply    (chips → firmware): 5A | op | target | status | n_in | n_in bytes
//! ```
//! - `op` [`SPI`]: one chip-select-low transaction on chip-select `target`: the `n_out` bytes are
//!   clocked out on MOSI, and the reply carries the `n_in` (= `n_out`) bytes clocked in on MISO in
//!   the same clocks. A chip-select with no chip answers FFh for every byte (MISO pull-up).
//! - `op` [`I2C`]: a write of `n_out` bytes to 7-bit address `target`, then (with a repeated
//!   start) a read of `n_in` bytes; status [`NACK`] when the address was not acknowledged.
//! - `op` [`ADC`]: one conversion of ADC channel `target`: `n_in` = 2, the 12-bit code LE.
//!
//! A reply that does not arrive in time is a dead bus (the firmware's timeout).

/// Request start byte.
pub const REQ: u8 = 0xA5;
/// Reply start byte.
pub const REP: u8 = 0x5A;
/// SPI transaction.
pub const SPI: u8 = 1;
/// I2C write-then-read.
pub const I2C: u8 = 2;
/// ADC conversion.
pub const ADC: u8 = 3;
/// Reply status: done.
pub const OK: u8 = 0;
/// Reply status: I2C address not acknowledged.
pub const NACK: u8 = 1;
/// Request/reply header length.
pub const HEADER: usize = 5;
/// Longest payload either way.
pub const MAX_DATA: usize = 32;

/// Encode a request into `out`; returns its length (`None` when the payload is too long).
pub fn request(op: u8, target: u8, data_out: &[u8], n_in: usize, out: &mut [u8]) -> Option<usize> {
    if data_out.len() > MAX_DATA || n_in > MAX_DATA || out.len() < HEADER + data_out.len() {
        return None;
    }
    out[..HEADER].copy_from_slice(&[REQ, op, target, data_out.len() as u8, n_in as u8]);
    out[HEADER..HEADER + data_out.len()].copy_from_slice(data_out);
    Some(HEADER + data_out.len())
}

/// A reply header: `(op, target, status, n_in)`; `None` when it is not a reply header.
pub fn reply_header(h: &[u8; HEADER]) -> Option<(u8, u8, u8, usize)> {
    if h[0] != REP || usize::from(h[4]) > MAX_DATA {
        return None;
    }
    Some((h[1], h[2], h[3], usize::from(h[4])))
}
