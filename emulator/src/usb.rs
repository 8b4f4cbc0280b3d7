//! USB OTG FS in device mode (RM0351 Rev 9 §45 "USB on-the-go full-speed (OTG_FS)", registers
//! §45.15, device programming model §45.16.x) and the host at the other end of the cable,
//! played by the model the way Linux's USB core and cdc-acm driver do it (USB 2.0 §9.1.2
//! enumeration, CDC PSTN 1.2 §6.3 requests):
//!
//! - **VBUS** on PA9 and the B-session valid comparator: plugging the cable sets GOTGCTL.BSVLD
//!   and GINTSTS.SRQINT (session request) when VBUS sensing is on (GCCFG.VBDEN).
//! - **Connect and reset**: once the device has its transceiver powered (GCCFG.PWRDWN), its
//!   soft-disconnect cleared (DCTL.SDIS) and a 48 MHz clock good enough for USB (the MSI only
//!   when trimmed by the LSE, RM0351 §6.2.3), the host resets the bus (GINTSTS.USBRST) and
//!   enumerates at full speed (ENUMDNE, DSTS.ENUMSPD = 11).
//! - **Transfers** through the FIFOs: SETUP and OUT packets are pushed to the receive FIFO with
//!   their status entries (GRXSTSP: SETUP data / SETUP done / OUT data / OUT done), DOEPINT.STUP
//!   after the SETUP-done entry is popped; IN packets leave the endpoint's transmit FIFO when
//!   DIEPCTL.EPENA is set and DIEPTSIZ's bytes are all written, with DIEPINT.XFRC. An OUT
//!   endpoint NAKs (the host retries) from each packet until the application clears NAK
//!   (DOEPCTL.CNAK): back-pressure as on the wire.
//! - **The host**: GET_DESCRIPTOR(device, 64), SET_ADDRESS (checked in DCFG.DAD), the device,
//!   configuration and string descriptors, SET_CONFIGURATION(1); then for each CDC-ACM port a
//!   socket: a client connecting opens the port (SET_LINE_CODING 115200 8N1,
//!   SET_CONTROL_LINE_STATE DTR|RTS) and polls its bulk IN endpoint; closing the socket sends
//!   SET_CONTROL_LINE_STATE 0 and stops polling (a packet the device queued stays in its FIFO
//!   until the port is opened again, as on Linux); a DTR pulse on an open port
//!   ([`HostHandle::toggle_dtr`]) sends SET_CONTROL_LINE_STATE 0 and 3 and nothing between.
//! - **Scheduling** in steps of 50 µs of board time: a step with a control transfer in
//!   progress moves it one stage on; any other step carries one bulk OUT packet to and one
//!   bulk IN poll of every port whose line state is settled, then the SETUP of the next
//!   control transfer due. A control transfer queued behind another gets its SETUP in the
//!   same step as the other's status stage (a host controller runs queued control transfers
//!   back to back, USB 2.0 §5.5.4).

use crate::io::Io;
use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// Board time between two host transactions (a frame holds many; 50 µs keeps the model simple).
const STEP_PS: u64 = 50_000_000;
const EPS: usize = 6;
/// Bytes a port's client has not read yet beyond which the host stops polling the bulk IN
/// endpoint (the tty's buffer is full; the device sees NAKs).
const CLIENT_BACKLOG: usize = 4096;

/// A client's connection to a CDC port (a Unix socket, or TCP for PIPython's socket gateway).
enum Conn {
    Unix(UnixStream),
    Tcp(TcpStream),
}

impl Conn {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Conn::Unix(s) => s.read(b),
            Conn::Tcp(s) => s.read(b),
        }
    }
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        match self {
            Conn::Unix(s) => s.write(b),
            Conn::Tcp(s) => s.write(b),
        }
    }
    fn shutdown(&self) {
        let _ = match self {
            Conn::Unix(s) => s.shutdown(std::net::Shutdown::Both),
            Conn::Tcp(s) => s.shutdown(std::net::Shutdown::Both),
        };
    }
}

enum Listener {
    Unix(UnixListener),
    Tcp(TcpListener),
}

impl Listener {
    /// A waiting connection, non-blocking.
    fn accept(&self) -> Option<Conn> {
        match self {
            Listener::Unix(l) => l.accept().ok().map(|(s, _)| {
                let _ = s.set_nonblocking(true);
                Conn::Unix(s)
            }),
            Listener::Tcp(l) => l.accept().ok().map(|(s, _)| {
                let _ = s.set_nonblocking(true);
                let _ = s.set_nodelay(true);
                Conn::Tcp(s)
            }),
        }
    }
}

/// One CDC-ACM port as the tests see it.
#[derive(Default)]
struct PortState {
    /// A client has the port open.
    open: bool,
    /// The line state changes the host has not yet told the device, oldest first.
    line_state_due: VecDeque<LineChange>,
    /// Bytes from the client for the device (bulk OUT).
    out: VecDeque<u8>,
    /// Bulk IN bytes received for the client and not yet written to its socket.
    backlog: Vec<u8>,
    /// Bulk IN bytes the host received while the port was open.
    received: u64,
    /// The interface numbers (communication, data) and endpoints (notify IN, bulk OUT, bulk IN).
    comm_if: u8,
    ep_out: usize,
    ep_in: usize,
}

/// A line state change the host tells the device.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LineChange {
    /// DTR (and RTS) after the change.
    dtr: bool,
    /// SET_LINE_CODING first (a tty being opened; a DTR toggle on an open tty sends none).
    coding: bool,
}

