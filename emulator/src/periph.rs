//! The buses to the outside: UART4 (RM0351 §40 "Universal synchronous asynchronous receiver
//! transmitter (USART/UART)", registers §40.8), SPI1 (§42 "Serial peripheral interface (SPI)",
//! registers §42.6), DMA1 (§11 "Direct memory access controller (DMA)", registers §11.6, request
//! map Table 44) and I2C2 (§39 "Inter-integrated circuit (I2C) interface", registers §39.7).
//! Each moves bytes at the speed its clock and settings give, and only while clocked.

use crate::io::Io;
use crate::simple::Gpio;
use std::collections::VecDeque;

const PS: u64 = 1_000_000_000_000;

// ------------------------------------------------------------------------------------ UART

/// UART4: 8N1 frames of 10 bits at the baud rate BRR gives (OVER8 = 0: baud = fck / BRR).
#[derive(Default)]
pub struct Usart {
    /// CR1, CR2, CR3.
    pub cr: [u32; 3],
    /// BRR.
    pub brr: u32,
    /// ISR flags kept by the model (PE..IDLE, RXNE, TC, TXE).
    isr: u32,
    rdr: u8,
    tdr: Option<u8>,
    /// The byte in the transmit shift register and when it is out, ps.
    shift: Option<(u8, u64)>,
    /// When the next received byte may complete (one frame after the last), ps.
    rx_free_at: u64,
    /// When the line went idle after the last received byte, for IDLE.
    idle_at: Option<u64>,
    /// Received bytes lost to an overrun (RM0351 §40.5.5: ORE, RDR keeps the old byte).
    pub overruns: u64,
    /// Baud rate in force, for the bench.
    pub baud: u64,
    /// Injected: the transmitter is stuck (the byte in the shift register never leaves).
    pub tx_stalled: bool,
}

impl Usart {
    fn frame_ps(&self, hz: u64) -> u64 {
        if self.brr == 0 || hz == 0 {
            return u64::MAX / 4;
        }
        let over8 = self.cr[0] & (1 << 15) != 0;
        let baud = if over8 {
            2 * hz / u64::from(self.brr & !0xF | ((self.brr & 7) << 1)).max(1)
        } else {
            hz / u64::from(self.brr)
        };
        10 * PS / baud.max(1)
    }

    fn enabled(&self) -> bool {
        self.cr[0] & 1 != 0
    }

    fn flags(&self) -> u32 {
        let mut f = self.isr;
        if self.tdr.is_none() {
            f |= 1 << 7; // TXE
        }
        if self.enabled() {
            if self.cr[0] & (1 << 3) != 0 {
                f |= 1 << 21; // TEACK
            }
            if self.cr[0] & (1 << 2) != 0 {
                f |= 1 << 22; // REACK
            }
        }
        if self.shift.is_some() || self.tdr.is_some() {
            f |= 1 << 16; // BUSY (approximate: transmitting)
        }
        f
    }

    /// Progress transmission and reception up to `now`.
    pub fn update(&mut self, now: u64, hz: u64, io: &mut Io) {
        if !self.enabled() {
            return;
        }
        let frame = self.frame_ps(hz);
        self.baud = (10 * PS).checked_div(frame).unwrap_or(0);
        // transmitter
        while let Some((b, done)) = self.shift {
            if now < done || self.tx_stalled {
                break;
            }
            io.uart_send(b, done);
            self.shift = self.tdr.take().map(|n| (n, done + frame));
            if self.shift.is_none() {
                self.isr |= 1 << 6; // TC
            }
        }
        // receiver: the bytes on the line arrive back to back, each one frame long
        let receiving = self.cr[0] & (1 << 2) != 0;
        while let Some(&(b, start)) = io.uart_rx.queue.front() {
            let done = start.max(self.rx_free_at) + frame;
            if done > now {
                break;
            }
            io.uart_rx.queue.pop_front();
            self.rx_free_at = done;
            if !receiving {
                continue; // RE off: the receiver ignores the line
            }
            self.idle_at = Some(done + frame);
            let lost = io.uart_rx.lose_in == Some(0);
            io.uart_rx.lose_in = match io.uart_rx.lose_in {
                Some(k) if k > 0 => Some(k - 1),
                _ => None,
            };
            if lost || self.isr & (1 << 5) != 0 {
                // RXNE still set (or the injected "CPU too slow"): the byte is lost (ORE),
                // unless overrun detection is off (CR3.OVRDIS)
                if self.cr[2] & (1 << 12) == 0 || lost {
                    self.isr |= 1 << 3;
                    self.overruns += 1;
                } else {
                    self.rdr = b;
                }
            } else {
                self.rdr = b;
                self.isr |= 1 << 5;
            }
        }
        if let Some(t) = self.idle_at {
            // IDLE: a whole idle frame after the last byte (§40.8.10)
            let next_start = io.uart_rx.queue.front().map(|q| q.1.max(self.rx_free_at));
            if now >= t && next_start.is_none_or(|s| s >= t) {
                self.isr |= 1 << 4;
                self.idle_at = None;
            } else if next_start.is_some_and(|s| s < t) {
                self.idle_at = None; // the next byte follows before the line went idle
            }
        }
    }

