//! Rig for the shipped STM32 image (`nanocal-fw`, default features, release) on the
//! emulated B-L475E-IOT01A (`nanocal-stm32-board`, the `emulator/` crate): builds the image once
//! per test process, runs the board on a thread, and puts the virtual bench's simulated stage
//! controller and register-level sensor chips on its pins.
//!
//! **Time is the board's.** The board's clock is virtual (instructions, then jumps to the next
//! timer event while the core sleeps) and moves only as far as the rig lets it: a test runs the
//! board *until something holds, within so many seconds of board time* ([`Stm32::run_until`]),
//! and the clients the rig hands out ([`Stm32::port`], [`Stm32::mgmt`], [`Stm32::gcs`]) run
//! the board while they wait for a reply. Whatever a test sends, it sends while the board is
//! paused, so it arrives at the same board time on an idle and on a loaded machine; the stage
//! controller and the sensor chips run on the board's thread at the board's time. Only
//! [`Stm32::paced`] (for external processes: PIPython, the CLI) lets the wall clock move the
//! board, and says so.
//!
//! The host tests (`host-tests/tests/stm32_sim/`) re-export it; the `stm32-bench` binary runs
//! campaigns on it ([`crate::bench`]).

use nanocal::device::Client;
use nanocal::virtual_bench::chips::{I2cChip, SpiChip};
use nanocal::virtual_bench::{Buses, Config, Controller, Event, IdealPlant, ManualClock};
use nanocal_stm32_board::flash::StoreFlash;
use nanocal_stm32_board::{
    usb, Board, Clock, Control, Halt, Inject, Io, SensorBus, Status, UartPeer, PS,
};
use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::JoinHandle;
use std::time::Duration;

/// Build the STM32 image once per test process (`cargo build --release` at the repository
/// root); its path.
pub fn stm32_elf() -> PathBuf {
    static ELF: OnceLock<PathBuf> = OnceLock::new();
    ELF.get_or_init(|| {
        let root = nanocal::virtual_bench::repo_root();
        let cargo = option_env!("CARGO").unwrap_or("cargo");
        let status = Command::new(cargo)
            .current_dir(&root)
            .args(["build", "--release", "--bin", "nanocal-fw"])
            .env_remove("CARGO_TARGET_DIR")
            .env_remove("CARGO_BUILD_TARGET")
            .env_remove("RUSTFLAGS")
            .env_remove("CARGO_ENCODED_RUSTFLAGS")
            .status()
            .expect("run cargo to build the STM32 firmware");
        assert!(status.success(), "building the STM32 firmware failed");
        root.join("target/thumbv7em-none-eabihf/release/nanocal-fw")
    })
    .clone()
}

/// The virtual bench's chips (the same register-level models the QEMU board's bus stand-in
/// serves) on the emulated board's SPI1 chip-selects, I2C2 and ADC1.
pub struct Chips(pub Arc<Mutex<Buses>>);

impl SensorBus for Chips {
    fn spi_select(&mut self, cs: usize, now_s: f64) {
        if let Some(Some(c)) = self.0.lock().unwrap().spi.get_mut(cs) {
            c.select(now_s);
        }
    }
    fn spi_exchange(&mut self, cs: usize, mosi: u8) -> u8 {
        let mut b = self.0.lock().unwrap();
        if b.dead {
            return 0xFF;
        }
        match b.spi.get_mut(cs) {
            Some(Some(c)) => c.exchange(mosi),
            _ => 0xFF,
        }
    }
    fn spi_deselect(&mut self, cs: usize, now_s: f64) {
        if let Some(Some(c)) = self.0.lock().unwrap().spi.get_mut(cs) {
            c.deselect(now_s);
        }
    }
    fn i2c_present(&mut self, addr: u8) -> bool {
        let b = self.0.lock().unwrap();
        !b.dead && b.i2c.contains_key(&addr)
    }
    fn i2c_write(&mut self, addr: u8, data: &[u8], now_s: f64) {
        if let Some(c) = self.0.lock().unwrap().i2c.get_mut(&addr) {
            c.write(data, now_s);
        }
    }
    fn i2c_read(&mut self, addr: u8, n: usize, now_s: f64) -> Vec<u8> {
        let mut out = vec![0xFF; n];
        if let Some(c) = self.0.lock().unwrap().i2c.get_mut(&addr) {
            c.read(&mut out, now_s);
        }
        out
    }
    fn adc(&mut self, ch: u8) -> Option<u16> {
        self.0
            .lock()
            .unwrap()
            .adc
            .get(usize::from(ch))
            .copied()
            .flatten()
    }
}

