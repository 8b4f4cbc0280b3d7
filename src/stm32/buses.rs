//! The sensor buses: SPI1 (DMA) with one chip-select per amplifier, I2C2 to the on-board
//! LPS22HB, ADC1 on A0 (PC5) for the force input.

use crate::app::InputBus;
use core::ptr::{read_volatile, write_volatile};
use embassy_stm32::adc::{Adc, SampleTime};
use embassy_stm32::gpio::Output;
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::mode::{Async, Blocking};
use embassy_stm32::peripherals::{ADC1, PC5};
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::Peri;
use embassy_time::Duration;

/// Chip-selects, one per amplifier (see `src/README.md`, *Wiring*).
pub const CS_PINS: usize = 16;

/// The longest an I2C transaction may take: the LPS22HB's longest (a 6-byte burst read at
/// 400 kHz) takes 0.2 ms. The transaction blocks the executor (embassy's I2C in blocking mode),
/// so embassy's default of 1 s would stall the command path that long on a stuck bus.
pub const I2C_TIMEOUT: Duration = Duration::from_millis(2);

/// SPI1, the chip-selects, I2C2, ADC1 and its A0 pin.
pub struct Buses {
    /// SPI1, mode 1, 1 MHz, DMA.
    pub spi: Spi<'static, Async, spi::mode::Master>,
    /// Chip-select pins, CS0 first.
    pub cs: [Output<'static>; CS_PINS],
    /// I2C2 (PB10 SCL, PB11 SDA), with [`I2C_TIMEOUT`].
    pub i2c: I2c<'static, Blocking, i2c::Master>,
    /// ADC1.
    pub adc: Adc<'static, ADC1>,
    /// A0.
    pub a0: Peri<'static, PC5>,
    /// Bus recoveries done (nine clocks on SCL).
    pub i2c_recoveries: u32,
}

/// A chip-select held low; high again when dropped — also when the transfer's future is
/// dropped half-way (its timeout fired), which would otherwise leave the chip selected and
/// the next transaction talking to two chips at once.
struct Selected<'a>(&'a mut Output<'static>);

impl<'a> Selected<'a> {
    fn low(pin: &'a mut Output<'static>) -> Self {
        pin.set_low();
        Self(pin)
    }
}

impl Drop for Selected<'_> {
    fn drop(&mut self) {
        self.0.set_high();
    }
}

const GPIOB: usize = 0x4800_0400;
const GPIO_MODER: usize = 0x00;
const GPIO_OTYPER: usize = 0x04;
const GPIO_IDR: usize = 0x10;
const GPIO_BSRR: usize = 0x18;
const SCL: u32 = 10;
const SDA: u32 = 11;
const I2C2_CR1: usize = 0x4000_5800;
const CR1_PE: u32 = 1;

fn reg(a: usize) -> u32 {
    // SAFETY: GPIOB / I2C2 register, 32-bit access.
    unsafe { read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(a as *mut u32, v) }
}

/// Half an SCL period of the recovery clock (100 kHz at 80 MHz).
fn half_period() {
    cortex_m::asm::delay(400);
}

/// Free a bus a slave holds (SDA low, e.g. after a reset in the middle of a read): I2C2 off
/// (PE = 0 resets its state machine, RM0351 §39.4.6), SCL driven as an open-drain GPIO for up
/// to nine clocks until the slave lets SDA go, a STOP, then the pins back to I2C2 (UM10204
/// §3.1.16 "Bus clear").
fn recover_i2c2() {
    set(I2C2_CR1, reg(I2C2_CR1) & !CR1_PE);
    set(
        GPIOB + GPIO_OTYPER,
        reg(GPIOB + GPIO_OTYPER) | (1 << SCL) | (1 << SDA),
    );
    set(GPIOB + GPIO_BSRR, (1 << SCL) | (1 << SDA));
    let moder = reg(GPIOB + GPIO_MODER) & !((3 << (2 * SCL)) | (3 << (2 * SDA)));
    set(
        GPIOB + GPIO_MODER,
        moder | (1 << (2 * SCL)) | (1 << (2 * SDA)),
    );
    half_period();
    for _ in 0..9 {
        if reg(GPIOB + GPIO_IDR) & (1 << SDA) != 0 {
            break;
        }
        set(GPIOB + GPIO_BSRR, 1 << (SCL + 16));
        half_period();
        set(GPIOB + GPIO_BSRR, 1 << SCL);
        half_period();
    }
    // STOP: SDA rises while SCL is high
    set(GPIOB + GPIO_BSRR, 1 << (SDA + 16));
    half_period();
    set(GPIOB + GPIO_BSRR, 1 << SDA);
    half_period();
    set(
        GPIOB + GPIO_MODER,
        moder | (2 << (2 * SCL)) | (2 << (2 * SDA)),
    );
    set(I2C2_CR1, reg(I2C2_CR1) | CR1_PE);
}

impl InputBus for Buses {
    async fn spi(&mut self, cs: u8, buf: &mut [u8]) -> Result<(), ()> {
        let Some(pin) = self.cs.get_mut(usize::from(cs)) else {
            buf.fill(0xFF); // nothing wired: MISO pull-up
            return Ok(());
        };
        let _selected = Selected::low(pin);
        // DMA transfer: the executor runs the command path meanwhile
        self.spi.transfer_in_place(buf).await.map_err(|_| ())
    }

    async fn i2c(&mut self, addr: u8, w: &[u8], r: &mut [u8]) -> Result<(), ()> {
        // a few bytes at 400 kHz (< 0.2 ms): blocking is shorter than a context switch; a bus
        // that does not answer within I2C_TIMEOUT is freed for the next transaction
        let res = if r.is_empty() {
            self.i2c.blocking_write(addr, w)
        } else {
            self.i2c.blocking_write_read(addr, w, r)
        };
        match res {
            Ok(()) => Ok(()),
            // an absent chip is no stuck bus
            Err(i2c::Error::Nack) => Err(()),
            Err(_) => {
                recover_i2c2();
                self.i2c_recoveries = self.i2c_recoveries.wrapping_add(1);
                Err(())
            }
        }
    }

    async fn adc(&mut self, channel: u8) -> Result<u16, ()> {
        if channel != 0 {
            return Err(());
        }
        Ok(self
            .adc
            .blocking_read(&mut self.a0, SampleTime::CYCLES247_5))
    }

    fn adc_channels(&self) -> u32 {
        1
    }

    fn chip_selects(&self) -> u8 {
        self.cs.len() as u8
    }
}
