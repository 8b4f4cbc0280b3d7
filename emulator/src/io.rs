//! What hangs on the board's pins: the stage controller on UART4 (a byte stream), the sensor
//! chips on SPI1's chip-selects and I2C2, the force input on ADC1, and the USB host. The tests
//! supply these ([`Wiring`]); the board's models call them at the board's clock.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// The chips on the sensor buses, as the bench models them.
pub trait SensorBus: Send {
    /// Chip-select `cs` went low.
    fn spi_select(&mut self, cs: usize, now_s: f64);
    /// One byte on SPI with chip-select `cs` low: MOSI in, MISO out.
    fn spi_exchange(&mut self, cs: usize, mosi: u8) -> u8;
    /// Chip-select `cs` went high.
    fn spi_deselect(&mut self, cs: usize, now_s: f64);
    /// A chip answers I2C address `addr` (ACK).
    fn i2c_present(&mut self, addr: u8) -> bool;
    /// A write transaction to `addr` ended (STOP or repeated START).
    fn i2c_write(&mut self, addr: u8, data: &[u8], now_s: f64);
    /// `n` bytes read from `addr`.
    fn i2c_read(&mut self, addr: u8, n: usize, now_s: f64) -> Vec<u8>;
    /// The 12-bit code of force channel `ch` (None: nothing connected, the input reads 0).
    fn adc(&mut self, ch: u8) -> Option<u16>;
}

/// A bus with nothing on it.
pub struct NoChips;

impl SensorBus for NoChips {
    fn spi_select(&mut self, _: usize, _: f64) {}
    fn spi_exchange(&mut self, _: usize, _: u8) -> u8 {
        0xFF
    }
    fn spi_deselect(&mut self, _: usize, _: f64) {}
    fn i2c_present(&mut self, _: u8) -> bool {
        false
    }
    fn i2c_write(&mut self, _: u8, _: &[u8], _: f64) {}
    fn i2c_read(&mut self, _: u8, n: usize, _: f64) -> Vec<u8> {
        vec![0xFF; n]
    }
    fn adc(&mut self, _: u8) -> Option<u16> {
        None
    }
}

/// What hangs on UART4's TX and RX lines: the stage controller, called on the board's thread
/// at the board's time (so its replies are as deterministic as the board).
pub trait UartPeer: Send {
    /// A byte the board's UART finished sending at board time `now_s`; the bytes the peer
    /// sends back in answer (they start on the RX line at `now_s`).
    fn byte_from_board(&mut self, b: u8, now_s: f64) -> Vec<u8>;
}

/// The stage link's RX line: bytes the peer sent, with the board time each may start, ps.
#[derive(Default)]
pub struct UartLine {
    /// Bytes on their way to the board.
    pub queue: VecDeque<(u8, u64)>,
    /// Fault injection: the received byte this many bytes from now is lost to an overrun, as
    /// if the CPU had not read RDR in time (RM0351 §40.5.5).
    pub lose_in: Option<u32>,
}

/// The board's chip-select wiring: (GPIO port, pin) of CS0, CS1, … (src/README.md).
pub const CHIP_SELECTS: [(usize, usize); 16] = [
    (0, 2),
    (0, 15),
    (1, 2),
    (0, 4),
    (1, 1),
    (1, 4),
    (0, 3),
    (1, 0),
    (3, 14),
    (2, 4),
    (2, 3),
    (2, 2),
    (2, 1),
    (2, 0),
    (1, 9),
    (1, 8),
];

/// Everything outside the chip.
pub struct Io {
    /// The board's time, s (the chips' clock).
    pub now_s: f64,
    /// Sensor chips.
    pub bus: Arc<Mutex<dyn SensorBus>>,
    /// Chip-select low now.
    selected: Option<usize>,
    /// Times a chip-select went low while another was still low.
    pub cs_conflicts: u64,
    /// The stage controller on UART4.
    pub uart: Option<Box<dyn UartPeer>>,
    /// UART4's RX line.
    pub uart_rx: UartLine,
    /// A slave holds SDA low (until a bus recovery).
    pub sda_held: Arc<AtomicBool>,
    /// The USB host.
    pub usb: crate::usb::Host,
}

