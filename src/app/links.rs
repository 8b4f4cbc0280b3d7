//! Host link and stage link: bytes ↔ `nanocal_compensator::proxy::Proxy`.
//!
//! Both links hand the proxy whole read buffers; the proxy takes as much as it can before it has
//! output (one line, one single-character command, one reply or a buffer-full of relayed
//! bytes), the link sends that output and hands over the rest. Replies stream through as they
//! arrive; a line the proxy holds until the controller answered its own query is resumed from
//! the stage link, which also gives the proxy the time for its reply timeout.

use super::{read_some, task, Core, Shared};
use core::sync::atomic::Ordering;
use embassy_futures::join::join;
use embassy_futures::select::{select, select3, Either, Either3};
use embassy_time::{Instant, Timer};
use embedded_io_async::{Error as _, ErrorKind, Read, Write};
use nanocal_compensator::proxy::Output;

/// How often the stage link lets the proxy check its reply timeout, ms.
const POLL_MS: u64 = 50;

/// How often the stage link lets the proxy look at a held target that follows the model, ms
/// (only while one is armed; the fold changes every 1 to 10 s).
const FOLLOW_MS: u64 = 250;

/// How long the host may leave a packet for it unread before it is dropped, ms: a host that
/// has its port open but does not read must not stop the compensator (its replies go; what the
/// controller sends is still read, see [`send_from_stage`]).
const HOST_STALL_MS: u64 = 1_000;

fn now_ms() -> u32 {
    Instant::now().as_millis() as u32
}

/// Bytes for the stage controller, out on its link. While a write waits (the UART sends at
/// its baud rate) the task is marked busy: a transmitter that never finishes is a wedged link,
/// and the supervisor lets the watchdog reset the board.
async fn stage_pump<W: Write>(sh: &Shared, tx: &mut W) -> ! {
    let mut buf = [0u8; 128];
    loop {
        let n = sh.to_stage.read(&mut buf).await;
        let _busy = sh.beats[task::STAGE_OUT].busy(super::now_ms());
        if tx.write_all(&buf[..n]).await.is_err() {
            warn!("stage link write failed; {=usize} bytes dropped", n);
        }
        let _ = tx.flush().await;
    }
}

/// Bytes for the host, out packet by packet. A session that ends meanwhile takes the rest
/// with it (never delivered to the next one: the write waiting for the USB endpoint is
/// cancelled, not woken), and a host that leaves a packet unread for [`HOST_STALL_MS`] loses
/// the bytes.
async fn host_pump<W: Write>(sh: &Shared, tx: &mut W) -> ! {
    let mut buf = [0u8; 128];
    loop {
        let n = sh.to_host.read(&mut buf).await;
        let session = sh.host_session.load(Ordering::Acquire);
        sh.host_cancel.reset();
        let mut off = 0;
        while off < n && sh.host_session.load(Ordering::Acquire) == session {
            match select3(
                sh.host_cancel.wait(),
                Timer::after_millis(HOST_STALL_MS),
                tx.write(&buf[off..n]),
            )
            .await
            {
                Either3::First(()) => break,
                Either3::Second(()) => {
                    warn!(
                        "the host did not read for 1 s; {=usize} bytes dropped",
                        n - off
                    );
                    sh.host_bytes_dropped
                        .fetch_add((n - off) as u32, Ordering::Relaxed);
                    break;
                }
                Either3::Third(Ok(k)) => off += k,
                Either3::Third(Err(_)) => break,
            }
        }
        let _ = tx.flush().await;
    }
}

