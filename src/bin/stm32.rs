//! B-L475E-IOT01A board (STM32L475VG): host link and management on two USB CDC-ACM interfaces,
//! stage link on UART4 (Arduino D1 = PA0 TX, D0 = PA1 RX, through a MAX3232-class transceiver,
//! see src/README.md), MAX31856/MAX31865 amplifiers on SPI1 (D13 SCK, D12 MISO with pull-up,
//! D11 MOSI) with one chip-select per sensor, the on-board LPS22HB on I2C2, a force input on
//! ADC1 (A0 = PC5), the store in the last 64 KiB of flash bank 2, LD2 (PB14) as the status LED,
//! IWDG, defmt over RTT.
#![no_std]
#![no_main]

use defmt_rtt as _;

use core::sync::atomic::Ordering;
use embassy_executor::Spawner;
use embassy_stm32::adc::Adc;
use embassy_stm32::gpio::{Level, Output, Pull, Speed};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::peripherals::{DMA1_CH2, DMA1_CH3, UART4, USB_OTG_FS};
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, usb};
use embassy_time::{Duration, Timer};
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::UsbDevice;
use nanocal_compensator::l4flash::L4Nor;
use nanocal_compensator::line_state::LineSeen;
use nanocal_compensator::store::Store;
use nanocal_fw::app::{self, Identity, Shared};
use nanocal_fw::stm32::buses::{Buses, I2C_TIMEOUT};
use nanocal_fw::stm32::flash::{self, L4Flash, ERASE};
use nanocal_fw::stm32::stage::{StageRx, StageRxWatch, RX_RING};
use nanocal_fw::stm32::usb::{LineWatch, UsbDriver, UsbRx, UsbTx, GCS_PORT, PORTS, USB_PACKET};
use nanocal_fw::stm32::{clocks, crash, stage};
use nanocal_interface::identity;
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<USB_OTG_FS>;
    // the loss watch reads UART4's status before embassy's handler clears it
    UART4 => StageRxWatch, usart::BufferedInterruptHandler<UART4>;
    DMA1_CHANNEL2 => dma::InterruptHandler<DMA1_CH2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<DMA1_CH3>;
});

type Flash = L4Nor<L4Flash, ERASE>;

static SHARED: StaticCell<Shared> = StaticCell::new();
static STORE: StaticCell<Store<Flash>> = StaticCell::new();
static SERIAL: StaticCell<[u8; 24]> = StaticCell::new();

#[embassy_executor::task]
async fn usb_task(mut dev: UsbDevice<'static, UsbDriver>) {
    dev.run().await
}

/// Both CDC ports' line states, as the QEMU board's one line-state task: a DTR fall of the GCS
/// port ends the host session, of the management port drops a frame still arriving — also a
/// fall and rise that came in between two looks (counted by [`LineWatch`]).
#[embassy_executor::task]
async fn line_state_task(sh: &'static Shared) {
    let mut seen = [LineSeen::new(); PORTS];
    loop {
        for (port, seen) in seen.iter_mut().enumerate() {
            for &dtr in seen.look(LineWatch::state(port)).iter() {
                match port {
                    GCS_PORT => app::host_line_state(sh, dtr),
                    _ => app::mgmt_line_state(sh, dtr),
                }
            }
        }
        LineWatch::changed().await;
    }
}

#[embassy_executor::task]
async fn host_link_task(rx: UsbRx, tx: UsbTx, sh: &'static Shared) {
    app::host_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn stage_link_task(rx: StageRx, tx: BufferedUartTx<'static>, sh: &'static Shared) {
    app::stage_link(rx, tx, sh).await
}

#[embassy_executor::task]
async fn sensor_task(bus: Buses, sh: &'static Shared) {
    app::sensors(bus, Duration::from_millis(20), sh).await
}

fn reset() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}

#[embassy_executor::task]
async fn management_task(
    rx: UsbRx,
    tx: UsbTx,
    store: &'static mut Store<Flash>,
    sh: &'static Shared,
) {
    app::management(rx, tx, store, reset, sh).await
}

