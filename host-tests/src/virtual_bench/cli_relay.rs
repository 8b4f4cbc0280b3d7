//! The management port as a `nanocal` process sees it: a relay that announces its bytes.
//!
//! The board's clock holds while its reader waits for bytes the bench *announced*
//! (`BenchLink::announce`); the tests' own clients announce what they write. A `nanocal` CLI
//! that a test runs is another process and cannot: its request reached the board byte by byte,
//! whenever QEMU's main loop ran, with only the polling `InputWatch` between it and a clock that
//! ran on. On a loaded CI machine a CLI's first request was dropped at the board's frame timeout
//! and the CLI gave up ("no reply from the device within 5s (request: identify)").
//!
//! So the CLI talks to this relay instead of QEMU's socket: a Unix socket in the board's socket
//! folder. Each connection the relay accepts is carried to the management port (serial 3) on a
//! connection of its own, every byte announced before it is written, and every byte of the
//! board's back unchanged — the bytes the board reads are exactly the CLI's. One connection at a
//! time, as QEMU serves one client per port; the next waits until the previous has closed.

use super::link::{Announced, BenchLink};
use std::io::{Read, Write};
use std::net::Shutdown;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A relay from a Unix socket to the board's management port; stopped on drop.
pub(crate) struct CliRelay {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    accept: Option<JoinHandle<()>>,
}

impl CliRelay {
    /// Listen at `path`; relay each connection to the board's management socket `board`.
    pub(crate) fn start(path: PathBuf, board: PathBuf, link: Arc<BenchLink>) -> Self {
        let _ = std::fs::remove_file(&path);
        let listener = UnixListener::bind(&path).expect("bind the CLI relay's socket");
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let accept = std::thread::Builder::new()
            .name("cli-relay".into())
            .spawn(move || {
                for cli in listener.incoming() {
                    if stopping.load(Ordering::Acquire) {
                        break;
                    }
                    match cli {
                        Ok(cli) => relay_one(cli, &board, &link),
                        Err(e) => eprintln!("cli relay: accept failed: {e}"),
                    }
                }
            })
            .expect("spawn the CLI relay");
        Self {
            path,
            stop,
            accept: Some(accept),
        }
    }

    /// The port spec a `nanocal` process opens (`unix:PATH`).
    pub(crate) fn spec(&self) -> String {
        format!("unix:{}", self.path.display())
    }
}

impl Drop for CliRelay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        // wake the blocked accept
        let _ = UnixStream::connect(&self.path);
        if let Some(t) = self.accept.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Carry one CLI connection to the board until either side closes.
fn relay_one(cli: UnixStream, board: &Path, link: &Arc<BenchLink>) {
    // QEMU always listens (a connection waits in its backlog while it serves another)
    let deadline = Instant::now() + Duration::from_secs(20);
    let to_board = loop {
        match UnixStream::connect(board) {
            Ok(s) => break s,
            Err(e) if Instant::now() > deadline => {
                eprintln!("cli relay: the board's management port: {e}");
                return;
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let (Ok(from_board), Ok(mut to_cli)) = (to_board.try_clone(), cli.try_clone()) else {
        return;
    };
    let back = std::thread::spawn(move || {
        let mut from_board = from_board;
        let _ = std::io::copy(&mut from_board, &mut to_cli);
        let _ = to_cli.shutdown(Shutdown::Both);
    });
    let Ok(closer) = to_board.try_clone() else {
        return;
    };
    let mut w = Announced {
        inner: to_board,
        link: link.clone(),
        serial: 3,
    };
    let mut cli = cli;
    let mut buf = [0u8; 1024];
    loop {
        match cli.read(&mut buf) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Ok(0) | Err(_) => break,
            Ok(n) => {
                if w.write_all(&buf[..n]).is_err() {
                    break;
                }
            }
        }
    }
    // the CLI is done: QEMU sees the close and serves the next client
    let _ = closer.shutdown(Shutdown::Both);
    let _ = back.join();
}