/// The simulated PI controller on UART4, answering on the board's thread at the board's time.
#[derive(Clone)]
pub struct Stage {
    ctl: Arc<Mutex<Controller>>,
    clock: ManualClock,
    /// Lines (and single characters, as `#n`) the controller received, not yet taken.
    lines: Arc<Mutex<VecDeque<String>>>,
    /// Every line received since power-on.
    all: Arc<Mutex<Vec<String>>>,
}

impl Stage {
    fn new(cfg: Config) -> Self {
        let start: Vec<f64> = cfg.axes.iter().map(|a| a.start).collect();
        let clock = ManualClock::new();
        let ctl = Controller::new(
            cfg,
            Box::new(IdealPlant::new(&start)),
            Arc::new(clock.clone()),
        );
        Self::with_controller(ctl, clock)
    }

    /// The controller `ctl` on UART4; `clock` is set to board time before each byte reaches it
    /// (`ctl`'s own clock may be a view of it, e.g. plan time).
    pub fn with_controller(ctl: Controller, clock: ManualClock) -> Self {
        Self {
            ctl: Arc::new(Mutex::new(ctl)),
            clock,
            lines: Arc::default(),
            all: Arc::default(),
        }
    }

    /// Work on the controller itself (positions, targets, events), at board time `now_s`.
    fn with_at<R>(&self, now_s: f64, f: impl FnOnce(&mut Controller) -> R) -> R {
        self.clock.set(now_s);
        f(&mut self.ctl.lock().unwrap())
    }

    /// Lines received and not taken yet.
    pub fn drain(&self) -> Vec<String> {
        self.lines.lock().unwrap().drain(..).collect()
    }

    /// Every line received since power-on.
    pub fn all(&self) -> Vec<String> {
        self.all.lock().unwrap().clone()
    }
}

impl UartPeer for Stage {
    fn byte_from_board(&mut self, b: u8, now_s: f64) -> Vec<u8> {
        self.clock.set(now_s);
        let mut c = self.ctl.lock().unwrap();
        let reply = c.input(&[b]);
        let got = c.take_received();
        drop(c);
        self.all.lock().unwrap().extend(got.iter().cloned());
        self.lines.lock().unwrap().extend(got);
        reply
    }
}

/// An E-727 with one axis, servo on, whose stage arrives at once.
pub fn e727() -> Config {
    let mut cfg = Config::e727(1).ready();
    for a in &mut cfg.axes {
        a.velocity = 1e12;
    }
    cfg
}

/// Default step of [`Stm32::run_until`]: its condition is looked at this often (board time),
/// and whenever the board hands a USB client bytes.
const STEP_S: f64 = 0.01;

/// The firmware's default fold period, s: the status's inputs and fold count move once a fold
/// (settings layout 3, paper 001 §VI), so a wait for a fold allows a period more.
pub const FOLD_S: f64 = nanocal_interface::settings::DEFAULT_FOLD_PERIOD_MS as f64 / 1000.0;

fn ps(s: f64) -> u64 {
    (s * PS as f64).round() as u64
}