/// What the host knows; shared with the tests.
#[derive(Default)]
pub struct HostShared {
    /// The cable is plugged in (VBUS).
    pub attached: bool,
    /// Enumeration finished (SET_CONFIGURATION accepted).
    pub configured: bool,
    /// Times the host enumerated the device (each device reset re-enumerates).
    pub enumerations: u32,
    /// The device descriptor read.
    pub device_descriptor: Vec<u8>,
    /// The full configuration descriptor read.
    pub config_descriptor: Vec<u8>,
    /// String descriptors read (index, text).
    pub strings: Vec<(u8, String)>,
    /// Requests the device stalled (bmRequestType, bRequest, wValue).
    pub stalls: Vec<(u8, u8, u16)>,
    /// Problems the host found (protocol violations by the device).
    pub errors: Vec<String>,
    /// Where the host is (for failure reports).
    pub state: String,
    ports: Vec<PortState>,
    /// The port sockets clients connect to, by port.
    listeners: [Vec<Listener>; 2],
    /// The open connection of each port.
    clients: [Option<Conn>; 2],
    /// The host application reads port k (false: it stopped reading; once its buffer is
    /// full the host no longer polls the bulk IN endpoint).
    reading: [bool; 2],
    /// Opens and closes of each port requested by the test ([`HostHandle::toggle_dtr`]).
    dtr_pulses: [u32; 2],
    /// SET_CONTROL_LINE_STATE requests the device accepted, by port.
    line_states: [u32; 2],
}

/// The socket folder, removed when the last handle goes.
struct SocketDir(PathBuf);

impl Drop for SocketDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The tests' handle: plug, unplug, port sockets, what the host saw.
#[derive(Clone)]
pub struct HostHandle {
    shared: Arc<Mutex<HostShared>>,
    dir: Arc<SocketDir>,
}

impl HostHandle {
    /// Plug the cable into the board's USB OTG connector (VBUS on PA9).
    pub fn attach(&self) {
        self.shared.lock().unwrap().attached = true;
    }

    /// Unplug it.
    pub fn detach(&self) {
        let mut s = self.shared.lock().unwrap();
        s.attached = false;
        s.configured = false;
    }

    /// What the host knows.
    pub fn with<R>(&self, f: impl FnOnce(&HostShared) -> R) -> R {
        f(&self.shared.lock().unwrap())
    }

    /// Socket path of CDC port `k` (0: the GCS port, interface 0; 1: management, interface 2).
    pub fn port_path(&self, k: usize) -> PathBuf {
        self.dir.0.join(format!("acm{k}"))
    }

    /// The port spec for the nanocal CLI (`unix:PATH`).
    pub fn port_spec(&self, k: usize) -> String {
        format!("unix:{}", self.port_path(k).display())
    }

    /// Serve CDC port `k` on a local TCP port too (PIPython's socket gateway speaks TCP); the
    /// port number.
    pub fn tcp_port(&self, k: usize) -> u16 {
        let l = TcpListener::bind("127.0.0.1:0").expect("bind a local TCP port");
        l.set_nonblocking(true).expect("non-blocking listener");
        let port = l.local_addr().expect("local address").port();
        self.shared.lock().unwrap().listeners[k].push(Listener::Tcp(l));
        port
    }

    /// The host application stops (`false`) or resumes reading port `k`.
    pub fn set_reading(&self, k: usize, reading: bool) {
        self.shared.lock().unwrap().reading[k] = reading;
    }

    /// The client of port `k` drops DTR and raises it again at once, the connection kept (DTR
    /// 1 → 0 → 1: two SET_CONTROL_LINE_STATE requests and nothing between them, as Linux's
    /// cdc-acm sends for TIOCMBIC/TIOCMBIS on an open tty, `acm_tty_tiocmset`). The host
    /// controller runs the second right after the first's status stage, in the same frame
    /// (see [`Otg::update`]).
    pub fn toggle_dtr(&self, k: usize) {
        self.shared.lock().unwrap().dtr_pulses[k] += 1;
    }

    /// SET_CONTROL_LINE_STATE requests of port `k` the device has accepted (opens and closes).
    pub fn line_states(&self, k: usize) -> u32 {
        self.with(|s| s.line_states[k])
    }

    /// Bulk IN bytes the host took for port `k` while it was open.
    pub fn received(&self, k: usize) -> u64 {
        self.with(|s| s.ports.get(k).map_or(0, |p| p.received))
    }
}