impl Io {
    /// A board with `bus` on its sensor buses and the given USB host.
    pub fn new(
        bus: Arc<Mutex<dyn SensorBus>>,
        uart: Option<Box<dyn UartPeer>>,
        usb: crate::usb::Host,
    ) -> Self {
        Self {
            now_s: 0.0,
            bus,
            selected: None,
            cs_conflicts: 0,
            uart,
            uart_rx: UartLine::default(),
            sda_held: Arc::new(AtomicBool::new(false)),
            usb,
        }
    }

    /// A byte the UART finished sending at `now_ps`: the peer answers onto the RX line.
    pub fn uart_send(&mut self, b: u8, now_ps: u64) {
        if let Some(u) = self.uart.as_mut() {
            let now_s = now_ps as f64 / crate::clock::PS as f64;
            for r in u.byte_from_board(b, now_s) {
                self.uart_rx.queue.push_back((r, now_ps));
            }
        }
    }

    /// Take in what came from outside while the board was paused (USB clients).
    pub fn poll_inputs(&mut self) {
        self.usb.poll_sockets();
    }

    /// Hand the USB clients what the device sent; true when a client got bytes.
    pub fn flush(&mut self) -> bool {
        self.usb.flush()
    }

    /// A GPIO level changed: a chip-select edge selects or deselects its chip.
    pub fn cs_changed(&mut self, port: usize, pin: usize, level: bool) {
        let Some(cs) = CHIP_SELECTS.iter().position(|&p| p == (port, pin)) else {
            return;
        };
        let mut bus = self.bus.lock().unwrap();
        if !level {
            if self.selected.is_some_and(|o| o != cs) {
                // two chips selected: both would drive MISO; the model keeps talking to the
                // first and counts the fault
                self.cs_conflicts += 1;
                return;
            }
            self.selected = Some(cs);
            bus.spi_select(cs, self.now_s);
        } else if self.selected == Some(cs) {
            self.selected = None;
            bus.spi_deselect(cs, self.now_s);
        }
    }

    /// One SPI byte: the selected chip answers; none selected reads the MISO pull-up.
    pub fn spi_exchange(&mut self, mosi: u8, _gpio: &[crate::simple::Gpio]) -> u8 {
        match self.selected {
            Some(cs) => self.bus.lock().unwrap().spi_exchange(cs, mosi),
            None => 0xFF,
        }
    }

    /// SDA held low by a slave.
    pub fn i2c_sda_held(&self) -> bool {
        self.sda_held.load(Ordering::Relaxed)
    }

    /// Nine clocks freed SDA.
    pub fn i2c_release_sda(&mut self) {
        self.sda_held.store(false, Ordering::Relaxed);
    }

    /// An address answers.
    pub fn i2c_present(&mut self, addr: u8) -> bool {
        self.bus.lock().unwrap().i2c_present(addr)
    }

    /// A write transaction.
    pub fn i2c_write(&mut self, addr: u8, data: &[u8]) {
        let now = self.now_s;
        self.bus.lock().unwrap().i2c_write(addr, data, now)
    }

    /// A read transaction.
    pub fn i2c_read(&mut self, addr: u8, n: usize) -> Vec<u8> {
        let now = self.now_s;
        self.bus.lock().unwrap().i2c_read(addr, n, now)
    }

    /// The force input (ADC1 channel 14, A0 = PC5).
    pub fn adc(&mut self, ch: u8) -> Option<u16> {
        self.bus.lock().unwrap().adc(ch)
    }

    /// VBUS present (a host cable is plugged into the OTG connector).
    pub fn usb_attached(&self) -> bool {
        self.usb.attached()
    }
}
