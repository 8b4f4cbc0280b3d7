//! B-L475E-IOT01A board (STM32L475VG): host link and management on two USB CDC-ACM interfaces,
//! stage link on UART4 (Arduino D1 = PA0 TX, D0 = PA1 RX; 115200 8N1 by default), MAX31856
//! thermocouple amplifiers on SPI1 (D13 SCK, D12 MISO, D11 MOSI) with one chip-select per
//! sensor, model slots in the last 32 KiB of internal flash, defmt over RTT.
#![no_std]
#![no_main]

use defmt_rtt as _;
use panic_probe as _;

use embassy_executor::Spawner;
use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::{DMA1_CH2, DMA1_CH3, UART4, USB_OTG_FS};
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::{bind_interrupts, dma, usb, Config};
use embassy_time::{Duration, Timer};
use embassy_usb::class::cdc_acm::{BufferedReceiver, CdcAcmClass, Sender, State};
use embassy_usb::UsbDevice;
use nanocal_compensator::fault::Policy;
use nanocal_compensator::sensor::{Chip, SensorFault, FRAME_LEN};
use nanocal_compensator::slots::{SlotStorage, StorageError};
use nanocal_fw::app::{self, SensorBus, Shared};
use nanocal_model::blob;
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<USB_OTG_FS>;
    UART4 => usart::BufferedInterruptHandler<UART4>;
    DMA1_CHANNEL2 => dma::InterruptHandler<DMA1_CH2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<DMA1_CH3>;
});

/// Stage link baud rate (the controller's setting; 8N1).
const STAGE_BAUD: u32 = 115_200;
/// Sensors fitted: one MAX31856 per chip-select (the chip-select pins are listed in `main`).
const CHIPS: [Chip; 4] = [Chip::Max31856; 4];
/// Model slots: the last 32 KiB of flash (excluded from FLASH in memory.x), 16 KiB each.
const SLOT_BASE: u32 = 0x000F_8000;
const SLOT_SIZE: u32 = 0x4000;
/// USB packet size of the CDC-ACM endpoints.
const USB_PACKET: u16 = 64;

type UsbDriver = usb::Driver<'static, USB_OTG_FS>;

/// Internal flash as two model slots.
struct FlashSlots {
    flash: Flash<'static, Blocking>,
}

impl SlotStorage for FlashSlots {
    fn slot_size(&self) -> usize {
        SLOT_SIZE as usize
    }
    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        let at = self.at(slot, offset, buf.len())?;
        self.flash
            .blocking_read(at, buf)
            .map_err(|_| StorageError::Device)
    }
    fn erase(&mut self, slot: usize) -> Result<(), StorageError> {
        let at = self.at(slot, 0, SLOT_SIZE as usize)?;
        self.flash
            .blocking_erase(at, at + SLOT_SIZE)
            .map_err(|_| StorageError::Device)
    }
    fn write(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        let at = self.at(slot, offset, data.len())?;
        self.flash
            .blocking_write(at, data)
            .map_err(|_| StorageError::Device)
    }
}

impl FlashSlots {
    fn at(&self, slot: usize, offset: usize, len: usize) -> Result<u32, StorageError> {
        if slot > 1 || offset + len > SLOT_SIZE as usize {
            return Err(StorageError::OutOfBounds);
        }
        Ok(SLOT_BASE + slot as u32 * SLOT_SIZE + offset as u32)
    }
}