/// Send what the proxy produced from the controller's bytes: commands to the stage controller
/// as [`send`]; what is for the host goes into its pipe as far as there is room and the rest is
/// dropped (counted) — waiting for a host that does not read would stop the stage link reading
/// the UART, and the controller's next bytes would be lost in the receive buffer.
async fn send_from_stage(sh: &Shared, out: &Output) {
    if !out.to_stage.is_empty() {
        sh.to_stage.write_all(out.to_stage.as_bytes()).await;
        sh.stage_sent.signal(());
    }
    let host_connected = sh
        .host_connected
        .load(core::sync::atomic::Ordering::Relaxed);
    let mut bytes = out.to_host.as_bytes();
    if !host_connected {
        return;
    }
    while !bytes.is_empty() {
        match sh.to_host.try_write(bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(_) => {
                warn!("host pipe full: {=usize} reply bytes dropped", bytes.len());
                sh.host_bytes_dropped
                    .fetch_add(bytes.len() as u32, Ordering::Relaxed);
                return;
            }
        }
    }
}

/// Send what the proxy produced: commands to the stage controller, answers to the host — unless
/// nobody has the host port open: what would be queued belongs to no connection.
async fn send(sh: &Shared, out: &Output) {
    if !out.to_stage.is_empty() {
        // (the stage link's re-issue of a held target waits until the line is all in the pipe)
        sh.host_to_stage.store(true, Ordering::Relaxed);
        sh.to_stage.write_all(out.to_stage.as_bytes()).await;
        sh.host_to_stage.store(false, Ordering::Relaxed);
        // the proxy may now wait for a reply: the stage link polls its timeout from now on
        sh.stage_sent.signal(());
    }
    let host_connected = sh.host_connected.load(Ordering::Relaxed);
    if !out.to_host.is_empty() && host_connected {
        sh.to_host.write_all(out.to_host.as_bytes()).await;
    }
}

/// Hand `buf` to the proxy through `step` until it has taken all of it, sending what it
/// produces each time. (When it takes nothing and produces nothing, a held line fills its
/// input: wait for the controller's answer.) `session` is the host session host bytes were
/// read in (they stop when it ends); `None` for the controller's bytes (sent as
/// [`send_from_stage`] sends).
async fn feed(
    sh: &Shared,
    buf: &[u8],
    out: &mut Output,
    session: Option<u32>,
    step: impl Fn(&mut Core, &[u8], &mut Output) -> usize,
) {
    let mut i = 0;
    while i < buf.len() {
        if session.is_some_and(|s| s != sh.host_session.load(Ordering::Acquire)) {
            // the host closed the port meanwhile: the rest belongs to no one
            return;
        }
        let used = sh.core.lock(|c| step(&mut c.borrow_mut(), &buf[i..], out));
        i += used;
        if session.is_none() {
            send_from_stage(sh, out).await;
        } else {
            send(sh, out).await;
        }
        if used == 0 && out.is_empty() {
            Timer::after_millis(1).await;
        }
    }
}

/// Host lines received earlier that the proxy can process now (after the controller answered
/// a held line's query), and the proxy's own answers that are due.
async fn resume(sh: &Shared, out: &mut Output) {
    // (called from the stage link: its output for the host must not wait for the host)
    loop {
        let worked = sh.core.lock(|c| {
            let mut c = c.borrow_mut();
            let c = &mut *c;
            if !c.proxy.has_work() {
                return false;
            }
            let now = now_ms();
            c.drive(now, |proxy, comp| proxy.host_bytes(comp, &[], now, out));
            true
        });
        if !worked {
            return;
        }
        send_from_stage(sh, out).await;
    }
}

/// At least one byte from the stage link into `buf`; `None` when the link lost bytes (a UART
/// overrun or a full receive buffer: the board's reader reports it as `InvalidData`). Other
/// errors are retried after a short pause, as [`read_some`] does.
async fn read_stage<R: Read>(rx: &mut R, buf: &mut [u8]) -> Option<usize> {
    loop {
        match rx.read(buf).await {
            Ok(n) if n > 0 => return Some(n),
            Err(e) if e.kind() == ErrorKind::InvalidData => return None,
            _ => Timer::after_millis(5).await,
        }
    }
}

