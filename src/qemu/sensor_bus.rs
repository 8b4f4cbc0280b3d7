//! The peripheral-bus stand-in: SPI, I2C and ADC transactions, byte-exact in the
//! `nanocal_interface::bus` framing, through the mailbox of the bench's page
//! (`nanocal_interface::bench_link`) to register-level chip simulations on the host.
//!
//! A transaction is synchronous and takes no board time: the request is posted, the bench is
//! rung (unless it watches the page), and the board waits for the reply — a short busy wait
//! while the bench watches, else halted until the bench rings — which the chip models computed
//! at the board's clock. A reply of [`BusStatus::NoAnswer`] (a dead bus, an unplugged
//! device on a bus without pull-ups) never completes: the caller's timeout ends it, in board time,
//! as on the real board. Without the page nothing answers.

use super::{link, uart};
use crate::app::InputBus;
use nanocal_interface::bench_link as bl;
use nanocal_interface::bus::{self, BusOp, BusReply, BusRequest, BusStatus};

/// Turns of the busy wait for a reply while the bench watches the page (a few guest
/// instructions each: ≈ 10 µs of QEMU's time, more than a watching bench takes to answer).
const WATCHED_REPLY_TURNS: u32 = 2_000;

/// The bus stand-in of the bench's mailbox.
pub struct MailboxBus {
    seq: u32,
    /// The request, then the reply, as they cross the page (kept between transactions: a
    /// fresh zeroed frame each way, and the SPI data copied once more for the request, were a
    /// third of a transaction's own guest instructions; issue 20 §5).
    frame: [u8; bl::FRAME_LEN],
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
            frame: [0; bl::FRAME_LEN],
        }
    }

    /// The bench has posted the reply to the newest request.
    fn replied(&self) -> bool {
        link::read_u32(bl::BUS_REP_SEQ) == self.seq
    }

    /// Wait for the reply to the newest request: a short busy wait when the bench watches the
    /// page (its answer takes microseconds), then a halt until the bench rings — at once when
    /// nobody watches (the bench's doorbell reader answers, then rings a halted board). The
    /// busy wait for every reply was 17 % of the guest instructions of a campaign's step, most
    /// of it for requests answered through a doorbell (issue 20 §5).
    fn wait_reply(&self, watched: bool) {
        if watched {
            for _ in 0..WATCHED_REPLY_TURNS {
                if self.replied() {
                    return;
                }
                core::hint::spin_loop();
            }
        }
        while !self.replied() {
            // the bench posts the reply, then rings if it finds the board halted; a halt
            // that ends for another interrupt looks again
            link::halt(|| self.replied(), false);
        }
    }

    /// Send a request and wait for its reply. With [`BusStatus::Ok`] the reply's `n_in` bytes
    /// are [`Self::reply_data`].
    async fn transact(
        &mut self,
        op: BusOp,
        target: u8,
        data_out: &[u8],
        n_in: usize,
    ) -> Result<BusStatus, ()> {
        if !super::time::linked() {
            return core::future::pending().await;
        }
        let request = BusRequest {
            op,
            target,
            data_out,
            n_in,
        };
        let n = request.encode(&mut self.frame).map_err(|_| ())?;
        link::write_bytes(bl::BUS_REQ, &self.frame[..n]);
        self.seq = self.seq.wrapping_add(1);
        link::barrier();
        link::write_u32(bl::BUS_REQ_SEQ, self.seq);
        link::barrier();
        let watched = link::read_u32(bl::WATCHING) != 0;
        if !watched {
            uart::ring(bl::RING_BUS);
        }
        self.wait_reply(watched);
        link::barrier();
        let n_rep = self.read_reply();
        let reply = BusReply::decode(&self.frame[..bus::HEADER + n_rep]).map_err(|_| ())?;
        if reply.status == BusStatus::NoAnswer {
            return core::future::pending().await;
        }
        if reply.op != op || reply.target != target {
            return Err(());
        }
        if reply.status == BusStatus::Ok && reply.data_in.len() != n_in {
            return Err(());
        }
        Ok(reply.status)
    }

    /// Read the posted reply into the frame: its header, then only the data bytes it announces
    /// (at most [`bus::MAX_DATA`]: a longer count is left for the decoder to refuse, as it was
    /// when the whole frame was read); the count of data bytes read.
    fn read_reply(&mut self) -> usize {
        // the first two words: the header and the first data bytes
        const FIRST: usize = 8;
        const _: () = assert!(bus::HEADER <= FIRST && FIRST <= bl::FRAME_LEN);
        link::read_bytes(bl::BUS_REP, &mut self.frame[..FIRST]);
        let n = usize::from(self.frame[bus::HEADER - 1]).min(bus::MAX_DATA);
        let end = bus::HEADER + n;
        if end > FIRST {
            link::read_bytes(bl::BUS_REP + FIRST, &mut self.frame[FIRST..end]);
        }
        n
    }

    /// The data of the last reply, `n` bytes (as [`Self::transact`] checked).
    fn reply_data(&self, n: usize) -> &[u8] {
        &self.frame[bus::HEADER..bus::HEADER + n]
    }
}

impl InputBus for MailboxBus {
    async fn spi(&mut self, cs: u8, buf: &mut [u8]) -> Result<(), ()> {
        let n = buf.len().min(bus::MAX_DATA);
        match self.transact(BusOp::Spi, cs, &buf[..n], n).await? {
            BusStatus::Ok => {
                buf[..n].copy_from_slice(self.reply_data(n));
                Ok(())
            }
            _ => Err(()),
        }
    }

    async fn i2c(&mut self, addr: u8, w: &[u8], r: &mut [u8]) -> Result<(), ()> {
        match self.transact(BusOp::I2c, addr, w, r.len()).await? {
            BusStatus::Ok => {
                r.copy_from_slice(self.reply_data(r.len()));
                Ok(())
            }
            _ => Err(()),
        }
    }

    async fn adc(&mut self, channel: u8) -> Result<u16, ()> {
        match self.transact(BusOp::Adc, channel, &[], 2).await? {
            BusStatus::Ok => {
                let d = self.reply_data(2);
                Ok(u16::from_le_bytes([d[0], d[1]]))
            }
            _ => Err(()),
        }
    }

    fn adc_channels(&self) -> u32 {
        // the stand-in offers channels 0..4; a channel the host does not simulate does not answer
        0x0F
    }

    fn chip_selects(&self) -> u8 {
        // the stand-in serves every chip-select the settings can configure
        nanocal_interface::settings::SENSORS as u8
    }
}
