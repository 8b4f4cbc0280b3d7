//! What the tests hold the virtual bench by, and nothing the product uses: starting QEMU or
//! skipping a test without it, the GCS host's side of the link as a test drives it, raw
//! management bytes, sensor chips to break, unplug and brown out, the lines the simulated
//! controller received. Compiled only with the `test-support` feature, which the crate's own
//! tests, benchmarks and examples switch on (Cargo.toml: nanocal dev-depends on itself with it);
//! `cargo build` and the `nanocal` binary leave it out.
//!
//! It lives in the library rather than in `tests/` because it reaches into the bench's private
//! state (QEMU's child process and sockets, the chips on the bus, the controller's line queue):
//! from `tests/` that state would have to become public API.

use super::chips::{Lps22hb, Max31856, Max31865, SpiChip};
use super::cli_relay::CliRelay;
use super::controller::StageSim;
use super::link::{BenchClock, BenchLink};
use super::qemu::{apply_line_state, dial_unix, have_qemu, Qemu, HANG};
use super::sensors::Buses;
use nanocal_interface::bench_link as bl;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Whether `test` can run QEMU; if not, it is skipped with a loud message — except in CI, where
/// a missing QEMU fails it.
pub fn qemu_or_skip(test: &str) -> bool {
    if have_qemu() {
        return true;
    }
    if std::env::var_os("CI").is_some() {
        panic!("{test}: qemu-system-arm is missing in CI (run .ci/firmware.sh first)");
    }
    eprintln!("\n**********\n{test}: SKIPPED — qemu-system-arm not found (install QEMU ≥ 10, see .ci/firmware.sh)\n**********\n");
    false
}

impl Qemu {
    /// Start QEMU, or skip (None) as [`qemu_or_skip`] says.
    pub fn start_or_skip(test: &str) -> Option<Self> {
        qemu_or_skip(test).then(|| Self::start(&[]))
    }

    /// [`Self::start_lockstep_with_rings`] (serial ports on their UARTs), or skip (None) as
    /// [`qemu_or_skip`] says.
    pub fn start_lockstep_or_skip(test: &str) -> Option<Self> {
        qemu_or_skip(test).then(|| Self::start_lockstep_with_rings(&[], 0))
    }

    /// Wait until the board has read every byte the test's GCS hosts wrote (up to 10 s).
    fn wait_gcs_drained(&self) {
        let sent = self.gcs_sent.load(Ordering::Relaxed) as u32;
        let deadline = Instant::now() + Duration::from_secs(10);
        while self.link.rx_bytes(0) != sent {
            if Instant::now() > deadline {
                eprintln!(
                    "qemu: the board read {} of the {sent} GCS bytes sent",
                    self.link.rx_bytes(0)
                );
                return;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The management client opens (`true`) or closes (`false`) the management port: its line
    /// state (DTR), as [`Self::set_dtr`]'s for the GCS port, and returns once the board has
    /// applied it (false if not within 10 s). The board drops a management frame still
    /// arriving when the port closes.
    pub fn set_mgmt_dtr(&mut self, on: bool) -> bool {
        apply_line_state(&self.link, bl::LINE_MGMT, on)
    }

    /// The GCS host side (serial0): the port opened (DTR raised, a new host session).
    pub fn gcs_host(&mut self) -> GcsHost {
        let s = self.connect(0);
        self.set_dtr(true);
        GcsHost::new(s, self.gcs_sent.clone(), self.link.clone())
    }

    /// A new GCS host connection on serial0 (after the previous one was dropped): the old
    /// session ends (DTR falls once the board has read its bytes), the new one starts (DTR
    /// rises before anything is sent on it).
    pub fn reconnect_gcs(&mut self) -> GcsHost {
        self.wait_gcs_drained();
        self.set_dtr(false);
        let s = self.dial(0);
        self.set_dtr(true);
        GcsHost::new(s, self.gcs_sent.clone(), self.link.clone())
    }

    /// Give up the test's own connection to serial0 and return its port, for an external GCS
    /// client (QEMU serves one client per port at a time); the port is opened for it (DTR).
    pub fn gcs_port(&mut self) -> u16 {
        self.streams[0] = None;
        self.set_dtr(true);
        self.ports[0]
    }

    /// The management port spec to give a `nanocal` process (`--port`): a relay in this
    /// process that announces the process's bytes to the board (`cli_relay.rs`), so its
    /// requests reach the board at one instant of its time, as the tests' own clients' do.
    pub fn cli_spec(&self) -> String {
        self.cli_relay
            .get_or_init(|| {
                let dir = self.log.with_extension("d");
                CliRelay::start(dir.join("cli"), dir.join("s3"), self.link.clone())
            })
            .spec()
    }

    /// A raw connection to the management port (serial3), for tests that send bytes no client
    /// would (a frame cut off); one connection at a time, as [`Self::client`]'s.
    pub fn mgmt_stream(&mut self) -> UnixStream {
        dial_unix(
            &mut self.child,
            &self.log.with_extension("d").join("s3"),
            3,
            &self.log,
        )
    }
}

/// The host's side of the GCS link.
pub struct GcsHost {
    s: TcpStream,
    buf: Vec<u8>,
    sent: Arc<AtomicU64>,
    link: Arc<BenchLink>,
}

impl GcsHost {
    fn new(s: TcpStream, sent: Arc<AtomicU64>, link: Arc<BenchLink>) -> Self {
        Self {
            s,
            buf: vec![],
            sent,
            link,
        }
    }

    /// Send one line.
    pub fn send(&mut self, line: &str) {
        self.send_raw(format!("{line}\n").as_bytes());
    }

    /// Send raw bytes.
    pub fn send_raw(&mut self, b: &[u8]) {
        self.link.announce(0, b.len());
        self.s.write_all(b).unwrap();
        self.sent.fetch_add(b.len() as u64, Ordering::Relaxed);
    }

    /// Read one line (LF removed, trailing space kept).
    pub fn read_line(&mut self, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(p) = self.buf.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = self.buf.drain(..=p).collect();
                return String::from_utf8_lossy(&line[..line.len() - 1]).into_owned();
            }
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "no reply from the compensator within {timeout:?}"
            );
            self.s
                .set_read_timeout(Some(left.min(Duration::from_millis(200))))
                .unwrap();
            let mut b = [0u8; 256];
            match self.s.read(&mut b) {
                Ok(0) => panic!("compensator closed the host link"),
                Ok(n) => self.buf.extend_from_slice(&b[..n]),
                Err(_) => {}
            }
        }
    }

