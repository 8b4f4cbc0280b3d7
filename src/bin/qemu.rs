//! QEMU `mps2-an386` board: host link on serial0, stage link on serial1, sensor-bus stand-in
//! on serial2, management on serial3; RAM-emulated flash for the two model slots.
#![no_std]
#![no_main]

use cortex_m_rt::exception;
use cortex_m_semihosting::{debug, hprintln};
use embassy_executor::Spawner;
use embassy_time::Duration;
use nanocal_compensator::fault::Policy;
use nanocal_compensator::sensor::Chip;
use nanocal_compensator::slots::RamFlash;
use nanocal_fw::app::{self, Shared};
use nanocal_fw::qemu::sensor_bus::SerialSensorBus;
use nanocal_fw::qemu::uart::{Uart, UartRx, UartTx};
use nanocal_fw::qemu::{self, time};
use nanocal_model::blob;
use static_cell::StaticCell;

/// Sensors on the stand-in bus (chip-selects 0..4).
const CHIPS: [Chip; 4] = [Chip::Max31856; 4];
/// Slot size of the emulated flash.
const SLOT: usize = 8192;

static SHARED: StaticCell<Shared> = StaticCell::new();
static FLASH: StaticCell<RamFlash<SLOT>> = StaticCell::new();
static UPLOAD: StaticCell<[u8; blob::MAX_BLOB_LEN]> = StaticCell::new();

#[exception]
fn SysTick() {
    time::on_systick();
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    qemu::on_interrupt(irqn);
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("nanocal-fw panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[embassy_executor::task]
async fn host_link_task(rx: UartRx, tx: UartTx, sh: &'static Shared) {
    app::host_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn stage_link_task(rx: UartRx, tx: UartTx, sh: &'static Shared) {
    app::stage_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn sensor_task(bus: SerialSensorBus<UartRx, UartTx>, sh: &'static Shared) {
    app::sensors(bus, &CHIPS, Duration::from_millis(100), sh).await
}

#[embassy_executor::task]
async fn management_task(
    rx: UartRx,
    tx: UartTx,
    flash: &'static mut RamFlash<SLOT>,
    buf: &'static mut [u8; blob::MAX_BLOB_LEN],
    sh: &'static Shared,
) {
    app::management(rx, tx, flash, buf, sh).await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let Some(cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    time::init(cp.SYST);
    hprintln!("nanocal-fw (qemu mps2-an386) up");
    let sh: &'static Shared = SHARED.init(Shared::new(CHIPS.len() as u8, Policy::default()));
    // SAFETY: each UART index is taken exactly once, here.
    let (host, stage, sensors, mgmt) = unsafe {
        (
            Uart::new(0, 115_200),
            Uart::new(1, 115_200),
            Uart::new(2, 115_200),
            Uart::new(3, 115_200),
        )
    };
    let (hrx, htx) = host.split();
    let (srx, stx) = stage.split();
    let (brx, btx) = sensors.split();
    let (mrx, mtx) = mgmt.split();
    let bus = SerialSensorBus::new(brx, btx, Duration::from_millis(200));
    let flash = FLASH.init(RamFlash::new());
    let buf = UPLOAD.init([0; blob::MAX_BLOB_LEN]);
    spawner.spawn(management_task(mrx, mtx, flash, buf, sh).expect("task pool"));
    spawner.spawn(sensor_task(bus, sh).expect("task pool"));
    spawner.spawn(stage_link_task(srx, stx, sh).expect("task pool"));
    spawner.spawn(host_link_task(hrx, htx, sh).expect("task pool"));
}
