//! The board's side of its link to the virtual bench: the page shared with the host
//! (`nanocal_interface::bench_link` has the layout and the why) and the doorbell on serial4.

use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{fence, Ordering};
use nanocal_interface::bench_link as bl;

fn at<T>(off: usize) -> *mut T {
    (bl::GUEST_ADDR + off) as *mut T
}

/// Read a u32 field.
pub fn read_u32(off: usize) -> u32 {
    // SAFETY: an aligned word of the PSRAM page; plain memory (shared with the host).
    unsafe { read_volatile(at::<u32>(off)) }
}

/// Write a u32 field.
pub fn write_u32(off: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(at::<u32>(off), v) }
}

/// Read a u64 field (two words, low first: the host writes the horizon only while the board
/// cannot be reading it in a torn state — it writes it with one 8-byte store, and the board's
/// reads of the page are word reads of memory; a torn read is retried).
pub fn read_u64(off: usize) -> u64 {
    loop {
        let hi = read_u32(off + 4);
        let lo = read_u32(off);
        if hi == read_u32(off + 4) {
            return (u64::from(hi) << 32) | u64::from(lo);
        }
    }
}

/// Write a u64 field (high word last, so a reader that checks the high word twice sees it whole).
pub fn write_u64(off: usize, v: u64) {
    write_u32(off, v as u32);
    write_u32(off + 4, (v >> 32) as u32);
}

/// Read a byte of the page.
pub fn read_u8(off: usize) -> u8 {
    // SAFETY: a byte of the PSRAM page.
    unsafe { read_volatile(at::<u8>(off)) }
}

/// Write a byte of the page.
pub fn write_u8(off: usize, v: u8) {
    // SAFETY: as above.
    unsafe { write_volatile(at::<u8>(off), v) }
}

/// Copy `bytes` into the page from `off` (a multiple of 4): a word store per four bytes, then
/// the last bytes one by one — nothing past `bytes` is written. The bus mailbox's frames went
/// a byte at a time, ≈ 5 guest instructions a byte, and 86 a campaign step (issue 20 §5).
pub fn write_bytes(off: usize, bytes: &[u8]) {
    debug_assert_eq!(off % 4, 0);
    let mut words = bytes.chunks_exact(4);
    let mut o = off;
    for w in &mut words {
        write_u32(o, u32::from_le_bytes([w[0], w[1], w[2], w[3]]));
        o += 4;
    }
    for &b in words.remainder() {
        write_u8(o, b);
        o += 1;
    }
}

/// Fill `out` from the page from `off` (a multiple of 4), a word load per four bytes (the
/// counterpart of [`write_bytes`]; nothing past `out`'s length is read).
pub fn read_bytes(off: usize, out: &mut [u8]) {
    debug_assert_eq!(off % 4, 0);
    let mut words = out.chunks_exact_mut(4);
    let mut o = off;
    for w in &mut words {
        w.copy_from_slice(&read_u32(o).to_le_bytes());
        o += 4;
    }
    for b in words.into_remainder() {
        *b = read_u8(o);
        o += 1;
    }
}

/// Order this side's writes before the next ones (DMB: QEMU makes it a host fence).
pub fn barrier() {
    fence(Ordering::SeqCst);
    cortex_m::asm::dmb();
}

/// Halt (WFI) until the bench rings the wake port, unless `ready` (what the board waits for)
/// holds: mark the halt in the page (`bench_link::HALTED`), then look once more — the bench
/// writes what it writes, then looks at the mark and rings. Any interrupt ends the halt; the
/// caller looks again. The CMSDK watchdog (QEMU's clock) is paused over the halt when
/// `pause_watchdog` (the idle loop: the bench may take seconds, e.g. fitting a model).
pub fn halt(ready: impl Fn() -> bool, pause_watchdog: bool) {
    let in_already = super::uart::wake_arm();
    write_u32(bl::HALTED, 1);
    barrier();
    if !in_already && !ready() {
        write_u32(bl::HALTS, read_u32(bl::HALTS).wrapping_add(1));
        if pause_watchdog {
            super::board::watchdog_pause();
        }
        cortex_m::asm::wfi();
        if pause_watchdog {
            super::board::watchdog_resume();
        }
    }
    write_u32(bl::HALTED, 0);
}

/// Busy-wait up to `turns` turns for `ready`; whether it came. No `YIELD` in the loop: QEMU
/// runs a `YIELD` of a one-CPU board as an exit of its execution loop, which would make each
/// turn cost as much as a short halt.
pub fn spin_until(turns: u32, ready: impl Fn() -> bool) -> bool {
    for _ in 0..turns {
        if ready() {
            return true;
        }
        core::sync::atomic::compiler_fence(Ordering::SeqCst);
    }
    false
}

