//! Host link and stage link: bytes ↔ `nanocal_compensator::proxy::Proxy`.
//!
//! Both links hand the proxy whole read buffers; the proxy takes as much as it can before it has
//! output (one line, one single-character command, one reply or a buffer-full of relayed
//! bytes), the link sends that output and hands over the rest. Replies stream through as they
//! arrive; a line the proxy holds until the controller answered its own query is resumed from
//! the stage link, which also gives the proxy the time for its reply timeout.

use super::{read_some, Core, Shared, PIPE_LEN};
use core::sync::atomic::Ordering;
use embassy_futures::join::join;
use embassy_futures::select::{select, Either};
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, Write};
use nanocal_compensator::proxy::Output;

/// How often the stage link lets the proxy check its reply timeout, ms.
const POLL_MS: u64 = 50;

fn now_ms() -> u32 {
    Instant::now().as_millis() as u32
}

async fn pump<W: Write>(pipe: &embassy_sync::pipe::Pipe<super::Cs, PIPE_LEN>, tx: &mut W) -> ! {
    let mut buf = [0u8; 128];
    loop {
        let n = pipe.read(&mut buf).await;
        if tx.write_all(&buf[..n]).await.is_err() {
            warn!("link write failed; {=usize} bytes dropped", n);
        }
        let _ = tx.flush().await;
    }
}

/// Send what the proxy produced: commands to the stage controller, answers to the host — unless
/// nobody has the host port open: what would be queued belongs to no connection.
async fn send(sh: &Shared, out: &Output) {
    if !out.to_stage.is_empty() {
        sh.to_stage.write_all(out.to_stage.as_bytes()).await;
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
/// input: wait for the controller's answer.) Host bytes stop when their session ends
/// (`session`: the session they were read in).
async fn feed(
    sh: &Shared,
    buf: &[u8],
    out: &mut Output,
    session: Option<u32>,
    step: impl Fn(&mut Core, &[u8], &mut Output) -> usize,
) {
    let mut i = 0;
    while i < buf.len() {
        if session.is_some_and(|s| s != sh.session.load(Ordering::Relaxed)) {
            // the host closed the port meanwhile: the rest belongs to no one
            return;
        }
        let used = sh.core.lock(|c| step(&mut c.borrow_mut(), &buf[i..], out));
        i += used;
        send(sh, out).await;
        if used == 0 && out.is_empty() {
            Timer::after_millis(1).await;
        }
    }
}

/// Host lines received earlier that the proxy can process now (after the controller answered
/// a held line's query), and the proxy's own answers that are due.
async fn resume(sh: &Shared, out: &mut Output) {
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
        send(sh, out).await;
    }
}

/// The host link: GCS commands from the host go through the proxy to the stage controller (or
/// are answered by the proxy itself).
pub async fn host_link<R: Read, W: Write>(mut rx: R, mut tx: W, sh: &Shared) -> ! {
    let rx_loop = async {
        let mut out = Output::new();
        let mut buf = [0u8; 64];
        loop {
            let session = sh.session.load(Ordering::Relaxed);
            let n = match select(read_some(&mut rx, &mut buf), sh.host_hangup.wait()).await {
                Either::First(n) => n,
                // the host closed or opened the port: nothing of the old connection survives
                // it (the session was ended where the line state changed)
                Either::Second(()) => continue,
            };
            if session != sh.session.load(Ordering::Relaxed)
                || !sh.host_connected.load(Ordering::Relaxed)
            {
                // read in a session that has ended, or while the port is closed: no one's
                continue;
            }
            feed(sh, &buf[..n], &mut out, Some(session), |c, b, out| {
                let now = now_ms();
                c.drive(now, |proxy, comp| proxy.host_bytes(comp, b, now, out))
            })
            .await;
        }
    };
    join(rx_loop, pump(&sh.to_host, &mut tx)).await;
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
            let awaiting = sh.core.lock(|c| c.borrow().proxy.awaiting_controller());
            let tick = async {
                if awaiting {
                    Timer::after_millis(POLL_MS).await
                } else {
                    sh.stage_sent.wait().await
                }
            };
            match select(read_some(&mut rx, &mut buf), tick).await {
                Either::First(n) => {
                    feed(sh, &buf[..n], &mut out, None, |c, b, out| {
                        let now = now_ms();
                        c.drive(now, |proxy, comp| proxy.stage_bytes(comp, b, now, out))
                    })
                    .await
                }
                Either::Second(()) => {
                    sh.core.lock(|c| {
                        let mut c = c.borrow_mut();
                        let now = now_ms();
                        c.drive(now, |proxy, comp| proxy.poll(comp, now, &mut out))
                    });
                    send(sh, &out).await;
                }
            }
            resume(sh, &mut out).await;
        }
    };
    join(rx_loop, pump(&sh.to_stage, &mut tx)).await;
    unreachable!()
}
