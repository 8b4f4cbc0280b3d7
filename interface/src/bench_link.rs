//! The QEMU board's link to its virtual bench: one page of memory shared with the host (the
//! board's PSRAM, backed by a host file) that carries the board's clock and its peripheral-bus
//! stand-in, and the doorbell bytes that say something changed in it (serial4 to the host,
//! serial2 to the board).
//!
//! **Why.** The firmware's lag filters, sample periods, timeouts and fold ages run on its own
//! clock. On the virtual bench the emulated board's time must advance with the digital twin's
//! simulated time — days in minutes — and every sample the firmware takes must see the twin's
//! temperature at that simulated instant. So the host drives the board's clock: it publishes a
//! *horizon*, and the board runs its timers up to it — jumping from one timer to the next, since
//! nothing happens in between — then waits, idle, until the host moves the horizon. Time never
//! passes while the host is busy, and a bus transaction takes no simulated time (the chip models
//! are stamped with the board's clock). The STM32 board has none of this: it runs at 1×.
//!
//! ```text
//! offset size  written by  field
//! 0x000  u32   host        MAGIC ("NCLK"): the page is present
//! 0x004  u32   host        VERSION
//! 0x008  u64   host        HORIZON: the board may advance its clock up to here (bench ticks)
//! 0x010  u64   board       NOW: the board's clock (bench ticks)
//! 0x018  u64   board       NEXT_ALARM: the board's next timer (bench ticks; u64::MAX: none)
//! 0x020  u32   board       WAITING: 1 while the board is idle at the horizon
//! 0x024  u32   board       BOOTS: incremented at every boot (the host sees resets)
//! 0x028  u64   board       BOOT_AT: bench time of the last boot (the board's uptime = NOW − BOOT_AT)
//! 0x030  u32×5 board       TX_BYTES[n]: bytes the board has written to serial n since power-on
//! 0x048  u32   host        WATCHING: 1 while the host polls this page (no doorbells needed)
//! 0x04C  u32   board       LINE_STATES: line state bytes applied, either port (the bench knows
//!                          a new session has started before it sends on it; layout 2)
//! 0x050  u32×5 board       RX_BYTES[n]: bytes the board has read from serial n since power-on
//! 0x064  u32×5 host        ANNOUNCED[n]: bytes the host has written (or is writing) to serial n,
//!                          on RX_BYTES[n]'s count; while RX_BYTES[n] is behind it and the
//!                          board's reader of serial n waits, the board's clock holds (layout 3)
//! 0x078  u32   board       TX_WAITING: bit n set while the board's writer of serial n waits for
//!                          room (QEMU's UART holds a byte its socket does not take yet) (layout 4)
//! 0x07C  u32   host        TX_HOLD: 1 while the host runs the clock freely and reads what the
//!                          board writes: the board's clock holds while TX_WAITING is not 0; 0 in
//!                          lockstep, or once a wait has made no progress for long (layout 4)
//! 0x080  u32   board       BUS_REQ_SEQ: incremented when a request is posted (after its bytes)
//! 0x084  37 B  board       BUS_REQ: the request frame (`crate::bus` layout, A5 … )
//! 0x0C0  u32   host        BUS_REP_SEQ: set to BUS_REQ_SEQ when the reply is posted (after its bytes)
//! 0x0C4  37 B  host        BUS_REP: the reply frame (`crate::bus` layout, 5A …)
//! 0x0EC  u32   host        RING_PORTS: bit n set: serial n is carried by the page's rings
//!                          instead of its UART (read by the board at boot; layout 5)
//! 0x0F0  u32   board       HALTED: 1 while the board halts (WFI) waiting for the bench: idle
//!                          at the horizon, or for a bus reply (layout 6)
//! 0x0F4  u32   board       HALTS: times the board halted waiting for the bench (a counter)
//! 0x0F8  u32   board       RX_ARMED: bit n set while the board's reader of a ring port waits
//! 0x0FC  u32   host        IDLE_SPIN: turns the board may busy-wait, idle at the horizon, for
//!                          the host's next bytes or horizon before it halts (0: halt at once;
//!                          layout 7)
//! 0x100  u32×2 ×8          RING[k] head (producer), tail (consumer), k = 2·n + d: serial n,
//!                          d = 0 host → board, d = 1 board → host
//! 0x400  1 KiB ×8          RING[k]'s bytes (index: counter mod RING_LEN)
//! ```
//!
//! **Rings (layout 5).** QEMU's CMSDK UART holds one byte: every byte into the board is a
//! hand-over between QEMU's I/O thread and its vCPU (a wake-up of the board when it sleeps),
//! every byte out is a `sendmsg` and a wake-up of the reader. The published campaign moves
//! ≈ 350 bytes a step that way (a `MOV`, an `ERR?`, the stage's copies of both, a ≈ 300-byte
//! status). A bench that sets [`RING_PORTS`] before the board boots gets those ports as byte
//! rings in this memory instead: the board reads and writes them as its UART drivers would
//! (same tasks, same proxy and management code; counted in RX_BYTES/TX_BYTES as before), and
//! it looks at them once more before a halt; the host rings [`RING_HORIZON`] only when it
//! finds the board halted ([`HALTED`]) after it wrote. Each ring has one producer and one
//! consumer: the producer writes the bytes, then (after a barrier) its head; the consumer
//! reads them, then its tail.
//! All fields little-endian. Bench ticks count [`TICK_HZ`] from the start of the bench (QEMU's
//! start), across resets of the board; the board's own `Instant` is its uptime.
//!
//! Line states (serial4, host → board): [`LINE_HOST`] | bits for the GCS host link,
//! [`LINE_MGMT`] | bits for the management port, bits as USB CDC SET_CONTROL_LINE_STATE's
//! wValue ([`LINE_DTR`], bit 1 RTS), sent whenever the bench's client opens or closes the port
//! (the USB ports' line state on the STM32 board).
//!
//! Doorbells:
//! - board → host, serial4: [`RING_WAITING`]: the board is idle at the horizon (once per
//!   instant); [`RING_BUS`]: a bus request is posted. Neither is sent while WATCHING is set:
//!   the host polls the page then, and clears WATCHING and looks once more before it stops
//!   polling.
//! - host → board, serial2, the *wake port* (layout 6; serial4 before): [`RING_HORIZON`] while
//!   the board is HALTED, after the host moved the horizon, put bytes in a ring, made room in
//!   one or posted a bus reply. The board reads nothing else from that port: it drains it and
//!   arms its receive interrupt before each halt, so a doorbell ends every halt.
//!
//! **Halts (layout 6).** The board halts (WFI) at once when it has nothing to do at the horizon
//! (after [`IDLE_SPIN`] turns, layout 7),
//! and when it waits for a bus reply nobody is there to post at once (WATCHING clear; while
//! WATCHING is set, after a short busy wait). Before, it spun 500 µs of QEMU's clock before
//! each halt and for every bus reply: those spins were 60 % of the guest instructions of a
//! campaign's step (issue 20 §5). Either halt sets HALTED, then looks once more at what it
//! waits for; the host writes what it writes, then looks at HALTED and rings if it is set.
//!
//! **Idle spin (layout 7).** A halt costs a doorbell through QEMU's I/O thread and a wake-up of
//! its vCPU — ≈ 100 µs on the 2-core machine, four of them a campaign step (the move, its
//! `ERR?`, the status, the next horizon). A bench that has given the board a core of its own
//! (the campaign's core split, `host-tests/src/virtual_bench/core_split.rs`) sets [`IDLE_SPIN`]:
//! the board, idle at the horizon, then watches its rings and the horizon for that many turns
//! before it halts, and the host's next command finds it awake. A bench without that core
//! leaves it 0: a spinning board would hold the core the bench needs.
//!
//! A bus reply carries status [`BusStatus::Ok`], [`BusStatus::Nack`], or
//! [`BusStatus::NoAnswer`]: the addressed device did not answer at all — the board then waits
//! for its own timeout, in simulated time, exactly as a real board waits on a dead bus.
//!
//! Without the page (QEMU started by hand without the memory backend) the board's clock follows
//! its SysTick (1×) and the bus answers nothing.

