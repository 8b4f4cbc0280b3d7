//! CMSDK APB UART (QEMU `cmsdk-apb-uart`) with interrupt-driven receive, as
//! `embedded-io-async` Read/Write halves.
//!
//! Registers: DATA 0x00, STATE 0x04 (bit0 TX full, bit1 RX full), CTRL 0x08 (bit0 TX enable,
//! bit1 RX enable, bit2 TX interrupt enable, bit3 RX interrupt enable), INTSTATUS/INTCLEAR 0x0C
//! (bit0 TX, bit1 RX), BAUDDIV 0x10. On `mps2-an386`, UART n (n = 0..=3) sits at
//! 0x4000_4000 + n·0x1000 and UART4 at 0x4000_9000, serial port n of QEMU's command line, with
//! its RX interrupt at IRQ 0, 2, 4, 18, 20 and its TX interrupt one above (QEMU
//! `hw/arm/mps2.c`). Bytes written are counted in the bench's page ([`super::link::count_tx`]).
//!
//! Both directions wait for their interrupt, never in a loop: QEMU's UART holds one byte and
//! keeps TX full while its socket takes no more (a peer that does not read: a Unix socket
//! takes ≈ 280 one-byte writes), and a writer that polled the flag with `yield_now` kept the
//! executor busy, so the board's clock stood still — no timeout of the writer could fire (the
//! management reply's `REPLY_STALL_MS`), the supervisor never ran, and QEMU's own watchdog
//! reset the board after 4 s of its clock. A bench that reads only between steps of the board's
//! clock waited for the board's time while the board waited for it to read. A waiting writer
//! is marked in the bench's page (`bench_link::TX_WAITING`): while the bench runs freely the
//! board's clock holds for it (`super::time`), so QEMU's delay in passing bytes on is no board
//! time.
//!
//! A port the bench asked for on the page's rings (`bench_link::RING_PORTS`, layout 5) reads and
//! writes its ring instead of the UART's data register, many bytes at a time: the same halves,
//! the same tasks above them. Its reader marks itself waiting in the page (`RX_ARMED`), and
//! [`ring_wake`] (the clock's idle loop) wakes it when bytes are in; its writer waits for room
//! as the UART's does (`TX_WAITING`).

use core::convert::Infallible;
use core::future::poll_fn;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Poll;
use cortex_m::peripheral::NVIC;
use embassy_sync::waitqueue::AtomicWaker;

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INTCLEAR: usize = 0x0C;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_TX_INT: u32 = 1 << 2;
const CTRL_RX_INT: u32 = 1 << 3;
const INT_TX: u32 = 1 << 0;
const INT_RX: u32 = 1 << 1;

/// UARTs the board uses.
pub const COUNT: usize = 5;
/// The UART that carries the board's doorbells to the bench and the host link's line state.
pub const BENCH: usize = 4;
/// The UART whose received bytes only end a halt: the bench's doorbells to the board
/// (`bench_link` layout 6, the *wake port*). Nothing reads it but [`wake_arm`], which drains it
/// before each halt — so a doorbell never waits behind an unread one, as it did on [`BENCH`],
/// whose bytes a task reads only when the executor runs it (not while the board halts inside a
/// task, waiting for a bus reply).
pub const WAKE: usize = 2;
const BASES: [usize; COUNT] = [
    0x4000_4000,
    0x4000_5000,
    0x4000_6000,
    0x4000_7000,
    0x4000_9000,
];
const RX_IRQS: [u16; COUNT] = [0, 2, 4, 18, 20];
/// TX interrupt of UART n: its RX interrupt + 1.
const TX_IRQ_OFFSET: u16 = 1;

static WAKERS: [AtomicWaker; COUNT] = [const { AtomicWaker::new() }; COUNT];
static TX_WAKERS: [AtomicWaker; COUNT] = [const { AtomicWaker::new() }; COUNT];

#[derive(Clone, Copy)]
struct Irq(u16);
// SAFETY: the numbers are device interrupt lines of the mps2-an386 NVIC.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

