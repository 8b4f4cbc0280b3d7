//! Bytes on their way into the QEMU board that the board has not taken yet.
//!
//! The QEMU board's clock moves only while its executor is idle, up to a horizon the bench
//! sets; free-running, the bench moves the horizon with the wall clock. Its time driver
//! (`src/qemu/time.rs`) relies on the bench holding the horizon while it sends input. A test
//! that writes to a serial port does not: QEMU's UART takes one byte at a time, and only when
//! QEMU's main loop runs. On a loaded machine QEMU can be off the CPU for longer than the
//! management decoder's frame timeout (500 ms of board time), and the board then sees a
//! frame's first byte, half a second of silence, and the rest — so it drops a frame the host
//! wrote in one piece. A real USB CDC link delivers a written frame within a millisecond or
//! two. This watch tells the free-running clock that input is still in flight, so board time
//! does not age it (see `BenchLink::free_run`).
//!
//! It looks from outside, by polling, so a starved bench thread can miss a byte in flight.
//! Writers in this process therefore also *announce* what they write (`BenchLink::announce`:
//! the tests' management client and GCS host), and the board itself holds its clock while a
//! reader waits for announced bytes — no polling in between. A `nanocal` CLI that a test runs
//! as another process reaches the board through a relay that announces for it
//! (`cli_relay.rs`). The watch remains for writers that cannot announce: PIPython on the GCS
//! port (the campaign runs the board in lockstep, where nothing needs announcing).
//!
//! - TCP ports (serial 0–2): the receive queue of QEMU's accepted socket, from `/proc/net/tcp`
//!   (the sender's own queue empties as soon as the loopback peer's kernel has the bytes).
//! - Unix sockets (serial 3, the management port): the receive queue (`FIONREAD`, unix(7)) of
//!   QEMU's accepted sockets on that path, whoever the client is (a test's own client, or the
//!   `nanocal` CLI in another process). `/proc/net/unix` names the sockets bound to the path (an
//!   accepted socket carries its listener's path) by inode; the watch takes a duplicate of
//!   QEMU's descriptor for each (`pidfd_getfd(2)`: QEMU is this process's child) and reads its
//!   queue.

use std::collections::HashMap;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The ways into the board the bench watches for input in flight.
#[derive(Default)]
pub struct InputWatch {
    tcp_ports: Mutex<Vec<u16>>,
    unix: Mutex<Option<UnixWatch>>,
}

/// QEMU's accepted sockets on one unix path.
struct UnixWatch {
    /// QEMU (the process that accepted the connections).
    pid: u32,
    path: PathBuf,
    /// A pidfd of QEMU, opened on first use.
    pidfd: Option<OwnedFd>,
    /// QEMU's descriptor number of each socket, by inode (checked before each use).
    fd_of: HashMap<u64, i32>,
}

impl InputWatch {
    /// Watch the loopback TCP port QEMU listens on for a serial port.
    pub fn watch_tcp_port(&self, port: u16) {
        self.tcp_ports.lock().unwrap().push(port);
    }

    /// Watch the connections QEMU (process `pid`, a child of this one) accepts on the unix
    /// socket at `path`.
    pub fn watch_unix_path(&self, pid: u32, path: &Path) {
        *self.unix.lock().unwrap() = Some(UnixWatch {
            pid,
            path: path.to_path_buf(),
            pidfd: None,
            fd_of: HashMap::new(),
        });
    }

    /// Bytes written towards the board and not yet taken by it (summed over every watched way).
    pub fn pending_bytes(&self) -> u64 {
        let mut total = 0u64;
        let ports = self.tcp_ports.lock().unwrap().clone();
        if !ports.is_empty() {
            if let Ok(table) = std::fs::read_to_string("/proc/net/tcp") {
                total += tcp_unread(&table, &ports);
            }
        }
        if let Some(w) = self.unix.lock().unwrap().as_mut() {
            total += w.unread();
        }
        total
    }
}

