//! The bench's side of the QEMU board's link (`nanocal_interface::bench_link` has the layout
//! and the why): the page shared with the board through a host file that backs the board's
//! PSRAM, the doorbells on serial4, the board's clock, and the bus mailbox.
//!
//! The clock runs in one of two modes:
//! - **free-running** (the default, what the end-to-end tests use): a thread moves the horizon
//!   with the wall clock × a scale every millisecond, so the board lives in real time (scale 1);
//! - **lockstep** ([`BenchClock::lockstep`]): the horizon moves only when a caller says
//!   [`BenchClock::advance_to`], which returns once the board is idle there — every timer up to
//!   that instant has run, and no board time passes while the caller works (sends a command,
//!   reads a status). This is what makes a simulated day deterministic and fast.

use nanocal_interface::bench_link as bl;
use nanocal_interface::bus::{BusOp, BusReply, BusRequest, BusStatus};
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use super::board_first::BoardFirst;
use super::input_watch::InputWatch;

/// Size of the file behind the board's PSRAM (QEMU's mps2 machines have exactly 16 MiB).
pub const RAM_FILE_LEN: u64 = 16 * 1024 * 1024;
/// Bytes mapped: the page and the rings after it (`bench_link::SHARED_LEN`), whole pages.
const MAP_LEN: usize = bl::SHARED_LEN.next_multiple_of(4096);
/// How long [`BenchClock::advance_to`] watches the page without any progress of the board
/// before it sleeps until a doorbell. (Measured on the shortened campaign, loaded machine: it
/// stops watching ≈ 3 times a step, and the bus requests after it ring ≈ 30 doorbells a step.
/// Longer watches lose under load, where QEMU's vCPU and this thread take turns on the cores:
/// 2 ms and watching again at the first of those doorbells made it worse at load 9; 5 ms took
/// the steps' wait from 11 s to 303 s at load 12, and watching again at every bus doorbell to
/// 54 s — two spinners that each wait for the other.)
const SPIN: Duration = Duration::from_micros(500);
/// Longest the free-running clock holds for input in flight that the board does not take.
const MAX_HOLD: Duration = Duration::from_secs(2);

/// The page, mapped in this process.
pub struct Page {
    ptr: *mut u8,
    path: PathBuf,
}

// SAFETY: the mapping lives as long as the Page; every access is an atomic or volatile access of
// plain memory shared with the board (which orders its side with barriers).
unsafe impl Send for Page {}
// SAFETY: as above.
unsafe impl Sync for Page {}

impl Page {
    /// Create the file that backs the board's RAM, with the page initialised (magic, version,
    /// horizon 0), and map its first page.
    pub fn create(path: &Path) -> std::io::Result<Page> {
        let f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)?;
        f.set_len(RAM_FILE_LEN)?;
        use std::os::fd::AsRawFd;
        // SAFETY: a shared mapping of the first page of a file we just sized; checked below.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                MAP_LEN,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                f.as_raw_fd(),
                0,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(std::io::Error::last_os_error());
        }
        let page = Page {
            ptr: ptr as *mut u8,
            path: path.to_path_buf(),
        };
        page.set_u64(bl::HORIZON, 0);
        page.set_u32(bl::VERSION, bl::VERSION_VALUE);
        page.set_u32(bl::MAGIC, bl::MAGIC_VALUE);
        Ok(page)
    }

    /// Path of the backing file (QEMU's `mem-path`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn a32(&self, off: usize) -> &AtomicU32 {
        assert!(off.is_multiple_of(4) && off + 4 <= bl::SHARED_LEN);
        // SAFETY: aligned, inside the mapping, which outlives `self`.
        unsafe { &*(self.ptr.add(off) as *const AtomicU32) }
    }

    /// A u32 field.
    pub fn u32(&self, off: usize) -> u32 {
        self.a32(off).load(Ordering::Acquire)
    }

    /// Set a u32 field.
    pub fn set_u32(&self, off: usize, v: u32) {
        self.a32(off).store(v, Ordering::Release)
    }

    /// A u64 field the board writes as two words, low first (re-read until the high word is
    /// the same before and after).
    pub fn u64(&self, off: usize) -> u64 {
        loop {
            let hi = self.u32(off + 4);
            let lo = self.u32(off);
            if hi == self.u32(off + 4) {
                return (u64::from(hi) << 32) | u64::from(lo);
            }
        }
    }

    /// Set a u64 field in one store (the board reads it high, low, high).
    pub fn set_u64(&self, off: usize, v: u64) {
        assert!(off.is_multiple_of(8));
        // SAFETY: 8-aligned, inside the mapping.
        let a = unsafe { &*(self.ptr.add(off) as *const AtomicU64) };
        a.store(v, Ordering::Release)
    }

    /// `n` bytes from `off`.
    pub fn bytes(&self, off: usize, n: usize) -> Vec<u8> {
        assert!(off + n <= bl::SHARED_LEN);
        // SAFETY: inside the mapping; volatile reads of memory the board may write.
        (0..n)
            .map(|i| unsafe { std::ptr::read_volatile(self.ptr.add(off + i)) })
            .collect()
    }

    /// Write `b` at `off`.
    pub fn set_bytes(&self, off: usize, b: &[u8]) {
        assert!(off + b.len() <= bl::SHARED_LEN);
        for (i, &v) in b.iter().enumerate() {
            // SAFETY: inside the mapping.
            unsafe { std::ptr::write_volatile(self.ptr.add(off + i), v) }
        }
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        // SAFETY: the mapping made in `create`.
        unsafe { libc::munmap(self.ptr as *mut libc::c_void, MAP_LEN) };
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Serves one bus transaction: `(op, target, bytes out, bytes in, board time s)` → `(status,
/// bytes in)`, or `None` when nothing answers.
pub type BusHandler =
    Box<dyn FnMut(BusOp, u8, &[u8], usize, f64) -> Option<(BusStatus, Vec<u8>)> + Send>;

/// Errors of the bench's clock.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClockError {
    /// The board did not reach the horizon in time (hung, reset loop, or QEMU gone).
    #[error("the board did not reach {target_s:.3} s of bench time within {waited:?} (it is at {now_s:.3} s)")]
    Stalled {
        /// Where it was asked to go, s.
        target_s: f64,
        /// Where it is, s.
        now_s: f64,
        /// How long we waited.
        waited: Duration,
    },
    /// The clock is free-running: lockstep calls are not allowed.
    #[error("the bench clock is free-running; call lockstep() first")]
    FreeRunning,
}