/// The host model inside the board.
pub struct Host {
    shared: Arc<Mutex<HostShared>>,
    stage: Stage,
    next_ps: u64,
    addr: u8,
    /// A control transfer in progress.
    ctl: Option<Control>,
    /// Descriptors still to read during enumeration.
    todo: VecDeque<Request>,
    /// Bytes for the clients, flushed after each slice.
    pending_in: Vec<(usize, Vec<u8>)>,
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Stage {
    Detached,
    /// VBUS on, waiting for the device to connect.
    Powered,
    /// Bus reset signalled, waiting for the device to take it.
    Reset,
    /// Enumeration done, waiting for the device to take it.
    EnumDone,
    /// Control transfers of enumeration.
    Enumerating,
    /// Configured: CDC traffic.
    Running,
}

#[derive(Clone, Debug)]
struct Request {
    setup: [u8; 8],
    /// Data for an OUT data stage.
    out: Vec<u8>,
    what: Purpose,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Purpose {
    DeviceDesc64,
    SetAddress(u8),
    DeviceDesc,
    ConfigHead,
    ConfigFull,
    String(u8),
    SetConfig,
    LineCoding(usize),
    LineState(usize, bool),
}

struct Control {
    req: Request,
    phase: Phase,
    got: Vec<u8>,
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Phase {
    /// SETUP sent, waiting for the data stage.
    Data,
    /// OUT data sent, waiting for the status ZLP IN.
    StatusIn,
    /// IN data received, status ZLP OUT to send.
    StatusOut,
}

impl Host {
    /// A host with its cable unplugged, sockets for the CDC ports under a fresh folder (removed
    /// when the host and every handle are gone).
    pub fn new() -> (Host, HostHandle) {
        let dir = std::env::temp_dir().join(format!(
            "nanocal-stm32-usb-{}-{}",
            std::process::id(),
            next_id()
        ));
        let _ = std::fs::create_dir_all(&dir);
        let mut sh = HostShared {
            reading: [true; 2],
            ..HostShared::default()
        };
        for k in 0..2 {
            let l = UnixListener::bind(dir.join(format!("acm{k}"))).expect("bind a port socket");
            l.set_nonblocking(true).expect("non-blocking listener");
            sh.listeners[k].push(Listener::Unix(l));
        }
        let shared = Arc::new(Mutex::new(sh));
        let handle = HostHandle {
            shared: shared.clone(),
            dir: Arc::new(SocketDir(dir)),
        };
        (Host::with_shared(shared), handle)
    }

    fn with_shared(shared: Arc<Mutex<HostShared>>) -> Host {
        Host {
            shared,
            stage: Stage::Detached,
            next_ps: 0,
            addr: 0,
            ctl: None,
            todo: VecDeque::new(),
            pending_in: vec![],
        }
    }

    /// A host with no sockets and no cable (a stand-in while the board swaps its chip state).
    pub fn placeholder() -> Host {
        Host::with_shared(Arc::new(Mutex::new(HostShared::default())))
    }

    /// A cable is plugged in.
    pub fn attached(&self) -> bool {
        self.shared.lock().unwrap().attached
    }

    /// Take in what the clients did while the board was paused: new connections open their
    /// port (once the device is configured; before that the tty does not exist and the
    /// connection is refused), their bytes go to the device, a closed connection closes the
    /// port; and write out what they have not read yet.
    pub fn poll_sockets(&mut self) {
        let mut guard = self.shared.lock().unwrap();
        let s = &mut *guard;
        for k in 0..2 {
            while s.dtr_pulses[k] > 0 {
                s.dtr_pulses[k] -= 1;
                if let Some(p) = s.ports.get_mut(k).filter(|p| p.open) {
                    p.line_state_due.extend([
                        LineChange {
                            dtr: false,
                            coding: false,
                        },
                        LineChange {
                            dtr: true,
                            coding: false,
                        },
                    ]);
                }
            }
            // the open connection first: a client that closed and connected again is seen
            // closing, then opening
            if let Some(c) = s.clients[k].as_mut() {
                let mut closed = false;
                let mut b = [0u8; 512];
                loop {
                    match c.read(&mut b) {
                        Ok(0) => {
                            closed = true;
                            break;
                        }
                        Ok(n) => s.ports[k].out.extend(&b[..n]),
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                        Err(_) => {
                            closed = true;
                            break;
                        }
                    }
                }
                let p = &mut s.ports[k];
                while !closed && !p.backlog.is_empty() {
                    match c.write(&p.backlog) {
                        Ok(0) => closed = true,
                        Ok(n) => {
                            p.backlog.drain(..n);
                        }
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                        Err(_) => closed = true,
                    }
                }
                if closed {
                    // the client closed its end: the tty is closed (DTR drops); what the
                    // device sent for it is gone with it
                    s.clients[k] = None;
                    p.open = false;
                    p.out.clear();
                    p.backlog.clear();
                    p.line_state_due.push_back(LineChange {
                        dtr: false,
                        coding: false,
                    });
                }
            }
            for l in &s.listeners[k] {
                while let Some(c) = l.accept() {
                    let usable = s.configured && k < s.ports.len() && s.clients[k].is_none();
                    if !usable {
                        c.shutdown();
                        continue;
                    }
                    let p = &mut s.ports[k];
                    p.open = true;
                    p.line_state_due.push_back(LineChange {
                        dtr: true,
                        coding: true,
                    });
                    s.clients[k] = Some(c);
                }
            }
        }
    }

    /// Hand the clients what the device sent; true when a client got bytes.
    pub fn flush(&mut self) -> bool {
        if self.pending_in.is_empty() {
            return false;
        }
        {
            let mut s = self.shared.lock().unwrap();
            for (k, data) in self.pending_in.drain(..) {
                if let Some(p) = s.ports.get_mut(k) {
                    p.received += data.len() as u64;
                    p.backlog.extend_from_slice(&data);
                }
            }
        }
        self.poll_sockets();
        true
    }

