//! The peripheral-bus stand-in: SPI, I2C and ADC transactions carried byte-exact over a UART
//! (framing in `nanocal_compensator::wire`) to register-level chip simulations on the host.

use crate::app::InputBus;
use embedded_io_async::{Read, Write};
use nanocal_compensator::wire;

/// A serial port playing the board's buses.
pub struct SerialBus<R, W> {
    rx: R,
    tx: W,
}

impl<R: Read, W: Write> SerialBus<R, W> {
    /// A bus on a serial port (the caller bounds each transaction with a timeout).
    pub fn new(rx: R, tx: W) -> Self {
        Self { rx, tx }
    }

    async fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), ()> {
        let mut got = 0;
        while got < buf.len() {
            let n = self.rx.read(&mut buf[got..]).await.map_err(|_| ())?;
            if n == 0 {
                return Err(());
            }
            got += n;
        }
        Ok(())
    }

    /// Send a request and wait for its reply; the reply data go to `data_in`. Replies to
    /// earlier requests (that timed out) are skipped.
    async fn transact(
        &mut self,
        op: u8,
        target: u8,
        out: &[u8],
        data_in: &mut [u8],
    ) -> Result<u8, ()> {
        let mut req = [0u8; wire::HEADER + wire::MAX_DATA];
        let n = wire::request(op, target, out, data_in.len(), &mut req).ok_or(())?;
        self.tx.write_all(&req[..n]).await.map_err(|_| ())?;
        loop {
            // resynchronise on the reply start byte
            let mut h = [0u8; wire::HEADER];
            self.read_exact(&mut h[..1]).await?;
            if h[0] != wire::REP {
                continue;
            }
            self.read_exact(&mut h[1..]).await?;
            let (rop, rtarget, status, n_in) = wire::reply_header(&h).ok_or(())?;
            let mut data = [0u8; wire::MAX_DATA];
            self.read_exact(&mut data[..n_in]).await?;
            if rop == op && rtarget == target && (n_in == data_in.len() || status != wire::OK) {
                if status == wire::OK {
                    data_in.copy_from_slice(&data[..n_in]);
                }
                return Ok(status);
            }
        }
    }
}

impl<R: Read, W: Write> InputBus for SerialBus<R, W> {
    async fn spi(&mut self, cs: u8, buf: &mut [u8]) -> Result<(), ()> {
        let mut out = [0u8; wire::MAX_DATA];
        let n = buf.len().min(wire::MAX_DATA);
        out[..n].copy_from_slice(&buf[..n]);
        match self
            .transact(wire::SPI, cs, &out[..n], &mut buf[..n])
            .await?
        {
            wire::OK => Ok(()),
            _ => Err(()),
        }
    }

    async fn i2c(&mut self, addr: u8, w: &[u8], r: &mut [u8]) -> Result<(), ()> {
        match self.transact(wire::I2C, addr, w, r).await? {
            wire::OK => Ok(()),
            _ => Err(()),
        }
    }

    async fn adc(&mut self, channel: u8) -> Result<u16, ()> {
        let mut d = [0u8; 2];
        match self.transact(wire::ADC, channel, &[], &mut d).await? {
            wire::OK => Ok(u16::from_le_bytes(d)),
            _ => Err(()),
        }
    }

    fn adc_channels(&self) -> u32 {
        // the stand-in offers channels 0..4; a channel the host does not simulate times out
        0x0F
    }

    fn chip_selects(&self) -> u8 {
        // the stand-in serves every chip-select the settings can configure
        nanocal_compensator::settings::SENSORS as u8
    }
}