impl UnixWatch {
    /// Bytes queued towards QEMU on its connections at the path. Each look takes a duplicate of
    /// QEMU's descriptor and closes it again: holding one would keep the connection open after
    /// QEMU closed it (its client would never see the end).
    fn unread(&mut self) -> u64 {
        let Ok(table) = std::fs::read_to_string("/proc/net/unix") else {
            return 0;
        };
        let inodes = unix_connected_inodes(&table, &self.path);
        self.fd_of.retain(|i, _| inodes.contains(i));
        let mut total = 0;
        for inode in inodes {
            let theirs = match self.fd_of.get(&inode) {
                Some(&n) if fd_names(self.pid, n, inode) => n,
                _ => match self.find_fd(inode) {
                    Some(n) => n,
                    None => continue,
                },
            };
            if let Some(fd) = self.duplicate(theirs) {
                total += queued(fd.as_raw_fd());
            }
        }
        total
    }

    /// QEMU's descriptor number of socket `inode`.
    fn find_fd(&mut self, inode: u64) -> Option<i32> {
        let dir = std::fs::read_dir(format!("/proc/{}/fd", self.pid)).ok()?;
        for e in dir.flatten() {
            let Some(n) = e.file_name().to_str().and_then(|n| n.parse::<i32>().ok()) else {
                continue;
            };
            if fd_names(self.pid, n, inode) {
                self.fd_of.insert(inode, n);
                return Some(n);
            }
        }
        None
    }

    /// A duplicate of QEMU's descriptor `theirs` (pidfd_getfd(2): QEMU is our child).
    fn duplicate(&mut self, theirs: i32) -> Option<OwnedFd> {
        if self.pidfd.is_none() {
            // SAFETY: a plain syscall with integer arguments; a failure is a negative return.
            let r = unsafe { libc::syscall(libc::SYS_pidfd_open, self.pid as libc::pid_t, 0) };
            if r < 0 {
                return None;
            }
            // SAFETY: pidfd_open returned a new descriptor that we own.
            self.pidfd = Some(unsafe { OwnedFd::from_raw_fd(r as RawFd) });
        }
        let pidfd = self.pidfd.as_ref()?.as_raw_fd();
        // SAFETY: as above; on success the result is a new descriptor that we own.
        let r = unsafe { libc::syscall(libc::SYS_pidfd_getfd, pidfd, theirs, 0) };
        // SAFETY: pidfd_getfd returned a new descriptor.
        (r >= 0).then(|| unsafe { OwnedFd::from_raw_fd(r as RawFd) })
    }
}

/// True when descriptor `n` of process `pid` is socket `inode`.
fn fd_names(pid: u32, n: i32, inode: u64) -> bool {
    std::fs::read_link(format!("/proc/{pid}/fd/{n}"))
        .ok()
        .and_then(|t| t.to_str().map(|t| t == format!("socket:[{inode}]")))
        .unwrap_or(false)
}

/// Inodes of the connected sockets bound to `path` in the text of `/proc/net/unix` (proc(5):
/// `Num RefCount Protocol Flags Type St Inode Path`; St 03 = connected).
fn unix_connected_inodes(table: &str, path: &Path) -> Vec<u64> {
    let want = path.to_string_lossy();
    table
        .lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<&str> = line.split_whitespace().collect();
            (f.len() >= 8 && f[5] == "03" && f[7] == want)
                .then(|| f[6].parse().ok())
                .flatten()
        })
        .collect()
}

/// Bytes in a socket's receive queue (`FIONREAD`; 0 on a listening socket or an error).
fn queued(fd: RawFd) -> u64 {
    let mut n: libc::c_int = 0;
    // SAFETY: FIONREAD writes one int into `n`.
    let r = unsafe { libc::ioctl(fd, libc::FIONREAD, &mut n) };
    if r == 0 && n > 0 {
        n as u64
    } else {
        0
    }
}