/// The emulated board running the shipped image on a thread.
pub struct Stm32 {
    /// Board handles (status, stop, power cut, clock, fault injection).
    pub control: Control,
    thread: Option<JoinHandle<(Option<Halt>, Box<StoreFlash>)>>,
    /// The chips on the sensor buses.
    pub buses: Arc<Mutex<Buses>>,
    /// The USB host.
    pub usb: usb::HostHandle,
    /// The stage controller on UART4.
    pub stage: Stage,
    /// The LPS22HB holds I2C2's SDA low (until nine clocks free it).
    sda_held: Arc<std::sync::atomic::AtomicBool>,
}

impl Stm32 {
    /// Power the board on with `buses` on its sensor buses and an E-727 with one axis, servo
    /// on, whose stage arrives at once, on UART4. The board is paused at 0 s.
    pub fn start(buses: Buses) -> Self {
        Self::start_with(buses, e727(), None)
    }

    /// Power the board on with the given chips, controller and store flash (`None`: erased).
    pub fn start_with(buses: Buses, stage_cfg: Config, store: Option<Box<StoreFlash>>) -> Self {
        let buses = Arc::new(Mutex::new(buses));
        let bus = Arc::new(Mutex::new(Chips(buses.clone())));
        Self::start_on(buses, bus, Stage::new(stage_cfg), store)
    }

    /// Power the board on with `bus` on its sensor buses (serving the chips of `buses`, which
    /// the rig's fault helpers reach), `stage` on UART4 and the store flash (`None`: erased).
    /// The board is paused at 0 s.
    pub fn start_on(
        buses: Arc<Mutex<Buses>>,
        bus: Arc<Mutex<dyn SensorBus>>,
        stage: Stage,
        store: Option<Box<StoreFlash>>,
    ) -> Self {
        let elf = std::fs::read(stm32_elf()).expect("read the STM32 image");
        let (host, handle) = usb::Host::new();
        let io = Io::new(bus, Some(Box::new(stage.clone())), host);
        let sda_held = io.sda_held.clone();
        let control = Control::default();
        let c = control.clone();
        let thread = std::thread::spawn(move || {
            let mut board = match Board::new(&elf, store, io, c.clone()) {
                Ok(b) => b,
                Err(e) => {
                    c.clock.stop(0);
                    return (
                        Some(Halt::Fault(format!("board: {e}"))),
                        Box::new(StoreFlash::new()),
                    );
                }
            };
            let h = board.run();
            (h, board.into_store())
        });
        let b = Self {
            control,
            thread: Some(thread),
            buses,
            usb: handle,
            stage,
            sda_held,
        };
        b.clock().wait_paused(0);
        b
    }

    /// The board with no chips fitted.
    pub fn bare() -> Self {
        Self::start(Buses::default())
    }

    /// The board's clock.
    pub fn clock(&self) -> &Arc<Clock> {
        &self.control.clock
    }

    /// Board time, s (where the board paused last).
    pub fn now_s(&self) -> f64 {
        self.clock().last_pause().now_ps as f64 / PS as f64
    }

    /// What the board has done so far.
    pub fn status(&self) -> Status {
        self.control.status.lock().unwrap().clone()
    }

    /// Inject faults (taken by the board when it next runs).
    pub fn inject(&self, f: impl FnOnce(&mut Inject)) {
        f(&mut self.control.inject.lock().unwrap());
    }

    /// Run the board until `f` holds (looked at every [`STEP_S`] of board time and whenever the
    /// board hands a client bytes), within `within_s` seconds of board time; fails naming
    /// `what` and the board's state otherwise.
    pub fn run_until(
        &self,
        what: &str,
        within_s: f64,
        mut f: impl FnMut(&Status) -> bool,
    ) -> Status {
        let start = self.clock().last_pause().now_ps;
        let deadline = start + ps(within_s);
        loop {
            let s = self.status();
            if f(&s) {
                return s;
            }
            assert!(
                s.halt.is_none(),
                "the board halted waiting for {what}: {s:#?}"
            );
            let now = self.clock().last_pause().now_ps;
            assert!(
                now < deadline,
                "no {what} within {within_s} s of board time (board at {:.3} s): {s:#?}",
                now as f64 / PS as f64
            );
            self.clock().run_to(deadline.min(now + ps(STEP_S)));
        }
    }

