//! The QEMU board's peripheral-bus stand-in, host side: serves byte-exact SPI, I2C and ADC
//! transactions ([`nanocal_interface::bus`], through the mailbox of the board's link,
//! [`super::link`]) from register-level chip simulations ([`super::chips`]), at the board's clock.
//! A chip-select without a chip answers FFh (the board's MISO pull-up); an I2C address without a
//! chip is not acknowledged; the whole bus can be made to stop answering.

use super::chips::{I2cChip, Lps22hb, Max31856, Max31865, SpiChip};
use super::link::BenchLink;
use nanocal_interface::bus::{BusOp, BusStatus};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

/// What hangs on the buses.
#[derive(Default)]
pub struct Buses {
    /// SPI chips by chip-select (None: nothing fitted, MISO pulled up).
    pub spi: Vec<Option<Box<dyn SpiChip>>>,
    /// I2C chips by 7-bit address.
    pub i2c: HashMap<u8, Box<dyn I2cChip>>,
    /// ADC channels: 12-bit code per channel (None: no such channel answers).
    pub adc: Vec<Option<u16>>,
    /// The bus answers nothing (a hung bus: the firmware's timeouts must catch it).
    pub dead: bool,
    /// Transactions served, by op.
    pub served: [u64; 4],
}

impl Buses {
    /// The SPI chip on chip-select `cs`, as its concrete type.
    pub fn spi_mut<T: 'static>(&mut self, cs: usize) -> &mut T {
        let chip = self.spi[cs].as_mut().expect("a chip on that chip-select");
        chip.any_mut()
            .downcast_mut::<T>()
            .expect("chip of that type")
    }

    /// Serve one transaction; `None` when there is no answer.
    pub fn serve(
        &mut self,
        op: BusOp,
        target: u8,
        out: &[u8],
        n_in: usize,
        now_s: f64,
    ) -> Option<(BusStatus, Vec<u8>)> {
        if self.dead {
            return None;
        }
        if let Some(c) = self.served.get_mut(usize::from(op.code())) {
            *c += 1;
        }
        match op {
            BusOp::Spi => {
                let mut rx = vec![0xFF; out.len()];
                if let Some(Some(chip)) = self.spi.get_mut(usize::from(target)) {
                    chip.select(now_s);
                    for (i, &b) in out.iter().enumerate() {
                        rx[i] = chip.exchange(b);
                    }
                    chip.deselect(now_s);
                }
                Some((BusStatus::Ok, rx))
            }
            BusOp::I2c => match self.i2c.get_mut(&target) {
                None => Some((BusStatus::Nack, vec![])),
                Some(chip) => {
                    if !out.is_empty() {
                        chip.write(out, now_s);
                    }
                    let mut rx = vec![0u8; n_in];
                    if n_in > 0 {
                        chip.read(&mut rx, now_s);
                    }
                    Some((BusStatus::Ok, rx))
                }
            },
            BusOp::Adc => {
                let code = self.adc.get(usize::from(target)).copied().flatten()?;
                Some((BusStatus::Ok, code.to_le_bytes().to_vec()))
            }
            _ => None,
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
