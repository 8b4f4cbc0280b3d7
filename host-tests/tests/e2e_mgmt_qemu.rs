//! Device state you can trust over the management port, through the QEMU firmware (issue 21,
//! items 7 and 8):
//!
//! - the status names the model in service by its id *and* its content hash (the CRC-32 its
//!   blob carries): two uploads of blobs that differ only in one coefficient (same id) show
//!   different hashes, the same blob the same hash — also after a reset, from flash — in the
//!   client's status and in `nanocal device status`;
//! - a management frame cut off by a closing connection (the 26 bytes of a chunk frame
//!   announcing 260) does not leave the port deaf: the board drops it when its time is up
//!   (`FRAME_TIMEOUT_MS` of the board's clock, measured in lockstep) or at once when the port's
//!   line state falls, and the requests after it are answered;
//! - a request whose bytes QEMU hands over slowly (slower than the frame timeout) is dropped,
//!   unless the bench announced them: then the board's clock holds until they are in;
//! - a host that stops reading its replies loses them, not the board: the board's clock goes
//!   on while its replies wait for room (each is dropped after 1 s), the board does not reset,
//!   and the next connection's request is answered.
//!
//! Without qemu-system-arm the tests are skipped with a loud message, except in CI.

mod fw_sim;

use fw_sim::nanocal_cli;

use fw_sim::{wait_for, wait_until, Qemu, SensorSim, StageSim, HANG};
use nanocal::papers::published::published_1dof;
use nanocal_interface::bench_link as bl;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::{Decoder, Kind, Reply, Request, FRAME_TIMEOUT_MS, MAX_FRAME};
use nanocal_interface::status::{Flags, Status};
use nanocal_model::blob;
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

/// Temperatures the simulated sensors report (inside the published model's envelope).
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];

/// The published 1-DoF model's blob, and the same blob with its last term's coefficient
/// changed by one part in a million (same id, CRC recomputed): the issue's "changed
/// coefficients under the same id".
fn two_blobs() -> (Vec<u8>, Vec<u8>) {
    let model = published_1dof().unwrap();
    let mut a = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut a).unwrap();
    a.truncate(n);
    let mut b = a.clone();
    // the last term's coefficient is the f64 before the provenance (the model has no bound)
    let at = n - blob::TRAILER_LEN - blob::PROVENANCE_LEN - 8;
    let c = f64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    b[at..at + 8].copy_from_slice(&(c * (1.0 + 1e-6)).to_le_bytes());
    let crc = blob::crc32(&b[..n - blob::TRAILER_LEN]);
    b[n - blob::TRAILER_LEN..].copy_from_slice(&crc.to_le_bytes());
    let (ma, mb) = (blob::decode(&a).unwrap(), blob::decode(&b).unwrap());
    assert_eq!(ma.id(), mb.id(), "the same id");
    assert_ne!(ma, mb, "other coefficients");
    (a, b)
}