/// A campaign meets a stalled board as its bench's clock error.
impl From<ClockError> for crate::campaign::bench::BenchError {
    fn from(e: ClockError) -> Self {
        Self::Clock(Box::new(e))
    }
}

#[derive(Default)]
struct Rings {
    waiting: u64,
}

/// The bench's side of the link: page, doorbells, bus mailbox, clock.
pub struct BenchLink {
    page: Page,
    line: Mutex<UnixStream>,
    /// The board's wake port, serial2 (`bench_link` layout 6): the doorbells to the board go
    /// there once set ([`Self::set_wake_port`]), else on `line`.
    wake: Mutex<Option<UnixStream>>,
    rings: Mutex<Rings>,
    rung: Condvar,
    bus: Mutex<Option<BusHandler>>,
    bus_attached: Condvar,
    pub(super) lockstep: AtomicBool,
    stop: AtomicBool,
    /// Counts completed lockstep advances (for threads that follow the board's clock).
    advances: Mutex<u64>,
    advanced: Condvar,
    /// Bus transactions served.
    pub transactions: AtomicU64,
    /// Wake-ups for input stuck on its way into the board ([`Self::wake_for_input`]).
    pokes: AtomicU64,
    /// Input written towards the board and not yet taken: the free-running clock holds while
    /// there is some.
    inputs: InputWatch,
    /// Announced bytes given up on ([`Self::forgiven_bytes`]).
    forgiven: AtomicU64,
    /// Crossings counted for the campaign's profile ([`Crossings`]).
    counts: Counts,
    /// Called by every thread that waits on the board (see [`Self::set_pump`]).
    pump: Mutex<Option<Arc<dyn Fn() + Send + Sync>>>,
}

#[derive(Default)]
struct Counts {
    advances: AtomicU64,
    horizon_rings: AtomicU64,
    ring_rings: AtomicU64,
    bus_rings: AtomicU64,
    waiting_rings: AtomicU64,
    reply_rings: AtomicU64,
    nudges: AtomicU64,
    quiet: AtomicU64,
}

/// What crossed between the bench and the board since QEMU started: the figures of issue
/// 20 §5 (each costs a hand-over between threads or a halt of the emulated CPU, not
/// instructions).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Crossings {
    /// Lockstep advances of the board's clock.
    pub advances: u64,
    /// Times the board halted (WFI) waiting for the bench.
    pub halts: u32,
    /// Doorbells rung to the board: the horizon moved while it waited.
    pub horizon_rings: u64,
    /// Doorbells rung to the board for bytes put in a ring, or room made, while it was halted.
    pub ring_rings: u64,
    /// Doorbells rung to the board for input stuck in QEMU's UART.
    pub stuck_rings: u64,
    /// Doorbells from the board for a bus request, while nobody watched the page.
    pub bus_rings: u64,
    /// Doorbells from the board idle at the horizon, while nobody watched the page.
    pub waiting_rings: u64,
    /// Doorbells rung to the board for a bus reply, while it was halted waiting for it.
    pub reply_rings: u64,
    /// Lockstep advances that were nudges during an exchange (among `advances`).
    pub nudges: u64,
    /// Times a lockstep advance stopped watching the page (no progress for a while).
    pub quiet: u64,
    /// Bus transactions.
    pub transactions: u64,
    /// Bytes through the UARTs (serial 0, 1, 3, both ways).
    pub uart_bytes: u64,
    /// Bytes through the rings (both ways).
    pub ring_bytes: u64,
}

impl BenchLink {
    /// Link over `page` and the board's serial4 (`line`). Starts the doorbell reader and the
    /// free-running clock (scale 1).
    pub fn start(page: Page, line: UnixStream) -> Arc<BenchLink> {
        Self::start_with(page, line, false)
    }

    /// [`Self::start`], the clock in lockstep from the board's first instruction: the board
    /// boots at bench time 0 and no time passes until a caller advances it. Why: a board that
    /// boots on the free-running clock and is put in lockstep later boots at an instant the
    /// wall clock decides (35.4 or 35.9 ms in two runs), and every later sample of its sensors
    /// keeps that phase — the campaign's readings and table differed from run to run.
    pub fn start_lockstep(page: Page, line: UnixStream) -> Arc<BenchLink> {
        Self::start_with(page, line, true)
    }

    fn start_with(page: Page, line: UnixStream, lockstep: bool) -> Arc<BenchLink> {
        let reader = line.try_clone().expect("clone serial4");
        let link = Arc::new(BenchLink {
            page,
            line: Mutex::new(line),
            wake: Mutex::new(None),
            rings: Mutex::new(Rings::default()),
            rung: Condvar::new(),
            bus: Mutex::new(None),
            bus_attached: Condvar::new(),
            lockstep: AtomicBool::new(lockstep),
            stop: AtomicBool::new(false),
            advances: Mutex::new(0),
            advanced: Condvar::new(),
            transactions: AtomicU64::new(0),
            pokes: AtomicU64::new(0),
            inputs: InputWatch::default(),
            forgiven: AtomicU64::new(0),
            counts: Counts::default(),
            pump: Mutex::new(None),
        });
        let l = link.clone();
        std::thread::spawn(move || l.read_doorbells(reader));
        if !lockstep {
            let l = link.clone();
            std::thread::spawn(move || l.free_run(1.0));
        }
        link
    }

