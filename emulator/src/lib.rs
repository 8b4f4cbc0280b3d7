//! A register-level B-L475E-IOT01A (STM32L475VG) that runs the shipped `nanocal-fw` image: the
//! Cortex-M4F core is Unicorn's (GPL-2.0, hence this crate's licence; only the host tests link
//! it), everything around it — NVIC, SysTick, RCC, PWR, FLASH, GPIO, TIM15, IWDG, ADC1, UART4,
//! SPI1 with DMA1, I2C2, USB OTG FS — is modelled here from RM0351 (the section is cited in each
//! model). See the README's "Emulated board" section for what is modelled and what is not.

pub mod board;
pub mod chip;
pub mod clock;
pub mod elf;
pub mod flash;
pub mod io;
pub mod nvic;
pub mod periph;
pub mod rcc;
pub mod simple;
pub mod usb;

pub use board::{Board, BoardError, Control, Inject, ResetKind, Status};
pub use chip::Halt;
pub use clock::{Clock, Pause, PS};
pub use io::{Io, NoChips, SensorBus, UartPeer};
