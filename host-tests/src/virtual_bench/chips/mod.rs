//! Register-level simulations of the chips on the board's buses, written from their datasheets
//! (each file cites the sections it follows). They see only what the real chip sees: chip-select
//! edges and bytes on SPI, addressed writes and reads on I2C, and time.

pub mod lps22hb;
pub mod max31856;
pub mod max31865;

pub use lps22hb::Lps22hb;
pub use max31856::Max31856;
pub use max31865::Max31865;

/// A chip on the SPI bus (mode 1/3, MSB first; one call per byte clocked).
pub trait SpiChip: Send {
    /// Chip-select falls at `now_s`: a new transaction starts (the first byte is an address).
    fn select(&mut self, now_s: f64);
    /// One byte clocked: `mosi` in, the returned byte out on MISO.
    fn exchange(&mut self, mosi: u8) -> u8;
    /// Chip-select rises at `now_s` (one-shot conversions start here).
    fn deselect(&mut self, now_s: f64);
    /// Power cycle (brown-out, hot-plug): every register back to its power-on value.
    fn power_on_reset(&mut self, now_s: f64);
    /// The concrete chip (tests change its physics through it).
    fn any_mut(&mut self) -> &mut dyn std::any::Any;
}

/// A chip on the I2C bus.
pub trait I2cChip: Send {
    /// A write of `bytes` (the first is the register address) at `now_s`.
    fn write(&mut self, bytes: &[u8], now_s: f64);
    /// A read of `out.len()` bytes from the current register address at `now_s`.
    fn read(&mut self, out: &mut [u8], now_s: f64);
    /// The concrete chip (a bench changes its physics through it).
    fn any_mut(&mut self) -> &mut dyn std::any::Any;
}
