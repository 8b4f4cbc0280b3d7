//! The host side of the board: two CDC-ACM functions on USB OTG FS (the GCS port, interface 0;
//! management, interface 2), and both ports' line state.

use core::cell::RefCell;
use core::ptr::{read_volatile, write_volatile};
use embassy_stm32::peripherals::USB_OTG_FS;
use embassy_stm32::usb;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_usb::class::cdc_acm::{BufferedReceiver, Sender};
use embassy_usb::control::{OutResponse, Recipient, Request, RequestType};
pub use nanocal_compensator::line_state::LineWatch as Watch;

/// USB packet size of the CDC-ACM endpoints.
pub const USB_PACKET: u16 = 64;

/// The USB driver.
pub type UsbDriver = usb::Driver<'static, USB_OTG_FS>;

/// What the host sent on a port, buffered.
pub type UsbRx = BufferedReceiver<'static, UsbDriver>;

/// CDC-ACM sender writing at most one short packet per call, so that no zero-length packet is
/// ever needed to end a transfer. With DTR low nobody has the port open: the bytes belong to no
/// connection and are dropped instead of piling up for the next one.
pub struct UsbTx(pub Sender<'static, UsbDriver>);

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

/// The GCS port's communication interface (the first CDC-ACM function built).
const GCS_COMM_INTERFACE: u16 = 0;
/// The GCS port's bulk IN endpoint: the first function's notification endpoint is IN 1, its
/// data endpoints OUT 1 and IN 2 (embassy-usb allocates them in that order).
const GCS_DATA_IN_EP: usize = 2;
/// CDC PSTN 1.2 §6.3.12 SET_CONTROL_LINE_STATE.
const SET_CONTROL_LINE_STATE: u8 = 0x22;

const OTG: usize = 0x5000_0000;
const GRSTCTL: usize = OTG + 0x010;
const GRSTCTL_TXFFLSH: u32 = 1 << 5;
const DIEPEMPMSK: usize = OTG + 0x834;
const DIEPCTL_EPENA: u32 = 1 << 31;
const DIEPCTL_EPDIS: u32 = 1 << 30;
const DIEPCTL_SNAK: u32 = 1 << 27;
const DIEPINT_EPDISD: u32 = 1 << 1;

fn diepctl(n: usize) -> usize {
    OTG + 0x900 + 0x20 * n
}

fn diepint(n: usize) -> usize {
    OTG + 0x908 + 0x20 * n
}

fn reg(a: usize) -> u32 {
    // SAFETY: OTG_FS register, 32-bit access.
    unsafe { read_volatile(a as *const u32) }
}

fn set(a: usize, v: u32) {
    // SAFETY: as above.
    unsafe { write_volatile(a as *mut u32, v) }
}

/// Throw away what the GCS port's IN endpoint holds: a packet the device queued for the old
/// connection would otherwise be the first thing the next one reads (Linux's cdc-acm stops
/// polling at close and starts again at open). NAK, disable the endpoint, flush its transmit
/// FIFO (RM0351 §45.16.x "IN endpoint disable", GRSTCTL.TXFFLSH), and stop its FIFO-empty
/// interrupt: the write that was waiting is cancelled by the host link, never woken to put the
/// old bytes back.
fn flush_gcs_in() {
    let n = GCS_DATA_IN_EP;
    if reg(diepctl(n)) & DIEPCTL_EPENA != 0 {
        set(diepctl(n), reg(diepctl(n)) | DIEPCTL_SNAK | DIEPCTL_EPDIS);
        for _ in 0..10_000 {
            if reg(diepint(n)) & DIEPINT_EPDISD != 0 {
                break;
            }
        }
        set(diepint(n), DIEPINT_EPDISD);
    }
    set(DIEPEMPMSK, reg(DIEPEMPMSK) & !(1 << n));
    set(GRSTCTL, GRSTCTL_TXFFLSH | ((n as u32) << 6));
    for _ in 0..10_000 {
        if reg(GRSTCTL) & GRSTCTL_TXFFLSH == 0 {
            break;
        }
    }
}

/// The CDC ports (in the order their functions are built).
pub const PORTS: usize = 2;
/// The GCS port (the host link).
pub const GCS_PORT: usize = 0;
/// The management port.
pub const MGMT_PORT: usize = 1;

/// Each port's communication interface: the GCS port's function is built first (interfaces 0
/// and 1), the management port's second (2 and 3).
const COMM_INTERFACES: [u16; PORTS] = [GCS_COMM_INTERFACE, 2];

/// Both ports' line state as the host sets it
/// ([`nanocal_compensator::line_state::LineWatch`]: falls counted). embassy-usb's CDC-ACM keeps
/// DTR as a level that the application samples when told it changed: a quick close and open
/// (DTR 1 → 0 → 1) between two samples never ended the session. This handler, registered
/// before the CDC functions, sees every SET_CONTROL_LINE_STATE first (and leaves the answer to
/// the CDC function); at a fall of the GCS port it also flushes that port's IN endpoint.
pub struct LineWatch;

/// The ports' line states, as the requests set them.
static WATCH: Mutex<CriticalSectionRawMutex, RefCell<[Watch; PORTS]>> =
    Mutex::new(RefCell::new([Watch::new(); PORTS]));
/// A line state changed.
static CHANGED: Signal<CriticalSectionRawMutex, ()> = Signal::new();

impl LineWatch {
    /// The line state of `port` ([`GCS_PORT`], [`MGMT_PORT`]) now.
    pub fn state(port: usize) -> Watch {
        WATCH.lock(|w| w.borrow()[port])
    }

    /// Wait for the next SET_CONTROL_LINE_STATE or bus reset.
    pub async fn changed() {
        CHANGED.wait().await
    }

    /// Change the line states with `f` (true when the GCS port's DTR fell), then flush and
    /// signal.
    fn apply(f: impl FnOnce(&mut [Watch; PORTS]) -> bool) {
        let gcs_fell = WATCH.lock(|w| f(&mut w.borrow_mut()));
        if gcs_fell {
            flush_gcs_in();
        }
        CHANGED.signal(());
    }
}

impl embassy_usb::Handler for LineWatch {
    fn control_out(&mut self, req: Request, _data: &[u8]) -> Option<OutResponse> {
        if req.request_type == RequestType::Class
            && req.recipient == Recipient::Interface
            && req.request == SET_CONTROL_LINE_STATE
        {
            if let Some(port) = COMM_INTERFACES.iter().position(|&i| i == req.index) {
                let dtr = req.value & 1 != 0;
                Self::apply(|w| w[port].request(dtr) && port == GCS_PORT);
            }
        }
        // the CDC-ACM function answers
        None
    }

    fn reset(&mut self) {
        Self::apply(|w| {
            let mut fell = [false; PORTS];
            for (k, port) in w.iter_mut().enumerate() {
                fell[k] = port.bus_reset();
            }
            fell[GCS_PORT]
        });
    }
}
