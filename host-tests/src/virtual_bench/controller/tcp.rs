//! The simulated controller on a byte stream (the QEMU board's stage link, a TCP socket), or on
//! the stage link's rings in the bench's page (`nanocal_interface::bench_link`, *Rings*).

use super::device::{Config, Controller, Event};
use super::plant::{IdealPlant, SystemClock};
use crate::virtual_bench::link::BenchLink;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver};
use std::sync::{Arc, Mutex};

/// A [`Controller`] served on a socket by a thread: every line (and single character) it
/// receives is recorded before it answers.
pub struct StageSim {
    pub(in crate::virtual_bench) lines: Receiver<String>,
    ctl: Arc<Mutex<Controller>>,
    /// Bytes taken in (and acted on) and bytes answered, for a bench that must know the link is
    /// drained before its clock moves on.
    bytes: Arc<[AtomicU64; 2]>,
}

impl StageSim {
    /// An E-727 with `axes` axes, servo already on, on ideal stages that arrive at once, and
    /// the wall clock.
    pub fn start(s: TcpStream, axes: usize) -> Self {
        let mut cfg = Config::e727(axes).ready();
        for a in &mut cfg.axes {
            a.velocity = 1e12;
        }
        Self::serve(s, cfg)
    }

    /// A controller with configuration `cfg` on ideal stages and the wall clock.
    pub fn serve(s: TcpStream, cfg: Config) -> Self {
        let start: Vec<f64> = cfg.axes.iter().map(|a| a.start).collect();
        let ctl = Controller::new(
            cfg,
            Box::new(IdealPlant::new(&start)),
            Arc::new(SystemClock::new()),
        );
        Self::serve_controller(s, ctl)
    }

    /// Any controller (its own plant and clock).
    pub fn serve_controller(s: TcpStream, ctl: Controller) -> Self {
        let (tx, rx) = channel();
        let ctl = Arc::new(Mutex::new(ctl));
        let c2 = ctl.clone();
        let bytes = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
        let counts = bytes.clone();
        std::thread::spawn(move || {
            let mut r = match s.try_clone() {
                Ok(r) => r,
                Err(_) => return,
            };
            let mut w = s;
            let mut b = [0u8; 512];
            loop {
                let n = match r.read(&mut b) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                let (reply, received) = {
                    let mut c = c2.lock().expect("controller lock");
                    let reply = c.input(&b[..n]);
                    (reply, c.take_received())
                };
                // record before replying, so a host that saw the reply sees the record
                for l in received {
                    if tx.send(l).is_err() {
                        return;
                    }
                }
                // counted before they go: a bench must not think the board has read them all
                counts[1].fetch_add(reply.len() as u64, Ordering::AcqRel);
                counts[0].fetch_add(n as u64, Ordering::AcqRel);
                if !reply.is_empty() && w.write_all(&reply).is_err() {
                    return;
                }
            }
        });
        Self {
            lines: rx,
            ctl,
            bytes,
        }
    }

    /// Any controller on serial `port`'s rings of `link` (the board asked for the port on its
    /// rings): no thread of its own — whoever waits on the board pumps it
    /// ([`BenchLink::set_pump`]): it takes in what the board wrote, and puts its reply in the
    /// ring to the board.
    pub fn on_ring(link: &Arc<BenchLink>, port: usize, ctl: Controller) -> Self {
        let (tx, rx) = channel();
        let ctl = Arc::new(Mutex::new(ctl));
        let bytes = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
        // reply bytes that did not fit the ring yet
        let pending: Mutex<Vec<u8>> = Mutex::new(Vec::new());
        let (c2, counts, l) = (ctl.clone(), bytes.clone(), Arc::downgrade(link));
        link.set_pump(Arc::new(move || {
            // one pump at a time; a thread that finds it busy goes on waiting
            let Ok(mut out) = pending.try_lock() else {
                return;
            };
            let Some(link) = l.upgrade() else {
                return;
            };
            if !out.is_empty() {
                let n = link.ring_write(port, &out);
                out.drain(..n);
            }
            if !link.ring_readable(port) {
                return;
            }
            let mut b = [0u8; 512];
            let n = link.ring_read(port, &mut b);
            let (reply, received) = {
                let mut c = c2.lock().expect("controller lock");
                let reply = c.input(&b[..n]);
                (reply, c.take_received())
            };
            // record before replying, so a host that saw the reply sees the record
            for line in received {
                let _ = tx.send(line);
            }
            // counted before they go: a bench must not think the board has read them all
            counts[1].fetch_add(reply.len() as u64, Ordering::AcqRel);
            counts[0].fetch_add(n as u64, Ordering::AcqRel);
            out.extend_from_slice(&reply);
            let n = link.ring_write(port, &out);
            out.drain(..n);
        }));
        Self {
            lines: rx,
            ctl,
            bytes,
        }
    }

    /// Bytes the controller has taken in and acted on (its replies counted in [`Self::bytes_out`]).
    pub fn bytes_in(&self) -> u64 {
        self.bytes[0].load(Ordering::Acquire)
    }

    /// Bytes the controller has sent back or is sending.
    pub fn bytes_out(&self) -> u64 {
        self.bytes[1].load(Ordering::Acquire)
    }

    /// Lines received so far, without waiting.
    pub fn drain(&self) -> Vec<String> {
        self.lines.try_iter().collect()
    }

    /// What happened to the stage since the last call.
    pub fn events(&self) -> Vec<Event> {
        self.with(|c| c.take_events())
    }

    /// Work on the controller itself (positions, targets, configuration).
    pub fn with<R>(&self, f: impl FnOnce(&mut Controller) -> R) -> R {
        f(&mut self.ctl.lock().expect("controller lock"))
    }
}
