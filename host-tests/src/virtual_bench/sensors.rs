//! The QEMU board's peripheral-bus stand-in, host side: serves byte-exact SPI, I2C and ADC
//! transactions ([`nanocal_interface::bus`], through the mailbox of the board's link,
//! [`super::link`]) from register-level chip simulations ([`super::chips`]), at the board's clock.
//! A chip-select without a chip answers FFh (the board's MISO pull-up); an I2C address without a
//! chip is not acknowledged; the whole bus can be made to stop answering.

use super::chips::{I2cChip, SpiChip};
use nanocal_interface::bus::{BusOp, BusStatus};
use std::collections::HashMap;

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