    /// When the next byte completes (sent or received) or the line goes idle, ps.
    pub fn next_event(&self, hz: u64, io: &Io) -> Option<u64> {
        if !self.enabled() {
            return None;
        }
        let rx = io
            .uart_rx
            .queue
            .front()
            .map(|&(_, start)| start.max(self.rx_free_at) + self.frame_ps(hz));
        let tx = self.shift.filter(|_| !self.tx_stalled).map(|s| s.1);
        [tx, self.idle_at, rx].into_iter().flatten().min()
    }

    /// The interrupt line (RXNEIE covers RXNE and ORE, §40.8.1).
    pub fn irq(&self) -> bool {
        let f = self.flags();
        let c1 = self.cr[0];
        (c1 & (1 << 5) != 0 && f & (1 << 5 | 1 << 3) != 0)
            || (c1 & (1 << 7) != 0 && f & (1 << 7) != 0)
            || (c1 & (1 << 6) != 0 && f & (1 << 6) != 0)
            || (c1 & (1 << 4) != 0 && f & (1 << 4) != 0)
    }

    /// Read a register.
    pub fn read(&mut self, off: u32, now: u64, hz: u64, io: &mut Io) -> u32 {
        self.update(now, hz, io);
        match off {
            0x00 => self.cr[0],
            0x04 => self.cr[1],
            0x08 => self.cr[2],
            0x0C => self.brr,
            0x1C => self.flags(),
            0x24 => {
                self.isr &= !(1 << 5);
                u32::from(self.rdr)
            }
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, now: u64, hz: u64, io: &mut Io) {
        self.update(now, hz, io);
        match off {
            0x00 => {
                if v & 1 == 0 {
                    // UE off: the state machines stop (§40.8.1)
                    self.shift = None;
                    self.tdr = None;
                    self.isr = 0;
                } else if self.cr[0] & 1 == 0 {
                    self.isr |= 1 << 6;
                    self.rx_free_at = now;
                }
                self.cr[0] = v;
            }
            0x04 => self.cr[1] = v,
            0x08 => self.cr[2] = v,
            0x0C => self.brr = v & 0xFFFF,
            0x18 if v & (1 << 3) != 0 => self.isr &= !(1 << 5), // RQR.RXFRQ
            0x20 => {
                // ICR: PECF 0, FECF 1, NCF 2, ORECF 3, IDLECF 4, TCCF 6
                self.isr &= !(v & 0x5F);
            }
            0x28 => {
                if !self.enabled() || self.cr[0] & (1 << 3) == 0 {
                    return;
                }
                let b = v as u8;
                self.isr &= !(1 << 6);
                if self.shift.is_none() {
                    self.shift = Some((b, now + self.frame_ps(hz)));
                } else {
                    self.tdr = Some(b);
                }
            }
            _ => {}
        }
    }
}

// ------------------------------------------------------------------------------------ SPI

/// SPI1 in master mode with 8-bit frames: 4-byte FIFOs, one byte per 8 SCK periods
/// (SCK = PCLK2 / 2^(BR+1)); the chip on the chip-select that is low answers each byte.
#[derive(Default)]
pub struct Spi {
    /// CR1.
    pub cr1: u32,
    /// CR2.
    pub cr2: u32,
    tx: VecDeque<u8>,
    rx: VecDeque<u8>,
    /// The byte being shifted and when it completes, ps.
    shift: Option<(u8, u64)>,
    byte_ps: u64,
    ovr: bool,
    /// Bytes exchanged.
    pub bytes: u64,
    /// Injected: SCK stopped, the byte in flight never completes.
    pub stalled: bool,
}

impl Spi {
    fn enabled(&self) -> bool {
        self.cr1 & (1 << 6) != 0
    }

