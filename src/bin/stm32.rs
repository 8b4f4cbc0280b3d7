//! B-L475E-IOT01A board (STM32L475VG): host link and management on two USB CDC-ACM interfaces,
//! stage link on UART4 (Arduino D1 = PA0 TX, D0 = PA1 RX, through a MAX3232-class transceiver,
//! see src/README.md), MAX31856/MAX31865 amplifiers on SPI1 (D13 SCK, D12 MISO with pull-up,
//! D11 MOSI) with one chip-select per sensor, the on-board LPS22HB on I2C2, a force input on
//! ADC1 (A0 = PC5), the store in the last 64 KiB of flash bank 2, LD2 (PB14) as the status LED,
//! IWDG, defmt over RTT.
#![no_std]
#![no_main]

use defmt_rtt as _;

use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m_rt::exception;
use embassy_executor::Spawner;
use embassy_stm32::adc::{Adc, SampleTime};
use embassy_stm32::gpio::{Level, Output, Pull, Speed};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::mode::{Async, Blocking};
use embassy_stm32::peripherals::{ADC1, DMA1_CH2, DMA1_CH3, PC5, UART4, USB_OTG_FS};
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, usb, Config, Peri};
use embassy_time::{Duration, Timer};
use embassy_usb::class::cdc_acm::{BufferedReceiver, CdcAcmClass, ControlChanged, Sender, State};
use embassy_usb::UsbDevice;
use nanocal_compensator::clock;
use nanocal_compensator::l4flash::{FlashError, L4Nor, RawFlash, DWORD, PAGE};
use nanocal_compensator::store::Store;
use nanocal_fw::app::{self, Identity, InputBus, Shared};
use nanocal_interface::identity::{self, ResetCause};
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<USB_OTG_FS>;
    UART4 => usart::BufferedInterruptHandler<UART4>;
    DMA1_CHANNEL2 => dma::InterruptHandler<DMA1_CH2>;
    DMA1_CHANNEL3 => dma::InterruptHandler<DMA1_CH3>;
});

/// Chip-selects, one per amplifier, on the Arduino Uno V3 connector's free pins (UM2153's connector
/// table; the same mapping as Zephyr's disco_l475_iot1 board): D10 PA2, D9 PA15, D8 PB2, D7 PA4, D6 PB1, D5 PB4, D4 PA3, D3 PB0, D2 PD14, A1 PC4, A2 PC3,
/// A3 PC2, A4 PC1, A5 PC0, D14 PB9, D15 PB8): 16, as many as the settings and the model can
/// name. D0/D1 are the stage link, D11–D13 SPI1, A0 the force input.
const CS_PINS: usize = 16;
/// The store: the last 64 KiB of flash (bank 2, pages 224..255), excluded from FLASH in
/// memory.x.
const STORE_BASE: u32 = 0x080F_0000;
const STORE_SIZE: usize = 64 * 1024;
const BANK2_BASE: u32 = 0x0808_0000;
/// Store erase unit: four 2 KiB pages (a whole blob fits one unit).
const ERASE: usize = 8 * 1024;
/// USB packet size of the CDC-ACM endpoints.
const USB_PACKET: u16 = 64;

type UsbDriver = usb::Driver<'static, USB_OTG_FS>;
type Flash = L4Nor<L4Flash, ERASE>;

// ---------------------------------------------------------------- flash (RM0351 §3.3, §3.7)

const FLASH_KEYR: usize = 0x4002_2008;
const FLASH_SR: usize = 0x4002_2010;
const FLASH_CR: usize = 0x4002_2014;
const FLASH_ECCR: usize = 0x4002_2018;
const FLASH_ACR: usize = 0x4002_2000;
const SR_BSY: u32 = 1 << 16;
/// OPTVERR, RDERR, FASTERR, MISERR, PGSERR, SIZERR, PGAERR, WRPERR, PROGERR, OPERR.
const SR_ERRORS: u32 = 0xC3FA;
const CR_PG: u32 = 1 << 0;
const CR_PER: u32 = 1 << 1;
const CR_BKER: u32 = 1 << 11;
const CR_STRT: u32 = 1 << 16;
const CR_LOCK: u32 = 1 << 31;
const ECCR_ECCD: u32 = 1 << 31;

/// Set by the NMI handler when a flash read hit a double ECC error.
static ECC_ERROR: AtomicBool = AtomicBool::new(false);

/// True until the executor runs the tasks: the store's flash waits spin instead of awaiting a
/// timer (embassy-time's timers need an executor task; at start-up nothing else runs).
static BOOTING: AtomicBool = AtomicBool::new(true);

fn reg(a: usize) -> u32 {
    // SAFETY: FLASH controller register, 32-bit access.
    unsafe { read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(a as *mut u32, v) }
}