    /// Send a query and read its (possibly multi-line) reply, lines joined with LF.
    pub fn ask(&mut self, line: &str) -> String {
        self.send(line);
        let mut out = String::new();
        loop {
            let l = self.read_line(HANG);
            let more = l.ends_with(' ');
            out += l.trim_end();
            if !more {
                return out;
            }
            out.push('\n');
        }
    }
}

/// Simulated chips behind the QEMU board's bus stand-in.
pub struct SensorSim {
    buses: Arc<Mutex<Buses>>,
    link: Arc<BenchLink>,
}

impl SensorSim {
    /// Serve the bus of `link` with MAX31856 thermocouple amplifiers (type K) at the given
    /// temperatures on chip-selects 0.., the board's LPS22HB at 1013.25 hPa, and ADC channel 0
    /// at mid-scale.
    pub fn start(link: Arc<BenchLink>, temps: &[f32]) -> Self {
        let mut b = Buses::default();
        for &t in temps {
            b.spi.push(Some(Box::new(Max31856::new(f64::from(t)))));
        }
        b.i2c.insert(
            super::chips::lps22hb::ADDRESS,
            Box::new(Lps22hb::new(1013.25)),
        );
        b.adc = vec![Some(2048), None, None, None];
        Self::start_with(link, b)
    }

    /// Serve the bus of `link` with the given buses.
    pub fn start_with(link: Arc<BenchLink>, buses: Buses) -> Self {
        let buses = Arc::new(Mutex::new(buses));
        let bs = buses.clone();
        link.attach_bus(Box::new(move |op, target, out, n_in, now_s| {
            bs.lock().unwrap().serve(op, target, out, n_in, now_s)
        }));
        Self { buses, link }
    }

    /// The buses (to change what the chips see).
    pub fn buses(&self) -> MutexGuard<'_, Buses> {
        self.buses.lock().unwrap()
    }

    /// The board's clock, s of bench time.
    pub fn now_s(&self) -> f64 {
        self.link.now_s()
    }

    /// Set the fault condition of the MAX31856 on `cs` from status-register bits (OPEN: the
    /// thermocouple breaks; OVUV: shorted).
    pub fn set_status(&self, cs: usize, sr: u8) {
        let mut b = self.buses();
        let c: &mut Max31856 = b.spi_mut(cs);
        c.open = sr & 0x01 != 0;
        c.shorted = sr & 0x02 != 0;
    }

    /// Set the temperature of the chip on `cs` (MAX31856 or MAX31865).
    pub fn set_temp(&self, cs: usize, t: f32) {
        let mut b = self.buses();
        let chip = b.spi[cs].as_mut().expect("chip");
        let any = chip.any_mut();
        if let Some(c) = any.downcast_mut::<Max31856>() {
            c.temp_c = f64::from(t);
        } else if let Some(c) = any.downcast_mut::<Max31865>() {
            c.temp_c = f64::from(t);
        }
    }

    /// Unplug the chip on `cs` (MISO then reads the pull-up); returns it.
    pub fn unplug(&self, cs: usize) -> Option<Box<dyn SpiChip>> {
        self.buses().spi[cs].take()
    }

    /// Plug a chip into `cs` (it starts from power-on defaults, as a hot-plugged chip does).
    pub fn plug(&self, cs: usize, mut chip: Box<dyn SpiChip>) {
        let now = self.now_s();
        chip.power_on_reset(now);
        self.buses().spi[cs] = Some(chip);
    }

    /// A brown-out of the chip on `cs`: its registers return to their power-on values.
    pub fn brownout(&self, cs: usize) {
        let now = self.now_s();
        if let Some(c) = self.buses().spi[cs].as_mut() {
            c.power_on_reset(now);
        }
    }
}

impl Buses {
    /// The SPI chip on chip-select `cs`, as its concrete type.
    pub fn spi_mut<T: 'static>(&mut self, cs: usize) -> &mut T {
        let chip = self.spi[cs].as_mut().expect("a chip on that chip-select");
        chip.any_mut()
            .downcast_mut::<T>()
            .expect("chip of that type")
    }
}

impl StageSim {
    /// The next line the controller received (`#5` for a single character).
    pub fn next_line(&self, timeout: Duration) -> String {
        self.lines
            .recv_timeout(timeout)
            .expect("the controller received nothing in time")
    }

    /// Lines received up to and including the first one `last` accepts (each within
    /// `timeout`).
    pub fn drain_until(&self, last: impl Fn(&str) -> bool, timeout: Duration) -> Vec<String> {
        let mut v = vec![];
        loop {
            let l = self.next_line(timeout);
            let done = last(&l);
            v.push(l);
            if done {
                return v;
            }
        }
    }
}

impl BenchClock {
    /// Let the clock run with the wall clock × `scale` again.
    pub fn free_run(&self, scale: f64) {
        if self.link.lockstep.swap(false, Ordering::AcqRel) {
            let l = self.link.clone();
            std::thread::spawn(move || l.free_run(scale));
        }
    }
}