    fn sr(&self) -> u32 {
        let mut sr = 0;
        if !self.rx.is_empty() {
            sr |= 1; // RXNE (FRXTH = 1: one byte)
        }
        if self.tx.len() <= 2 {
            sr |= 2; // TXE: FIFO at most half full
        }
        if self.ovr {
            sr |= 1 << 6;
        }
        if self.shift.is_some() || !self.tx.is_empty() {
            sr |= 1 << 7; // BSY
        }
        sr |= (self.rx.len().min(3) as u32) << 9;
        sr |= (self.tx.len().min(3) as u32) << 11;
        sr
    }

    /// DMA requests: (RX, TX) — RXDMAEN with RXNE, TXDMAEN with TXE.
    pub fn dma_requests(&self) -> (bool, bool) {
        let sr = self.sr();
        (
            self.enabled() && self.cr2 & 1 != 0 && sr & 1 != 0,
            self.enabled() && self.cr2 & 2 != 0 && sr & 2 != 0,
        )
    }

    fn start_next(&mut self, at: u64, io: &mut Io, gpio: &[Gpio]) {
        if self.shift.is_none() {
            if let Some(b) = self.tx.pop_front() {
                let _ = (io, gpio);
                self.shift = Some((b, at + self.byte_ps));
            }
        }
    }

    /// Progress the transfer up to `now`.
    pub fn update(&mut self, now: u64, io: &mut Io, gpio: &[Gpio]) {
        while let Some((b, done)) = self.shift {
            if now < done || self.stalled {
                break;
            }
            let r = io.spi_exchange(b, gpio);
            self.bytes += 1;
            if self.rx.len() >= 4 {
                self.ovr = true;
            } else {
                self.rx.push_back(r);
            }
            self.shift = None;
            self.start_next(done, io, gpio);
        }
    }

    /// When the byte in flight completes, ps.
    pub fn next_event(&self) -> Option<u64> {
        self.shift.filter(|_| !self.stalled).map(|s| s.1)
    }

    /// The interrupt line (RXNEIE, TXEIE, ERRIE with OVR).
    pub fn irq(&self) -> bool {
        let sr = self.sr();
        (self.cr2 & (1 << 6) != 0 && sr & 1 != 0)
            || (self.cr2 & (1 << 7) != 0 && sr & 2 != 0)
            || (self.cr2 & (1 << 5) != 0 && self.ovr)
    }

    /// A chip-select or clock pin changed (the bus tells the chip).
    pub fn pin_changed(&mut self, port: usize, pin: usize, level: bool, io: &mut Io) {
        io.cs_changed(port, pin, level);
    }

    /// Read a register.
    pub fn read(
        &mut self,
        off: u32,
        _lane: u32,
        _size: usize,
        now: u64,
        io: &mut Io,
        gpio: &[Gpio],
    ) -> u32 {
        self.update(now, io, gpio);
        match off {
            0x00 => self.cr1,
            0x04 => self.cr2,
            0x08 => self.sr(),
            0x0C => u32::from(self.rx.pop_front().unwrap_or(0)),
            _ => 0,
        }
    }

    /// Write a register.
    #[allow(clippy::too_many_arguments)]
    pub fn write(
        &mut self,
        off: u32,
        v: u32,
        _size: usize,
        now: u64,
        pclk2: u64,
        io: &mut Io,
        gpio: &[Gpio],
    ) {
        self.update(now, io, gpio);
        match off {
            0x00 => {
                self.cr1 = v;
                let br = (v >> 3) & 7;
                let sck = pclk2 >> (br + 1);
                self.byte_ps = (8 * PS).checked_div(sck).unwrap_or(u64::MAX / 4);
                if v & (1 << 6) == 0 {
                    self.tx.clear();
                    self.shift = None;
                }
            }
            0x04 => self.cr2 = v,
            0x08 if v & (1 << 6) == 0 => self.ovr = false,
            0x0C => {
                if !self.enabled() {
                    return;
                }
                if self.tx.len() < 4 {
                    self.tx.push_back(v as u8);
                }
                self.start_next(now, io, gpio);
            }
            _ => {}
        }
    }