struct Stm32Board {
    led: Output<'static>,
    wdg: IndependentWatchdog<'static, embassy_stm32::peripherals::IWDG>,
}

impl app::Board for Stm32Board {
    fn set_led(&mut self, on: bool) {
        self.led
            .set_level(if on { Level::High } else { Level::Low });
    }
    fn pet_watchdog(&mut self) {
        self.wdg.pet();
    }
}

#[embassy_executor::task]
async fn supervisor_task(board: Stm32Board, sh: &'static Shared) {
    app::supervisor(board, sh).await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    clocks::flash_latency_first();
    let (cause, site) = crash::reset_cause();
    let p = embassy_stm32::init(clocks::config());
    // the watchdog first: a hang anywhere from here on resets the board
    let mut wdg = IndependentWatchdog::new(p.IWDG, 2_000_000);
    wdg.unleash();
    let uid = embassy_stm32::uid::uid();
    defmt::info!(
        "nanocal-fw {} (B-L475E-IOT01A) up; reset cause {}",
        app::VERSION,
        cause.code()
    );

    let store = STORE.init(Store::new(L4Nor::new(L4Flash)));
    // polled here before any task runs (flash waits spin meanwhile, see `BOOTING`), so the main
    // task's future does not keep the store's read state for ever
    let settings = embassy_futures::block_on(app::load_settings(store));
    flash::booted();
    let sh: &'static Shared = SHARED.init(Shared::new(
        settings,
        Identity {
            uid,
            reset_cause: cause,
            reset_site: site,
        },
    ));
    // nobody has the GCS port open until the host raises DTR
    sh.host_connected.store(false, Ordering::Relaxed);

    // USB: two CDC-ACM interfaces (GCS host link, management), composite with IADs.
    static EP_OUT: StaticCell<[u8; 256]> = StaticCell::new();
    // Self-powered from the OTG port's point of view (the board runs from its ST-LINK USB):
    // embassy-usb-synopsys-otg requires VBUS detection then; PA9 is wired to the OTG
    // connector's VBUS on this board (UM2153).
    let mut usb_config = usb::Config::default();
    usb_config.vbus_detection = true;
    let driver = usb::Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        EP_OUT.init([0; 256]),
        usb_config,
    );
    let serial = SERIAL.init([0; 24]);
    identity::usb_serial(&uid, serial);
    let mut config = embassy_usb::Config::new(0x1209, 0x0001);
    config.manufacturer = Some("nanocal");
    config.product = Some("nanocal inline compensator");
    config.serial_number = Some(core::str::from_utf8(serial).unwrap_or("0"));
    config.composite_with_iads = true;
    config.device_class = 0xEF;
    config.device_sub_class = 0x02;
    config.device_protocol = 0x01;
    config.self_powered = true;
    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 64]> = StaticCell::new();
    static MSOS_DESC: StaticCell<[u8; 0]> = StaticCell::new();
    static CONTROL: StaticCell<[u8; 64]> = StaticCell::new();
    static GCS_STATE: StaticCell<State> = StaticCell::new();
    static MGMT_STATE: StaticCell<State> = StaticCell::new();
    static GCS_RX: StaticCell<[u8; 64]> = StaticCell::new();
    static MGMT_RX: StaticCell<[u8; 64]> = StaticCell::new();
    static LINE_WATCH: StaticCell<LineWatch> = StaticCell::new();
    let mut builder = embassy_usb::Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 64]),
        MSOS_DESC.init([]),
        CONTROL.init([0; 64]),
    );
    // before the CDC functions: it sees both ports' line state requests first
    builder.handler(LINE_WATCH.init(LineWatch));
    let gcs = CdcAcmClass::new(&mut builder, GCS_STATE.init(State::new()), USB_PACKET);
    let mgmt = CdcAcmClass::new(&mut builder, MGMT_STATE.init(State::new()), USB_PACKET);
    let usb = builder.build();
    let (gcs_tx, gcs_rx) = gcs.split();
    let (mgmt_tx, mgmt_rx) = mgmt.split();

    // Stage link at the configured baud rate.
    static UART_TX: StaticCell<[u8; 256]> = StaticCell::new();
    static UART_RX: StaticCell<[u8; RX_RING as usize]> = StaticCell::new();
    let uart = match BufferedUart::new(
        p.UART4,
        p.PA1,
        p.PA0,
        UART_TX.init([0; 256]),
        UART_RX.init([0; RX_RING as usize]),
        Irqs,
        stage::uart_config(&settings),
    ) {
        Ok(u) => u,
        Err(_) => panic!("stage UART configuration rejected"),
    };
    let (stage_tx, stage_rx) = uart.split();
    let stage_rx = StageRx::new(stage_rx);

    // Sensors: SPI mode 1 (MAX31856/MAX31865 latch on the falling edge), 1 MHz, MISO pulled up
    // so that an absent chip reads all ones (a fault), never a floating temperature.
    let mut spi_config = spi::Config::default();
    spi_config.frequency = Hertz(1_000_000);
    spi_config.mode = spi::MODE_1;
    spi_config.miso_pull = Pull::Up;
    let spi = Spi::new(
        p.SPI1, p.PA5, p.PA7, p.PA6, p.DMA1_CH3, p.DMA1_CH2, Irqs, spi_config,
    );
    let cs = [
        Output::new(p.PA2, Level::High, Speed::Low),  // D10
        Output::new(p.PA15, Level::High, Speed::Low), // D9
        Output::new(p.PB2, Level::High, Speed::Low),  // D8
        Output::new(p.PA4, Level::High, Speed::Low),  // D7
        Output::new(p.PB1, Level::High, Speed::Low),  // D6
        Output::new(p.PB4, Level::High, Speed::Low),  // D5 (NJTRST at reset; SWD does not use it)
        Output::new(p.PA3, Level::High, Speed::Low),  // D4
        Output::new(p.PB0, Level::High, Speed::Low),  // D3
        Output::new(p.PD14, Level::High, Speed::Low), // D2
        Output::new(p.PC4, Level::High, Speed::Low),  // A1
        Output::new(p.PC3, Level::High, Speed::Low),  // A2
        Output::new(p.PC2, Level::High, Speed::Low),  // A3
        Output::new(p.PC1, Level::High, Speed::Low),  // A4
        Output::new(p.PC0, Level::High, Speed::Low),  // A5
        Output::new(p.PB9, Level::High, Speed::Low),  // D14
        Output::new(p.PB8, Level::High, Speed::Low),  // D15
    ];
    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = Hertz(400_000);
    i2c_config.timeout = I2C_TIMEOUT;
    let i2c = I2c::new_blocking(p.I2C2, p.PB10, p.PB11, i2c_config);
    let adc = Adc::new(p.ADC1);
    let bus = Buses {
        spi,
        cs,
        i2c,
        adc,
        a0: p.PC5,
        i2c_recoveries: 0,
    };

    let led = Output::new(p.PB14, Level::Low, Speed::Low); // LD2

    // Until the host opens an interface its reads fail and the tasks back off and retry.
    let gcs_rx = gcs_rx.into_buffered(GCS_RX.init([0; 64]));
    let mgmt_rx = mgmt_rx.into_buffered(MGMT_RX.init([0; 64]));
    spawner.spawn(supervisor_task(Stm32Board { led, wdg }, sh).expect("task pool"));
    spawner.spawn(usb_task(usb).expect("task pool"));
    spawner.spawn(line_state_task(sh).expect("task pool"));
    spawner.spawn(management_task(mgmt_rx, UsbTx(mgmt_tx), store, sh).expect("task pool"));
    spawner.spawn(sensor_task(bus, sh).expect("task pool"));
    spawner.spawn(stage_link_task(stage_rx, stage_tx, sh).expect("task pool"));
    spawner.spawn(host_link_task(gcs_rx, UsbTx(gcs_tx), sh).expect("task pool"));
    loop {
        Timer::after_secs(3600).await;
    }
}