    /// The device reset itself: it disconnects (its pull-up goes away); the host enumerates
    /// again when it comes back.
    pub fn bus_reset_by_device(&mut self) {
        self.stage = if self.attached() {
            Stage::Powered
        } else {
            Stage::Detached
        };
        self.ctl = None;
        self.todo.clear();
        self.pending_in.clear();
        let mut s = self.shared.lock().unwrap();
        s.configured = false;
        for k in 0..2 {
            // the tty goes away with the device; a client must open the port again
            if let Some(c) = s.clients[k].take() {
                c.shutdown();
            }
        }
        for p in &mut s.ports {
            p.line_state_due.clear();
            p.open = false;
            p.out.clear();
            p.backlog.clear();
        }
    }
}

fn next_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}

/// An entry of the receive FIFO: the status word and the packet.
struct RxEntry {
    status: u32,
    data: VecDeque<u32>,
}

/// The OTG FS core's device-mode registers and FIFOs.
pub struct Otg {
    gotgctl: u32,
    gotgint: u32,
    gahbcfg: u32,
    gusbcfg: u32,
    gintsts: u32,
    gintmsk: u32,
    grxfsiz: u32,
    txfsiz: [u32; EPS],
    gccfg: u32,
    dcfg: u32,
    dctl: u32,
    diepmsk: u32,
    doepmsk: u32,
    daintmsk: u32,
    diepempmsk: u32,
    diepctl: [u32; EPS],
    diepint: [u32; EPS],
    dieptsiz: [u32; EPS],
    doepctl: [u32; EPS],
    doepint: [u32; EPS],
    doeptsiz: [u32; EPS],
    pcgcctl: u32,
    /// Transmit FIFOs (bytes written by the application).
    tx: [Vec<u8>; EPS],
    rx: VecDeque<RxEntry>,
    /// Data words of the popped entry still to read.
    rx_data: VecDeque<u32>,
    /// OUT endpoints NAK until CNAK (set after each packet received).
    out_nak: [bool; EPS],
    session: bool,
}

impl Default for Otg {
    fn default() -> Self {
        Self {
            gotgctl: 0x0001_0000, // CIDSTS: B-device
            gotgint: 0,
            gahbcfg: 0,
            gusbcfg: 0x0000_1440,
            gintsts: 0x0400_0020,
            gintmsk: 0,
            grxfsiz: 0x200,
            txfsiz: [0x0200_0200; EPS],
            gccfg: 0,
            dcfg: 0x0220_0000,
            dctl: 2, // SDIS
            diepmsk: 0,
            doepmsk: 0,
            daintmsk: 0,
            diepempmsk: 0,
            diepctl: [0; EPS],
            diepint: [0x80; EPS],
            dieptsiz: [0; EPS],
            doepctl: [0; EPS],
            doepint: [0; EPS],
            doeptsiz: [0; EPS],
            pcgcctl: 0,
            tx: Default::default(),
            rx: VecDeque::new(),
            rx_data: VecDeque::new(),
            out_nak: [true; EPS],
            session: false,
        }
    }
}

impl Otg {
    fn daint(&self) -> u32 {
        let mut d = 0;
        for n in 0..EPS {
            let txfe = if self.diepempmsk & (1 << n) != 0 {
                0x80
            } else {
                0
            };
            if self.diepint[n] & (self.diepmsk | txfe) != 0 {
                d |= 1 << n;
            }
            if self.doepint[n] & (self.doepmsk | 0x8) & !0x8 != 0
                || (self.doepint[n] & 0x8 != 0 && self.doepmsk & 0x8 != 0)
            {
                d |= 1 << (16 + n);
            }
        }
        d
    }

    fn gintsts(&self) -> u32 {
        let mut g = self.gintsts & !(1 << 4 | 1 << 18 | 1 << 19);
        if !self.rx.is_empty() || !self.rx_data.is_empty() {
            g |= 1 << 4; // RXFLVL
        }
        let d = self.daint() & self.daintmsk;
        if d & 0xFFFF != 0 {
            g |= 1 << 18;
        }
        if d >> 16 != 0 {
            g |= 1 << 19;
        }
        if self.gotgint != 0 {
            g |= 1 << 2;
        }
        g
    }

    /// The interrupt line.
    pub fn irq(&self) -> bool {
        self.gahbcfg & 1 != 0 && self.gintsts() & self.gintmsk != 0
    }

    fn fifo_free_words(&self, n: usize) -> u32 {
        let depth = self.txfsiz[n] >> 16;
        depth.saturating_sub(self.tx[n].len().div_ceil(4) as u32)
    }