/// SPI1 (DMA) with one chip-select per sensor.
struct SpiSensors {
    spi: Spi<'static, Async, spi::mode::Master>,
    cs: [Output<'static>; CHIPS.len()],
}

impl SensorBus for SpiSensors {
    async fn transfer(&mut self, cs: u8, frame: &mut [u8; FRAME_LEN]) -> Result<(), SensorFault> {
        let pin = self
            .cs
            .get_mut(usize::from(cs))
            .ok_or(SensorFault::NoResponse)?;
        pin.set_low();
        // DMA transfer: the executor runs the command path meanwhile
        let r = self.spi.transfer_in_place(frame).await;
        pin.set_high();
        r.map_err(|_| SensorFault::NoResponse)
    }
}

/// CDC-ACM sender writing at most one short packet per call, so that no zero-length packet is
/// ever needed to end a transfer.
struct UsbTx(Sender<'static, UsbDriver>);

impl embedded_io_async::ErrorType for UsbTx {
    type Error = embassy_usb::class::cdc_acm::CdcAcmError;
}

impl embedded_io_async::Write for UsbTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(usize::from(USB_PACKET) - 1);
        self.0.write(&buf[..n]).await
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

type UsbRx = BufferedReceiver<'static, UsbDriver>;

static SHARED: StaticCell<Shared> = StaticCell::new();
static UPLOAD: StaticCell<[u8; blob::MAX_BLOB_LEN]> = StaticCell::new();

#[embassy_executor::task]
async fn usb_task(mut dev: UsbDevice<'static, UsbDriver>) {
    dev.run().await
}

#[embassy_executor::task]
async fn host_link_task(rx: UsbRx, tx: UsbTx, sh: &'static Shared) {
    app::host_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn stage_link_task(
    rx: BufferedUartRx<'static>,
    tx: BufferedUartTx<'static>,
    sh: &'static Shared,
) {
    app::stage_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn sensor_task(bus: SpiSensors, sh: &'static Shared) {
    app::sensors(bus, &CHIPS, Duration::from_millis(250), sh).await
}

#[embassy_executor::task]
async fn management_task(
    rx: UsbRx,
    tx: UsbTx,
    flash: FlashSlots,
    buf: &'static mut [u8; blob::MAX_BLOB_LEN],
    sh: &'static Shared,
) {
    app::management(rx, tx, flash, buf, sh).await
}

fn clocks() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    // MSI 48 MHz trimmed by the 32.768 kHz LSE (MSI PLL mode) clocks USB; PLL → 80 MHz SYSCLK.
    config.rcc.ls = LsConfig::default_lse();
    config.rcc.msi = Some(MSIRange::RANGE48M);
    config.rcc.pll = Some(Pll {
        source: PllSource::MSI,
        prediv: PllPreDiv::DIV6,
        mul: PllMul::MUL20,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.mux.clk48sel = mux::Clk48sel::MSI;
    config
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    defmt::info!("nanocal-fw (B-L475E-IOT01A) up");
    let sh: &'static Shared = SHARED.init(Shared::new(CHIPS.len() as u8, Policy::default()));

    // USB: two CDC-ACM interfaces (GCS host link, management), composite with IADs.
    static EP_OUT: StaticCell<[u8; 256]> = StaticCell::new();
    // No VBUS sensing: the board is powered from the same host through its ST-LINK port, and
    // this works whether or not PA9 is wired to the OTG connector's VBUS.
    let mut usb_config = usb::Config::default();
    usb_config.vbus_detection = false;
    let driver = usb::Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        EP_OUT.init([0; 256]),
        usb_config,
    );
    let mut config = embassy_usb::Config::new(0x1209, 0x0001);
    config.manufacturer = Some("nanocal");
    config.product = Some("nanocal inline compensator");
    config.serial_number = Some("0001");
    config.composite_with_iads = true;
    config.device_class = 0xEF;
    config.device_sub_class = 0x02;
    config.device_protocol = 0x01;
    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 64]> = StaticCell::new();
    static MSOS_DESC: StaticCell<[u8; 0]> = StaticCell::new();
    static CONTROL: StaticCell<[u8; 64]> = StaticCell::new();
    static GCS_STATE: StaticCell<State> = StaticCell::new();
    static MGMT_STATE: StaticCell<State> = StaticCell::new();
    static GCS_RX: StaticCell<[u8; 64]> = StaticCell::new();
    static MGMT_RX: StaticCell<[u8; 64]> = StaticCell::new();
    let mut builder = embassy_usb::Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 64]),
        MSOS_DESC.init([]),
        CONTROL.init([0; 64]),
    );
    let gcs = CdcAcmClass::new(&mut builder, GCS_STATE.init(State::new()), USB_PACKET);
    let mgmt = CdcAcmClass::new(&mut builder, MGMT_STATE.init(State::new()), USB_PACKET);
    let usb = builder.build();
    let (gcs_tx, gcs_rx) = gcs.split();
    let (mgmt_tx, mgmt_rx) = mgmt.split();

    // Stage link.
    static UART_TX: StaticCell<[u8; 256]> = StaticCell::new();
    static UART_RX: StaticCell<[u8; 256]> = StaticCell::new();
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = STAGE_BAUD;
    let uart = match BufferedUart::new(
        p.UART4,
        p.PA1,
        p.PA0,
        UART_TX.init([0; 256]),
        UART_RX.init([0; 256]),
        Irqs,
        uart_config,
    ) {
        Ok(u) => u,
        Err(_) => panic!("stage UART configuration rejected"),
    };
    let (stage_tx, stage_rx) = uart.split();

    // Sensors: SPI mode 1 (MAX31856/MAX31865 sample on the falling edge), 1 MHz.
    let mut spi_config = spi::Config::default();
    spi_config.frequency = Hertz(1_000_000);
    spi_config.mode = spi::MODE_1;
    let spi = Spi::new(
        p.SPI1, p.PA5, p.PA7, p.PA6, p.DMA1_CH3, p.DMA1_CH2, Irqs, spi_config,
    );
    let cs = [
        Output::new(p.PA2, Level::High, Speed::Low),  // D10
        Output::new(p.PA15, Level::High, Speed::Low), // D9
        Output::new(p.PB2, Level::High, Speed::Low),  // D8
        Output::new(p.PA4, Level::High, Speed::Low),  // D7
    ];
    let bus = SpiSensors { spi, cs };

    let flash = FlashSlots {
        flash: Flash::new_blocking(p.FLASH),
    };
    let buf = UPLOAD.init([0; blob::MAX_BLOB_LEN]);

    // Until the host opens an interface its reads fail and the tasks back off and retry.
    let gcs_rx = gcs_rx.into_buffered(GCS_RX.init([0; 64]));
    let mgmt_rx = mgmt_rx.into_buffered(MGMT_RX.init([0; 64]));
    spawner.spawn(usb_task(usb).expect("task pool"));
    spawner.spawn(management_task(mgmt_rx, UsbTx(mgmt_tx), flash, buf, sh).expect("task pool"));
    spawner.spawn(sensor_task(bus, sh).expect("task pool"));
    spawner.spawn(stage_link_task(stage_rx, stage_tx, sh).expect("task pool"));
    spawner.spawn(host_link_task(gcs_rx, UsbTx(gcs_tx), sh).expect("task pool"));
    loop {
        Timer::after_secs(3600).await;
    }
}