/// A flash read with two bit errors raises the NMI (RM0351 §3.3.4): clear ECCD and flag it, so
/// the read returns and the store treats that double word as corrupt. cortex-m-rt's default
/// handler would loop for ever and every boot that reads a torn double word would hang. Any
/// other NMI (clock security system) stops here and the IWDG resets the board.
#[exception]
unsafe fn NonMaskableInt() {
    let eccr = reg(FLASH_ECCR);
    if eccr & ECCR_ECCD != 0 {
        set(FLASH_ECCR, eccr);
        ECC_ERROR.store(true, Ordering::SeqCst);
        return;
    }
    loop {
        cortex_m::asm::nop();
    }
}

/// A panic logs where it happened (defmt over RTT; the message would pull in `core::fmt`,
/// about 3 KiB of flash, for the few panics the firmware has, all on start-up paths) and ends in
/// a permanent UDF, which probe-rs reports with a backtrace; without a probe the IWDG resets
/// the board.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(l) => defmt::error!("panic at {=str}:{=u32}", l.file(), l.line()),
        None => defmt::error!("panic"),
    }
    cortex_m::asm::udf()
}

/// The store's flash: bank 2, erased and programmed through the controller's registers with
/// BSY polled asynchronously. Code runs from bank 1, so while bank 2 is busy the executor keeps
/// serving the command path (read-while-write, RM0351 §3.3.1) instead of stalling ~22 ms per
/// page as embassy-stm32's blocking flash driver does.
struct L4Flash;

impl L4Flash {
    fn unlock() {
        if reg(FLASH_CR) & CR_LOCK != 0 {
            set(FLASH_KEYR, 0x4567_0123);
            set(FLASH_KEYR, 0xCDEF_89AB);
        }
    }

    async fn wait_idle(poll_us: u64) -> Result<(), FlashError> {
        while reg(FLASH_SR) & SR_BSY != 0 {
            if BOOTING.load(Ordering::Relaxed) {
                continue;
            }
            if poll_us == 0 {
                embassy_futures::yield_now().await;
            } else {
                Timer::after_micros(poll_us).await;
            }
        }
        let sr = reg(FLASH_SR);
        set(FLASH_SR, sr & (SR_ERRORS | 1));
        if sr & SR_ERRORS != 0 {
            return Err(FlashError::Controller);
        }
        Ok(())
    }

    /// Reset the data cache after an erase (RM0351 §3.3.3: stale lines may hold old data).
    fn reset_dcache() {
        let acr = reg(FLASH_ACR);
        set(FLASH_ACR, acr & !(1 << 10));
        set(FLASH_ACR, (acr & !(1 << 10)) | (1 << 12));
        set(FLASH_ACR, acr & !(1 << 12));
    }
}

impl RawFlash for L4Flash {
    fn capacity(&self) -> usize {
        STORE_SIZE
    }

    fn read_dword(&mut self, offset: u32) -> [u8; DWORD] {
        let a = (STORE_BASE + offset) as usize;
        let (lo, hi) = (reg(a), reg(a + 4));
        let mut d = [0u8; DWORD];
        d[..4].copy_from_slice(&lo.to_le_bytes());
        d[4..].copy_from_slice(&hi.to_le_bytes());
        d
    }

    fn take_ecc_error(&mut self) -> bool {
        ECC_ERROR.swap(false, Ordering::SeqCst)
    }

    async fn erase_page(&mut self, offset: u32) -> Result<(), FlashError> {
        let page = (STORE_BASE + offset - BANK2_BASE) / PAGE as u32;
        Self::wait_idle(500).await?;
        Self::unlock();
        set(FLASH_CR, CR_PER | CR_BKER | (page << 3));
        set(FLASH_CR, CR_PER | CR_BKER | (page << 3) | CR_STRT);
        let r = Self::wait_idle(1000).await;
        set(FLASH_CR, CR_LOCK);
        Self::reset_dcache();
        r
    }

    async fn program_dword(&mut self, offset: u32, data: [u8; DWORD]) -> Result<(), FlashError> {
        let a = (STORE_BASE + offset) as usize;
        Self::wait_idle(0).await?;
        Self::unlock();
        set(FLASH_CR, CR_PG);
        let w = |i: usize| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
        set(a, w(0));
        set(a + 4, w(4));
        let r = Self::wait_idle(0).await;
        set(FLASH_CR, CR_LOCK);
        r
    }
}

// ---------------------------------------------------------------- buses

/// SPI1 (DMA) with one chip-select per sensor, I2C2 (the LPS22HB), ADC1 channel A0.
struct Buses {
    spi: Spi<'static, Async, spi::mode::Master>,
    cs: [Output<'static>; CS_PINS],
    i2c: I2c<'static, Blocking, i2c::Master>,
    adc: Adc<'static, ADC1>,
    a0: Peri<'static, PC5>,
}

impl InputBus for Buses {
    async fn spi(&mut self, cs: u8, buf: &mut [u8]) -> Result<(), ()> {
        let Some(pin) = self.cs.get_mut(usize::from(cs)) else {
            buf.fill(0xFF); // nothing wired: MISO pull-up
            return Ok(());
        };
        pin.set_low();
        // DMA transfer: the executor runs the command path meanwhile
        let r = self.spi.transfer_in_place(buf).await;
        pin.set_high();
        r.map_err(|_| ())
    }