    /// The page.
    pub fn page(&self) -> &Page {
        &self.page
    }

    /// Ring the board's doorbells on `wake` (its serial2, the wake port of `bench_link` layout
    /// 6) from now on: the board drains that port itself before it halts, so a doorbell
    /// always ends a halt — whether the board waits at its horizon or for a bus reply.
    pub fn set_wake_port(&self, wake: UnixStream) {
        *self.wake.lock().unwrap() = Some(wake);
    }

    /// Let the board spin `turns` turns, idle at the horizon, before it halts
    /// (`bench_link::IDLE_SPIN`; 0: halt at once).
    pub fn set_idle_spin(&self, turns: u32) {
        self.page.set_u32(bl::IDLE_SPIN, turns);
    }

    /// Ring the board (a halted board wakes and looks at the page again).
    fn ring_board(&self) {
        if let Some(w) = self.wake.lock().unwrap().as_mut() {
            let _ = w.write_all(&[bl::RING_HORIZON]);
            return;
        }
        let _ = self.line.lock().unwrap().write_all(&[bl::RING_HORIZON]);
    }

    /// Send raw bytes on serial4 (the host link's line state `C0h | DTR`).
    pub fn send_line_state(&self, b: u8) {
        let _ = self.line.lock().unwrap().write_all(&[b]);
    }

    /// Wake the board when it waits at the horizon while input it has not read is on its way
    /// (the caller knows that): QEMU's CMSDK UART takes a byte from its socket only when QEMU's main
    /// loop looks at that socket again, and measured on the published campaign, once in a few
    /// thousand requests the last byte of one stayed in the socket while the board slept (WFI)
    /// with nothing left to wake QEMU's loop. A doorbell byte on serial4 wakes both; the board
    /// takes it as a horizon doorbell (it only re-reads the horizon). Rate-limited by the
    /// caller. Returns true if it rang.
    pub fn wake_for_input(&self) -> bool {
        let rang = self.ring_horizon_if_waiting();
        if rang {
            self.pokes.fetch_add(1, Ordering::Relaxed);
        }
        rang
    }

    /// Ring the horizon doorbell if the board waits at its horizon; true if it rang.
    fn ring_horizon_if_waiting(&self) -> bool {
        if self.page.u32(bl::WAITING) != 1 {
            return false;
        }
        self.ring_board();
        true
    }