/// True when the host set up the page (QEMU started with the memory backend and the bench).
pub fn present() -> bool {
    read_u32(bl::MAGIC) == bl::MAGIC_VALUE && read_u32(bl::VERSION) == bl::VERSION_VALUE
}

/// Count `n` bytes written to serial `port` (the host checks the stage link is drained before it
/// moves the clock on).
pub fn count_tx(port: usize, n: u32) {
    if port < bl::SERIALS {
        let off = bl::TX_BYTES + 4 * port;
        write_u32(off, read_u32(off).wrapping_add(n));
    }
}

/// Mark (`on`) or clear the board's writer of serial `port` as waiting for room
/// (`bench_link::TX_WAITING`). Thread mode only (the UART writers and the clock's start).
pub fn tx_waiting(port: usize, on: bool) {
    if port < bl::SERIALS {
        let bit = 1u32 << port;
        let m = read_u32(bl::TX_WAITING);
        write_u32(bl::TX_WAITING, if on { m | bit } else { m & !bit });
    }
}

/// True when the bench announced bytes on serial `port` that the board has not read yet.
pub fn announced_unread(port: usize) -> bool {
    port < bl::SERIALS
        && bl::announced_unread(
            read_u32(bl::ANNOUNCED + 4 * port),
            read_u32(bl::RX_BYTES + 4 * port),
        )
}

/// Count `n` bytes read from serial `port` (the bench checks its input was taken in before it
/// moves the clock on: a deterministic board time for every byte).
pub fn count_rx(port: usize, n: u32) {
    if port < bl::SERIALS {
        let off = bl::RX_BYTES + 4 * port;
        write_u32(off, read_u32(off).wrapping_add(n));
    }
}

/// True when the bench asked for serial `port` on the page's rings (`bench_link::RING_PORTS`;
/// read at boot, before the UART drivers are made).
pub fn ring_port(port: usize) -> bool {
    port < bl::RING_SERIALS && present() && read_u32(bl::RING_PORTS) & (1 << port) != 0
}

/// Take up to `buf.len()` bytes from serial `port`'s ring into the board; the count taken.
pub fn ring_read(port: usize, buf: &mut [u8]) -> usize {
    let k = bl::ring_to_board(port);
    let head = read_u32(bl::ring_head(k));
    let tail = read_u32(bl::ring_tail(k));
    let n = bl::ring_used(head, tail).min(bl::RING_LEN).min(buf.len());
    if n == 0 {
        return 0;
    }
    // the bytes were written before the head we read (the host's release store)
    barrier();
    for (i, b) in buf[..n].iter_mut().enumerate() {
        *b = read_u8(bl::ring_byte(k, tail.wrapping_add(i as u32)));
    }
    barrier();
    write_u32(bl::ring_tail(k), tail.wrapping_add(n as u32));
    n
}

/// True when serial `port`'s ring into the board holds bytes.
pub fn ring_readable(port: usize) -> bool {
    let k = bl::ring_to_board(port);
    read_u32(bl::ring_head(k)) != read_u32(bl::ring_tail(k))
}

/// Put as many of `buf`'s bytes as there is room for into serial `port`'s ring to the host;
/// the count put.
pub fn ring_write(port: usize, buf: &[u8]) -> usize {
    let k = bl::ring_to_host(port);
    let head = read_u32(bl::ring_head(k));
    let tail = read_u32(bl::ring_tail(k));
    let room = bl::RING_LEN - bl::ring_used(head, tail).min(bl::RING_LEN);
    let n = room.min(buf.len());
    if n == 0 {
        return 0;
    }
    for (i, &b) in buf[..n].iter().enumerate() {
        write_u8(bl::ring_byte(k, head.wrapping_add(i as u32)), b);
    }
    // counted before the host can see them (as the UART driver counts a write it has done)
    count_tx(port, n as u32);
    barrier();
    write_u32(bl::ring_head(k), head.wrapping_add(n as u32));
    n
}

/// True when serial `port`'s ring to the host has room.
pub fn ring_writable(port: usize) -> bool {
    let k = bl::ring_to_host(port);
    bl::ring_used(read_u32(bl::ring_head(k)), read_u32(bl::ring_tail(k))) < bl::RING_LEN
}

/// Mark (`on`) or clear the board's reader of ring port `port` as waiting
/// (`bench_link::RX_ARMED`). Thread mode, or with interrupts masked.
pub fn rx_armed(port: usize, on: bool) {
    let bit = 1u32 << port;
    let m = read_u32(bl::RX_ARMED);
    write_u32(bl::RX_ARMED, if on { m | bit } else { m & !bit });
}

/// The mask of ring ports whose reader waits.
pub fn rx_armed_mask() -> u32 {
    read_u32(bl::RX_ARMED)
}