    /// Read a register.
    pub fn read(&mut self, off: u32, _now: u64, _clk48: (u64, bool), _io: &mut Io) -> u32 {
        match off {
            0x000 => self.gotgctl | if self.session { 1 << 19 | 1 << 18 } else { 0 },
            0x004 => self.gotgint,
            0x008 => self.gahbcfg,
            0x00C => self.gusbcfg,
            0x010 => 1 << 31, // AHBIDL; resets and flushes complete at once
            0x014 => self.gintsts(),
            0x018 => self.gintmsk,
            0x01C => self.rx.front().map(|e| e.status).unwrap_or(0),
            0x020 => match self.rx.pop_front() {
                Some(e) => {
                    if (e.status >> 17) & 0xF == 4 {
                        // SETUP done popped: STUP (RM0351 §45.16.6 "SETUP transactions")
                        self.doepint[0] |= 0x8;
                    }
                    if (e.status >> 17) & 0xF == 3 {
                        let n = (e.status & 0xF) as usize;
                        self.doepint[n] |= 1; // XFRC
                    }
                    self.rx_data = e.data;
                    e.status
                }
                None => 0,
            },
            0x024 => self.grxfsiz,
            0x028 => self.txfsiz[0],
            0x038 => self.gccfg,
            0x03C => 0x0000_2000, // CID: the STM32L4's OTG core
            0x104..=0x114 => self.txfsiz[((off - 0x100) / 4) as usize],
            0x800 => self.dcfg,
            0x804 => self.dctl,
            0x808 => 3 << 1, // DSTS: ENUMSPD full speed (48 MHz PHY)
            0x810 => self.diepmsk,
            0x814 => self.doepmsk,
            0x818 => self.daint(),
            0x81C => self.daintmsk,
            0x834 => self.diepempmsk,
            0x900..=0x9FF => {
                let (n, r) = (((off - 0x900) / 0x20) as usize, (off - 0x900) % 0x20);
                if n >= EPS {
                    return 0;
                }
                // EP0 is always active (USBAEP reads 1, RM0351 §45.15.39)
                let ep0 = if n == 0 { 1 << 15 } else { 0 };
                match r {
                    0x00 => self.diepctl[n] | ep0,
                    0x08 => {
                        let txfe = if self.tx[n].is_empty() { 0x80 } else { 0 };
                        (self.diepint[n] & !0x80) | txfe
                    }
                    0x10 => self.dieptsiz[n],
                    0x18 => self.fifo_free_words(n),
                    _ => 0,
                }
            }
            0xB00..=0xBFF => {
                let (n, r) = (((off - 0xB00) / 0x20) as usize, (off - 0xB00) % 0x20);
                if n >= EPS {
                    return 0;
                }
                let ep0 = if n == 0 { 1 << 15 } else { 0 };
                match r {
                    0x00 => self.doepctl[n] | ep0 | if self.out_nak[n] { 1 << 17 } else { 0 },
                    0x08 => self.doepint[n],
                    0x10 => self.doeptsiz[n],
                    _ => 0,
                }
            }
            0xE00 => self.pcgcctl,
            0x1000..=0x1FFFF => self.rx_data.pop_front().unwrap_or(0),
            _ => 0,
        }
    }

    /// Write a register.
    pub fn write(&mut self, off: u32, v: u32, _now: u64, _clk48: (u64, bool), _io: &mut Io) {
        match off {
            0x000 => self.gotgctl = (self.gotgctl & 0x000F_0000) | (v & !0x000F_0000),
            0x004 => self.gotgint &= !v,
            0x008 => self.gahbcfg = v,
            0x00C => self.gusbcfg = v,
            0x010 => {
                if v & 0x10 != 0 {
                    self.rx.clear();
                    self.rx_data.clear();
                }
                if v & 0x20 != 0 {
                    let n = ((v >> 6) & 0x1F) as usize;
                    if n == 0x10 {
                        self.tx.iter_mut().for_each(Vec::clear);
                    } else if n < EPS {
                        self.tx[n].clear();
                    }
                }
                if v & 1 != 0 {
                    *self = Self {
                        session: self.session,
                        ..Self::default()
                    };
                }
            }
            // GINTSTS: rc_w1 bits (MMIS 1, SOF 3, ESUSP 10, USBSUSP 11, USBRST 12, ENUMDNE 13,
            // ISOODRP 14, EOPF 15, IISOIXFR 20, ..., SRQINT 30, WKUPINT 31)
            0x014 => self.gintsts &= !(v & 0xC07C_FC0A),
            0x018 => self.gintmsk = v,
            0x024 => self.grxfsiz = v,
            0x028 => self.txfsiz[0] = v,
            0x038 => self.gccfg = v,
            0x104..=0x114 => self.txfsiz[((off - 0x100) / 4) as usize] = v,
            0x800 => self.dcfg = v,
            0x804 => self.dctl = v,
            0x810 => self.diepmsk = v,
            0x814 => self.doepmsk = v,
            0x81C => self.daintmsk = v,
            0x834 => self.diepempmsk = v,
            0x900..=0x9FF => {
                let (n, r) = (((off - 0x900) / 0x20) as usize, (off - 0x900) % 0x20);
                if n >= EPS {
                    return;
                }
                match r {
                    0x00 => {
                        // CNAK 26, SNAK 27, SD0PID 28, SODDFRM 29 are write-only; EPDIS 30
                        // disables at once (EPDISD)
                        let mut c = v & !(0xF << 26);
                        if v & (1 << 30) != 0 {
                            c &= !(1 << 31 | 1 << 30);
                            self.diepint[n] |= 2;
                        } else if v & (1 << 31) != 0 {
                            c |= 1 << 31;
                        }
                        self.diepctl[n] = c;
                    }
                    0x08 => self.diepint[n] &= !v,
                    0x10 => self.dieptsiz[n] = v,
                    _ => {}
                }
            }
            0xB00..=0xBFF => {
                let (n, r) = (((off - 0xB00) / 0x20) as usize, (off - 0xB00) % 0x20);
                if n >= EPS {
                    return;
                }
                match r {
                    0x00 => {
                        if v & (1 << 26) != 0 {
                            self.out_nak[n] = false;
                        }
                        if v & (1 << 27) != 0 {
                            self.out_nak[n] = true;
                        }
                        let mut c = v & !(0xF << 26);
                        if v & (1 << 30) != 0 {
                            c &= !(1 << 31 | 1 << 30);
                            self.doepint[n] |= 2;
                        }
                        self.doepctl[n] = c;
                    }
                    0x08 => self.doepint[n] &= !v,
                    0x10 => self.doeptsiz[n] = v,
                    _ => {}
                }
            }
            0xE00 => self.pcgcctl = v,
            0x1000..=0x1FFFF => {
                let n = ((off - 0x1000) / 0x1000) as usize;
                if n < EPS {
                    self.tx[n].extend_from_slice(&v.to_le_bytes());
                }
            }
            _ => {}
        }
    }