    /// Run the board for `dt_s` seconds of board time.
    pub fn run_for(&self, dt_s: f64) -> Status {
        let end = self.clock().last_pause().now_ps + ps(dt_s);
        loop {
            let p = self.clock().run_to(end);
            let s = self.status();
            assert!(s.halt.is_none(), "the board halted: {s:#?}");
            if p.now_ps >= end || self.clock().stopped() {
                return s;
            }
        }
    }

    /// Run `f` (an external process: PIPython, the CLI) with the board paced by the wall clock
    /// × `scale` — the one place where the machine's speed moves board time; then pause the
    /// board again.
    pub fn paced<R>(&self, scale: f64, f: impl FnOnce() -> R) -> R {
        self.clock().pause_on_output(false);
        self.clock().pace(scale);
        let r = f();
        self.clock().stop_pacing();
        self.clock().pause_on_output(true);
        r
    }

    /// Work on the stage controller (at the board's time).
    pub fn stage_with<R>(&self, f: impl FnOnce(&mut Controller) -> R) -> R {
        self.stage.with_at(self.now_s(), f)
    }

    /// What happened to the stage since the last call.
    pub fn stage_events(&self) -> Vec<Event> {
        self.stage_with(|c| c.take_events())
    }

    /// The next line the controller receives (run the board until it does, within `within_s`
    /// of board time).
    pub fn stage_line(&self, within_s: f64) -> String {
        let lines = self.stage.lines.clone();
        self.run_until("line for the stage controller", within_s, |_| {
            !lines.lock().unwrap().is_empty()
        });
        let line = lines.lock().unwrap().pop_front().unwrap();
        line
    }

    /// Run until the host has the board configured (USB enumeration done).
    pub fn enumerated(&self, within_s: f64) {
        let usb = self.usb.clone();
        self.run_until("USB enumeration", within_s, move |_| {
            usb.with(|h| h.configured)
        });
    }

    /// Open CDC port `k` (0: GCS, 1: management) once the board is enumerated: a client
    /// connection whose reads run the board (see [`Port`]); returns once the host has told
    /// the device (SET_CONTROL_LINE_STATE DTR).
    pub fn port(&self, k: usize) -> Port {
        self.enumerated(10.0);
        let before = self.usb.line_states(k);
        let s = UnixStream::connect(self.usb.port_path(k)).expect("connect to the port socket");
        s.set_nonblocking(true).unwrap();
        let usb = self.usb.clone();
        self.run_until("the port opened (DTR up)", 1.0, move |_| {
            usb.line_states(k) > before
        });
        Port {
            s,
            clock: self.control.clock.clone(),
            status: self.control.status.clone(),
            reply_within_s: 10.0,
            name: self.usb.port_spec(k),
        }
    }

    /// A management client on CDC port 1 (replies awaited in board time, see [`Port`]).
    pub fn mgmt(&self) -> Client {
        let p = self.port(1);
        let name = p.name.clone();
        // the wall-clock timeout only guards against an emulator hang: the port gives up in
        // board time
        Client::new(Box::new(p), &name, Duration::from_secs(3600))
    }

    /// A GCS host on CDC port 0.
    pub fn gcs(&self) -> Gcs {
        Gcs {
            p: self.port(0),
            buf: vec![],
        }
    }

    /// Ask the device's status through `c` until `f` holds, running the board
    /// [`STEP_S`] × 10 between looks, within `within_s` of board time.
    pub fn status_until(
        &self,
        c: &mut Client,
        what: &str,
        within_s: f64,
        mut f: impl FnMut(&nanocal_interface::status::Status) -> bool,
    ) -> nanocal_interface::status::Status {
        let t0 = self.now_s();
        loop {
            let s = c.status().expect("status");
            if f(&s) {
                return s;
            }
            assert!(
                self.now_s() - t0 < within_s,
                "no {what} within {within_s} s of board time: {s:?}"
            );
            self.run_for(10.0 * STEP_S);
        }
    }