/// Unread bytes in the receive queues of established sockets whose local port is one of
/// `ports`, from the text of `/proc/net/tcp` (proc(5): `local_address rem_address st
/// tx_queue:rx_queue …`, hexadecimal).
fn tcp_unread(table: &str, ports: &[u16]) -> u64 {
    let mut total = 0;
    for line in table.lines().skip(1) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let (Some(local), Some(state), Some(queues)) = (f.get(1), f.get(3), f.get(4)) else {
            continue;
        };
        let Some(port) = local
            .rsplit(':')
            .next()
            .and_then(|p| u16::from_str_radix(p, 16).ok())
        else {
            continue;
        };
        // 01 = ESTABLISHED (a listening socket's rx_queue is its accept backlog)
        if *state != "01" || !ports.contains(&port) {
            continue;
        }
        if let Some(rx) = queues
            .split(':')
            .nth(1)
            .and_then(|q| u64::from_str_radix(q, 16).ok())
        {
            total += rx;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    #[test]
    fn unix_bytes_count_until_the_listener_side_reads_them_whoever_sent_them() {
        use std::os::unix::net::{UnixListener, UnixStream};
        let dir = std::env::temp_dir().join(format!("nanocal-watch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s3");
        let _ = std::fs::remove_file(&path);
        let l = UnixListener::bind(&path).unwrap();
        let w = InputWatch::default();
        // this process plays QEMU: it holds the accepted end
        w.watch_unix_path(std::process::id(), &path);
        let mut a = UnixStream::connect(&path).unwrap();
        let (mut b, _) = l.accept().unwrap();
        assert_eq!(w.pending_bytes(), 0);
        a.write_all(b"HELLO").unwrap();
        assert_eq!(w.pending_bytes(), 5);
        let mut buf = [0u8; 3];
        b.read_exact(&mut buf).unwrap();
        assert_eq!(w.pending_bytes(), 2);
        // a second client (another session) counts too
        let mut c = UnixStream::connect(&path).unwrap();
        let (d, _) = l.accept().unwrap();
        c.write_all(b"xyz").unwrap();
        assert_eq!(w.pending_bytes(), 5);
        // the accepted end closed: its queue is gone with it
        drop(d);
        drop(c);
        assert_eq!(w.pending_bytes(), 2);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn tcp_receive_queue_is_read_for_the_listening_port_only() {
        // two lines of a real /proc/net/tcp: QEMU's accepted socket on port 0x1F90 (8080)
        // with 0x0B bytes unread, the test's end (local port 0xC350) with 0x20 unread, and
        // the listening socket with a backlog of 1
        let table = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode
   0: 0100007F:1F90 00000000:0000 0A 00000000:00000001 00:00000000 00000000     0        0 1 1 0 100 0 0 10 0
   1: 0100007F:1F90 0100007F:C350 01 00000000:0000000B 00:00000000 00000000     0        0 2 1 0 20 4 30 10 -1
   2: 0100007F:C350 0100007F:1F90 01 00000000:00000020 00:00000000 00000000     0        0 3 1 0 20 4 30 10 -1";
        assert_eq!(tcp_unread(table, &[8080]), 11);
        assert_eq!(tcp_unread(table, &[8081]), 0);
    }

    #[test]
    fn tcp_bytes_count_until_the_listener_side_reads_them() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let mut c = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        let (mut s, _) = l.accept().unwrap();
        let w = InputWatch::default();
        w.watch_tcp_port(port);
        c.write_all(b"MOV 1 10\n").unwrap();
        // loopback delivery is immediate but not synchronous with write(): poll briefly
        let mut seen = 0;
        for _ in 0..5000 {
            seen = w.pending_bytes();
            if seen > 0 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert_eq!(seen, 9);
        let mut buf = [0u8; 9];
        s.read_exact(&mut buf).unwrap();
        assert_eq!(w.pending_bytes(), 0);
    }
}