fn reg(n: usize, off: usize) -> *mut u32 {
    (BASES[n] + off) as *mut u32
}

fn read(n: usize, off: usize) -> u32 {
    // SAFETY: an MMIO register of a UART this driver owns.
    unsafe { read_volatile(reg(n, off)) }
}

fn write(n: usize, off: usize, v: u32) {
    // SAFETY: as above; 32-bit access as the peripheral expects.
    unsafe { write_volatile(reg(n, off), v) }
}

/// One UART, taken once per index.
pub struct Uart {
    n: usize,
    /// Carried by the bench's ring (`bench_link::RING_PORTS`), not the UART.
    ring: bool,
}

impl Uart {
    /// Enable UART `n` (0..=4) at `baud` (QEMU ignores the rate) and its RX and TX interrupt
    /// lines (each source stays disabled in CTRL until a reader or writer waits for it).
    ///
    /// # Safety
    /// Call at most once per `n`: the halves assume exclusive use of the registers.
    pub unsafe fn new(n: usize, baud: u32) -> Self {
        assert!(n < COUNT);
        write(n, BAUDDIV, (super::SYSCLK_HZ / baud.max(1)).max(16));
        write(n, CTRL, CTRL_TX_EN | CTRL_RX_EN);
        // SAFETY: the handler only wakes a waker; no mask-based critical section relies on it.
        unsafe {
            NVIC::unmask(Irq(RX_IRQS[n]));
            NVIC::unmask(Irq(RX_IRQS[n] + TX_IRQ_OFFSET));
        }
        let ring = super::link::ring_port(n);
        MADE.fetch_or(1 << n, Ordering::Relaxed);
        if ring {
            RING_MASK.fetch_or(1 << n, Ordering::Relaxed);
        }
        Self { n, ring }
    }

    /// Split into receive and transmit halves.
    pub fn split(self) -> (UartRx, UartTx) {
        (
            UartRx {
                n: self.n,
                ring: self.ring,
            },
            UartTx {
                n: self.n,
                ring: self.ring,
            },
        )
    }
}

/// Receive half.
pub struct UartRx {
    n: usize,
    /// Carried by the bench's ring, not the UART.
    ring: bool,
}

/// Transmit half.
pub struct UartTx {
    n: usize,
    /// Carried by the bench's ring, not the UART.
    ring: bool,
}

/// UARTs made (bit n: serial n): only theirs are looked at by [`rx_armed`] (an MMIO read each).
static MADE: AtomicU32 = AtomicU32::new(0);

/// Ports carried by rings (bit n: serial n).
static RING_MASK: AtomicU32 = AtomicU32::new(0);

/// Wake the ring ports' readers that wait and have bytes, and writers that wait and have
/// room; true if any was woken (the executor has work: the clock must not move on). Call
/// from the clock's idle loop (interrupts masked).
pub fn ring_wake() -> bool {
    let mask = RING_MASK.load(Ordering::Relaxed);
    if mask == 0 {
        return false;
    }
    let mut woke = false;
    let armed = super::link::rx_armed_mask() & mask;
    let tx_waiting = super::link::read_u32(nanocal_interface::bench_link::TX_WAITING) & mask;
    for n in 0..nanocal_interface::bench_link::RING_SERIALS {
        if armed & (1 << n) != 0 && super::link::ring_readable(n) {
            super::link::rx_armed(n, false);
            WAKERS[n].wake();
            woke = true;
        }
        if tx_waiting & (1 << n) != 0 && super::link::ring_writable(n) {
            TX_WAKERS[n].wake();
            woke = true;
        }
    }
    woke
}