    /// A slave holds SDA low (as after a reset in the middle of a read), until nine clocks on
    /// SCL free the bus.
    pub fn hold_sda(&self) {
        self.sda_held.store(true, Ordering::Relaxed);
    }

    /// SDA is held low now.
    pub fn sda_is_held(&self) -> bool {
        self.sda_held.load(Ordering::Relaxed)
    }

    /// Set the fault condition of the MAX31856 on `cs` from status-register bits (OPEN: the
    /// thermocouple breaks; OVUV: shorted).
    pub fn set_tc_status(&self, cs: usize, sr: u8) {
        let mut b = self.buses.lock().unwrap();
        let c = b.spi[cs]
            .as_mut()
            .and_then(|c| {
                c.any_mut()
                    .downcast_mut::<nanocal::virtual_bench::chips::Max31856>()
            })
            .expect("a MAX31856 on that chip-select");
        c.open = sr & 0x01 != 0;
        c.shorted = sr & 0x02 != 0;
    }

    /// Stop the board (power off) and take its store's flash.
    pub fn power_off(mut self) -> Box<StoreFlash> {
        self.control.stop.store(true, Ordering::Relaxed);
        self.control.clock.stop(0);
        let (_, store) = self.thread.take().unwrap().join().expect("board thread");
        store
    }
}

impl Drop for Stm32 {
    fn drop(&mut self) {
        self.control.stop.store(true, Ordering::Relaxed);
        self.control.clock.stop(0);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if std::thread::panicking() {
            eprintln!("--- emulated board ---\n{:#?}", self.status());
        }
    }
}

/// A client's end of a CDC port whose reads run the board: a read returns what the board sent
/// (the board pauses right after it hands a client bytes), or runs the board on until it
/// sends; after `reply_within_s` of board time with nothing, the read fails ("no reply
/// within … of board time"). Writes go in while the board is paused.
pub struct Port {
    s: UnixStream,
    clock: Arc<Clock>,
    status: Arc<Mutex<Status>>,
    /// How long a read waits, board time.
    pub reply_within_s: f64,
    name: String,
}

impl Port {
    fn now(&self) -> u64 {
        self.clock.last_pause().now_ps
    }
}

impl Read for Port {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let deadline = self.now() + ps(self.reply_within_s);
        loop {
            match self.s.read(buf) {
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == ErrorKind::WouldBlock => {}
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
            if self.clock.stopped() {
                let halt = self.status.lock().unwrap().halt.clone();
                return Err(std::io::Error::other(format!(
                    "{}: the board stopped ({halt:?})",
                    self.name
                )));
            }
            let now = self.now();
            if now >= deadline {
                return Err(std::io::Error::other(format!(
                    "{}: nothing within {} s of board time (board at {:.3} s)",
                    self.name,
                    self.reply_within_s,
                    now as f64 / PS as f64
                )));
            }
            self.clock.run_to(deadline.min(now + ps(STEP_S)));
        }
    }
}

impl Write for Port {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        loop {
            match self.s.write(buf) {
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    // the socket is full: let the board take some in
                    let now = self.now();
                    self.clock.run_to(now + ps(0.001));
                }
                r => return r,
            }
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The GCS host on the GCS port.
pub struct Gcs {
    /// The port.
    pub p: Port,
    buf: Vec<u8>,
}

impl Gcs {
    /// Send one line.
    pub fn send(&mut self, line: &str) {
        self.p.write_all(format!("{line}\n").as_bytes()).unwrap();
    }

    /// Send raw bytes.
    pub fn send_raw(&mut self, b: &[u8]) {
        self.p.write_all(b).unwrap();
    }