    /// A DMA write to DR (one byte).
    pub fn dma_write(&mut self, b: u8, now: u64, io: &mut Io, gpio: &[Gpio]) {
        if self.enabled() && self.tx.len() < 4 {
            self.tx.push_back(b);
            self.start_next(now, io, gpio);
        }
    }

    /// A DMA read of DR.
    pub fn dma_read(&mut self) -> u8 {
        self.rx.pop_front().unwrap_or(0)
    }
}

// ------------------------------------------------------------------------------------ DMA

/// DMA1: seven channels; the request of channel x comes from the peripheral CSELR selects
/// (Table 44: channel 2 C2S = 0001 SPI1_RX, channel 3 C3S = 0001 SPI1_TX).
#[derive(Default)]
pub struct Dma {
    /// ISR flags (GIF, TCIF, HTIF, TEIF per channel, 4 bits each).
    pub isr: u32,
    /// CCR, CNDTR, CPAR, CMAR per channel.
    pub ch: [[u32; 4]; 7],
    /// CSELR.
    pub cselr: u32,
    /// Items left at the start of each channel's transfer (for HTIF).
    start_ndtr: [u32; 7],
}

/// A transfer step the board carries out with the memory it owns.
pub struct Step {
    /// Channel index (0 = channel 1).
    pub ch: usize,
    /// Memory address of this item.
    pub mem: u32,
    /// Direction: memory → peripheral.
    pub to_periph: bool,
}

impl Dma {
    /// Read a register.
    pub fn read(&self, off: u32) -> u32 {
        match off {
            0x00 => self.isr,
            0xA8 => self.cselr,
            0x08..=0x8C => {
                let (c, r) = (((off - 8) / 20) as usize, ((off - 8) % 20 / 4) as usize);
                if c < 7 && r < 4 {
                    self.ch[c][r]
                } else {
                    0
                }
            }
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32) {
        match off {
            0x04 => {
                // IFCR: clearing GIF clears all flags of the channel
                for c in 0..7 {
                    let f = (v >> (4 * c)) & 0xF;
                    let clear = if f & 1 != 0 { 0xF } else { f };
                    self.isr &= !(clear << (4 * c));
                }
            }
            0xA8 => self.cselr = v,
            0x08..=0x8C => {
                let (c, r) = (((off - 8) / 20) as usize, ((off - 8) % 20 / 4) as usize);
                if c < 7 && r < 4 {
                    if r == 0 && v & 1 != 0 && self.ch[c][0] & 1 == 0 {
                        self.start_ndtr[c] = self.ch[c][1];
                    }
                    if r != 0 && self.ch[c][0] & 1 != 0 {
                        return; // CNDTR/CPAR/CMAR are read-only while enabled
                    }
                    self.ch[c][r] = v;
                }
            }
            _ => {}
        }
    }

    /// The request line selected for channel `c` (0-based) is SPI1 RX / TX.
    pub fn selects(&self, c: usize, request: u32) -> bool {
        (self.cselr >> (4 * c)) & 0xF == request
    }

    /// The next item of channel `c` if it is enabled with items left.
    pub fn step(&self, c: usize) -> Option<Step> {
        let [ccr, ndtr, _par, mar] = self.ch[c];
        if ccr & 1 == 0 || ndtr == 0 {
            return None;
        }
        let done = self.start_ndtr[c].saturating_sub(ndtr);
        let msize = 1 << ((ccr >> 10) & 3);
        let mem = if ccr & (1 << 7) != 0 {
            mar + done * msize
        } else {
            mar
        };
        Some(Step {
            ch: c,
            mem,
            to_periph: ccr & (1 << 4) != 0,
        })
    }

    /// One item of channel `c` was moved.
    pub fn done_item(&mut self, c: usize) {
        let ndtr = self.ch[c][1].saturating_sub(1);
        self.ch[c][1] = ndtr;
        let half = self.start_ndtr[c] / 2;
        if ndtr == half {
            self.isr |= 0b0101 << (4 * c); // HTIF, GIF
        }
        if ndtr == 0 {
            self.isr |= 0b0011 << (4 * c); // TCIF, GIF
            if self.ch[c][0] & (1 << 5) != 0 {
                self.ch[c][1] = self.start_ndtr[c]; // circular
            }
        }
    }

    /// Channel `c`'s interrupt line (TCIE, HTIE, TEIE).
    pub fn irq(&self, c: usize) -> bool {
        let f = (self.isr >> (4 * c)) & 0xE;
        let ie = self.ch[c][0] & 0xE;
        f & ie != 0
    }
}

// ------------------------------------------------------------------------------------ I2C

/// I2C2 master (7-bit addresses) at the SCL rate TIMINGR gives: START, address, NBYTES data
/// bytes, AUTOEND or software STOP; NACK from an absent address (STOP follows, §39.4.8). A slave
/// holding SDA low keeps the bus BUSY: nothing progresses until nine SCL clocks driven as GPIO
/// free it (UM10204 §3.1.16 "Bus clear").
#[derive(Default)]
pub struct I2c {
    /// CR1.
    pub cr1: u32,
    /// CR2.
    pub cr2: u32,
    /// TIMINGR, TIMEOUTR, OAR1, OAR2.
    pub other: [u32; 8],
    isr: u32,
    /// The transfer in progress.
    xfer: Option<Xfer>,
    /// Bytes written since START (delivered at STOP or at a repeated START).
    wbuf: Vec<u8>,
    waddr: u8,
    rxdr: u8,
    /// SCL falling edges driven by software while SDA is held (bus recovery).
    recovery_clocks: u32,
    last_scl: Option<bool>,
}

struct Xfer {
    addr: u8,
    read: bool,
    left: u32,
    /// Bytes to hand out (read).
    data: VecDeque<u8>,
    /// When the current phase (address or byte) completes, ps.
    at: u64,
    /// Waiting for TXDR to be written.
    want_tx: bool,
}

impl I2c {
    fn byte_ps(&self) -> u64 {
        // TIMINGR: PRESC 31:28, SCLH 15:8, SCLL 7:0 in I2CCLK periods; I2CCLK = PCLK1 (80 MHz
        // here): 9 SCL periods per byte
        let t = self.other[0];
        let presc = u64::from(t >> 28) + 1;
        let period_clks = presc * (u64::from((t >> 8) & 0xFF) + 1 + u64::from(t & 0xFF) + 1);
        let ps = 9 * period_clks * PS / 80_000_000;
        ps.max(9 * PS / 1_000_000)
    }

