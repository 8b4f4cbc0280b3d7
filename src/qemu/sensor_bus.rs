//! The sensor-bus stand-in: SPI transfers to MAX31856/MAX31865 chips carried over a UART
//! (framing in `nanocal_compensator::sensor::bus`), so the real decode and fault code runs.

use crate::app::SensorBus;
use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};
use nanocal_compensator::sensor::{bus, SensorFault, FRAME_LEN};

/// A serial port playing the SPI bus.
pub struct SerialSensorBus<R, W> {
    rx: R,
    tx: W,
    timeout: Duration,
}

impl<R: Read, W: Write> SerialSensorBus<R, W> {
    /// A bus on a serial port; a transfer not answered within `timeout` is a fault.
    pub fn new(rx: R, tx: W, timeout: Duration) -> Self {
        Self { rx, tx, timeout }
    }

    async fn read_reply(&mut self, cs: u8) -> Result<[u8; FRAME_LEN], SensorFault> {
        let mut wire = [0u8; bus::WIRE_LEN];
        let mut got = 0;
        while got < wire.len() {
            let n = self
                .rx
                .read(&mut wire[got..])
                .await
                .map_err(|_| SensorFault::NoResponse)?;
            // resynchronise on the reply start byte
            if got == 0 {
                if let Some(p) = wire[..n].iter().position(|&b| b == bus::REP) {
                    wire.copy_within(p..n, 0);
                    got = n - p;
                }
                continue;
            }
            got += n;
        }
        bus::reply(cs, &wire).ok_or(SensorFault::NoResponse)
    }
}

impl<R: Read, W: Write> SensorBus for SerialSensorBus<R, W> {
    async fn transfer(&mut self, cs: u8, frame: &mut [u8; FRAME_LEN]) -> Result<(), SensorFault> {
        let req = bus::request(cs, frame);
        self.tx
            .write_all(&req)
            .await
            .map_err(|_| SensorFault::NoResponse)?;
        match with_timeout(self.timeout, self.read_reply(cs)).await {
            Ok(Ok(f)) => {
                *frame = f;
                Ok(())
            }
            _ => Err(SensorFault::NoResponse),
        }
    }
}