    /// The next line from the compensator (LF removed), within the port's board-time limit.
    pub fn read_line(&mut self) -> String {
        loop {
            if let Some(p) = self.buf.iter().position(|&b| b == b'\n') {
                let l: Vec<u8> = self.buf.drain(..=p).collect();
                return String::from_utf8_lossy(&l[..l.len() - 1]).into_owned();
            }
            let mut b = [0u8; 256];
            match self.p.read(&mut b) {
                Ok(0) => panic!("the compensator closed the GCS port"),
                Ok(n) => self.buf.extend_from_slice(&b[..n]),
                Err(e) => panic!("no reply from the compensator: {e}"),
            }
        }
    }

    /// Send a query and read its (possibly multi-line) reply, lines joined with LF.
    pub fn ask(&mut self, line: &str) -> String {
        self.send(line);
        let mut out = String::new();
        loop {
            let l = self.read_line();
            let more = l.ends_with(' ');
            out += l.trim_end();
            if !more {
                return out;
            }
            out.push('\n');
        }
    }
}

/// The image's section `name`: (address, size).
pub fn section(name: &str) -> (u32, u32) {
    let elf = nanocal::virtual_bench::Elf::read(&stm32_elf());
    elf.sections
        .iter()
        .find(|(n, _, _)| n == name)
        .map(|&(_, a, s)| (a, s))
        .unwrap_or_else(|| panic!("section {name} in the image"))
}

/// The address of a symbol whose demangled name contains `part`.
pub fn symbol_containing(part: &str) -> u32 {
    let elf = nanocal::virtual_bench::Elf::read(&stm32_elf());
    elf.symbols
        .iter()
        .find(|(n, v)| n.contains(part) && *v != 0)
        .map(|&(_, v)| v)
        .unwrap_or_else(|| panic!("a symbol with {part:?} in the image"))
}

/// A `core::panic::Location` of the image in `file` (the compiler emits one per panic site):
/// its address and line. Found as (address of the file name, its length, line, column) in the
/// flash image.
pub fn panic_location(file: &str) -> (u32, u32) {
    let bytes = std::fs::read(stm32_elf()).unwrap();
    let image = nanocal_stm32_board::elf::Image::parse(&bytes).expect("the image parses");
    let find = |needle: &[u8]| -> Vec<u32> {
        let mut hits = vec![];
        for seg in &image.segments {
            for (i, w) in seg.data.windows(needle.len()).enumerate() {
                if w == needle {
                    hits.push(seg.paddr + i as u32);
                }
            }
        }
        hits
    };
    for name_at in find(file.as_bytes()) {
        let mut key = name_at.to_le_bytes().to_vec();
        key.extend_from_slice(&(file.len() as u32).to_le_bytes());
        if let Some(&loc) = find(&key).first() {
            let seg = image
                .segments
                .iter()
                .find(|s| (s.paddr..s.paddr + s.data.len() as u32).contains(&loc))
                .unwrap();
            let o = (loc - seg.paddr) as usize + 8;
            let line = u32::from_le_bytes(seg.data[o..o + 4].try_into().unwrap());
            return (loc, line);
        }
    }
    panic!("no panic location in {file}")
}

/// The value of `axis` in a forwarded `MOV` line.
pub fn stage_value(line: &str, axis: &str) -> f64 {
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(t.first(), Some(&"MOV"), "forwarded line {line:?}");
    let i = t
        .iter()
        .position(|a| *a == axis)
        .unwrap_or_else(|| panic!("axis {axis} in {line:?}"));
    t[i + 1].parse().unwrap()
}

/// The MAX31856 / LPS22HB / force set-up of the QEMU e2e tests.
pub fn default_buses(temps: &[f32]) -> Buses {
    use nanocal::virtual_bench::chips::{lps22hb, Lps22hb, Max31856};
    let mut b = Buses::default();
    for &t in temps {
        b.spi.push(Some(
            Box::new(Max31856::new(f64::from(t))) as Box<dyn SpiChip>
        ));
    }
    b.i2c.insert(
        lps22hb::ADDRESS,
        Box::new(Lps22hb::new(1013.25)) as Box<dyn I2cChip>,
    );
    b.adc = vec![Some(2048)];
    b
}