#[test]
fn model_hash_tells_models_with_one_id_apart_under_qemu() {
    let Some(mut q) = Qemu::start_or_skip("model_hash_tells_models_with_one_id_apart_under_qemu")
    else {
        return;
    };
    let clk = q.clock();
    let _stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let (a, b) = two_blobs();
    let (crc_a, crc_b) = (blob::stored_crc(&a).unwrap(), blob::stored_crc(&b).unwrap());
    assert_ne!(crc_a, crc_b);
    let id = blob::decode(&a).unwrap().id();
    let dir = std::env::temp_dir().join(format!("nanocal-e2e-mgmt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let spec = q.cli_spec();
    drop(q.client()); // the board is up and answering

    let mut seen = vec![];
    for (name, bytes, crc) in [("a", &a, crc_a), ("b", &b, crc_b), ("a", &a, crc_a)] {
        let path = dir.join(format!("{name}.blob"));
        std::fs::write(&path, bytes).unwrap();
        let up = nanocal_cli(&["device", "upload", "--port", &spec, path.to_str().unwrap()]);
        assert!(
            up.contains(&format!("model {id:#010x} (blob CRC {crc:#010x})")),
            "{up}"
        );
        let mut c = q.client();
        let s = c.status().unwrap();
        assert!(s.flags.contains(Flags::MODEL));
        assert_eq!((s.model_id, s.model_crc32), (id, crc), "blob {name}");
        drop(c);
        let text = nanocal_cli(&["device", "status", "--port", &spec]);
        assert!(
            text.contains(&format!("model: {id:#010x}  blob CRC {crc:#010x}")),
            "{text}"
        );
        seen.push(s.model_crc32);
    }
    assert_ne!(
        seen[0], seen[1],
        "blobs differing in a coefficient: other hashes"
    );
    assert_eq!(seen[0], seen[2], "the same blob: the same hash");
    let _ = std::fs::remove_dir_all(&dir);

    // after a reset the model comes back from flash with the same hash
    let mut c = q.client();
    let boots = q.link().boots();
    c.reset().unwrap();
    drop(c);
    wait_until("the reset", &clk, 10.0, || {
        (q.link().boots() > boots).then_some(())
    });
    let mut c = q.client();
    let s = wait_until("model reloaded", &clk, 20.0, || {
        let s = c.status().ok()?;
        s.flags.contains(Flags::MODEL).then_some(s)
    });
    assert_eq!((s.model_id, s.model_crc32), (id, crc_a));
}

/// The first 26 bytes of an `UPLOAD_CHUNK` frame announcing 260 payload bytes: where the
/// issue's connection closed.
fn cut_chunk() -> Vec<u8> {
    let bytes = [0x5Au8; 256];
    let req = Request::UploadChunk {
        offset: 0,
        bytes: &bytes,
    };
    let mut f = [0u8; MAX_FRAME];
    req.frame(1, &mut f).unwrap();
    assert_eq!(u16::from_le_bytes([f[4], f[5]]), 260);
    f[..26].to_vec()
}

/// Send [`cut_chunk`] on `s` and wait until the board has read every byte of it, before the
/// caller closes the connection (QEMU drops what it has not handed to the UART when the
/// connection closes: the cut would not be what the board sees).
fn send_cut(q: &Qemu, s: &mut UnixStream) {
    let link = q.link();
    let had = link.rx_bytes(3);
    let cut = cut_chunk();
    s.write_all(&cut).unwrap();
    let want = had.wrapping_add(cut.len() as u32);
    wait_for(q, "the board reading the cut frame", || {
        link.rx_bytes(3) == want
    });
}

/// A raw management connection: requests written whole, replies read as they come.
struct Raw {
    s: UnixStream,
    dec: Decoder,
}

impl Raw {
    fn open(q: &mut Qemu) -> Raw {
        Raw::over(q.mgmt_stream())
    }

    /// Over a connection already open (e.g. to the `nanocal` processes' relay).
    fn over(s: UnixStream) -> Raw {
        s.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        Raw {
            s,
            dec: Decoder::new(),
        }
    }

    fn send(&mut self, seq: u8) {
        let mut f = [0u8; MAX_FRAME];
        let n = Request::Status.frame(seq, &mut f).unwrap();
        self.s.write_all(&f[..n]).unwrap();
    }

    /// The status answering request `seq`, if it has come (waits ≤ 50 ms of wall time).
    fn poll(&mut self, seq: u8) -> Option<Status> {
        let mut buf = [0u8; 512];
        let n = match self.s.read(&mut buf) {
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                0
            }
            Err(e) => panic!("management port: {e}"),
        };
        let mut got = None;
        for &b in &buf[..n] {
            let mut ev = self.dec.feed(b, 0);
            while let Some(e) = ev {
                if e.is_ok() {
                    let f = self.dec.frame();
                    if f.kind == Kind::Status.reply_code() && f.seq == seq {
                        match Reply::decode(Kind::Status, f.payload) {
                            Ok(Reply::Status(s)) => got = Some(s),
                            other => panic!("status reply: {other:?}"),
                        }
                    }
                }
                ev = self.dec.next(0);
            }
        }
        got
    }

    /// The status answering `seq` with the board's clock held: it must come without any of
    /// the board's time passing.
    fn status_now(&mut self, q: &Qemu, seq: u8) -> Status {
        self.send(seq);
        for _ in 0..(HANG.as_millis() / 50) {
            if let Some(s) = self.poll(seq) {
                return s;
            }
            q.link().wake_for_input();
        }
        panic!("no status reply within {HANG:?} of wall time");
    }
}

#[test]
fn a_cut_management_frame_does_not_deafen_the_port_under_qemu() {
    let Some(mut q) =
        Qemu::start_or_skip("a_cut_management_frame_does_not_deafen_the_port_under_qemu")
    else {
        return;
    };
    let clk = q.clock();
    let _stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let spec = q.cli_spec();
    drop(q.client()); // the board is up and answering

    // the scenario, as it happened: a connection closes 26 bytes into a chunk frame
    // announcing 260 (no line state: a TCP-like port), then `nanocal device status` and 24
    // more requests — each answered
    let mut cut = q.mgmt_stream();
    send_cut(&q, &mut cut);
    drop(cut);
    let text = nanocal_cli(&["device", "status", "--port", &spec]);
    assert!(text.contains("model: none"), "{text}");
    let mut c = q.client();
    for i in 0..24 {
        c.status()
            .unwrap_or_else(|e| panic!("request {} after the cut: {e}", i + 1));
    }
    drop(c);

    // with the board's clock held, a request after a cut frame is answered once
    // FRAME_TIMEOUT_MS of the board's time have passed, not before and not much later
    clk.lockstep();
    let mut raw = Raw::open(&mut q);
    let before = raw.status_now(&q, 1);
    send_cut(&q, &mut raw.s);
    drop(raw);
    let mut raw = Raw::open(&mut q);
    raw.send(2);
    let step_s = 0.05;
    let sent_s = clk.now_s();
    let mut t = sent_s;
    let after = loop {
        if let Some(s) = (0..4).find_map(|_| raw.poll(2)) {
            break s;
        }
        q.link().wake_for_input();
        // from when the request went, not from the last step (which never exceeds one step:
        // a swallowed request looped here for ever instead of failing)
        let waited_ms = (clk.now_s() - sent_s) * 1000.0;
        assert!(
            waited_ms < 4.0 * f64::from(FRAME_TIMEOUT_MS),
            "the request after the cut frame was swallowed"
        );
        t += step_s;
        clk.advance_to(t, HANG).unwrap();
    };
    let waited_ms = after.uptime_ms - before.uptime_ms;
    assert!(
        (FRAME_TIMEOUT_MS..=FRAME_TIMEOUT_MS + 150).contains(&waited_ms),
        "answered {waited_ms} ms of board time after the cut (the timeout is {FRAME_TIMEOUT_MS} ms)"
    );

    // the port's line state falling (the host closed it) drops the cut frame at once: the
    // next connection's request is answered without the board's time moving
    let before = raw.status_now(&q, 3);
    send_cut(&q, &mut raw.s);
    q.set_mgmt_dtr(false);
    drop(raw);
    let mut raw = Raw::open(&mut q);
    q.set_mgmt_dtr(true);
    let after = raw.status_now(&q, 4);
    assert_eq!(
        after.uptime_ms, before.uptime_ms,
        "answered at once, not at the timeout"
    );
    clk.free_run(1.0);
}

/// A management host that sends requests and stops reading (their replies outgrow what the
/// port's socket holds unread: a Unix socket takes ≈ 280 one-byte writes, QEMU's UART hands it
/// one byte at a time, a STATUS reply frame is 301 bytes). The board's writer then waits for
/// room; the board's clock must go on meanwhile — the reply is dropped after the management
/// task's 1 s, the supervisor pets the watchdog — and the board answers the next connection.
/// (A writer that waited in a `yield_now` loop kept the executor busy: the board's clock
/// stood still and QEMU's watchdog reset the board — what the cut-frame test above met when
/// the STATUS reply grew by 51 bytes.)
#[test]
fn a_host_that_stops_reading_loses_its_replies_not_the_board_under_qemu() {
    let Some(mut q) =
        Qemu::start_or_skip("a_host_that_stops_reading_loses_its_replies_not_the_board_under_qemu")
    else {
        return;
    };
    let clk = q.clock();
    let _stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    let up0_ms = q.client().status().unwrap().uptime_ms;
    let link = q.link();
    let boots = link.boots();

    clk.lockstep();
    let mut raw = Raw::open(&mut q);
    // eight replies of 301 bytes: many times what the socket takes unread
    let requests = 8u8;
    for seq in 1..=requests {
        raw.send(seq);
    }
    let (before_s, step_s) = (clk.now_s(), 0.1);
    // ten seconds of the board's time pass while nobody reads (8 replies × their 1 s, and more
    // than the watchdog's 4 s): each step must end with the board idle at its horizon
    for i in 1..=100 {
        clk.advance_to(before_s + f64::from(i) * step_s, HANG)
            .unwrap_or_else(|e| {
                panic!("the board's clock stood still while the host did not read: {e}")
            });
    }
    assert_eq!(
        link.boots(),
        boots,
        "the board reset while its replies waited for room"
    );
    // what the socket held: the replies did wait (and were dropped), else the test proved
    // nothing
    let mut got = 0usize;
    let mut buf = [0u8; 4096];
    while let Ok(n @ 1..) = raw.s.read(&mut buf) {
        got += n;
    }
    assert!(
        got < usize::from(requests) * 301,
        "all {got} bytes of the replies went out: none waited for room"
    );

    // the host comes back on a new connection: answered at once, by the board that never reset
    drop(raw);
    let mut raw = Raw::open(&mut q);
    let s = raw.status_now(&q, 9);
    assert_eq!(s.reset_cause, ResetCause::PowerOn, "{s:?}");
    assert!(
        s.uptime_ms >= up0_ms + 10_000,
        "the board's time went on: uptime {} ms, {up0_ms} ms before",
        s.uptime_ms
    );
    clk.free_run(1.0);
}

/// QEMU hands a serial port's bytes to the board one at a time, when its main loop runs; on a
/// busy machine a frame written in one piece can take longer than the frame timeout to go in.
/// Here the test plays that slow loop itself: it writes a status request's first byte, waits
/// until the free-running bench clock has gone well past the frame timeout, then writes the
/// rest. Unannounced, the board's clock runs on and the frame is dropped (the failure CI saw);
/// announced (`BenchLink::announce`, as the tests' clients do), the board's clock holds while
/// its reader waits for the rest, and the request is answered at the instant its first byte came.
#[test]
fn a_request_that_trickles_in_is_answered_when_announced_and_dropped_when_not() {
    let Some(mut q) = Qemu::start_or_skip(
        "a_request_that_trickles_in_is_answered_when_announced_and_dropped_when_not",
    ) else {
        return;
    };
    let clk = q.clock();
    let link = q.link();
    let _stage = StageSim::start(q.connect(1), 1);
    let _sensors = SensorSim::start(q.link(), &TEMPS_C);
    drop(q.client()); // the board is up and answering
                      // ten seconds of board time per second of wall time: the timeout passes quickly
    clk.lockstep();
    clk.free_run(10.0);
    let timeout_s = f64::from(FRAME_TIMEOUT_MS) / 1000.0;
    let horizon_s = || bl::ticks_to_s(link.page().u64(bl::HORIZON));
    let mut raw = Raw::open(&mut q);
    let mut frame = [0u8; MAX_FRAME];

    // unannounced: dropped
    let n = Request::Status.frame(1, &mut frame).unwrap();
    let rx0 = link.rx_bytes(3);
    raw.s.write_all(&frame[..1]).unwrap();
    wait_for(&q, "the board reads the first byte", || {
        link.rx_bytes(3) == rx0.wrapping_add(1)
    });
    let first_s = link.now_s();
    wait_for(&q, "the board's clock passes the frame timeout", || {
        link.now_s() > first_s + 2.0 * timeout_s
    });
    raw.s.write_all(&frame[1..n]).unwrap();
    wait_for(&q, "the board reads the rest", || {
        link.rx_bytes(3) == rx0.wrapping_add(n as u32)
    });
    let rest_s = link.now_s();
    let mut answered = false;
    wait_for(&q, "the board's clock runs on", || {
        answered |= raw.poll(1).is_some();
        link.now_s() > rest_s + 2.0 * timeout_s
    });
    assert!(
        !answered,
        "a frame whose bytes came {:.2} s of board time apart was answered (the frame timeout is {timeout_s} s)",
        rest_s - first_s
    );

    // announced: held and answered
    let n = Request::Status.frame(2, &mut frame).unwrap();
    let rx0 = link.rx_bytes(3);
    assert!(link.announce(3, n), "free-running: the bytes are counted");
    raw.s.write_all(&frame[..1]).unwrap();
    wait_for(&q, "the board reads the first byte", || {
        link.rx_bytes(3) == rx0.wrapping_add(1)
    });
    let first_s = link.now_s();
    wait_for(&q, "the bench's horizon passes the frame timeout", || {
        horizon_s() > first_s + 2.0 * timeout_s
    });
    assert_eq!(
        link.now_s(),
        first_s,
        "the board's clock moved while its reader waited for announced bytes"
    );
    raw.s.write_all(&frame[1..n]).unwrap();
    let mut status = None;
    wait_for(&q, "the announced request is answered", || {
        status = raw.poll(2);
        status.is_some()
    });
    assert_eq!(
        link.forgiven_bytes(),
        0,
        "no announced byte was given up on"
    );

    // a `nanocal` process's request, through the relay a test gives it (`Qemu::cli_spec`): the
    // relay announces every byte it carries, so the board's announced count ends equal to what
    // it read (unannounced, the count stays where it was)
    drop(raw);
    let spec = q.cli_spec();
    let path = spec.strip_prefix("unix:").unwrap();
    let mut cli = Raw::over(UnixStream::connect(path).unwrap());
    let n = Request::Status.frame(3, &mut frame).unwrap();
    let rx0 = link.rx_bytes(3);
    cli.s.write_all(&frame[..n]).unwrap();
    let mut status = None;
    wait_for(&q, "the relayed request is answered", || {
        status = cli.poll(3);
        status.is_some()
    });
    assert_eq!(link.rx_bytes(3), rx0.wrapping_add(n as u32));
    assert_eq!(
        link.page().u32(bl::ANNOUNCED + 4 * 3),
        rx0.wrapping_add(n as u32),
        "the relay announced exactly the bytes the board read"
    );
}
