//! The QEMU firmware as a process: build it, start it on `mps2-an386` with its serial ports on
//! local TCP sockets and its PSRAM on a host file (the bench's page: clock and bus mailbox, see
//! [`super::link`]), and talk GCS (serial0) and management (serial3) to it.

use super::link::{Announced, BenchClock, BenchLink, Page, RAM_FILE_LEN};
use crate::device::Client;
use nanocal_interface::bench_link as bl;
use std::net::{TcpListener, TcpStream};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The repository root (the firmware package).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host-tests has a parent")
        .to_path_buf()
}

/// Build a QEMU firmware binary (`--features qemu`) with cargo `profile`; returns its ELF.
fn build_qemu_bin(profile: &str, bin: &str) -> PathBuf {
    let root = repo_root();
    let cargo = option_env!("CARGO").unwrap_or("cargo");
    let status = Command::new(cargo)
        .current_dir(&root)
        .args([
            "build",
            "--profile",
            profile,
            "--no-default-features",
            "--features",
            "qemu",
            "--bin",
            bin,
        ])
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET")
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .status()
        .expect("run cargo to build the QEMU firmware");
    assert!(
        status.success(),
        "building the QEMU firmware ({bin}) failed"
    );
    // cargo's folder for the `release` profile is `release`, for the others their name
    root.join("target/thumbv7em-none-eabihf")
        .join(profile)
        .join(bin)
}

/// An image built before, for measurements that compare two firmware versions in turn with
/// one host binary (issue 20 §5): used as it is, nothing is built.
fn elf_from_env() -> Option<PathBuf> {
    std::env::var_os("NANOCAL_QEMU_ELF")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
}

/// The compensator's QEMU image, built once per process with the `qemu` profile (optimised for
/// speed: the virtual bench's board, see the profile in `Cargo.toml`), or
/// `NANOCAL_QEMU_ELF`.
pub fn qemu_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    ELF.get_or_init(|| elf_from_env().unwrap_or_else(|| build_qemu_bin("qemu", "nanocal-fw-qemu")))
        .clone()
}

/// The benchmark image, built once per process with the `release` profile — the STM32 image's
/// code generation, so that its guest-instruction counts stand for the shipped code — or the
/// `nanocal-fw-bench` beside `NANOCAL_QEMU_ELF`.
pub fn bench_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    ELF.get_or_init(|| match elf_from_env() {
        Some(elf) => elf.with_file_name("nanocal-fw-bench"),
        None => build_qemu_bin("release", "nanocal-fw-bench"),
    })
    .clone()
}

/// Symbols and section sizes of a little-endian ELF32 file.
pub struct Elf {
    /// (name, value) of every symbol.
    pub symbols: Vec<(String, u32)>,
    /// (name, address, size) of every section.
    pub sections: Vec<(String, u32, u32)>,
}

impl Elf {
    /// Read `path`.
    pub fn read(path: &Path) -> Elf {
        let b = std::fs::read(path).expect("read ELF");
        assert_eq!(&b[..5], b"\x7fELF\x01", "ELF32 expected");
        let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]) as usize;
        let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let shoff = u32_at(0x20) as usize;
        let (shentsize, shnum, shstrndx) = (u16_at(0x2E), u16_at(0x30), u16_at(0x32));
        let sh = |i: usize| shoff + i * shentsize;
        let cstr = |o: usize| {
            let end = b[o..].iter().position(|&c| c == 0).unwrap_or(0);
            String::from_utf8_lossy(&b[o..o + end]).into_owned()
        };
        let shstr = u32_at(sh(shstrndx) + 0x10) as usize;
        let mut sections = vec![];
        let mut symbols = vec![];
        for i in 0..shnum {
            let h = sh(i);
            let name = cstr(shstr + u32_at(h) as usize);
            let (ty, addr, off, size) = (
                u32_at(h + 4),
                u32_at(h + 0x0C),
                u32_at(h + 0x10),
                u32_at(h + 0x14),
            );
            sections.push((name, addr, size));
            if ty == 2 {
                // SHT_SYMTAB: its string table is the section in sh_link
                let strtab = u32_at(sh(u32_at(h + 0x18) as usize) + 0x10) as usize;
                for k in 0..(size / 16) as usize {
                    let e = off as usize + k * 16;
                    symbols.push((cstr(strtab + u32_at(e) as usize), u32_at(e + 4)));
                }
            }
        }
        Elf { symbols, sections }
    }

    /// A symbol's value.
    pub fn symbol(&self, name: &str) -> u32 {
        self.symbols
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("symbol {name}"))
            .1
    }

    /// Size of a section (0 when absent).
    pub fn section(&self, name: &str) -> u32 {
        self.sections
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|s| s.2)
            .unwrap_or(0)
    }

    /// Flash (vector table, code, constants, initialised data) and static RAM (data, bss).
    pub fn flash_ram(&self) -> (u32, u32) {
        let s = |n| self.section(n);
        (
            s(".vector_table") + s(".text") + s(".rodata") + s(".data"),
            s(".data") + s(".bss") + s(".uninit"),
        )
    }
}

