//! QEMU `mps2-an386` board: host link on serial0, stage link on serial1, management on serial3,
//! the host link's and the management port's line states (USB DTR stand-in) and the bench's
//! doorbells on serial4; the virtual bench's page (PSRAM) carries the board's clock and the bus
//! stand-in (SPI/I2C/ADC to simulated chips); CMSDK watchdog, FPGA LED 0 as the status LED, the L4 flash model in RAM that
//! survives a system reset.
#![no_std]
#![no_main]

use cortex_m_rt::exception;
use cortex_m_semihosting::{debug, hprintln};
use embassy_executor::Spawner;
use embassy_time::Duration;
use embedded_io_async::Read;
use nanocal_compensator::l4flash::L4Nor;
use nanocal_compensator::store::Store;
use nanocal_fw::app::{self, Identity, Shared};
use nanocal_fw::qemu::board::{self, TimedFlash};
use nanocal_fw::qemu::sensor_bus::MailboxBus;
use nanocal_fw::qemu::uart::{self, Uart, UartRx, UartTx};
use nanocal_fw::qemu::{self, executor, time};
use nanocal_interface::bench_link;
use static_cell::StaticCell;

/// Store erase unit: four 2 KiB pages (a whole blob fits one unit).
const ERASE: usize = 8 * 1024;
type Flash = L4Nor<TimedFlash, ERASE>;

static SHARED: StaticCell<Shared> = StaticCell::new();
static STORE: StaticCell<Store<Flash>> = StaticCell::new();

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
async fn sensor_task(bus: MailboxBus, sh: &'static Shared) {
    app::sensors(bus, Duration::from_millis(300), sh).await
}

#[embassy_executor::task]
async fn management_task(
    rx: UartRx,
    tx: UartTx,
    store: &'static mut Store<Flash>,
    sh: &'static Shared,
) {
    app::management(rx, tx, store, board::software_reset, sh).await
}

/// The ports' line states: the bench sends C0h | bits of USB CDC SET_CONTROL_LINE_STATE's
/// wValue (bit 0 DTR, bit 1 RTS) whenever its GCS client opens or closes the port, B0h | bits
/// for its management client (`nanocal_interface::bench_link::LINE_*`); the board counts each
/// one it applied in the bench's page (`LINE_STATES`: the bench waits for it before it talks
/// to the new session). The bench's doorbells on the same port only wake the board (its clock
/// reads the new horizon when idle).
#[embassy_executor::task]
async fn line_state_task(mut rx: UartRx, sh: &'static Shared) {
    let mut buf = [0u8; 16];
    loop {
        let n = rx.read(&mut buf).await.unwrap_or(0);
        for &b in &buf[..n] {
            let dtr = b & bench_link::LINE_DTR != 0;
            match b & 0xF0 {
                bench_link::LINE_HOST => app::host_line_state(sh, dtr),
                bench_link::LINE_MGMT => app::mgmt_line_state(sh, dtr),
                // a doorbell: it only woke the board
                _ => continue,
            }
            let off = bench_link::LINE_STATES;
            qemu::link::write_u32(off, qemu::link::read_u32(off).wrapping_add(1));
        }
    }
}

struct QemuBoard;

impl app::Board for QemuBoard {
    fn set_led(&mut self, on: bool) {
        board::set_led(on);
    }
    fn pet_watchdog(&mut self) {
        board::watchdog_pet();
    }
}

#[embassy_executor::task]
async fn supervisor_task(sh: &'static Shared) {
    app::supervisor(QemuBoard, sh).await
}

#[cortex_m_rt::entry]
fn main() -> ! {
    executor::run(start)
}

fn start(spawner: Spawner) {
    let Some(cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    time::init(cp.SYST);
    board::kick_io_init();
    let cause = board::reset_cause();
    hprintln!(
        "nanocal-fw (qemu mps2-an386) up; reset cause {}; clock {}",
        cause.code(),
        if time::linked() {
            "driven by the bench"
        } else {
            "SysTick (1x)"
        }
    );
    board::watchdog_start(2000);
    spawner.spawn(boot_task(spawner, cause).expect("task pool"));
}

/// The rest of the start-up needs the store (async): settings, then every task.
#[embassy_executor::task]
async fn boot_task(spawner: Spawner, cause: nanocal_interface::identity::ResetCause) {
    // SAFETY: called once, here.
    let flash = unsafe { board::flash(cause) };
    let store = STORE.init(Store::new(L4Nor::new(TimedFlash(flash))));
    let settings = app::load_settings(store).await;
    let identity = Identity {
        uid: *b"QEMU-mps2-an",
        reset_cause: cause,
        reset_site: nanocal_interface::identity::Site::None,
    };
    let sh: &'static Shared = SHARED.init(Shared::new(settings, identity));
    // SAFETY: each UART index is taken exactly once, here.
    let (host, stage, mgmt, line) = unsafe {
        (
            Uart::new(0, 115_200),
            Uart::new(1, settings.stage_baud),
            Uart::new(3, 115_200),
            Uart::new(uart::BENCH, 115_200),
        )
    };
    let (hrx, htx) = host.split();
    let (srx, stx) = stage.split();
    let (mrx, mtx) = mgmt.split();
    let (lrx, _) = line.split();
    spawner.spawn(supervisor_task(sh).expect("task pool"));
    spawner.spawn(management_task(mrx, mtx, store, sh).expect("task pool"));
    spawner.spawn(sensor_task(MailboxBus::new(), sh).expect("task pool"));
    spawner.spawn(stage_link_task(srx, stx, sh).expect("task pool"));
    spawner.spawn(host_link_task(hrx, htx, sh).expect("task pool"));
    spawner.spawn(line_state_task(lrx, sh).expect("task pool"));
}
