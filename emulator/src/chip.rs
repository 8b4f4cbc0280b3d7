//! The STM32L475VG's peripherals as one state, and the memory-mapped dispatch (RM0351 §2.2.2,
//! Table 1 "STM32L475xx … memory map and peripheral register boundary addresses").

use crate::flash::{self, FlashCtl, StoreFlash};
use crate::io::Io;
use crate::nvic::Nvic;
use crate::periph::{Dma, I2c, Spi, Usart};
use crate::rcc::{Enable, Rcc};
use crate::simple::{Adc, Gpio, Iwdg, Timer};
use crate::usb::Otg;
use std::collections::{BTreeMap, BTreeSet};

/// Interrupt numbers the board raises (RM0351 Table 57, vector positions).
pub mod irq {
    /// DMA1 channel n (1..=7): IRQ 10 + n.
    pub const DMA1_CH1: usize = 11;
    /// ADC1_2.
    pub const ADC1_2: usize = 18;
    /// TIM1 break / TIM15 global.
    pub const TIM15: usize = 24;
    /// I2C2 event.
    pub const I2C2_EV: usize = 33;
    /// I2C2 error.
    pub const I2C2_ER: usize = 34;
    /// SPI1.
    pub const SPI1: usize = 35;
    /// UART4.
    pub const UART4: usize = 52;
    /// USB OTG FS.
    pub const OTG_FS: usize = 67;
    /// FLASH global.
    pub const FLASH: usize = 4;
}

/// Why the chip stopped running the firmware.
#[derive(Clone, Debug, PartialEq)]
pub enum Halt {
    /// The model found the firmware doing what the hardware does not allow.
    Fault(String),
}

/// Everything of the chip outside the CPU core.
pub struct Chip {
    /// Board time, picoseconds since power-on.
    pub now_ps: u64,
    /// Core cycles (instructions) since power-on.
    pub cycles: u64,
    /// NVIC, SCB, SysTick.
    pub nvic: Nvic,
    /// RCC and PWR.
    pub rcc: Rcc,
    /// FLASH controller.
    pub flash: FlashCtl,
    /// The store's flash (survives resets and power cuts).
    pub store: Box<StoreFlash>,
    /// GPIOA..GPIOH.
    pub gpio: Vec<Gpio>,
    /// TIM15 (embassy-time).
    pub tim15: Timer,
    /// IWDG.
    pub iwdg: Iwdg,
    /// ADC1.
    pub adc: Adc,
    /// UART4 (stage link).
    pub uart4: Usart,
    /// SPI1 (amplifiers).
    pub spi1: Spi,
    /// DMA1.
    pub dma1: Dma,
    /// I2C2 (LPS22HB).
    pub i2c2: I2c,
    /// USB OTG FS.
    pub usb: Otg,
    /// The world around the board.
    pub io: Io,
    /// Registers of peripherals without a model (EXTI, SYSCFG, …): kept as written.
    pub plain: BTreeMap<u32, u32>,
    /// Addresses of accesses no model covers (QEMU's `-d unimp`).
    pub unmodelled: BTreeSet<u32>,
    /// Set by a model: stop the CPU (fault).
    pub halt: Option<Halt>,
    /// Set by a model: end the current slice now (an exception must be taken).
    pub stop_slice: bool,
    /// Times LD2 (PB14) was switched on in this boot.
    pub led_rises: u64,
}

impl Chip {
    /// Power-on: everything reset, the store as `store` holds it.
    pub fn power_on(store: Box<StoreFlash>, io: Io) -> Self {
        Self::with_rcc(Rcc::power_on(), store, io)
    }

    /// The chip after a system reset with `rcc` (its CSR reset flags and backup domain set by
    /// the caller).
    pub fn with_rcc(rcc: Rcc, store: Box<StoreFlash>, io: Io) -> Self {
        Self {
            now_ps: 0,
            cycles: 0,
            nvic: Nvic::default(),
            rcc,
            flash: FlashCtl::reset(),
            store,
            gpio: (0..8).map(Gpio::reset).collect(),
            tim15: Timer::default(),
            iwdg: Iwdg::reset(),
            adc: Adc::default(),
            uart4: Usart::default(),
            spi1: Spi::default(),
            dma1: Dma::default(),
            i2c2: I2c::default(),
            usb: Otg::default(),
            io,
            plain: BTreeMap::new(),
            unmodelled: BTreeSet::new(),
            halt: None,
            stop_slice: false,
            led_rises: 0,
        }
    }