    fn flags(&self) -> u32 {
        let mut f = self.isr;
        if self.xfer.is_some() {
            f |= 1 << 15; // BUSY
        }
        f | 1 // TXE (TXDR empty: the model takes bytes at once)
    }

    /// The event interrupt line (TXIE, RXIE, NACKIE, STOPIE, TCIE).
    pub fn irq_ev(&self) -> bool {
        let f = self.flags();
        let c = self.cr1;
        (c & 2 != 0 && f & 2 != 0)
            || (c & 4 != 0 && f & 4 != 0)
            || (c & 0x10 != 0 && f & 0x10 != 0)
            || (c & 0x20 != 0 && f & 0x20 != 0)
            || (c & 0x40 != 0 && f & 0xC0 != 0)
    }

    /// The error interrupt line (ERRIE with BERR, ARLO, OVR).
    pub fn irq_er(&self) -> bool {
        self.cr1 & 0x80 != 0 && self.isr & 0x700 != 0
    }

    /// SCL (PB10) driven as a GPIO: count the clocks of a bus recovery.
    pub fn pin_changed(&mut self, port: usize, pin: usize, level: bool, io: &mut Io) {
        if (port, pin) != (1, 10) {
            return;
        }
        if self.last_scl == Some(true) && !level {
            self.recovery_clocks += 1;
            if self.recovery_clocks >= 9 {
                io.i2c_release_sda();
                self.recovery_clocks = 0;
            }
        }
        self.last_scl = Some(level);
    }

    fn stop(&mut self, io: &mut Io) {
        if !self.wbuf.is_empty() {
            io.i2c_write(self.waddr, &self.wbuf);
            self.wbuf.clear();
        }
        self.xfer = None;
        self.isr |= 1 << 5; // STOPF
        self.isr &= !(0xC6);
    }

