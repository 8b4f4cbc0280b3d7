//! Host link and stage link: bytes ↔ lines ↔ proxy.

use super::{read_some, Shared, PIPE_LEN};
use embassy_futures::join::join;
use embassy_futures::select::{select, Either};
use embedded_io_async::{Read, Write};
use nanocal_compensator::gcs::{Feed, LineAssembler};
use nanocal_compensator::proxy::{Out, Route};

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

async fn route(sh: &Shared, route: Route, out: &Out) {
    match route {
        Route::Stage => sh.to_stage.write_all(out.as_bytes()).await,
        // nobody has the port open: what would be queued belongs to no connection
        Route::Host
            if !sh
                .host_connected
                .load(core::sync::atomic::Ordering::Relaxed) => {}
        Route::Host => sh.to_host.write_all(out.as_bytes()).await,
        Route::None => {}
    }
}

/// The host link: GCS lines from the host go through the proxy to the stage controller (or are
/// answered by the proxy itself); bytes for the host are written out.
pub async fn host_link<R: Read, W: Write>(mut rx: R, mut tx: W, sh: &Shared) -> ! {
    let rx_loop = async {
        let mut asm = LineAssembler::new();
        let mut out = Out::new();
        let mut buf = [0u8; 64];
        loop {
            let n = match select(read_some(&mut rx, &mut buf), sh.host_hangup.wait()).await {
                Either::First(n) => n,
                Either::Second(()) => {
                    // the host closed the port: nothing of that connection survives it
                    asm = LineAssembler::new();
                    super::end_host_session(sh);
                    continue;
                }
            };
            for &b in &buf[..n] {
                let feed = asm.feed(b);
                if feed == Feed::Pending {
                    continue;
                }
                let r = sh.core.lock(|c| {
                    let mut c = c.borrow_mut();
                    let c = &mut *c;
                    c.proxy
                        .host_feed(c.comp.as_ref(), feed, asm.line(), &mut out)
                });
                route(sh, r, &out).await;
            }
        }
    };
    join(rx_loop, pump(&sh.to_host, &mut tx)).await;
    unreachable!()
}

/// The stage link: replies from the controller go through the proxy (POS?/MOV? mapped back) to
/// the host; bytes for the controller are written out.
pub async fn stage_link<R: Read, W: Write>(mut rx: R, mut tx: W, sh: &Shared) -> ! {
    let rx_loop = async {
        let mut asm = LineAssembler::replies();
        let mut out = Out::new();
        let mut buf = [0u8; 64];
        loop {
            let n = read_some(&mut rx, &mut buf).await;
            for &b in &buf[..n] {
                let r = match asm.feed(b) {
                    Feed::Line => sh.core.lock(|c| {
                        let mut c = c.borrow_mut();
                        let c = &mut *c;
                        c.proxy.stage_line(c.comp.as_ref(), asm.line(), &mut out)
                    }),
                    _ => Route::None,
                };
                route(sh, r, &out).await;
            }
        }
    };
    join(rx_loop, pump(&sh.to_stage, &mut tx)).await;
    unreachable!()
}