    /// Stop with a fault.
    pub fn fault(&mut self, why: String) {
        if self.halt.is_none() {
            self.halt = Some(Halt::Fault(why));
        }
        self.stop_slice = true;
    }

    fn clocked(&self, e: Enable) -> bool {
        self.rcc.enabled(e)
    }

    /// Check the flash wait states against the clock in force (RM0351 §3.3.3 Table 12), and
    /// clock settings the hardware refuses.
    pub fn check_clocks(&mut self) {
        let c = self.rcc.clocks();
        let need = flash::wait_states_needed(c.hclk, self.rcc.vos_range());
        if self.flash.latency() < need {
            self.fault(format!(
                "HCLK {} Hz with {} flash wait states: RM0351 Table 12 needs {} (range {}) — \
                 the core would fetch wrong instructions",
                c.hclk,
                self.flash.latency(),
                need,
                self.rcc.vos_range()
            ));
        }
        if let Some(e) = self.rcc.errors.pop() {
            self.fault(e);
        }
        if let Some(e) = self.flash.errors.pop() {
            self.fault(e);
        }
    }

    /// Read `size` bytes of a peripheral at `addr`.
    pub fn read(&mut self, addr: u32, size: usize) -> u32 {
        let now = self.now_ps;
        let word = addr & !3;
        let shift = 8 * (addr & 3);
        let v = match word {
            0x4000_2800..=0x4000_2BFF => {
                if !self.clocked(Enable::Apb1(10)) {
                    return 0;
                }
                self.rcc.rtc_read(word - 0x4000_2800)
            }
            0x4000_3000..=0x4000_33FF => self.iwdg.read(word - 0x4000_3000),
            0x4000_4C00..=0x4000_4FFF => {
                if !self.clocked(Enable::Apb1(19)) {
                    return 0;
                }
                let hz = self.rcc.uart4_hz();
                self.uart4.read(word - 0x4000_4C00, now, hz, &mut self.io)
            }
            0x4000_5800..=0x4000_5BFF => {
                if !self.clocked(Enable::Apb1(22)) {
                    return 0;
                }
                self.i2c2.read(word - 0x4000_5800, now, &mut self.io)
            }
            0x4000_7000..=0x4000_73FF => {
                if !self.clocked(Enable::Apb1(28)) {
                    return 0;
                }
                self.rcc.pwr_read(word - 0x4000_7000)
            }
            0x4001_3000..=0x4001_33FF => {
                if !self.clocked(Enable::Apb2(12)) {
                    return 0;
                }
                self.spi1.read(
                    word - 0x4001_3000,
                    addr & 3,
                    size,
                    now,
                    &mut self.io,
                    &self.gpio,
                )
            }
            0x4001_4000..=0x4001_43FF => {
                let en = self.clocked(Enable::Apb2(16));
                let clk = self.rcc.clocks().tim2;
                self.tim15.read(word - 0x4001_4000, now, clk, en)
            }
            0x4002_0000..=0x4002_03FF => {
                if !self.clocked(Enable::Ahb1(0)) {
                    return 0;
                }
                self.dma1.read(word - 0x4002_0000)
            }
            0x4002_1000..=0x4002_13FF => self.rcc.read(word - 0x4002_1000),
            0x4002_2000..=0x4002_23FF => self.flash.read(word - 0x4002_2000, now),
            0x4800_0000..=0x4800_1FFF => {
                let port = ((word - 0x4800_0000) / 0x400) as usize;
                if !self.clocked(Enable::Ahb2(port as u32)) {
                    return 0;
                }
                self.gpio[port].read(word & 0x3FF)
            }
            0x5000_0000..=0x5003_FFFF => {
                if !self.clocked(Enable::Ahb2(crate::rcc::ahb2::OTGFS)) {
                    return 0;
                }
                let clk48 = self.rcc.clk48();
                self.usb.read(word - 0x5000_0000, now, clk48, &mut self.io)
            }
            0x5004_0000..=0x5004_03FF => {
                if !self.clocked(Enable::Ahb2(crate::rcc::ahb2::ADC)) {
                    return 0;
                }
                self.adc.read(word - 0x5004_0000, now, &mut self.io)
            }
            _ => {
                if !self.plain.contains_key(&word) {
                    self.unmodelled.insert(word);
                }
                self.plain.get(&word).copied().unwrap_or(0)
            }
        };
        let v = v >> shift;
        match size {
            1 => v & 0xFF,
            2 => v & 0xFFFF,
            _ => v,
        }
    }

