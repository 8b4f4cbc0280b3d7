//! The peripheral-bus stand-in: SPI, I2C and ADC transactions, byte-exact in the
//! `nanocal_compensator::wire` framing, through the mailbox of the bench's page
//! (`nanocal_compensator::bench_link`) to register-level chip simulations on the host.
//!
//! A transaction is synchronous and takes no board time: the request is posted, the bench is
//! rung, and the board waits (a short busy wait, microseconds) for the reply, which the chip
//! models computed at the board's clock. A reply of [`bl::NO_ANSWER`] (a dead bus, an unplugged
//! device on a bus without pull-ups) never completes: the caller's timeout ends it, in board time,
//! as on the real board. Without the page nothing answers.

use super::{link, uart};
use crate::app::InputBus;
use nanocal_compensator::bench_link as bl;
use nanocal_compensator::wire;

/// The bus stand-in of the bench's mailbox.
pub struct MailboxBus {
    seq: u32,
}

impl Default for MailboxBus {
    fn default() -> Self {
        Self::new()
    }
}

impl MailboxBus {
    /// The mailbox (continues the sequence numbers left by an earlier boot).
    pub fn new() -> Self {
        Self {
            seq: link::read_u32(bl::BUS_REQ_SEQ),
        }
    }

    /// Send a request and wait for its reply; the reply data go to `data_in`.
    async fn transact(
        &mut self,
        op: u8,
        target: u8,
        out: &[u8],
        data_in: &mut [u8],
    ) -> Result<u8, ()> {
        if !super::time::linked() {
            return core::future::pending().await;
        }
        let mut req = [0u8; bl::FRAME_LEN];
        let n = wire::request(op, target, out, data_in.len(), &mut req).ok_or(())?;
        for (i, &b) in req[..n].iter().enumerate() {
            link::write_u8(bl::BUS_REQ + i, b);
        }
        self.seq = self.seq.wrapping_add(1);
        link::barrier();
        link::write_u32(bl::BUS_REQ_SEQ, self.seq);
        link::barrier();
        if link::read_u32(bl::WATCHING) == 0 {
            uart::ring(bl::RING_BUS);
        }
        while link::read_u32(bl::BUS_REP_SEQ) != self.seq {
            core::hint::spin_loop();
        }
        link::barrier();
        let mut h = [0u8; wire::HEADER];
        for (i, b) in h.iter_mut().enumerate() {
            *b = link::read_u8(bl::BUS_REP + i);
        }
        if h[3] == bl::NO_ANSWER {
            return core::future::pending().await;
        }
        let (rop, rtarget, status, n_in) = wire::reply_header(&h).ok_or(())?;
        if rop != op || rtarget != target {
            return Err(());
        }
        if status == wire::OK {
            if n_in != data_in.len() {
                return Err(());
            }
            for (i, b) in data_in.iter_mut().enumerate() {
                *b = link::read_u8(bl::BUS_REP + wire::HEADER + i);
            }
        }
        Ok(status)
    }
}

impl InputBus for MailboxBus {
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
        // the stand-in offers channels 0..4; a channel the host does not simulate does not answer
        0x0F
    }

    fn chip_selects(&self) -> u8 {
        // the stand-in serves every chip-select the settings can configure
        nanocal_compensator::settings::SENSORS as u8
    }
}