    /// When the host acts next, ps: while it enumerates or a control transfer runs, and while
    /// a port has line state to send, OUT data for the device, or IN data queued that the host
    /// polls for.
    pub fn next_event(&self, host: &Host) -> Option<u64> {
        let busy = match host.stage {
            Stage::Detached => host.attached(),
            Stage::Running => {
                host.ctl.is_some() || !host.todo.is_empty() || {
                    let s = host.shared.lock().unwrap();
                    s.ports.iter().enumerate().any(|(k, p)| {
                        !p.line_state_due.is_empty()
                            || (p.open
                                && (!p.out.is_empty()
                                    || (s.reading[k]
                                        && p.backlog.len() < CLIENT_BACKLOG
                                        && !self.tx[p.ep_in].is_empty())))
                    })
                }
            }
            // waiting for the device: its register writes move the host on
            Stage::Powered => self.session && self.dctl & 2 == 0 && self.gccfg & (1 << 16) != 0,
            Stage::Reset => self.gintsts & (1 << 12) == 0,
            Stage::EnumDone => self.gintsts & (1 << 13) == 0,
            Stage::Enumerating => true,
        };
        busy.then_some(host.next_ps)
    }

    /// An IN packet of endpoint `n` ready for the host: its bytes.
    fn take_in(&mut self, n: usize) -> Option<Vec<u8>> {
        if self.diepctl[n] & (1 << 31) == 0
            || self.diepctl[n] & (1 << 15 | 1 << 21) != 1 << 15 && n != 0
        {
            return None;
        }
        if n == 0 && self.diepctl[0] & (1 << 21) != 0 {
            return None;
        }
        let len = (self.dieptsiz[n] & 0x7_FFFF) as usize;
        let words = len.div_ceil(4) * 4;
        if self.tx[n].len() < words {
            return None;
        }
        let mut pkt: Vec<u8> = self.tx[n].drain(..words).collect();
        pkt.truncate(len);
        self.diepctl[n] &= !(1 << 31);
        self.dieptsiz[n] &= !(0x3FF << 19 | 0x7_FFFF);
        self.diepint[n] |= 1; // XFRC
        Some(pkt)
    }

    /// The host sends an OUT (or SETUP) packet to endpoint `n`; false when the endpoint NAKs.
    fn push_out(&mut self, n: usize, data: &[u8], setup: bool) -> bool {
        if setup {
            let words = to_words(data);
            self.rx.push_back(RxEntry {
                status: (6 << 17) | (8 << 4),
                data: words,
            });
            self.rx.push_back(RxEntry {
                status: 4 << 17,
                data: VecDeque::new(),
            });
            self.out_nak[0] = true;
            return true;
        }
        let active = n == 0 || self.doepctl[n] & (1 << 15) != 0;
        if !active || self.out_nak[n] || self.doepctl[n] & (1 << 21) != 0 || self.rx.len() > 8 {
            return false;
        }
        self.rx.push_back(RxEntry {
            status: (2 << 17) | ((data.len() as u32) << 4) | n as u32,
            data: to_words(data),
        });
        self.rx.push_back(RxEntry {
            status: (3 << 17) | n as u32,
            data: VecDeque::new(),
        });
        self.out_nak[n] = true;
        true
    }

    fn stalled(&self, n: usize) -> bool {
        self.diepctl[n] & (1 << 21) != 0 || self.doepctl[n] & (1 << 21) != 0
    }

    /// Progress the host up to `now`.
    pub fn update(&mut self, now: u64, clk48: (u64, bool), io: &mut Io) {
        let host = &mut io.usb;
        let attached = host.attached();
        // VBUS: the B-session comparator (GCCFG.VBDEN) and the session request
        if attached && !self.session {
            self.session = true;
            if self.gccfg & (1 << 21) != 0 {
                self.gintsts |= 1 << 30; // SRQINT
            }
        } else if !attached && self.session {
            self.session = false;
            self.gotgint |= 1 << 2; // SEDET
            host.stage = Stage::Detached;
        }
        if now < host.next_ps {
            return;
        }
        let connected = self.session
            && self.dctl & 2 == 0
            && self.gccfg & (1 << 16) != 0
            && clk48.1
            && (47_880_000..=48_120_000).contains(&clk48.0);
        if !connected && host.stage != Stage::Detached {
            if host.stage != Stage::Powered {
                host.bus_reset_by_device();
            }
            if !attached {
                host.stage = Stage::Detached;
            }
            return;
        }
        host.next_ps = now + STEP_PS;
        if host.stage == Stage::Running {
            // (the state line is for failures to enumerate)
        } else if let Ok(mut s) = host.shared.try_lock() {
            s.state = format!(
                "{:?} ctl {:?} todo {} gintsts {:#x} gintmsk {:#x} dctl {:#x} gccfg {:#x} diepctl0 {:#x} dieptsiz0 {:#x} tx0 {} rx {} nak0 {}",
                host.stage,
                host.ctl.as_ref().map(|c| (c.req.what, c.phase)),
                host.todo.len(),
                self.gintsts(),
                self.gintmsk,
                self.dctl,
                self.gccfg,
                self.diepctl[0],
                self.dieptsiz[0],
                self.tx[0].len(),
                self.rx.len(),
                self.out_nak[0]
            );
        }
        match host.stage {
            Stage::Detached => {
                if attached {
                    host.stage = Stage::Powered;
                }
            }
            Stage::Powered => {
                if connected {
                    // 100 ms debounce and the reset (USB 2.0 §7.1.7.3) are not waited for
                    self.gintsts |= 1 << 12; // USBRST
                    host.stage = Stage::Reset;
                    host.addr = 0;
                    self.dcfg &= !(0x7F << 4);
                }
            }
            Stage::Reset => {
                if self.gintsts & (1 << 12) == 0 {
                    self.gintsts |= 1 << 13; // ENUMDNE
                    host.stage = Stage::EnumDone;
                }
            }
            Stage::EnumDone => {
                if self.gintsts & (1 << 13) == 0 {
                    host.stage = Stage::Enumerating;
                    host.todo = [
                        req(0x80, 6, 0x0100, 0, 64, Purpose::DeviceDesc64),
                        req(0x00, 5, 1, 0, 0, Purpose::SetAddress(1)),
                        req(0x80, 6, 0x0100, 0, 18, Purpose::DeviceDesc),
                        req(0x80, 6, 0x0200, 0, 9, Purpose::ConfigHead),
                    ]
                    .into();
                }
            }
            Stage::Enumerating | Stage::Running => self.host_transfers(io),
        }
    }