    /// Ring the board awake if it is halted (after bytes were put in a ring or room made in
    /// one: the board looks at its rings before it halts, and marks the halt first).
    fn ring_if_halted(&self) {
        fence(Ordering::SeqCst);
        if self.page.u32(bl::HALTED) == 1 {
            self.ring_board();
            self.counts.ring_rings.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Put up to `b.len()` bytes into serial `port`'s ring to the board (bytes sent on the
    /// port: the board must have asked for it on the ring, [`Page::create`]'s `ring_ports`);
    /// the count put (0: the ring is full).
    pub fn ring_write(&self, port: usize, b: &[u8]) -> usize {
        let k = bl::ring_to_board(port);
        let head = self.page.u32(bl::ring_head(k));
        let tail = self.page.u32(bl::ring_tail(k));
        let room = bl::RING_LEN - bl::ring_used(head, tail).min(bl::RING_LEN);
        let n = room.min(b.len());
        if n == 0 {
            return 0;
        }
        for (i, &v) in b[..n].iter().enumerate() {
            let off = bl::ring_byte(k, head.wrapping_add(i as u32));
            // SAFETY: inside the mapping (`ring_byte` < SHARED_LEN).
            unsafe { std::ptr::write_volatile(self.page.ptr.add(off), v) }
        }
        self.page
            .a32(bl::ring_head(k))
            .store(head.wrapping_add(n as u32), Ordering::SeqCst);
        self.ring_if_halted();
        n
    }

    /// Take up to `b.len()` bytes from serial `port`'s ring from the board; the count taken.
    pub fn ring_read(&self, port: usize, b: &mut [u8]) -> usize {
        let k = bl::ring_to_host(port);
        let head = self.page.u32(bl::ring_head(k));
        let tail = self.page.u32(bl::ring_tail(k));
        let n = bl::ring_used(head, tail).min(bl::RING_LEN).min(b.len());
        if n == 0 {
            return 0;
        }
        for (i, v) in b[..n].iter_mut().enumerate() {
            let off = bl::ring_byte(k, tail.wrapping_add(i as u32));
            // SAFETY: inside the mapping.
            *v = unsafe { std::ptr::read_volatile(self.page.ptr.add(off)) };
        }
        self.page
            .a32(bl::ring_tail(k))
            .store(tail.wrapping_add(n as u32), Ordering::SeqCst);
        // a writer of the board that waited for room may go on
        if self.page.u32(bl::TX_WAITING) & (1 << port) != 0 {
            self.ring_if_halted();
        }
        n
    }

    /// True when serial `port`'s ring from the board holds bytes.
    pub fn ring_readable(&self, port: usize) -> bool {
        let k = bl::ring_to_host(port);
        self.page.u32(bl::ring_head(k)) != self.page.u32(bl::ring_tail(k))
    }

    /// Have `pump` called by every thread of the bench that waits on the board (a lockstep
    /// advance, a reader of a ring port): the simulated controller on the stage's ring
    /// answers through it, with no thread of its own to wake.
    pub fn set_pump(&self, pump: Arc<dyn Fn() + Send + Sync>) {
        *self.pump.lock().unwrap() = Some(pump);
    }

    /// Call the pump, if any.
    pub fn pump(&self) {
        let p = self.pump.lock().unwrap().clone();
        if let Some(p) = p {
            p();
        }
    }

    /// What crossed between the bench and the board so far.
    pub fn crossings(&self) -> Crossings {
        let c = &self.counts;
        let uart_and_ring: u64 = [0usize, 1, 3]
            .iter()
            .map(|&p| u64::from(self.tx_bytes(p)) + u64::from(self.rx_bytes(p)))
            .sum();
        let ring_bytes: u64 = (0..bl::RINGS)
            .map(|k| u64::from(self.page.u32(bl::ring_tail(k))))
            .sum();
        Crossings {
            advances: c.advances.load(Ordering::Relaxed),
            halts: self.page.u32(bl::HALTS),
            horizon_rings: c.horizon_rings.load(Ordering::Relaxed),
            ring_rings: c.ring_rings.load(Ordering::Relaxed),
            stuck_rings: self.pokes(),
            bus_rings: c.bus_rings.load(Ordering::Relaxed),
            waiting_rings: c.waiting_rings.load(Ordering::Relaxed),
            reply_rings: c.reply_rings.load(Ordering::Relaxed),
            nudges: c.nudges.load(Ordering::Relaxed),
            quiet: c.quiet.load(Ordering::Relaxed),
            transactions: self.transactions.load(Ordering::Relaxed),
            uart_bytes: uart_and_ring.saturating_sub(ring_bytes),
            ring_bytes,
        }
    }

    /// Times [`Self::wake_for_input`] had to ring.
    pub fn pokes(&self) -> u64 {
        self.pokes.load(Ordering::Relaxed)
    }

    /// Stop the threads (QEMU is going away).
    pub fn shutdown(&self) {
        self.stop.store(true, Ordering::Release);
        self.rung.notify_all();
        self.advanced.notify_all();
    }

    /// Serve the bus with `handler` from now on.
    pub fn attach_bus(&self, handler: BusHandler) {
        *self.bus.lock().unwrap() = Some(handler);
        self.bus_attached.notify_all();
    }

    /// The board's clock, s of bench time.
    pub fn now_s(&self) -> f64 {
        bl::ticks_to_s(self.page.u64(bl::NOW))
    }

    /// Boots of the board since QEMU started.
    pub fn boots(&self) -> u32 {
        self.page.u32(bl::BOOTS)
    }

    /// Bytes the board has read from serial `port` since power-on.
    pub fn rx_bytes(&self, port: usize) -> u32 {
        self.page.u32(bl::RX_BYTES + 4 * port)
    }

    /// Say that `n` bytes are about to be written to serial `port` — call *before* writing
    /// them. While the board's reader of that port waits and has not read them all, its clock
    /// holds (`bench_link::ANNOUNCED`), so a frame written in one piece arrives at one board
    /// instant however slowly QEMU hands it over. Counted on from the board's read count when
    /// that is ahead (bytes nobody announced: another process's). Free-running only: in
    /// lockstep the horizon moves only when the caller says so, which is hold enough.
    /// Returns whether it counted them.
    pub fn announce(&self, port: usize, n: usize) -> bool {
        if port >= bl::SERIALS || n == 0 || self.lockstep.load(Ordering::Acquire) {
            return false;
        }
        let rx = self.rx_bytes(port);
        let _ = self.page.a32(bl::ANNOUNCED + 4 * port).fetch_update(
            Ordering::AcqRel,
            Ordering::Acquire,
            |a| {
                let base = if bl::announced_unread(a, rx) { a } else { rx };
                Some(base.wrapping_add(n as u32))
            },
        );
        true
    }

    /// Take back `n` of the bytes [`Self::announce`] counted on serial `port` (they were not
    /// written after all).
    pub fn unannounce(&self, port: usize, n: usize) {
        if port < bl::SERIALS {
            self.page
                .a32(bl::ANNOUNCED + 4 * port)
                .fetch_sub(n as u32, Ordering::AcqRel);
        }
    }

    /// Bytes announced on serial `port` that the board has not read yet.
    pub fn announced_unread(&self, port: usize) -> u32 {
        let a = self.page.u32(bl::ANNOUNCED + 4 * port);
        let rx = self.rx_bytes(port);
        if bl::announced_unread(a, rx) {
            a.wrapping_sub(rx)
        } else {
            0
        }
    }

    /// Give up on announced bytes that did not arrive (their connection closed before QEMU
    /// took them): the board's clock holds no longer for them, and it is woken.
    fn forgive_announced(&self) {
        for port in 0..bl::SERIALS {
            let off = bl::ANNOUNCED + 4 * port;
            let a = self.page.u32(off);
            let rx = self.rx_bytes(port);
            if bl::announced_unread(a, rx) {
                // only if nothing was announced meanwhile (counted only then)
                if self
                    .page
                    .a32(off)
                    .compare_exchange(a, rx, Ordering::AcqRel, Ordering::Acquire)
                    .is_ok()
                {
                    self.forgiven
                        .fetch_add(u64::from(a.wrapping_sub(rx)), Ordering::Relaxed);
                }
            }
        }
        fence(Ordering::SeqCst);
        self.ring_horizon_if_waiting();
    }

    /// Announced bytes given up on because they never reached the board (see
    /// [`Self::announce`]); a test that counts on its input expects 0.
    pub fn forgiven_bytes(&self) -> u64 {
        self.forgiven.load(Ordering::Relaxed)
    }

    /// Bytes the board has written to serial `port` since power-on.
    pub fn tx_bytes(&self, port: usize) -> u32 {
        self.page.u32(bl::TX_BYTES + 4 * port)
    }

    /// True when the board is idle at the horizon (nothing left to do before it moves).
    pub fn idle_at_horizon(&self) -> bool {
        self.page.u32(bl::WAITING) == 1 && self.page.u64(bl::NOW) == self.page.u64(bl::HORIZON)
    }

    /// Wait (up to `timeout`) until the clock has advanced past generation `seen`; returns the
    /// current generation (for threads that follow the board's clock, e.g. an instrument).
    pub fn wait_advanced(&self, seen: u64, timeout: Duration) -> u64 {
        let g = self.advances.lock().unwrap();
        let (g, _) = self
            .advanced
            .wait_timeout_while(g, timeout, |g| {
                *g == seen && !self.stop.load(Ordering::Acquire)
            })
            .unwrap();
        *g
    }

    /// True once the link is shut down.
    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    fn notify_advanced(&self) {
        *self.advances.lock().unwrap() += 1;
        self.advanced.notify_all();
    }

    fn read_doorbells(&self, mut r: UnixStream) {
        let mut b = [0u8; 256];
        loop {
            let n = match r.read(&mut b) {
                Ok(0) | Err(_) => {
                    self.shutdown();
                    return;
                }
                Ok(n) => n,
            };
            let mut waiting = false;
            for &x in &b[..n] {
                match x {
                    bl::RING_BUS => {
                        self.counts.bus_rings.fetch_add(1, Ordering::Relaxed);
                        self.serve_bus()
                    }
                    bl::RING_WAITING => {
                        self.counts.waiting_rings.fetch_add(1, Ordering::Relaxed);
                        waiting = true
                    }
                    _ => {}
                }
            }
            if waiting {
                self.rings.lock().unwrap().waiting += 1;
                self.rung.notify_all();
            }
        }
    }

    /// True when the board has posted a bus request not yet answered.
    fn bus_pending(&self) -> bool {
        self.page.u32(bl::BUS_REQ_SEQ) != self.page.u32(bl::BUS_REP_SEQ)
    }

    /// Answer the board's pending bus request, if any (whichever thread sees it first: the
    /// doorbell reader, or a caller of [`BenchClock::advance_to`] watching the page).
    fn serve_bus(&self) {
        let mut bus = self.bus.lock().unwrap();
        let seq = self.page.u32(bl::BUS_REQ_SEQ);
        if self.page.u32(bl::BUS_REP_SEQ) == seq {
            return; // already served
        }
        let frame = self.page.bytes(bl::BUS_REQ, bl::FRAME_LEN);
        let request = BusRequest::decode(&frame);
        let now = self.now_s();
        // the board waits for its reply without its clock moving: give a bench that is still
        // being set up a moment to attach its chips
        let deadline = Instant::now() + Duration::from_secs(5);
        while bus.is_none() && Instant::now() < deadline && !self.stop.load(Ordering::Acquire) {
            bus = self
                .bus_attached
                .wait_timeout(bus, Duration::from_millis(50))
                .unwrap()
                .0;
        }
        // a request the board cannot have sent (its ops are typed) is answered like a dead bus,
        // with an op it did not ask for: the board takes that as a bus error
        let (op, target) = request.map_or((BusOp::Spi, 0xFF), |r| (r.op, r.target));
        let answer = match request {
            Ok(r) => bus
                .as_mut()
                .and_then(|f| f(r.op, r.target, r.data_out, r.n_in, now)),
            Err(_) => None,
        };
        drop(bus);
        let (status, data) = answer.unwrap_or((BusStatus::NoAnswer, Vec::new()));
        let mut rep = [0u8; bl::FRAME_LEN];
        let reply = BusReply {
            op,
            target,
            status,
            data_in: &data,
        };
        let n = reply.encode(&mut rep).unwrap_or_else(|_| {
            BusReply {
                status: BusStatus::NoAnswer,
                data_in: &[],
                ..reply
            }
            .encode(&mut rep)
            .unwrap_or(0)
        });
        self.page.set_bytes(bl::BUS_REP, &rep[..n]);
        fence(Ordering::SeqCst);
        self.page.set_u32(bl::BUS_REP_SEQ, seq);
        self.transactions.fetch_add(1, Ordering::Relaxed);
        // a board that waits for its reply halted (it halts at once when nobody watches the
        // page, and after a short busy wait when someone does): wake it
        fence(Ordering::SeqCst);
        if self.page.u32(bl::HALTED) == 1 {
            self.ring_board();
            self.counts.reply_rings.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Move the horizon to `ticks` (never back) and wake the board if it is halted (while it
    /// waits at the horizon it looks at the page before it halts, and marks the halt first).
    fn set_horizon(&self, ticks: u64) {
        if ticks > self.page.u64(bl::HORIZON) {
            self.page.set_u64(bl::HORIZON, ticks);
        }
        fence(Ordering::SeqCst);
        if self.page.u32(bl::HALTED) == 1 {
            self.ring_board();
            self.counts.horizon_rings.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Count a nudge of the board's clock during an exchange (the campaign's profile).
    pub fn count_nudge(&self) {
        self.counts.nudges.fetch_add(1, Ordering::Relaxed);
    }

    /// The ways into the board whose input in flight holds the free-running clock.
    pub fn inputs(&self) -> &InputWatch {
        &self.inputs
    }

    /// Set `TX_HOLD` (`on`: only while the clock runs freely — a racing [`BenchClock::lockstep`]
    /// wins) or clear it.
    fn hold_for_output(&self, on: bool) {
        // all in one order with the lockstep flag (SeqCst): a free-running thread that saw the
        // flag clear wrote its 1 before lockstep()'s 0
        let hold = self.page.a32(bl::TX_HOLD);
        if on && !self.lockstep.load(Ordering::SeqCst) {
            hold.store(1, Ordering::SeqCst);
            if !self.lockstep.load(Ordering::SeqCst) {
                return;
            }
        }
        hold.store(0, Ordering::SeqCst);
    }

    /// Move the horizon with the wall clock × `scale`, except while input is in flight (see
    /// [`InputWatch`] and [`Self::announce`]): then the horizon holds and the board is rung until it has taken the
    /// input, as `src/qemu/time.rs` expects of the bench. A hold lasts at most [`MAX_HOLD`] of
    /// wall time while the unread count stays the same, so a board that stops reading a port
    /// still sees its time pass; likewise announced bytes the board holds its clock for
    /// (see [`Self::forgive_announced`]). The board holds its clock too while one of its writers
    /// waits for room (`bench_link::TX_WAITING`: QEMU's socket takes ≈ 280 one-byte writes
    /// unread, and QEMU passes the rest on when the bench has read them): the bench sets
    /// `TX_HOLD` while it runs freely, and clears it when such a wait makes no progress for
    /// [`MAX_HOLD`] (nobody reads: the board's reply timeout may then pass).
    pub(super) fn free_run(&self, scale: f64) {
        self.hold_for_output(true);
        let mut out: Option<((u32, u64, u64), Instant)> = None;
        let mut last = Instant::now();
        let mut held = Duration::ZERO;
        let t0 = last;
        let base = self.page.u64(bl::HORIZON);
        let mut episode: Option<(u64, Instant)> = None;
        let mut stuck: Option<(u64, u64, Instant)> = None;
        while !self.stop.load(Ordering::Acquire) && !self.lockstep.load(Ordering::Acquire) {
            let now = Instant::now();
            let dt = now - last;
            last = now;
            let pending = self.inputs.pending_bytes();
            let hold = if pending == 0 {
                episode = None;
                false
            } else {
                match episode {
                    Some((n, since)) if n == pending => now - since < MAX_HOLD,
                    _ => {
                        episode = Some((pending, now));
                        true
                    }
                }
            };
            // the board holds its own clock for announced bytes while their reader waits; if
            // it stays held with the same bytes unread for MAX_HOLD, they are not coming
            let announced: u64 = (0..bl::SERIALS)
                .map(|p| u64::from(self.announced_unread(p)))
                .sum();
            let board_now = self.page.u64(bl::NOW);
            let held_by_board = announced > 0 && board_now < self.page.u64(bl::HORIZON);
            match stuck {
                Some((a, t, since)) if held_by_board && a == announced && t == board_now => {
                    if now - since >= MAX_HOLD {
                        self.forgive_announced();
                        stuck = None;
                    }
                }
                _ => stuck = held_by_board.then_some((announced, board_now, now)),
            }
            // a writer of the board waits, and neither it nor the board's clock moves: after
            // MAX_HOLD the bench is taken not to read
            let waiting = self.page.u32(bl::TX_WAITING);
            if waiting == 0 {
                out = None;
                self.hold_for_output(true);
            } else {
                let written: u64 = (0..bl::SERIALS)
                    .map(|p| u64::from(self.page.u32(bl::TX_BYTES + 4 * p)))
                    .sum();
                let key = (waiting, written, board_now);
                match out {
                    Some((k, since)) if k == key => {
                        if now - since >= MAX_HOLD {
                            self.hold_for_output(false);
                        }
                    }
                    _ => out = Some((key, now)),
                }
            }
            self.pump();
            if hold {
                held += dt;
                self.wake_for_input();
            } else {
                let t = base + bl::s_to_ticks((now - t0 - held).as_secs_f64() * scale);
                self.set_horizon(t);
                self.notify_advanced();
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

/// The board's clock as the bench drives it.
#[derive(Clone)]
pub struct BenchClock {
    pub(super) link: Arc<BenchLink>,
}

impl BenchClock {
    /// The clock of `link`.
    pub fn new(link: Arc<BenchLink>) -> Self {
        Self { link }
    }

    /// Now, s of bench time (the board's clock).
    pub fn now_s(&self) -> f64 {
        self.link.now_s()
    }

    /// Stop the free-running thread: from now on the clock moves only by [`Self::advance_to`].
    pub fn lockstep(&self) {
        self.link.lockstep.store(true, Ordering::SeqCst);
        // the board's clock must reach every horizon: no holding for its writers
        self.link.hold_for_output(false);
    }

    /// Move the board's clock to `t_s` of bench time (lockstep): raise the horizon and wait
    /// until the board is idle there. `timeout` bounds the wall time of the whole step.
    pub fn advance_to(&self, t_s: f64, timeout: Duration) -> Result<(), ClockError> {
        self.advance_to_ticks(bl::s_to_ticks(t_s), timeout)
    }

    /// The board's next timer, bench ticks, as it published it when it last went idle at its
    /// horizon (`bench_link::NEXT_ALARM`; `None`: it has none, or it is not idle at the
    /// horizon, so the figure may be old).
    pub fn next_alarm_ticks(&self) -> Option<u64> {
        let page = &self.link.page;
        if !self.link.idle_at_horizon() {
            return None;
        }
        let next = page.u64(bl::NEXT_ALARM);
        (next != u64::MAX && next > page.u64(bl::NOW)).then_some(next)
    }

    /// [`Self::advance_to`] in bench ticks.
    pub fn advance_to_ticks(&self, ticks: u64, timeout: Duration) -> Result<(), ClockError> {
        if !self.link.lockstep.load(Ordering::Acquire) {
            return Err(ClockError::FreeRunning);
        }
        let start = Instant::now();
        let page = &self.link.page;
        self.link.counts.advances.fetch_add(1, Ordering::Relaxed);
        let target = ticks.max(page.u64(bl::HORIZON));
        let stalled = |page: &Page| ClockError::Stalled {
            target_s: bl::ticks_to_s(target),
            now_s: bl::ticks_to_s(page.u64(bl::NOW)),
            waited: start.elapsed(),
        };
        self.link.set_horizon(target);
        // Watch the page while the board runs towards the horizon, answering its bus requests
        // here: no thread hand-over per transaction (the board waits for each reply). Sleep
        // until a doorbell only when the board makes no progress for a while.
        let mut last = (page.u64(bl::NOW), page.u32(bl::BUS_REQ_SEQ));
        let mut quiet_since = Instant::now();
        // the poll below gives way to QEMU's threads (they run what it waits for)
        let mut board_first = BoardFirst::enter();
        page.set_u32(bl::WATCHING, 1);
        let result = loop {
            board_first.look();
            if self.link.bus_pending() {
                self.link.serve_bus();
            }
            self.link.pump();
            if page.u32(bl::WAITING) == 1 && page.u64(bl::NOW) == target {
                break Ok(());
            }
            if start.elapsed() > timeout || self.link.stop.load(Ordering::Acquire) {
                break Err(stalled(page));
            }
            let now = (page.u64(bl::NOW), page.u32(bl::BUS_REQ_SEQ));
            if now != last {
                last = now;
                quiet_since = Instant::now();
            } else if quiet_since.elapsed() > SPIN {
                // stop polling: the board rings from now on; look once more, then sleep
                self.link.counts.quiet.fetch_add(1, Ordering::Relaxed);
                page.set_u32(bl::WATCHING, 0);
                fence(Ordering::SeqCst);
                if !self.link.bus_pending() && page.u32(bl::WAITING) == 0 {
                    let rings = self.link.rings.lock().unwrap();
                    let _ = self
                        .link
                        .rung
                        .wait_timeout(rings, Duration::from_millis(2))
                        .unwrap();
                    board_first.rested();
                }
                page.set_u32(bl::WATCHING, 1);
                quiet_since = Instant::now();
            } else {
                std::hint::spin_loop();
            }
        };
        // Stop watching, then look once more: a request the board posted while it still saw
        // WATCHING set was not rung, and nothing else would answer it — the board spins for its
        // reply with its executor blocked until the QEMU-clock watchdog resets it (measured:
        // the published campaign's STATUS timeouts and its "watchdog" resets, after a
        // management request made the sensor task fold while an exchange's nudge ended).
        page.set_u32(bl::WATCHING, 0);
        fence(Ordering::SeqCst);
        if self.link.bus_pending() {
            self.link.serve_bus();
        }
        if result.is_ok() {
            self.link.notify_advanced();
        }
        result
    }
}

/// A stream into serial `serial` of the board that announces what it writes
/// ([`BenchLink::announce`]): a request written in one piece reaches the board at one instant
/// of its time.
pub(crate) struct Announced<S> {
    pub(crate) inner: S,
    pub(crate) link: Arc<BenchLink>,
    pub(crate) serial: usize,
}

impl<S: Read> Read for Announced<S> {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        self.inner.read(b)
    }
}

impl<S: Write> Write for Announced<S> {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        // announced in full before any goes, what did not go taken back
        let counted = self.link.announce(self.serial, b.len());
        let r = self.inner.write(b);
        let n = *r.as_ref().unwrap_or(&0);
        if counted && n < b.len() {
            self.link.unannounce(self.serial, b.len() - n);
        }
        r
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// How long a reader of a ring port spins on the ring before it sleeps between looks: the
/// board answers most requests within this (measured: a status in ≈ 0.1 ms), and a thread that
/// sleeps and is woken costs more on a loaded machine than one that spins (see
/// [`BenchClock::advance_to`]).
const RING_SPIN: Duration = Duration::from_millis(2);
/// Sleep between looks at a ring after [`RING_SPIN`].
const RING_NAP: Duration = Duration::from_micros(50);

/// Serial `port` of the board through its rings (`bench_link`, *Rings*): what a socket to
/// QEMU's serial port is otherwise, with no UART in between — a request goes in, and its reply
/// comes out, in one piece. Reads time out after `read_timeout` (`WouldBlock`, as a socket's),
/// and end (0) once the link is shut down.
pub struct RingPort {
    link: Arc<BenchLink>,
    port: usize,
    read_timeout: Duration,
}

impl RingPort {
    /// Serial `port` of `link` (the board must have been started with it on its rings).
    pub fn new(link: Arc<BenchLink>, port: usize, read_timeout: Duration) -> Self {
        assert!(port < bl::RING_SERIALS);
        Self {
            link,
            port,
            read_timeout,
        }
    }

    /// Wait a little for the board, pumping the stage meanwhile; false once `since` is more
    /// than `limit` ago or the link is shut down.
    /// `board_first`: the caller's poll, lowered at its first wait (not when the reply is
    /// there at the first look).
    fn wait(&self, since: Instant, limit: Duration, board_first: &mut Option<BoardFirst>) -> bool {
        if self.link.stopped() {
            return false;
        }
        let board_first = board_first.get_or_insert_with(BoardFirst::enter);
        board_first.look();
        self.link.pump();
        let waited = since.elapsed();
        if waited >= limit {
            return false;
        }
        if waited < RING_SPIN {
            std::hint::spin_loop();
        } else {
            std::thread::sleep(RING_NAP);
            board_first.rested();
        }
        true
    }
}

impl Read for RingPort {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        if b.is_empty() {
            return Ok(0);
        }
        let start = Instant::now();
        let mut board_first = None;
        loop {
            let n = self.link.ring_read(self.port, b);
            if n > 0 {
                return Ok(n);
            }
            if self.link.stopped() {
                return Ok(0);
            }
            if !self.wait(start, self.read_timeout, &mut board_first) {
                return Err(std::io::ErrorKind::WouldBlock.into());
            }
        }
    }
}

impl Write for RingPort {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        if b.is_empty() {
            return Ok(0);
        }
        let start = Instant::now();
        let mut board_first = None;
        loop {
            let n = self.link.ring_write(self.port, b);
            if n > 0 {
                return Ok(n);
            }
            // the ring is full: the board takes its bytes as it reads (a board that stopped
            // reading for a minute is hung)
            if !self.wait(start, Duration::from_secs(60), &mut board_first) {
                return Err(std::io::ErrorKind::BrokenPipe.into());
            }
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The board's side of a ring, as `src/qemu/link.rs` reads and writes it (same offsets,
    /// producer writes bytes then head, consumer reads bytes then tail).
    fn board_read(page: &Page, port: usize) -> Vec<u8> {
        let k = bl::ring_to_board(port);
        let (head, tail) = (page.u32(bl::ring_head(k)), page.u32(bl::ring_tail(k)));
        let n = bl::ring_used(head, tail);
        let out = (0..n)
            .map(|i| page.bytes(bl::ring_byte(k, tail.wrapping_add(i as u32)), 1)[0])
            .collect();
        page.set_u32(bl::ring_tail(k), head);
        out
    }

    fn board_write(page: &Page, port: usize, b: &[u8]) {
        let k = bl::ring_to_host(port);
        let head = page.u32(bl::ring_head(k));
        for (i, &v) in b.iter().enumerate() {
            page.set_bytes(bl::ring_byte(k, head.wrapping_add(i as u32)), &[v]);
        }
        page.set_u32(bl::ring_head(k), head.wrapping_add(b.len() as u32));
    }

    #[test]
    fn ring_ports_carry_bytes_both_ways_across_the_wrap_and_ring_only_a_halted_board() {
        let path = std::env::temp_dir().join(format!("nanocal-ring-{}", std::process::id()));
        let page = Page::create(&path).unwrap();
        let (ours, mut board_line) = UnixStream::pair().unwrap();
        board_line
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let link = BenchLink::start(page, ours);
        BenchClock::new(link.clone()).lockstep();
        // start near the counters' wrap and the ring's end
        for k in 0..bl::RINGS {
            link.page().set_u32(bl::ring_head(k), u32::MAX - 5);
            link.page().set_u32(bl::ring_tail(k), u32::MAX - 5);
        }
        let mut port = RingPort::new(link.clone(), 3, Duration::from_millis(20));
        port.write_all(b"STATUS?\n").unwrap();
        assert_eq!(board_read(link.page(), 3), b"STATUS?\n");
        let mut b = [0u8; 64];
        assert_eq!(
            port.read(&mut b).unwrap_err().kind(),
            std::io::ErrorKind::WouldBlock,
            "nothing from the board yet"
        );
        board_write(link.page(), 3, b"reply\n");
        let n = port.read(&mut b).unwrap();
        assert_eq!(&b[..n], b"reply\n");
        // a full ring takes no more; the board reading makes room
        let big = vec![7u8; bl::RING_LEN + 10];
        assert_eq!(link.ring_write(0, &big), bl::RING_LEN);
        assert_eq!(link.ring_write(0, &big), 0);
        assert_eq!(board_read(link.page(), 0).len(), bl::RING_LEN);
        // no doorbell while the board runs; one when it is halted
        let mut one = [0u8; 1];
        assert!(board_line.read(&mut one).is_err(), "no doorbell yet");
        link.page().set_u32(bl::HALTED, 1);
        assert_eq!(link.ring_write(0, b"x"), 1);
        board_line.read_exact(&mut one).unwrap();
        assert_eq!(one[0], bl::RING_HORIZON);
        assert_eq!(link.crossings().ring_rings, 1);
        link.shutdown();
    }

    #[test]
    fn doorbells_go_to_the_wake_port_and_a_bus_reply_wakes_a_halted_board() {
        let path = std::env::temp_dir().join(format!("nanocal-wake-{}", std::process::id()));
        let page = Page::create(&path).unwrap();
        let (ours, mut board_line) = UnixStream::pair().unwrap();
        let (wake, mut board_wake) = UnixStream::pair().unwrap();
        for s in [&board_line, &board_wake] {
            s.set_read_timeout(Some(Duration::from_millis(200)))
                .unwrap();
        }
        let link = BenchLink::start(page, ours);
        BenchClock::new(link.clone()).lockstep();
        link.set_wake_port(wake);
        link.attach_bus(Box::new(|_, _, _, n_in, _| {
            Some((BusStatus::Ok, vec![0x5A; n_in]))
        }));
        let mut one = [0u8; 1];
        // the board posts a request and halts waiting for it: the reply rings the wake port
        let post = |seq: u32| {
            let mut f = [0u8; bl::FRAME_LEN];
            let n = BusRequest {
                op: BusOp::Spi,
                target: 1,
                data_out: &[0x0C, 0, 0, 0],
                n_in: 4,
            }
            .encode(&mut f)
            .unwrap();
            link.page().set_bytes(bl::BUS_REQ, &f[..n]);
            link.page().set_u32(bl::BUS_REQ_SEQ, seq);
        };
        post(1);
        link.page().set_u32(bl::HALTED, 1);
        link.serve_bus();
        assert_eq!(link.page().u32(bl::BUS_REP_SEQ), 1, "answered");
        board_wake.read_exact(&mut one).unwrap();
        assert_eq!(one[0], bl::RING_HORIZON);
        assert!(
            board_line.read(&mut one).is_err(),
            "nothing on serial4: it carries line states to the board"
        );
        assert_eq!(link.crossings().reply_rings, 1);
        // a board that spins for its reply (the bench watches) is not rung
        link.page().set_u32(bl::HALTED, 0);
        post(2);
        link.serve_bus();
        assert_eq!(link.page().u32(bl::BUS_REP_SEQ), 2);
        assert!(board_wake.read(&mut one).is_err(), "no doorbell");
        assert_eq!(link.crossings().reply_rings, 1);
        // bytes put in a ring of a halted board: the wake port again
        link.page().set_u32(bl::HALTED, 1);
        assert_eq!(link.ring_write(0, b"x"), 1);
        board_wake.read_exact(&mut one).unwrap();
        assert_eq!(one[0], bl::RING_HORIZON);
        assert!(board_line.read(&mut one).is_err());
        link.shutdown();
    }
}