/// The host link: GCS commands from the host go through the proxy to the stage controller (or
/// are answered by the proxy itself).
pub async fn host_link<R: Read, W: Write>(mut rx: R, mut tx: W, sh: &Shared) -> ! {
    let rx_loop = async {
        let mut out = Output::new();
        let mut buf = [0u8; 64];
        loop {
            let session = sh.host_session.load(Ordering::Acquire);
            // the line state first: when the port opened (a new session) before this task
            // looked again, the bytes already in are the new host's — taken first, they were
            // read under the old session and dropped, and a host that writes as soon as the
            // port is open lost its first bytes (`ERR?` reached the controller as `RR?`:
            // `e2e_proxy_findings_qemu`, finding 9, under load). (A pending read takes no byte:
            // dropping it loses nothing.)
            let n = match select(sh.host_hangup.wait(), read_some(&mut rx, &mut buf)).await {
                // the host closed or opened the port: nothing of the old connection survives
                // it (the session was ended where the line state changed)
                Either::First(()) => continue,
                Either::Second(n) => n,
            };
            if session != sh.host_session.load(Ordering::Acquire)
                || !sh.host_connected.load(Ordering::Relaxed)
            {
                // read in a session that has ended, or while the port is closed: no one's
                continue;
            }
            let _busy = sh.beats[task::HOST_IN].busy(now_ms());
            feed(sh, &buf[..n], &mut out, Some(session), |c, b, out| {
                let now = now_ms();
                c.drive(now, |proxy, comp| proxy.host_bytes(comp, b, now, out))
            })
            .await;
        }
    };
    join(rx_loop, host_pump(sh, &mut tx)).await;
    unreachable!()
}

/// The stage link: replies from the controller go through the proxy (positions mapped back) to
/// the host.
pub async fn stage_link<R: Read, W: Write>(mut rx: R, mut tx: W, sh: &Shared) -> ! {
    let rx_loop = async {
        let mut out = Output::new();
        let mut buf = [0u8; 64];
        loop {
            // poll the reply timeout only while a reply is awaited; otherwise sleep until the
            // controller sends or something is sent to it (a wake-up every 50 ms for nothing
            // was most of what the board did in a day on the virtual bench)
            let (awaiting, follow) = sh.core.lock(|c| {
                let c = c.borrow();
                (c.proxy.awaiting_controller(), c.proxy.follow_due())
            });
            let tick = async {
                if awaiting {
                    Timer::after_millis(POLL_MS).await
                } else if follow {
                    select(Timer::after_millis(FOLLOW_MS), sh.stage_sent.wait()).await;
                } else {
                    sh.stage_sent.wait().await
                }
            };
            match select(read_stage(&mut rx, &mut buf), tick).await {
                Either::First(Some(n)) => {
                    let _busy = sh.beats[task::STAGE_IN].busy(now_ms());
                    feed(sh, &buf[..n], &mut out, None, |c, b, out| {
                        let now = now_ms();
                        c.drive(now, |proxy, comp| proxy.stage_bytes(comp, b, now, out))
                    })
                    .await
                }
                Either::First(None) => {
                    warn!("stage link lost bytes: replies in flight dropped");
                    sh.core
                        .lock(|c| c.borrow_mut().proxy.stage_bytes_lost(now_ms()));
                }
                Either::Second(()) => {
                    sh.core.lock(|c| {
                        let mut c = c.borrow_mut();
                        let now = now_ms();
                        c.drive(now, |proxy, comp| proxy.poll(comp, now, &mut out))
                    });
                    send_from_stage(sh, &out).await;
                }
            }
            resume(sh, &mut out).await;
            if !sh.host_to_stage.load(Ordering::Relaxed) {
                // held targets that follow the model (nothing unless armed): the proxy's
                // check, or the re-issue once the check's reply is in (whole lines, never
                // inside a host line on its way)
                sh.core.lock(|c| {
                    let mut c = c.borrow_mut();
                    let now = now_ms();
                    c.drive(now, |proxy, comp| proxy.follow_tick(comp, now, &mut out))
                });
                send_from_stage(sh, &out).await;
            }
        }
    };
    join(rx_loop, stage_pump(sh, &mut tx)).await;
    unreachable!()
}