    /// Write `size` bytes of a peripheral at `addr`.
    pub fn write(&mut self, addr: u32, size: usize, value: u32) {
        let now = self.now_ps;
        let word = addr & !3;
        // narrow writes: merge into the register as read (AHB/APB byte lanes)
        let v = if size == 4 {
            value
        } else {
            let shift = 8 * (addr & 3);
            let mask = if size == 1 { 0xFF } else { 0xFFFF } << shift;
            let old = match word {
                // data registers: a narrow write is a narrow transfer, not a read-modify-write
                0x4000_4C28 | 0x4001_300C | 0x4000_5828 => 0,
                _ => self.peek(word),
            };
            (old & !mask) | ((value << shift) & mask)
        };
        match word {
            0x4000_2800..=0x4000_2BFF => {
                if self.clocked(Enable::Apb1(10)) {
                    self.rcc.rtc_write(word - 0x4000_2800, v);
                }
            }
            0x4000_3000..=0x4000_33FF => self.iwdg.write(word - 0x4000_3000, v, now, &mut self.rcc),
            0x4000_4C00..=0x4000_4FFF => {
                if self.clocked(Enable::Apb1(19)) {
                    let hz = self.rcc.uart4_hz();
                    self.uart4
                        .write(word - 0x4000_4C00, v, now, hz, &mut self.io);
                }
            }
            0x4000_5800..=0x4000_5BFF => {
                if self.clocked(Enable::Apb1(22)) {
                    let hz = self.rcc.i2c2_hz();
                    self.i2c2
                        .write(word - 0x4000_5800, v, now, hz, &mut self.io);
                }
            }
            0x4000_7000..=0x4000_73FF => {
                if self.clocked(Enable::Apb1(28)) {
                    self.rcc.pwr_write(word - 0x4000_7000, v);
                    self.check_clocks();
                }
            }
            0x4001_3000..=0x4001_33FF => {
                if self.clocked(Enable::Apb2(12)) {
                    let pclk2 = self.rcc.clocks().pclk2;
                    self.spi1.write(
                        word - 0x4001_3000,
                        v,
                        size,
                        now,
                        pclk2,
                        &mut self.io,
                        &self.gpio,
                    );
                }
            }
            0x4001_4000..=0x4001_43FF => {
                let en = self.clocked(Enable::Apb2(16));
                let clk = self.rcc.clocks().tim2;
                self.tim15.write(word - 0x4001_4000, v, now, clk, en);
            }
            0x4002_0000..=0x4002_03FF => {
                if self.clocked(Enable::Ahb1(0)) {
                    self.dma1.write(word - 0x4002_0000, v);
                }
            }
            0x4002_1000..=0x4002_13FF => {
                self.rcc.write(word - 0x4002_1000, v);
                self.check_clocks();
            }
            0x4002_2000..=0x4002_23FF => {
                self.flash
                    .write(word - 0x4002_2000, v, now, &mut self.store);
                self.check_clocks();
            }
            0x4800_0000..=0x4800_1FFF => {
                let port = ((word - 0x4800_0000) / 0x400) as usize;
                if self.clocked(Enable::Ahb2(port as u32)) {
                    let before: Vec<bool> = (0..16).map(|p| self.gpio[port].level(p)).collect();
                    self.gpio[port].write(word & 0x3FF, v);
                    for (p, was) in before.into_iter().enumerate() {
                        let is = self.gpio[port].level(p);
                        if is != was {
                            if (port, p) == (1, 14) && is {
                                self.led_rises += 1;
                            }
                            self.spi1.pin_changed(port, p, is, &mut self.io);
                            self.i2c2.pin_changed(port, p, is, &mut self.io);
                        }
                    }
                }
            }
            0x5000_0000..=0x5003_FFFF => {
                if self.clocked(Enable::Ahb2(crate::rcc::ahb2::OTGFS)) {
                    let clk48 = self.rcc.clk48();
                    self.usb
                        .write(word - 0x5000_0000, v, now, clk48, &mut self.io);
                }
            }
            0x5004_0000..=0x5004_03FF => {
                if self.clocked(Enable::Ahb2(crate::rcc::ahb2::ADC)) {
                    let rcc = &self.rcc;
                    self.adc
                        .write(word - 0x5004_0000, v, now, rcc, &mut self.io);
                }
            }
            _ => {
                if !self.plain.contains_key(&word) {
                    self.unmodelled.insert(word);
                }
                // EXTI_PR1/PR2 are write-1-to-clear
                if word == 0x4001_0414 || word == 0x4001_0434 {
                    let old = self.plain.get(&word).copied().unwrap_or(0);
                    self.plain.insert(word, old & !v);
                } else {
                    self.plain.insert(word, v);
                }
            }
        }
    }