    fn host_transfers(&mut self, io: &mut Io) {
        if io.usb.ctl.is_none() {
            if io.usb.stage == Stage::Running {
                self.bulk_traffic(io);
            }
            self.start_control(io);
            return;
        }
        let host = &mut io.usb;
        let Some(mut ctl) = host.ctl.take() else {
            return;
        };
        let [bm, breq, wv0, wv1, _, _, wl0, wl1] = ctl.req.setup;
        let wlength = usize::from(u16::from_le_bytes([wl0, wl1]));
        if self.stalled(0) {
            let shared = host.shared.clone();
            let mut s = shared.lock().unwrap();
            s.stalls.push((bm, breq, u16::from_le_bytes([wv0, wv1])));
            drop(s);
            // a STALL ends the transfer; the next SETUP clears it (RM0351 §45.16.6)
            self.diepctl[0] &= !(1 << 21);
            self.doepctl[0] &= !(1 << 21);
            return;
        }
        match ctl.phase {
            Phase::Data if bm & 0x80 != 0 => {
                if let Some(pkt) = self.take_in(0) {
                    let short = pkt.len() < 64;
                    ctl.got.extend(pkt);
                    if short || ctl.got.len() >= wlength {
                        ctl.phase = Phase::StatusOut;
                    }
                }
                host.ctl = Some(ctl);
            }
            Phase::Data => {
                if !ctl.req.out.is_empty() {
                    let data = ctl.req.out.clone();
                    if self.push_out(0, &data, false) {
                        ctl.req.out.clear();
                        ctl.phase = Phase::StatusIn;
                    }
                } else {
                    ctl.phase = Phase::StatusIn;
                }
                host.ctl = Some(ctl);
            }
            Phase::StatusIn => {
                if self.take_in(0).is_some() {
                    self.control_done(ctl, io);
                    self.start_control(io);
                } else {
                    host.ctl = Some(ctl);
                }
            }
            Phase::StatusOut => {
                if self.push_out(0, &[], false) {
                    self.control_done(ctl, io);
                    self.start_control(io);
                } else {
                    host.ctl = Some(ctl);
                }
            }
        }
    }

    /// Start the next control transfer due, if any: its SETUP goes out now. Called when EP0 is
    /// free, also right after a transfer's status stage: a host controller runs the control
    /// transfers queued for a device back to back, as many in a frame as fit (USB 2.0
    /// §5.5.4: control transfers are given up to 10 % of every frame; §8.5.3: a device
    /// always accepts a SETUP), and the class driver may queue the next request before the
    /// last completes (CDC PSTN 1.2 §6.3.12 sets no time between two
    /// SET_CONTROL_LINE_STATE requests). Enumeration's requests first, then the ports' line
    /// state changes.
    fn start_control(&mut self, io: &mut Io) {
        let host = &mut io.usb;
        if host.todo.is_empty() && host.stage == Stage::Running {
            let shared = host.shared.clone();
            let mut s = shared.lock().unwrap();
            for k in 0..s.ports.len() {
                if let Some(c) = s.ports[k].line_state_due.pop_front() {
                    let comm = u16::from(s.ports[k].comm_if);
                    if c.coding {
                        host.todo.push_back(Request {
                            setup: setup(0x21, 0x20, 0, comm, 7),
                            out: vec![0x00, 0xC2, 0x01, 0x00, 0, 0, 8],
                            what: Purpose::LineCoding(k),
                        });
                    }
                    host.todo.push_back(req(
                        0x21,
                        0x22,
                        if c.dtr { 3 } else { 0 },
                        comm,
                        0,
                        Purpose::LineState(k, c.dtr),
                    ));
                    break;
                }
            }
        }
        if let Some(r) = host.todo.pop_front() {
            if !self.push_out(0, &r.setup, true) {
                host.todo.push_front(r);
                return;
            }
            host.ctl = Some(Control {
                req: r,
                phase: Phase::Data,
                got: vec![],
            });
        }
    }

