//! Test rig for the shipped STM32 image (`nanocal-fw`, default features, release) on the
//! emulated B-L475E-IOT01A (`nanocal-stm32-board`, the `emulator/` crate): builds the image once
//! per test process, runs the board on a thread, and puts the virtual bench's simulated stage
//! controller and register-level sensor chips on its pins.
#![allow(dead_code)]

use nanocal::virtual_bench::chips::{I2cChip, SpiChip};
use nanocal::virtual_bench::Buses;
use nanocal_stm32_board::{usb, Board, Control, Halt, Io, SensorBus, SerialEnd, Status};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

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

/// A connected pair of local TCP sockets.
fn socket_pair() -> (TcpStream, TcpStream) {
    let l = TcpListener::bind("127.0.0.1:0").expect("bind a local port");
    let a = TcpStream::connect(l.local_addr().unwrap()).expect("connect");
    let (b, _) = l.accept().expect("accept");
    a.set_nodelay(true).ok();
    b.set_nodelay(true).ok();
    (a, b)
}

/// The emulated board running the shipped image on a thread.
pub struct Stm32 {
    /// Board handles (status, stop, power cut, time scale).
    pub control: Control,
    thread: Option<JoinHandle<Option<Halt>>>,
    stage: Option<TcpStream>,
    /// The chips on the sensor buses.
    pub buses: Arc<Mutex<Buses>>,
    /// The USB host.
    pub usb: usb::HostHandle,
}

impl Stm32 {
    /// Power the board on with `buses` on its sensor buses (and the stage link's socket ready
    /// for [`Self::stage`]).
    pub fn start(buses: Buses) -> Self {
        let elf = std::fs::read(stm32_elf()).expect("read the STM32 image");
        let buses = Arc::new(Mutex::new(buses));
        let (board_end, test_end) = socket_pair();
        let writer = board_end.try_clone().expect("clone the stage socket");
        let serial = SerialEnd::new(board_end, Box::new(writer));
        let (host, handle) = usb::Host::new();
        let io = Io::new(
            Arc::new(Mutex::new(Chips(buses.clone()))),
            Some(serial),
            host,
        );
        let control = Control::default();
        let c = control.clone();
        let thread = std::thread::spawn(move || {
            let mut board = match Board::new(&elf, None, io, c) {
                Ok(b) => b,
                Err(e) => return Some(Halt::Fault(format!("board: {e}"))),
            };
            board.run()
        });
        Self {
            control,
            thread: Some(thread),
            stage: Some(test_end),
            buses,
            usb: handle,
        }
    }

    /// The board with no chips fitted.
    pub fn bare() -> Self {
        Self::start(Buses::default())
    }

    /// The stage link's far end (the controller's RS-232), once.
    pub fn stage(&mut self) -> TcpStream {
        self.stage.take().expect("stage link taken once")
    }

    /// What the board has done so far.
    pub fn status(&self) -> Status {
        self.control.status.lock().unwrap().clone()
    }

    /// Wait until `f` holds for the board's status (fails with the status after `timeout`).
    pub fn wait_for(&self, what: &str, timeout: Duration, f: impl Fn(&Status) -> bool) -> Status {
        let deadline = Instant::now() + timeout;
        loop {
            let s = self.status();
            if f(&s) {
                return s;
            }
            assert!(
                s.halt.is_none(),
                "the board halted waiting for {what}: {s:#?}"
            );
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}; board status: {s:#?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Stm32 {
    fn drop(&mut self) {
        self.control.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if std::thread::panicking() {
            eprintln!("--- emulated board ---\n{:#?}", self.status());
        }
    }
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