#[cfg(doc)]
use crate::bus::BusStatus;

/// Bench clock ticks per second (the boards' embassy tick rate, 1 MHz on both).
pub const TICK_HZ: u64 = 1_000_000;
/// Guest address of the page on `mps2-an386` (PSRAM, QEMU's machine RAM).
pub const GUEST_ADDR: usize = 0x2100_0000;
/// Size of the page, bytes.
pub const PAGE_LEN: usize = 0x100;
/// End of the whole shared area (page, ring heads and ring bytes), bytes from [`GUEST_ADDR`].
pub const SHARED_LEN: usize = RING_DATA + RINGS * RING_LEN;
/// Magic value at [`MAGIC`].
pub const MAGIC_VALUE: u32 = 0x4B4C_434E; // "NCLK"
/// Layout version at [`VERSION`].
pub const VERSION_VALUE: u32 = 7;

/// Offset of the magic.
pub const MAGIC: usize = 0x000;
/// Offset of the layout version.
pub const VERSION: usize = 0x004;
/// Offset of the horizon.
pub const HORIZON: usize = 0x008;
/// Offset of the board's clock.
pub const NOW: usize = 0x010;
/// Offset of the board's next alarm.
pub const NEXT_ALARM: usize = 0x018;
/// Offset of the waiting flag.
pub const WAITING: usize = 0x020;
/// Offset of the boot counter.
pub const BOOTS: usize = 0x024;
/// Offset of the bench time of the last boot.
pub const BOOT_AT: usize = 0x028;
/// Offset of the per-serial transmit byte counters.
pub const TX_BYTES: usize = 0x030;
/// Serial ports with a transmit counter.
pub const SERIALS: usize = 5;
/// Offset of the host's "polling the page" flag.
pub const WATCHING: usize = 0x048;
/// Offset of the count of line state bytes (GCS or management port) the board has applied.
pub const LINE_STATES: usize = 0x04C;
/// Offset of the per-serial receive byte counters (the bench knows its input was taken in).
pub const RX_BYTES: usize = 0x050;
/// Offset of the per-serial counts of bytes the host announced (see [`announced_unread`]).
pub const ANNOUNCED: usize = 0x064;
/// Offset of the mask of serial ports whose writer waits for room.
///
/// **Why.** QEMU hands each byte the board writes to its socket on its own, and a Unix socket
/// takes ≈ 280 such bytes unread: a 301-byte management reply waits for the bench to read the
/// first ones, and for QEMU's main loop to pass the rest on. A real USB CDC host reads into
/// kilobytes of buffer. The board's writer sleeps meanwhile (`src/qemu/uart.rs`). With
/// [`TX_HOLD`] set (the bench runs freely) the board's clock holds while a writer waits, as it
/// does for announced input: a loaded machine's delay in passing bytes on is no board time,
/// else the board's reply timeout (1 s, `src/app/mgmt.rs`) drops replies the bench reads. In
/// lockstep the bench moves the clock itself and clears [`TX_HOLD`]: a bench that reads only
/// between its steps would otherwise wait for the board's time while the board waited for it
/// to read; so would a free-running bench that stops reading, which is why it clears
/// [`TX_HOLD`] when a wait makes no progress for long.
pub const TX_WAITING: usize = 0x078;
/// Offset of the host's "hold the clock while a writer waits" flag (see [`TX_WAITING`]).
pub const TX_HOLD: usize = 0x07C;
/// Offset of the bus request sequence number.
pub const BUS_REQ_SEQ: usize = 0x080;
/// Offset of the bus request frame.
pub const BUS_REQ: usize = 0x084;
/// Offset of the bus reply sequence number.
pub const BUS_REP_SEQ: usize = 0x0C0;
/// Offset of the bus reply frame.
pub const BUS_REP: usize = 0x0C4;
/// Offset of the mask of serial ports carried by rings (see the module's *Rings*).
pub const RING_PORTS: usize = 0x0EC;
/// Offset of the board's "halted, waiting for the bench" flag.
pub const HALTED: usize = 0x0F0;
/// Offset of the board's count of halts.
pub const HALTS: usize = 0x0F4;
/// Offset of the mask of ring ports whose reader waits.
pub const RX_ARMED: usize = 0x0F8;
/// Offset of the turns the board may spin, idle at the horizon, before it halts (see the
/// module's *Idle spin*).
pub const IDLE_SPIN: usize = 0x0FC;
/// Offset of the rings' heads and tails: ring k's head at `RING_HEADS + 8·k`, tail 4 after.
pub const RING_HEADS: usize = 0x100;
/// Offset of the rings' bytes: ring k's at `RING_DATA + k·RING_LEN`.
pub const RING_DATA: usize = 0x400;
/// Bytes a ring holds.
pub const RING_LEN: usize = 1024;
/// Serial ports that can be carried by rings (0..RING_SERIALS).
pub const RING_SERIALS: usize = 4;
/// Rings: one each way per ring serial port.
pub const RINGS: usize = 2 * RING_SERIALS;
/// Ring of serial `port` in direction host → board.
pub const fn ring_to_board(port: usize) -> usize {
    2 * port
}
/// Ring of serial `port` in direction board → host.
pub const fn ring_to_host(port: usize) -> usize {
    2 * port + 1
}
/// Offset of ring `k`'s head (producer's count of bytes written, wrapping).
pub const fn ring_head(k: usize) -> usize {
    RING_HEADS + 8 * k
}
/// Offset of ring `k`'s tail (consumer's count of bytes read, wrapping).
pub const fn ring_tail(k: usize) -> usize {
    RING_HEADS + 8 * k + 4
}
/// Offset of byte `count` (a head or tail value) of ring `k`.
pub const fn ring_byte(k: usize, count: u32) -> usize {
    RING_DATA + k * RING_LEN + (count as usize % RING_LEN)
}
/// Bytes in a ring between `tail` and `head` (wrapping counters).
pub const fn ring_used(head: u32, tail: u32) -> usize {
    head.wrapping_sub(tail) as usize
}