    /// One bulk OUT packet to each open port with bytes for the device, and one bulk IN poll
    /// of each port whose client reads — for ports whose line state is settled (a tty being
    /// opened is written once SET_CONTROL_LINE_STATE has raised DTR; a close goes out before
    /// anything after it).
    fn bulk_traffic(&mut self, io: &mut Io) {
        let host = &mut io.usb;
        let busy: Vec<usize> = host
            .todo
            .iter()
            .filter_map(|r| match r.what {
                Purpose::LineCoding(k) | Purpose::LineState(k, _) => Some(k),
                _ => None,
            })
            .collect();
        let shared = host.shared.clone();
        let mut s = shared.lock().unwrap();
        let mut ins = vec![];
        for k in 0..s.ports.len() {
            let (ep_out, ep_in, open) = (s.ports[k].ep_out, s.ports[k].ep_in, s.ports[k].open);
            if !open || !s.ports[k].line_state_due.is_empty() || busy.contains(&k) {
                continue;
            }
            if !s.ports[k].out.is_empty() {
                let n = s.ports[k].out.len().min(64);
                let pkt: Vec<u8> = s.ports[k].out.iter().take(n).copied().collect();
                if self.push_out(ep_out, &pkt, false) {
                    s.ports[k].out.drain(..n);
                }
            }
            let polls_in = s.reading[k] && s.ports[k].backlog.len() < CLIENT_BACKLOG;
            if polls_in {
                if let Some(pkt) = self.take_in(ep_in) {
                    ins.push((k, pkt));
                }
            }
        }
        drop(s);
        host.pending_in.extend(ins);
    }

    fn control_done(&mut self, ctl: Control, io: &mut Io) {
        let host = &mut io.usb;
        let shared = host.shared.clone();
        let mut s = shared.lock().unwrap();
        match ctl.req.what {
            Purpose::DeviceDesc64 | Purpose::DeviceDesc => s.device_descriptor = ctl.got,
            Purpose::SetAddress(a) => {
                let dad = ((self.dcfg >> 4) & 0x7F) as u8;
                if dad != a {
                    s.errors.push(format!(
                        "SET_ADDRESS {a}: DCFG.DAD is {dad} after the status stage"
                    ));
                }
                host.addr = a;
            }
            Purpose::ConfigHead => {
                let total = ctl
                    .got
                    .get(2..4)
                    .map(|w| u16::from_le_bytes([w[0], w[1]]))
                    .unwrap_or(9);
                host.todo
                    .push_back(req(0x80, 6, 0x0200, 0, total, Purpose::ConfigFull));
            }
            Purpose::ConfigFull => {
                s.config_descriptor = ctl.got.clone();
                s.ports = parse_cdc_ports(&ctl.got);
                let d = s.device_descriptor.clone();
                for (i, idx) in [(14usize, 0u8), (15, 0), (16, 0)]
                    .iter()
                    .map(|(i, _)| (*i, d.get(*i).copied().unwrap_or(0)))
                {
                    let _ = i;
                    if idx != 0 {
                        host.todo.push_back(req(
                            0x80,
                            6,
                            0x0300 | u16::from(idx),
                            0x0409,
                            255,
                            Purpose::String(idx),
                        ));
                    }
                }
                host.todo
                    .push_back(req(0x00, 9, 1, 0, 0, Purpose::SetConfig));
            }
            Purpose::String(i) => {
                let text: Vec<u16> = ctl
                    .got
                    .get(2..)
                    .unwrap_or(&[])
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect();
                s.strings.push((i, String::from_utf16_lossy(&text)));
            }
            Purpose::SetConfig => {
                s.configured = true;
                s.enumerations += 1;
                host.stage = Stage::Running;
            }
            Purpose::LineCoding(_) => {}
            Purpose::LineState(k, _) => {
                if let Some(n) = s.line_states.get_mut(k) {
                    *n += 1;
                }
            }
        }
    }
}

fn to_words(data: &[u8]) -> VecDeque<u32> {
    data.chunks(4)
        .map(|c| {
            let mut w = [0u8; 4];
            w[..c.len()].copy_from_slice(c);
            u32::from_le_bytes(w)
        })
        .collect()
}

fn setup(bm: u8, breq: u8, wvalue: u16, windex: u16, wlength: u16) -> [u8; 8] {
    let v = wvalue.to_le_bytes();
    let i = windex.to_le_bytes();
    let l = wlength.to_le_bytes();
    [bm, breq, v[0], v[1], i[0], i[1], l[0], l[1]]
}

fn req(bm: u8, breq: u8, wvalue: u16, windex: u16, wlength: u16, what: Purpose) -> Request {
    Request {
        setup: setup(bm, breq, wvalue, windex, wlength),
        out: vec![],
        what,
    }
}

/// The CDC-ACM functions of a configuration descriptor: communication interface (class 2,
/// subclass 2) and the bulk endpoints of the data interface after it (class 0x0A).
fn parse_cdc_ports(cfg: &[u8]) -> Vec<PortState> {
    let mut ports = vec![];
    let mut i = 0;
    let mut in_data = false;
    while i + 2 <= cfg.len() {
        let len = usize::from(cfg[i]);
        if len == 0 {
            break;
        }
        let ty = cfg[i + 1];
        if ty == 4 && i + 6 < cfg.len() {
            let (num, class) = (cfg[i + 2], cfg[i + 5]);
            if class == 2 {
                ports.push(PortState {
                    comm_if: num,
                    ..PortState::default()
                });
                in_data = false;
            } else if class == 0x0A {
                in_data = true;
            }
        }
        if ty == 5 && in_data && i + 3 < cfg.len() {
            let (addr, attr) = (cfg[i + 2], cfg[i + 3]);
            if attr & 3 == 2 {
                if let Some(p) = ports.last_mut() {
                    if addr & 0x80 != 0 {
                        p.ep_in = usize::from(addr & 0xF);
                    } else {
                        p.ep_out = usize::from(addr & 0xF);
                    }
                }
            }
        }
        i += len;
    }
    ports
}