/// True when a ring port's reader or writer could go on (see [`ring_wake`]), without waking
/// it: the busy wait before a halt looks at this.
pub fn ring_ready() -> bool {
    let mask = RING_MASK.load(Ordering::Relaxed);
    if mask == 0 {
        return false;
    }
    let armed = super::link::rx_armed_mask() & mask;
    let tx_waiting = super::link::read_u32(nanocal_interface::bench_link::TX_WAITING) & mask;
    (0..nanocal_interface::bench_link::RING_SERIALS).any(|n| {
        (armed & (1 << n) != 0 && super::link::ring_readable(n))
            || (tx_waiting & (1 << n) != 0 && super::link::ring_writable(n))
    })
}

/// True while a reader waits on UART `n` (its receive interrupt is armed: `read` found nothing
/// and sleeps until a byte comes). A ring port's reader is never held for here: its bytes are
/// in the ring at once ([`ring_wake`]).
pub fn rx_armed(n: usize) -> bool {
    n < COUNT
        && (MADE.load(Ordering::Relaxed) & !RING_MASK.load(Ordering::Relaxed)) & (1 << n) != 0
        && read(n, CTRL) & CTRL_RX_INT != 0
}

/// Call from `DefaultHandler`: wakes the reader of the UART whose RX line fired, the writer
/// of the one whose TX line fired (its byte went out: room for the next).
pub fn on_interrupt(irqn: i16) {
    for (n, &irq) in RX_IRQS.iter().enumerate() {
        if irqn == irq as i16 {
            // mask further RX interrupts until the reader re-arms; clear the pending one
            cortex_m::interrupt::free(|_| {
                write(n, CTRL, read(n, CTRL) & !CTRL_RX_INT);
            });
            write(n, INTCLEAR, INT_RX);
            WAKERS[n].wake();
        } else if irqn == (irq + TX_IRQ_OFFSET) as i16 {
            // the same for the writer
            cortex_m::interrupt::free(|_| {
                write(n, CTRL, read(n, CTRL) & !CTRL_TX_INT);
            });
            write(n, INTCLEAR, INT_TX);
            TX_WAKERS[n].wake();
        }
    }
}

impl embedded_io_async::ErrorType for UartRx {
    type Error = Infallible;
}

impl embedded_io_async::ErrorType for UartTx {
    type Error = Infallible;
}

impl embedded_io_async::Read for UartRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        let n = self.n;
        if self.ring {
            return poll_fn(|cx| {
                let got = super::link::ring_read(n, buf);
                if got > 0 {
                    super::link::rx_armed(n, false);
                    super::link::count_rx(n, got as u32);
                    return Poll::Ready(Ok(got));
                }
                WAKERS[n].register(cx.waker());
                super::link::rx_armed(n, true);
                super::link::barrier();
                // bytes may have come between the look and the mark
                if super::link::ring_readable(n) {
                    cx.waker().wake_by_ref();
                }
                Poll::Pending
            })
            .await;
        }
        poll_fn(|cx| {
            let mut got = 0;
            while got < buf.len() && read(n, STATE) & STATE_RX_FULL != 0 {
                buf[got] = read(n, DATA) as u8;
                got += 1;
                super::board::kick_io();
            }
            if got > 0 {
                super::link::count_rx(n, got as u32);
                return Poll::Ready(Ok(got));
            }
            WAKERS[n].register(cx.waker());
            cortex_m::interrupt::free(|_| write(n, CTRL, read(n, CTRL) | CTRL_RX_INT));
            // a byte may have arrived between the check and arming the interrupt
            if read(n, STATE) & STATE_RX_FULL != 0 {
                cx.waker().wake_by_ref();
            }
            Poll::Pending
        })
        .await
    }
}

/// The writer of a UART waits for room: marked in the bench's page while it does
/// (`bench_link::TX_WAITING`), cleared when it stops waiting — also when its write is dropped
/// (a reply given up on).
struct TxWaiting(usize);

impl TxWaiting {
    fn new(n: usize) -> Self {
        super::link::tx_waiting(n, true);
        Self(n)
    }
}

impl Drop for TxWaiting {
    fn drop(&mut self) {
        super::link::tx_waiting(self.0, false);
    }
}