/// Longest frame in the mailbox (header + data).
pub const FRAME_LEN: usize = crate::bus::FRAME_LEN;

/// Doorbell board → host: idle at the horizon.
pub const RING_WAITING: u8 = 0xE1;
/// Doorbell board → host: a bus request is posted.
pub const RING_BUS: u8 = 0xE2;
/// Doorbell host → board: the horizon moved.
pub const RING_HORIZON: u8 = 0xD1;
/// Line state host → board of the GCS host link: `LINE_HOST | bits` (low nibble).
pub const LINE_HOST: u8 = 0xC0;
/// Line state host → board of the management port: `LINE_MGMT | bits` (low nibble).
pub const LINE_MGMT: u8 = 0xB0;
/// Line-state bit: DTR (the port is open).
pub const LINE_DTR: u8 = 0x01;
/// True when the host has announced bytes on a port that the board has not read yet:
/// `announced` (ANNOUNCED\[n\]) is ahead of `rx` (RX_BYTES\[n\]), both counters wrapping.
///
/// **Why.** QEMU's UART takes one byte at a time, and only when QEMU's main loop runs; a loaded
/// host can keep that loop off the CPU for longer than the management decoder's frame timeout.
/// A board whose clock ran on meanwhile would see a frame the host wrote in one piece arrive in
/// parts half a second apart and drop it. A real USB CDC link delivers it in a millisecond.
/// So the host counts what it writes *before* writing it, and the board's clock does not pass
/// while a reader waits for announced bytes (`src/qemu/time.rs`).
pub fn announced_unread(announced: u32, rx: u32) -> bool {
    (announced.wrapping_sub(rx) as i32) > 0
}

