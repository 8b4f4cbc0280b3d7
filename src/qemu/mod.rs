//! The QEMU `mps2-an386` board's drivers (Cortex-M4F, 25 MHz): CMSDK APB UARTs, a clock the
//! virtual bench drives (1 MHz ticks; SysTick at 1× without the bench) and the executor loop
//! that moves it, the bus stand-in, watchdog, LED, storage. Only what the compensator needs; no
//! third-party HAL exists for it.

pub mod board;
pub mod executor;
pub mod link;
pub mod sensor_bus;
pub mod time;
pub mod uart;

/// CPU clock of the emulated board, Hz.
pub const SYSCLK_HZ: u32 = 25_000_000;

/// Dispatch a device interrupt (call from `DefaultHandler`).
pub fn on_interrupt(irqn: i16) {
    uart::on_interrupt(irqn);
}