    /// Progress up to `now`.
    pub fn update(&mut self, now: u64, io: &mut Io) {
        let byte = self.byte_ps();
        loop {
            let Some(x) = self.xfer.as_mut() else {
                return;
            };
            if now < x.at || x.want_tx {
                return;
            }
            if x.left == 0 {
                // transfer of NBYTES done
                if self.cr2 & (1 << 25) != 0 {
                    self.stop(io);
                } else {
                    self.isr |= 1 << 6; // TC
                    x.at = u64::MAX;
                }
                return;
            }
            if x.read {
                if self.isr & 4 != 0 {
                    return; // RXNE not read yet: clock stretching
                }
                self.rxdr = x.data.pop_front().unwrap_or(0xFF);
                x.left -= 1;
                self.isr |= 4;
                x.at += byte;
            } else {
                self.isr |= 2; // TXIS
                x.want_tx = true;
            }
        }
    }

    /// When the next phase completes, ps.
    pub fn next_event(&self) -> Option<u64> {
        self.xfer
            .as_ref()
            .filter(|x| !x.want_tx && x.at != u64::MAX)
            .map(|x| x.at)
    }

    /// Read a register.
    pub fn read(&mut self, off: u32, now: u64, io: &mut Io) -> u32 {
        self.update(now, io);
        match off {
            0x00 => self.cr1,
            0x04 => self.cr2,
            0x18 => self.flags(),
            0x24 => {
                self.isr &= !4;
                u32::from(self.rxdr)
            }
            0x08..=0x14 => self.other[((off - 0x08) / 4) as usize + 2],
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, now: u64, _hz: u64, io: &mut Io) {
        self.update(now, io);
        match off {
            0x00 => {
                if v & 1 == 0 {
                    // PE off: software reset of the interface (§39.4.6)
                    self.xfer = None;
                    self.isr = 0;
                    self.wbuf.clear();
                }
                self.cr1 = v;
            }
            0x04 => {
                self.cr2 = v & !(1 << 13 | 1 << 14);
                if self.cr1 & 1 == 0 {
                    return;
                }
                if v & (1 << 13) != 0 {
                    self.start(v, now, io);
                } else if v & (1 << 14) != 0 && self.xfer.is_some() {
                    self.stop(io);
                }
            }
            0x10 => self.other[0] = v,
            0x14 => self.other[1] = v,
            0x08 => self.other[2] = v,
            0x0C => self.other[3] = v,
            0x1C => self.isr &= !(v & 0x3F38),
            0x28 => {
                let byte = self.byte_ps();
                if let Some(x) = self.xfer.as_mut() {
                    if x.want_tx {
                        self.wbuf.push(v as u8);
                        x.want_tx = false;
                        x.left -= 1;
                        x.at = now + byte;
                        self.isr &= !2;
                    }
                }
            }
            _ => {}
        }
    }

    fn start(&mut self, cr2: u32, now: u64, io: &mut Io) {
        if io.i2c_sda_held() {
            // a START cannot be generated while the bus is busy: BUSY stays set, nothing moves
            self.xfer = Some(Xfer {
                addr: 0,
                read: false,
                left: 1,
                data: VecDeque::new(),
                at: u64::MAX,
                want_tx: false,
            });
            return;
        }
        let addr = ((cr2 >> 1) & 0x7F) as u8;
        let read = cr2 & (1 << 10) != 0;
        let n = (cr2 >> 16) & 0xFF;
        // a repeated START ends the write phase: the chip gets the bytes written so far
        if !self.wbuf.is_empty() && read {
            io.i2c_write(self.waddr, &self.wbuf);
            self.wbuf.clear();
        }
        self.isr &= !(1 << 6 | 1 << 5 | 1 << 4);
        if !io.i2c_present(addr) {
            // address NACK: NACKF, then the automatic STOP (§39.4.8)
            self.isr |= 1 << 4;
            self.xfer = None;
            self.isr |= 1 << 5;
            return;
        }
        let data = if read {
            io.i2c_read(addr, n as usize).into()
        } else {
            VecDeque::new()
        };
        self.waddr = addr;
        self.xfer = Some(Xfer {
            addr,
            read,
            left: n,
            data,
            at: now + self.byte_ps(),
            want_tx: false,
        });
        let _ = self.xfer.as_ref().map(|x| x.addr);
    }
}