/// True when qemu-system-arm runs.
pub fn have_qemu() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free local port")
}

/// Wall time after which the test rig's waits for the board (a reply, a management answer)
/// give up: only a hung board or QEMU gets there, never a slow or loaded machine. The
/// behaviours' own bounds are in the board's time.
pub const HANG: Duration = Duration::from_secs(120);

/// Serial ports of the QEMU board: 0 host (GCS), 1 stage, 2 the bench's doorbells to the board
/// (its wake port, `bench_link` layout 6), 3 management, 4 the host link's line state (USB DTR
/// stand-in) and the board's doorbells to the bench.
pub const SERIALS: usize = 5;

/// A running QEMU with the firmware; killed on drop.
pub struct Qemu {
    pub(super) child: Child,
    pub(super) ports: [u16; SERIALS],
    pub(super) streams: [Option<TcpStream>; 3],
    pub(super) link: Arc<BenchLink>,
    pub(super) log: PathBuf,
    /// Bytes the test's GCS hosts wrote to serial0 (the board has read them all before the
    /// port is closed: a new session starts clean).
    #[cfg(feature = "test-support")]
    pub(super) gcs_sent: Arc<std::sync::atomic::AtomicU64>,
    /// The management port for `nanocal` processes a test runs (started on first use).
    #[cfg(feature = "test-support")]
    pub(super) cli_relay: std::sync::OnceLock<super::cli_relay::CliRelay>,
}

/// Where the file behind the board's RAM goes: tmpfs when there is one.
fn ram_file(tag: u16) -> PathBuf {
    let dir = Path::new("/dev/shm");
    let dir = if dir.is_dir() {
        dir.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("nanocal-bench-{}-{tag}", std::process::id()))
}

impl Qemu {
    /// Start QEMU with extra arguments (e.g. a TCG plugin).
    pub fn start(extra: &[String]) -> Self {
        Self::start_with_rings(extra, 0)
    }

    /// Start QEMU with extra arguments, the serial ports in the mask `ring_ports` (bit n:
    /// serial n, n < 4) carried by the page's rings instead of their UARTs
    /// (`nanocal_interface::bench_link`, *Rings*; [`super::link::RingPort`]).
    pub fn start_with_rings(extra: &[String], ring_ports: u32) -> Self {
        Self::start_inner(extra, ring_ports, false)
    }

    /// [`Self::start_with_rings`], the board's clock in lockstep from its boot
    /// ([`BenchLink::start_lockstep`]): a campaign's board boots at the same instant every run.
    pub fn start_lockstep_with_rings(extra: &[String], ring_ports: u32) -> Self {
        Self::start_inner(extra, ring_ports, true)
    }