    /// A register's value without side effects (for narrow writes).
    fn peek(&mut self, word: u32) -> u32 {
        match word {
            0x4002_1000..=0x4002_13FF => self.rcc.read(word - 0x4002_1000),
            0x4800_0000..=0x4800_1FFF => {
                let port = ((word - 0x4800_0000) / 0x400) as usize;
                self.gpio[port].read(word & 0x3FF)
            }
            _ => self.plain.get(&word).copied().unwrap_or(0),
        }
    }

    /// Bring every peripheral to `now_ps` and set the interrupt lines.
    pub fn update(&mut self) {
        let now = self.now_ps;
        let c = self.rcc.clocks();
        let en15 = self.clocked(Enable::Apb2(16));
        self.tim15.update(now, c.tim2, en15);
        self.adc.update(now, &mut self.io);
        self.flash.finish(now);
        let hz = self.rcc.uart4_hz();
        if self.clocked(Enable::Apb1(19)) {
            self.uart4.update(now, hz, &mut self.io);
        }
        if self.clocked(Enable::Apb1(22)) {
            self.i2c2.update(now, &mut self.io);
        }
        if self.clocked(Enable::Apb2(12)) {
            self.spi1.update(now, &mut self.io, &self.gpio);
        }
        let clk48 = self.rcc.clk48();
        if self.clocked(Enable::Ahb2(crate::rcc::ahb2::OTGFS)) {
            // VBUS on PA9 (UM2153: the OTG connector's VBUS through a divider)
            self.usb.update(now, clk48, &mut self.io);
            self.gpio[0].external[9] = Some(self.io.usb_attached());
        }
        // SDA (PB11) held low by a slave: what the pin reads, whatever drives it
        self.gpio[1].external[11] = self.io.i2c_sda_held().then_some(false);
        let lines = &mut self.nvic.lines;
        lines[16 + irq::TIM15] = self.tim15.irq();
        lines[16 + irq::ADC1_2] = self.adc.irq();
        lines[16 + irq::UART4] = self.uart4.irq();
        lines[16 + irq::SPI1] = self.spi1.irq();
        lines[16 + irq::I2C2_EV] = self.i2c2.irq_ev();
        lines[16 + irq::I2C2_ER] = self.i2c2.irq_er();
        lines[16 + irq::OTG_FS] = self.usb.irq();
        for ch in 0..7 {
            lines[16 + irq::DMA1_CH1 + ch] = self.dma1.irq(ch);
        }
        self.nvic.latch_lines();
    }

    /// The earliest time something inside the chip happens by itself, ps.
    pub fn next_event(&self) -> Option<u64> {
        let c = self.rcc.clocks();
        let en15 = self.rcc.enabled(Enable::Apb2(16));
        [
            self.tim15.next_event(c.tim2, en15),
            self.adc.next_event(),
            self.iwdg.running.then_some(self.iwdg.deadline_ps),
            self.flash.busy_until(),
            self.rcc
                .enabled(Enable::Apb1(19))
                .then(|| self.uart4.next_event(self.rcc.uart4_hz(), &self.io))
                .flatten(),
            self.spi1.next_event(),
            self.i2c2.next_event(),
            self.usb.next_event(&self.io.usb),
        ]
        .into_iter()
        .flatten()
        .min()
    }
}
