//! The B-L475E-IOT01A board (STM32L475VG, embassy-stm32): what the application needs from it
//! that embassy does not give as is. `src/bin/stm32.rs` wires it up.
//!
//! - [`clocks`]: the clock tree, and the flash wait states raised before it;
//! - [`buses`]: SPI1 with a chip-select guard, I2C2 with a bounded timeout and bus recovery,
//!   ADC1;
//! - [`flash`]: the store's flash on bank 2 (read-while-write, ES0250's data cache) and the NMI
//!   of a double ECC error;
//! - [`usb`]: the CDC-ACM sender, and the GCS port's line state (DTR falls counted, its IN
//!   endpoint flushed at close);
//! - [`stage`]: UART4 at the stored baud rate, its receive side with lost bytes reported;
//! - [`crash`]: panics, HardFaults and ECC errors outside the store recorded over the reset,
//!   and the reset cause read at boot.

pub mod buses;
pub mod clocks;
pub mod crash;
pub mod flash;
pub mod stage;
pub mod usb;