    fn start_inner(extra: &[String], ring_ports: u32, lockstep: bool) -> Self {
        let elf = qemu_elf();
        let ports = [
            free_port(),
            free_port(),
            free_port(),
            free_port(),
            free_port(),
        ];
        let log = std::env::temp_dir().join(format!(
            "nanocal-qemu-{}-{}.log",
            std::process::id(),
            ports[0]
        ));
        let page = Page::create(&ram_file(ports[0])).expect("the bench's RAM file");
        // before the board boots: its UART drivers look at it once
        page.set_u32(bl::RING_PORTS, ring_ports);
        let mut cmd = Command::new("qemu-system-arm");
        cmd.args(["-M", "mps2-an386,memory-backend=bench-ram"])
            .arg("-object")
            .arg(format!(
                "memory-backend-file,id=bench-ram,size={RAM_FILE_LEN},mem-path={},share=on",
                page.path().display()
            ))
            .args(["-display", "none", "-monitor", "none"])
            // its threads named ("ALL CPUs/TCG"): a campaign finds the vCPU to give it a core
            // of its own (`core_split`)
            .args(["-name", "nanocal-board,debug-threads=on"])
            .args(["-semihosting-config", "enable=on,target=native"]);
        // serial0-2 on TCP (an external GCS client such as PIPython connects to serial0), the
        // management port and the bench's doorbells on Unix sockets: the board writes a byte
        // at a time, which loopback TCP turns into a segment each (≈ 15 µs per byte)
        let sockets = log.with_extension("d");
        std::fs::create_dir_all(&sockets).expect("socket folder");
        for (i, p) in ports.iter().enumerate() {
            let dev = if i >= 2 {
                format!(
                    "socket,id=s{i},path={},server=on,wait=off",
                    sockets.join(format!("s{i}")).display()
                )
            } else {
                format!("socket,id=s{i},host=127.0.0.1,port={p},server=on,wait=off,nodelay=on")
            };
            cmd.arg("-chardev").arg(dev);
            cmd.arg("-serial").arg(format!("chardev:s{i}"));
        }
        cmd.args(extra).arg("-kernel").arg(&elf);
        // a TCG plugin for measurements (the guest-instruction profile of issue 20 §5:
        // `tools/qemu-plugin/insn_profile.c`), its argument as `-plugin` takes it
        if let Some(plugin) = std::env::var_os("NANOCAL_QEMU_PLUGIN").filter(|p| !p.is_empty()) {
            cmd.arg("-plugin").arg(plugin);
        }
        let logf = std::fs::File::create(&log).expect("qemu log file");
        let child = cmd
            .stdout(logf.try_clone().expect("log"))
            .stderr(logf)
            .spawn()
            .expect("start qemu-system-arm");
        // its CPU time is the bench's own, not other work on the machine
        super::board_first::board_started(child.id());
        let mut child = child;
        let line = dial_unix(&mut child, &sockets.join("s4"), 4, &log);
        let wake = dial_unix(&mut child, &sockets.join("s2"), 2, &log);
        let link = if lockstep {
            BenchLink::start_lockstep(page, line)
        } else {
            BenchLink::start(page, line)
        };
        link.set_wake_port(wake);
        // input in flight holds the free-running clock: serial 0-1 (TCP) and the management
        // port (serial 3), not the bench's doorbells (serial 2 and 4)
        for p in &ports[..2] {
            link.inputs().watch_tcp_port(*p);
        }
        link.inputs()
            .watch_unix_path(child.id(), &sockets.join("s3"));
        let mut q = Self {
            child,
            ports,
            streams: [None, None, None],
            link,
            log,
            #[cfg(feature = "test-support")]
            gcs_sent: Arc::new(std::sync::atomic::AtomicU64::new(0)),
            #[cfg(feature = "test-support")]
            cli_relay: std::sync::OnceLock::new(),
        };
        for i in [0, 1] {
            q.streams[i] = Some(q.dial(i));
        }
        q
    }

    /// The host opens (`true`) or closes (`false`) the GCS port: the line state a USB host
    /// sends with CDC SET_CONTROL_LINE_STATE (DTR, bit 0), carried to the board on serial4.
    /// Returns once the board has applied it (it counts them in the bench's page), so nothing
    /// sent afterwards can overtake it; false if it did not within 10 s.
    pub fn set_dtr(&mut self, on: bool) -> bool {
        apply_line_state(&self.link, bl::LINE_HOST, on)
    }

    /// Process id of QEMU.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// CPU time QEMU has used so far (user + system, from `/proc`), s; None where it cannot be
    /// read.
    pub fn cpu_s(&self) -> Option<f64> {
        let s = std::fs::read_to_string(format!("/proc/{}/stat", self.pid())).ok()?;
        // the fields after the command's closing parenthesis; utime and stime are the 14th and
        // 15th of the line (proc(5)), in clock ticks of 1/100 s
        let f: Vec<&str> = s.rsplit(')').next()?.split_whitespace().collect();
        let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
        Some(ticks / 100.0)
    }

    /// The bench's side of the board's link (page, doorbells, bus mailbox).
    pub fn link(&self) -> Arc<BenchLink> {
        self.link.clone()
    }