/// Seconds of bench time of `ticks`.
pub fn ticks_to_s(ticks: u64) -> f64 {
    ticks as f64 / TICK_HZ as f64
}

/// Bench ticks of `s` seconds, rounded to the nearest tick (negative: 0).
pub fn s_to_ticks(s: f64) -> u64 {
    if s.is_finite() && s > 0.0 {
        libm::round(s * TICK_HZ as f64) as u64
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_do_not_overlap_and_fit_the_page() {
        let fields = [
            (MAGIC, 4),
            (VERSION, 4),
            (HORIZON, 8),
            (NOW, 8),
            (NEXT_ALARM, 8),
            (WAITING, 4),
            (BOOTS, 4),
            (BOOT_AT, 8),
            (TX_BYTES, 4 * SERIALS),
            (WATCHING, 4),
            (LINE_STATES, 4),
            (RX_BYTES, 4 * SERIALS),
            (ANNOUNCED, 4 * SERIALS),
            (TX_WAITING, 4),
            (TX_HOLD, 4),
            (BUS_REQ_SEQ, 4),
            (BUS_REQ, FRAME_LEN),
            (BUS_REP_SEQ, 4),
            (BUS_REP, FRAME_LEN),
            (RING_PORTS, 4),
            (HALTED, 4),
            (HALTS, 4),
            (RX_ARMED, 4),
            (IDLE_SPIN, 4),
        ];
        for (i, &(a, n)) in fields.iter().enumerate() {
            assert!(a + n <= PAGE_LEN);
            assert_eq!(a % 4, 0, "aligned");
            for &(b, m) in &fields[i + 1..] {
                assert!(a + n <= b || b + m <= a, "{a:#x} overlaps {b:#x}");
            }
        }
        assert_eq!(s_to_ticks(1.5), 1_500_000);
        assert_eq!(
            ANNOUNCED,
            RX_BYTES + 4 * SERIALS,
            "layout 3 fills the gap after RX_BYTES"
        );
        assert_eq!(
            TX_WAITING,
            ANNOUNCED + 4 * SERIALS,
            "layout 4 fills the gap after ANNOUNCED"
        );
        assert_eq!(TX_HOLD + 4, BUS_REQ_SEQ, "and ends at the bus mailbox");
        assert_eq!(
            IDLE_SPIN + 4,
            PAGE_LEN,
            "layout 7 takes the page's last word"
        );
        assert_eq!(ticks_to_s(250_000), 0.25);
        // layout 5: the rings after the page, heads before bytes, none overlapping
        assert!(ring_tail(RINGS - 1) + 4 <= RING_DATA);
        assert_eq!(ring_head(ring_to_host(3)), 0x138);
        assert_eq!(ring_byte(ring_to_board(1), 1025), 0xC01);
        assert_eq!(SHARED_LEN, 0x2400);
        assert!(
            RING_LEN.is_power_of_two(),
            "the u32 counters wrap on a multiple of it"
        );
        assert_eq!(ring_used(3, u32::MAX - 1), 5);
    }

    #[test]
    fn announced_bytes_are_unread_until_the_board_has_read_them_across_the_wrap() {
        assert!(!announced_unread(0, 0));
        assert!(announced_unread(10, 0));
        assert!(!announced_unread(10, 10));
        // the board read bytes nobody announced (another process wrote them): nothing held
        assert!(!announced_unread(10, 25));
        assert!(
            announced_unread(3, u32::MAX - 2),
            "6 bytes on, across the wrap"
        );
        assert!(!announced_unread(u32::MAX - 2, 3));
    }
}