    async fn i2c(&mut self, addr: u8, w: &[u8], r: &mut [u8]) -> Result<(), ()> {
        // a few bytes at 400 kHz (< 0.2 ms): blocking is shorter than a context switch
        let res = if r.is_empty() {
            self.i2c.blocking_write(addr, w)
        } else {
            self.i2c.blocking_write_read(addr, w, r)
        };
        res.map_err(|_| ())
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
        // see `CS_PINS`
        self.cs.len() as u8
    }
}

// ---------------------------------------------------------------- USB

/// CDC-ACM sender writing at most one short packet per call, so that no zero-length packet is
/// ever needed to end a transfer. With DTR low nobody has the port open: the bytes belong to no
/// connection and are dropped instead of piling up for the next one.
struct UsbTx(Sender<'static, UsbDriver>);

impl embedded_io_async::ErrorType for UsbTx {
    type Error = embassy_usb::class::cdc_acm::CdcAcmError;
}

impl embedded_io_async::Write for UsbTx {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(usize::from(USB_PACKET) - 1);
        if !self.0.dtr() {
            return Ok(n);
        }
        self.0.write(&buf[..n]).await
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

type UsbRx = BufferedReceiver<'static, UsbDriver>;

static SHARED: StaticCell<Shared> = StaticCell::new();
static STORE: StaticCell<Store<Flash>> = StaticCell::new();
static SERIAL: StaticCell<[u8; 24]> = StaticCell::new();

#[embassy_executor::task]
async fn usb_task(mut dev: UsbDevice<'static, UsbDriver>) {
    dev.run().await
}

/// A port's line state, told to the application by `tell` on every change: the GCS port's
/// (a DTR fall ends the host session) and the management port's (a DTR fall drops a management
/// frame still arriving).
#[embassy_executor::task(pool_size = 2)]
async fn line_state_task(
    ctl: ControlChanged<'static>,
    sh: &'static Shared,
    tell: fn(&'static Shared, bool),
) {
    loop {
        tell(sh, ctl.dtr());
        ctl.control_changed().await;
    }
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

/// Why the chip reset (RCC_CSR, RM0351 §6.4.29), then clear the flags (RMVF).
fn reset_cause() -> ResetCause {
    const RCC_CSR: usize = 0x4002_1094;
    let csr = reg(RCC_CSR);
    set(RCC_CSR, csr | (1 << 23));
    ResetCause::from_rcc_csr(csr)
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    flash_latency_first();
    let cause = reset_cause();
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
    BOOTING.store(false, Ordering::Relaxed);
    let sh: &'static Shared = SHARED.init(Shared::new(
        settings,
        Identity {
            uid,
            reset_cause: cause,
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
    let (gcs_tx, gcs_rx, gcs_ctl) = gcs.split_with_control();
    let (mgmt_tx, mgmt_rx, mgmt_ctl) = mgmt.split_with_control();

    // Stage link at the configured baud rate.
    static UART_TX: StaticCell<[u8; 256]> = StaticCell::new();
    static UART_RX: StaticCell<[u8; 256]> = StaticCell::new();
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = settings.stage_baud;
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
    let i2c = I2c::new_blocking(p.I2C2, p.PB10, p.PB11, i2c_config);
    let adc = Adc::new(p.ADC1);
    let bus = Buses {
        spi,
        cs,
        i2c,
        adc,
        a0: p.PC5,
    };

    let led = Output::new(p.PB14, Level::Low, Speed::Low); // LD2

    // Until the host opens an interface its reads fail and the tasks back off and retry.
    let gcs_rx = gcs_rx.into_buffered(GCS_RX.init([0; 64]));
    let mgmt_rx = mgmt_rx.into_buffered(MGMT_RX.init([0; 64]));
    spawner.spawn(supervisor_task(Stm32Board { led, wdg }, sh).expect("task pool"));
    spawner.spawn(usb_task(usb).expect("task pool"));
    spawner.spawn(line_state_task(gcs_ctl, sh, app::host_line_state).expect("task pool"));
    spawner.spawn(line_state_task(mgmt_ctl, sh, app::mgmt_line_state).expect("task pool"));
    spawner.spawn(management_task(mgmt_rx, UsbTx(mgmt_tx), store, sh).expect("task pool"));
    spawner.spawn(sensor_task(bus, sh).expect("task pool"));
    spawner.spawn(stage_link_task(stage_rx, stage_tx, sh).expect("task pool"));
    spawner.spawn(host_link_task(gcs_rx, UsbTx(gcs_tx), sh).expect("task pool"));
    loop {
        Timer::after_secs(3600).await;
    }
}