    /// The board's clock (free-running at 1× until [`BenchClock::lockstep`]).
    pub fn clock(&self) -> BenchClock {
        BenchClock::new(self.link.clone())
    }

    /// Send raw bytes to a serial port the test still owns (e.g. the bus stand-in's).
    pub fn port(&self, i: usize) -> u16 {
        self.ports[i]
    }

    pub(super) fn dial(&mut self, i: usize) -> TcpStream {
        dial(&mut self.child, self.ports[i], i, &self.log)
    }

    /// QEMU's output so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// The host TCP port QEMU listens on for serial `i`.
    pub fn serial_port(&self, i: usize) -> u16 {
        self.ports[i]
    }

    /// Take the connection to serial `i` (0 host, 1 stage).
    pub fn connect(&mut self, i: usize) -> TcpStream {
        self.streams[i].take().expect("serial port taken once")
    }

    /// Management port spec for the CLI (`unix:PATH`).
    pub fn mgmt_spec(&self) -> String {
        format!("unix:{}", self.log.with_extension("d").join("s3").display())
    }

    /// A management client (serial3); one at a time.
    pub fn client(&mut self) -> Client {
        let s = dial_unix(
            &mut self.child,
            &self.log.with_extension("d").join("s3"),
            3,
            &self.log,
        );
        s.set_read_timeout(Some(Duration::from_millis(50))).ok();
        let port = Announced {
            inner: s,
            link: self.link.clone(),
            serial: 3,
        };
        let mut c = Client::new(Box::new(port), &self.mgmt_spec(), HANG);
        // QEMU may still be handing over from a previous client, the board may be resetting:
        // retry the first request
        let deadline = Instant::now() + HANG;
        c.timeout = Duration::from_secs(2);
        while c.hello().is_err() {
            assert!(Instant::now() < deadline, "management port never answered");
        }
        c.timeout = HANG;
        c
    }
}

/// Send a port's line state (`port`: [`bl::LINE_HOST`] or [`bl::LINE_MGMT`]; DTR `on`) on
/// serial4 and wait (up to 10 s) until the board has applied it (it counts them in the bench's
/// page); false if it did not.
pub fn apply_line_state(link: &BenchLink, port: u8, on: bool) -> bool {
    let page = link.page();
    let before = page.u32(bl::LINE_STATES);
    let dtr = if on { bl::LINE_DTR } else { 0 };
    link.send_line_state(port | dtr);
    let deadline = Instant::now() + Duration::from_secs(10);
    while page.u32(bl::LINE_STATES) == before {
        if Instant::now() > deadline {
            eprintln!("qemu: the board did not apply line state {port:#04x} DTR={on} within 10 s");
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    true
}

pub(super) fn dial_unix(child: &mut Child, path: &Path, i: usize, log: &Path) -> UnixStream {
    dial_with(child, i, log, || UnixStream::connect(path).ok())
}

fn dial(child: &mut Child, port: u16, i: usize, log: &Path) -> TcpStream {
    dial_with(child, i, log, || {
        let s = TcpStream::connect(("127.0.0.1", port)).ok()?;
        s.set_nodelay(true).ok();
        Some(s)
    })
}

/// Retry `connect` until QEMU listens on serial `i` (20 s), telling QEMU's log if it exits.
fn dial_with<S>(
    child: &mut Child,
    i: usize,
    log: &Path,
    mut connect: impl FnMut() -> Option<S>,
) -> S {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if let Ok(Some(st)) = child.try_wait() {
            panic!(
                "qemu exited ({st}): {}",
                std::fs::read_to_string(log).unwrap_or_default()
            );
        }
        if let Some(s) = connect() {
            return s;
        }
        assert!(Instant::now() < deadline, "qemu serial{i} never listened");
        std::thread::sleep(Duration::from_millis(20));
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        self.link.shutdown();
        super::board_first::board_stopped(self.child.id());
        let _ = self.child.kill();
        let _ = self.child.wait();
        // before its socket goes with the folder (its drop wakes its accept through it)
        #[cfg(feature = "test-support")]
        drop(self.cli_relay.take());
        if std::thread::panicking() {
            eprintln!("--- qemu log ---\n{}", self.log_text());
        }
        let _ = std::fs::remove_file(&self.log);
        let _ = std::fs::remove_dir_all(self.log.with_extension("d"));
    }
}