impl UartTx {
    /// Wait until the UART holds no byte (QEMU handed the last one to its socket). While it
    /// does, the task sleeps until the TX interrupt (QEMU raises it when TX full clears with
    /// the interrupt enabled): the executor idles and the board's clock moves on — unless the
    /// free-running bench takes the bytes on their way (`TxWaiting`, `super::time`).
    async fn room(&self) {
        let n = self.n;
        if read(n, STATE) & STATE_TX_FULL == 0 {
            return;
        }
        let _waiting = TxWaiting::new(n);
        poll_fn(|cx| {
            if read(n, STATE) & STATE_TX_FULL == 0 {
                return Poll::Ready(());
            }
            TX_WAKERS[n].register(cx.waker());
            cortex_m::interrupt::free(|_| write(n, CTRL, read(n, CTRL) | CTRL_TX_INT));
            // the byte may have gone between the check and arming the interrupt (QEMU raises
            // it only on the transition): then disarm it, the writer goes on
            if read(n, STATE) & STATE_TX_FULL == 0 {
                cortex_m::interrupt::free(|_| write(n, CTRL, read(n, CTRL) & !CTRL_TX_INT));
                write(n, INTCLEAR, INT_TX);
                return Poll::Ready(());
            }
            Poll::Pending
        })
        .await
    }
}

impl UartTx {
    /// Put `buf` into the ring, waiting for room as the UART's writer does.
    async fn ring_write(&self, buf: &[u8]) {
        let n = self.n;
        let mut done = super::link::ring_write(n, buf);
        if done == buf.len() {
            return;
        }
        let _waiting = TxWaiting::new(n);
        poll_fn(|cx| {
            done += super::link::ring_write(n, &buf[done..]);
            if done == buf.len() {
                return Poll::Ready(());
            }
            TX_WAKERS[n].register(cx.waker());
            super::link::barrier();
            if super::link::ring_writable(n) {
                cx.waker().wake_by_ref();
            }
            Poll::Pending
        })
        .await
    }
}

impl embedded_io_async::Write for UartTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        if self.ring {
            self.ring_write(buf).await;
            return Ok(buf.len());
        }
        for &b in buf {
            self.room().await;
            write(self.n, DATA, u32::from(b));
        }
        super::link::count_tx(self.n, buf.len() as u32);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// Enable the wake port's receiver and its receive interrupt line (at boot, with the bench's
/// page; the source stays disabled in CTRL until [`wake_arm`]). The shared handler
/// ([`on_interrupt`]) disarms it again when it fires.
pub fn wake_init() {
    write(WAKE, CTRL, CTRL_RX_EN);
    // SAFETY: the handler only disarms the source and wakes a waker nobody registers.
    unsafe { NVIC::unmask(Irq(RX_IRQS[WAKE])) };
}

/// Before a halt: drain the wake port (doorbells of earlier wake-ups) and arm its receive
/// interrupt, so that the bench's next doorbell ends the halt. True if a byte came in after the
/// drain (QEMU may flag it only when the interrupt was armed at its arrival): then do not
/// halt, look again.
pub fn wake_arm() -> bool {
    let mut drained = false;
    while read(WAKE, STATE) & STATE_RX_FULL != 0 {
        let _ = read(WAKE, DATA);
        drained = true;
    }
    if drained {
        // QEMU takes the next byte from the socket when its main loop looks again
        super::board::kick_io();
    }
    write(WAKE, INTCLEAR, INT_RX);
    cortex_m::interrupt::free(|_| write(WAKE, CTRL, read(WAKE, CTRL) | CTRL_RX_INT));
    read(WAKE, STATE) & STATE_RX_FULL != 0
}

/// Send one doorbell byte to the bench on [`BENCH`] (any context; UART4's transmit side is the
/// bench's alone). QEMU takes a byte at once unless its socket is full: then a bounded wait.
pub fn ring(b: u8) {
    for _ in 0..100_000 {
        if read(BENCH, STATE) & STATE_TX_FULL == 0 {
            write(BENCH, DATA, u32::from(b));
            return;
        }
    }
}
