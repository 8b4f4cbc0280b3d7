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
//! - TCP ports (serial 0–2): the receive queue of QEMU's accepted socket, from `/proc/net/tcp`
//!   (the sender's own queue empties as soon as the loopback peer's kernel has the bytes).
//! - Unix sockets (serial 3): `SIOCOUTQ` on the test's end, which for a unix stream socket counts
//!   bytes written and not yet read by the peer (unix(7)). The test owns the socket, so the
//!   watch keeps only the descriptor number and the socket's inode, and forgets the entry as
//!   soon as that descriptor no longer names the same socket (closed, or reused).

use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::net::UnixStream;
use std::sync::Mutex;

/// One watched way into the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Way {
    /// QEMU listens on this loopback TCP port.
    TcpPort(u16),
    /// The test's end of a unix stream socket: descriptor and inode.
    Unix { fd: RawFd, inode: u64 },
}

/// The ways into the board the bench watches for input in flight.
#[derive(Default)]
pub struct InputWatch {
    ways: Mutex<Vec<Way>>,
}

impl InputWatch {
    /// Watch the loopback TCP port QEMU listens on for a serial port.
    pub fn watch_tcp_port(&self, port: u16) {
        self.ways.lock().unwrap().push(Way::TcpPort(port));
    }

    /// Watch the test's end of a unix socket connected to a serial port (not owned: the entry
    /// lapses when the test closes it).
    pub fn watch_unix(&self, s: &UnixStream) {
        let fd = s.as_raw_fd();
        if let Some(inode) = inode_of(fd) {
            let mut w = self.ways.lock().unwrap();
            w.retain(|x| !matches!(x, Way::Unix { fd: f, .. } if *f == fd));
            w.push(Way::Unix { fd, inode });
        }
    }

    /// Bytes written towards the board and not yet taken by it (summed over every watched way).
    pub fn pending_bytes(&self) -> u64 {
        let mut ways = self.ways.lock().unwrap();
        let mut total = 0u64;
        ways.retain(|w| match *w {
            Way::Unix { fd, inode } => match inode_of(fd) {
                Some(i) if i == inode => {
                    total += unix_unread(fd);
                    true
                }
                _ => false,
            },
            Way::TcpPort(_) => true,
        });
        let ports: Vec<u16> = ways
            .iter()
            .filter_map(|w| match w {
                Way::TcpPort(p) => Some(*p),
                _ => None,
            })
            .collect();
        if !ports.is_empty() {
            if let Ok(table) = std::fs::read_to_string("/proc/net/tcp") {
                total += tcp_unread(&table, &ports);
            }
        }
        total
    }
}

fn inode_of(fd: RawFd) -> Option<u64> {
    // SAFETY: fstat writes into the zeroed struct we own; an invalid fd is an error return.
    let mut st: libc::stat = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::fstat(fd, &mut st) };
    (r == 0 && (st.st_mode & libc::S_IFMT) == libc::S_IFSOCK).then_some(st.st_ino)
}

fn unix_unread(fd: RawFd) -> u64 {
    let mut n: libc::c_int = 0;
    // SAFETY: SIOCOUTQ (the same request number as TIOCOUTQ on Linux) writes one int; `fd` was
    // just checked to be a socket.
    let r = unsafe { libc::ioctl(fd, libc::TIOCOUTQ, &mut n) };
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
    fn unix_bytes_count_until_the_peer_reads_them() {
        let (a, mut b) = UnixStream::pair().unwrap();
        let w = InputWatch::default();
        w.watch_unix(&a);
        assert_eq!(w.pending_bytes(), 0);
        (&a).write_all(b"HELLO").unwrap();
        assert!(w.pending_bytes() >= 5, "{}", w.pending_bytes());
        let mut buf = [0u8; 5];
        b.read_exact(&mut buf).unwrap();
        assert_eq!(w.pending_bytes(), 0);
        (&a).write_all(b"x").unwrap();
        drop(a);
        // the test closed its end: the entry lapses, whatever the peer left unread
        assert_eq!(w.pending_bytes(), 0);
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
