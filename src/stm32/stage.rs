//! The stage link's receive side on UART4 (interrupt-driven into embassy-stm32's ring buffer),
//! with what embassy does not report: bytes lost to an overrun (RDR not read in time,
//! RM0351 §40.5.5, ISR.ORE) and bytes dropped because the ring was full (embassy only logs the
//! first and silently drops the second). Either is told to the stage link as an `InvalidData`
//! read error, before any byte that may come after the lost one.

use core::ptr::read_volatile;
use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32::interrupt;
use embassy_stm32::usart::{self, BufferedUartRx};
use embedded_io_async::{ErrorKind, ErrorType, Read};
use nanocal_interface::settings::{Settings, MAX_STAGE_BAUD, MIN_STAGE_BAUD};

/// Bytes of the receive ring (the buffer given to `BufferedUart::new`).
pub const RX_RING: u32 = 256;

const UART4_ISR: usize = 0x4000_4C1C;
const ISR_ORE: u32 = 1 << 3;
const ISR_RXNE: u32 = 1 << 5;

/// Bytes the UART received (RXNE interrupts seen).
static SEEN: AtomicU32 = AtomicU32::new(0);
/// Bytes the stage link took from the ring.
static TAKEN: AtomicU32 = AtomicU32::new(0);
/// Times bytes were lost.
static LOST: AtomicU32 = AtomicU32::new(0);

/// Runs before embassy-stm32's buffered-UART handler on UART4 (`bind_interrupts!` calls them in
/// order) and reads only the status: an overrun, or a received byte that finds the ring full
/// (more bytes seen than taken and the ring holds), is a loss. (A byte the stage link has just
/// taken but not yet counted can make a nearly full ring look full: a loss reported too many,
/// never one missed.)
pub struct StageRxWatch;

impl interrupt::typelevel::Handler<interrupt::typelevel::UART4> for StageRxWatch {
    unsafe fn on_interrupt() {
        // SAFETY: UART4_ISR, a read-only status register.
        let isr = unsafe { read_volatile(UART4_ISR as *const u32) };
        if isr & ISR_ORE != 0 {
            LOST.fetch_add(1, Ordering::AcqRel);
        }
        if isr & ISR_RXNE != 0 {
            let seen = SEEN.fetch_add(1, Ordering::AcqRel).wrapping_add(1);
            if seen.wrapping_sub(TAKEN.load(Ordering::Acquire)) > RX_RING {
                LOST.fetch_add(1, Ordering::AcqRel);
            }
        }
    }
}

/// A read of the stage link.
#[derive(Debug)]
#[non_exhaustive]
pub enum StageRxError {
    /// Bytes were lost since the last read.
    Lost,
    /// The UART reported an error.
    Uart(usart::Error),
}

impl core::fmt::Display for StageRxError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StageRxError::Lost => f.write_str("stage link bytes lost"),
            StageRxError::Uart(e) => write!(f, "UART: {e:?}"),
        }
    }
}

impl core::error::Error for StageRxError {}

impl embedded_io_async::Error for StageRxError {
    fn kind(&self) -> ErrorKind {
        match self {
            StageRxError::Lost => ErrorKind::InvalidData,
            StageRxError::Uart(_) => ErrorKind::Other,
        }
    }
}

/// The stage link's receiver: embassy's buffered receiver, counting what it hands over.
pub struct StageRx {
    rx: BufferedUartRx<'static>,
    lost_seen: u32,
}

impl StageRx {
    /// Watch `rx` (whose interrupt has [`StageRxWatch`] bound before embassy's handler).
    pub fn new(rx: BufferedUartRx<'static>) -> Self {
        Self {
            rx,
            lost_seen: LOST.load(Ordering::Acquire),
        }
    }

    fn take_loss(&mut self) -> bool {
        let lost = LOST.load(Ordering::Acquire);
        let new = lost != self.lost_seen;
        self.lost_seen = lost;
        new
    }
}

impl ErrorType for StageRx {
    type Error = StageRxError;
}

impl Read for StageRx {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, StageRxError> {
        if self.take_loss() {
            return Err(StageRxError::Lost);
        }
        let n = self.rx.read(buf).await.map_err(StageRxError::Uart)?;
        TAKEN.fetch_add(n as u32, Ordering::AcqRel);
        // a loss while the read waited: these bytes may follow the lost one
        if self.take_loss() {
            return Err(StageRxError::Lost);
        }
        Ok(n)
    }
}

/// The stage link's UART at the stored baud rate. A rate the USART cannot make (a record stored
/// by a firmware that accepted it) must not stop the board at every boot: the default is used
/// instead, and the settings show what is stored.
pub fn uart_config(settings: &Settings) -> usart::Config {
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
