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
use embassy_stm32::{bind_interrupts, dma, usb, Config};
use embassy_time::{Duration, Timer};
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::UsbDevice;
use nanocal_compensator::clock;
use nanocal_compensator::l4flash::L4Nor;
use nanocal_compensator::line_state::LineSeen;
use nanocal_compensator::store::Store;
use nanocal_fw::app::{self, Identity, Shared};
use nanocal_fw::stm32::buses::{Buses, I2C_TIMEOUT};
use nanocal_fw::stm32::crash;
use nanocal_fw::stm32::flash::{self, L4Flash, ERASE};
use nanocal_fw::stm32::stage::{StageRx, StageRxWatch, RX_RING};
use nanocal_fw::stm32::usb::{LineWatch, UsbDriver, UsbRx, UsbTx, GCS_PORT, PORTS, USB_PACKET};
use nanocal_interface::identity::{self, ResetCause, Site};
use nanocal_interface::settings::{Settings, MAX_STAGE_BAUD, MIN_STAGE_BAUD};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<USB_OTG_FS>;
    // the loss watch reads UART4's status before embassy's handler clears it
    UART4 => StageRxWatch, usart::BufferedInterruptHandler<UART4>;
    DMA1_CHANNEL2 => dma::InterruptHandler<DMA1_CH2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<DMA1_CH3>;
});

type Flash = L4Nor<L4Flash, ERASE>;

const FLASH_ACR: usize = 0x4002_2000;

fn reg(a: usize) -> u32 {
    // SAFETY: a peripheral register, 32-bit access.
    unsafe { core::ptr::read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(a as *mut u32, v) }
}

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
    // The ADC's kernel clock: CCIPR.ADCSEL resets to 00, "no clock" (RM0351 §6.4.28), and
    // embassy-stm32 leaves ADC_CCR.CKMODE at 00 (the asynchronous clock), so an unset mux
    // leaves the ADC unclocked: `Adc::new` spins on ADCAL for ever and the watchdog resets the
    // board every 2 s (issue 16; tests/stm32_boot.rs). SYSCLK (80 MHz) is within the ADC's
    // 80 MHz maximum (datasheet fADC).
    config.rcc.mux.adcsel = mux::Adcsel::SYS;
    config
}

/// Program the flash wait states for 80 MHz before embassy-stm32 touches a clock.
///
/// embassy-stm32 0.6.0 `rcc/l.rs` `init()` calls `msi_enable(RANGE48M)` while MSI is the
/// system clock and writes FLASH_ACR.LATENCY only after the PLL is configured; from reset the
/// L4 runs 0 wait states, valid to 16 MHz (RM0351 §3.3.3, Table 12), so the core would run
/// 48 MHz from flash at 0 WS. Fixed upstream after 0.6.0 (embassy-rs/embassy#6768, "set max
/// flash latency before raising the MSI range"), not released: more wait states are always
/// safe, and init then writes the exact value for the final clocks.
fn flash_latency_first() {
    let acr = reg(FLASH_ACR);
    let ws = u32::from(clock::BOOT_WAIT_STATES);
    set(FLASH_ACR, (acr & !0x7) | ws);
    while reg(FLASH_ACR) & 0x7 != ws {}
}

/// Why the chip reset: the firmware's own record when it made one (a panic, an ECC error
/// outside the store, a HardFault — RCC_CSR would say "watchdog" or "software"), else RCC_CSR
/// (RM0351 §6.4.29); the flags are cleared (RMVF).
fn reset_cause() -> (ResetCause, Site<'static>) {
    const RCC_CSR: usize = 0x4002_1094;
    let csr = reg(RCC_CSR);
    set(RCC_CSR, csr | (1 << 23));
    crash::take().unwrap_or((ResetCause::from_rcc_csr(csr), Site::None))
}

/// The stage link's UART at the stored baud rate. A rate the USART cannot make (a record stored
/// by a firmware that accepted it) must not stop the board at every boot: the default is used
/// instead, and the settings show what is stored.
fn stage_uart_config(settings: &Settings) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = settings.stage_baud;
    if !(MIN_STAGE_BAUD..=MAX_STAGE_BAUD).contains(&c.baudrate) {
        defmt::warn!(
            "stored stage baud rate {=u32} is out of range: {=u32} in force",
            c.baudrate,
            Settings::default().stage_baud
        );
        c.baudrate = Settings::default().stage_baud;
    }
    c
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    flash_latency_first();
    let (cause, site) = reset_cause();
    let p = embassy_stm32::init(clocks());
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
        stage_uart_config(&settings),
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
