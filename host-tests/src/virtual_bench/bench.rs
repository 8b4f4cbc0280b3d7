//! The virtual bench a campaign runs on (`nanocal campaign --virtual`): the QEMU firmware, and
//! the digital twin in three roles around it — the PI controller's stage on the stage link, the
//! interferometer (a TCP server speaking the reference line protocol of
//! [`crate::campaign::reference`]), and the temperature sensors behind the register-level chip
//! models on the bus stand-in. The board's clock is in lockstep with the campaign: plan time
//! `t` is bench time `t + offset`, and nothing on the board happens between the instants the
//! campaign lets it reach.

use super::board_first::BoardFirst;
use super::chips::{max31856::TempSource, Lps22hb, Max31856};
use super::controller::{Clock, Config, Controller, IdealPlant, Plant, StageSim};
use super::link::{BenchClock, BenchLink, RingPort};
use super::qemu::Qemu;
use super::sensors::Buses;
use super::twin_stage::TwinStage;
use crate::campaign::bench::{BenchDriver, BenchError};
use crate::device::Port;
use crate::twin::{Trajectory, Twin};
use nanocal_interface::bench_link as bl;
use nanocal_interface::bus::BusOp;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Serial ports whose input the bench counts (GCS host link, management).
const COUNTED: [usize; 2] = [0, 3];

/// Board time the bench lets pass at once while a request waits for the board's own timers,
/// when the board has published no next timer (it always has one: the supervisor's).
const NUDGE_S: f64 = 0.01;

/// Wall time after which input the board has not read, while it sleeps, counts as stuck.
const STUCK_AFTER: Duration = Duration::from_millis(5);

/// Wall time after which an exchange lets board time pass even though the board has started
/// to answer (a reply the board finishes only after waiting for its own time).
const ANSWERED_GRACE: Duration = Duration::from_millis(500);

/// How often an exchange looks at the board while the host talks to it (the host's own reads
/// pump the stage's ring meanwhile).
const EXCHANGE_LOOK: Duration = Duration::from_micros(100);

/// A stream that counts the bytes written into the board, and marks what the board had
/// replied when the newest request went ([`ReplyMark`]).
struct Counted<S> {
    inner: S,
    sent: Arc<AtomicU64>,
    mark: Arc<ReplyMark>,
}

/// The bytes the board had written to the host (GCS and management ports) when the host last
/// wrote to it: an exchange knows the board has started to answer its newest request when that
/// count has moved on. Marked by the writer itself, at the write: an exchange loop that looked
/// only from time to time missed requests answered in full between two of its looks (through
/// the rings, most are), and let the board's time run on as if it were still waiting.
struct ReplyMark {
    link: Arc<BenchLink>,
    replied: std::sync::atomic::AtomicU32,
    /// Reads of the host's ports under way: the host waits for the board.
    ///
    /// **Why.** An exchange lets board time pass only while the host waits for an answer the
    /// board has not begun. Without this, a host between two writes of one exchange (`MOV`,
    /// then `ERR?`; a frame written in parts) looked the same — every byte in, the board idle,
    /// nothing answered — and got a nudge of the board's clock whenever its thread took more
    /// than 50 µs to write again: 1.3 nudges a step in the published campaign, each an advance
    /// and mostly a halt of the board, and board time that depended on the host's scheduling.
    reading: AtomicU32,
}

impl ReplyMark {
    /// Bytes the board has written to the host so far.
    fn replied_now(&self) -> u32 {
        COUNTED
            .iter()
            .fold(0u32, |n, &p| n.wrapping_add(self.link.tx_bytes(p)))
    }

    /// A request goes now.
    fn mark(&self) {
        self.replied.store(self.replied_now(), Ordering::Release);
    }

    /// The board has written to the host since the newest request went.
    fn answered(&self) -> bool {
        self.replied_now() != self.replied.load(Ordering::Acquire)
    }

    /// The host waits in a read of one of its ports.
    fn host_reading(&self) -> bool {
        self.reading.load(Ordering::Acquire) > 0
    }
}

impl<S: Read> Read for Counted<S> {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        self.mark.reading.fetch_add(1, Ordering::AcqRel);
        let r = self.inner.read(b);
        self.mark.reading.fetch_sub(1, Ordering::AcqRel);
        r
    }
}

impl<S: Write> Write for Counted<S> {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        // counted before they go (the bench must never see the board as having read them all
        // while they are on their way), corrected for what did not go
        self.sent.fetch_add(b.len() as u64, Ordering::AcqRel);
        self.mark.mark();
        let r = self.inner.write(b);
        let n = *r.as_ref().unwrap_or(&0);
        self.sent.fetch_sub((b.len() - n) as u64, Ordering::AcqRel);
        r
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Read timeout of the bench's ports to the board.
const PORT_READ_TIMEOUT: Duration = Duration::from_millis(50);

/// A socket to the board as the bench's port: the bytes written are counted into `sent` (the
/// bench waits until the board has read them).
fn counted<S: Read + Write + Send + 'static>(
    inner: S,
    sent: &Arc<AtomicU64>,
    mark: &Arc<ReplyMark>,
) -> Box<dyn Port> {
    Box::new(Counted {
        inner,
        sent: sent.clone(),
        mark: mark.clone(),
    })
}

/// Opens (management, GCS) ports to the compensator again.
pub type PortOpener = Box<dyn FnMut() -> std::io::Result<(Box<dyn Port>, Box<dyn Port>)> + Send>;

/// Faults the virtual bench stages at plan times, for the campaign's tests of what a bench of
/// days meets (none by default). A device reset is the campaign's own to stage
/// ([`crate::campaign::Faults`]): the bench has no second management connection.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Faults {
    /// From this plan time on the interferometer sends nothing more; its connection stays open
    /// (a laser that lost its beam, a program that hangs), s.
    pub reference_silent_from_s: Option<f64>,
    /// From this plan time on the thermocouple on this chip-select is broken: the MAX31856
    /// reports an open circuit (datasheet, SR bit 0 OPEN, with CR0.OCFAULT enabled), s.
    pub thermocouple_open: Option<(usize, f64)>,
}

/// The virtual bench.
pub struct VirtualBench {
    qemu: Qemu,
    link: Arc<BenchLink>,
    clock: BenchClock,
    stage: Arc<Mutex<TwinStage>>,
    stage_sim: StageSim,
    /// Commands already handed to the campaign.
    commands_seen: usize,
    sent: [Arc<AtomicU64>; 2],
    mark: Arc<ReplyMark>,
    /// Bench time of plan time 0, s.
    offset_s: f64,
    reference_port: u16,
    stop_reference: Arc<AtomicBool>,
    /// Serial ports on the page's rings ([`ring_ports`]).
    rings: u32,
}

/// The serial ports a campaign's board is started with on the page's rings: the host link (0),
/// the stage link (1) and the management port (3) — every byte of a step — unless
/// `NANOCAL_BENCH_UART=1` asks for QEMU's UARTs (for comparison: the same campaign through the
/// sockets and the UARTs' interrupts, ≈ 3× the wall time).
fn ring_ports() -> u32 {
    if std::env::var_os("NANOCAL_BENCH_UART").is_some_and(|v| v == "1") {
        0
    } else {
        0b1011
    }
}

/// The board's clock in plan time: the simulated controller stamps what it receives with it.
struct PlanClock {
    link: Arc<BenchLink>,
    offset_s: f64,
}

impl Clock for PlanClock {
    fn now_s(&self) -> f64 {
        self.link.now_s() - self.offset_s
    }
}

/// The twin as the controller's stage: the controller's own sensor follows its drive commands
/// at once and exactly (closed loop on the E-727's capacitive sensors); where the stage really
/// goes is the twin's business ([`TwinStage`]), which learns every target the moment the
/// controller accepts it.
pub struct TwinPlant {
    ideal: IdealPlant,
    targets: Vec<f64>,
    stage: Arc<Mutex<TwinStage>>,
}

impl TwinPlant {
    /// The stage at rest at `first_um`, telling `stage` every target.
    pub fn new(first_um: &[f64], stage: Arc<Mutex<TwinStage>>) -> Self {
        Self {
            ideal: IdealPlant::new(first_um),
            targets: first_um.to_vec(),
            stage,
        }
    }

    fn tell(&self, t_s: f64) {
        self.stage
            .lock()
            .unwrap()
            .command(t_s, self.targets.clone());
    }
}

impl Plant for TwinPlant {
    fn drive(&mut self, axis: usize, target: f64, velocity: f64, t_s: f64) {
        self.ideal.drive(axis, target, velocity, t_s);
        self.targets[axis] = target;
        self.tell(t_s);
    }
    fn stop(&mut self, axis: usize, t_s: f64) {
        self.ideal.stop(axis, t_s);
        self.targets[axis] = self.ideal.position(axis, t_s);
        self.tell(t_s);
    }
    fn position(&self, axis: usize, t_s: f64) -> f64 {
        self.ideal.position(axis, t_s)
    }
    fn settled(&self, axis: usize, t_s: f64) -> bool {
        self.ideal.settled(axis, t_s)
    }
}

/// The simulated E-727 of a campaign on the twin: its axes rest at the plan's first pose
/// (`traj`'s first dwell), servo on, the stage is `stage` ([`TwinPlant`]); `clock` is plan
/// time (the controller stamps what it receives with it).
pub fn twin_controller(
    traj: &Trajectory,
    axes_n: usize,
    stage: Arc<Mutex<TwinStage>>,
    clock: Arc<dyn Clock>,
) -> Controller {
    let first: Vec<f64> = traj
        .dwells
        .first()
        .map(|d| d.cmd_um.clone())
        .unwrap_or(vec![0.0; axes_n]);
    let mut cfg = Config::e727(axes_n).ready();
    for (a, ax) in cfg.axes.iter_mut().enumerate() {
        ax.start = first[a];
    }
    Controller::new(cfg, Box::new(TwinPlant::new(&first, stage)), clock)
}

/// The sensor chips of a campaign on the twin: a MAX31856 per recorded sensor reading the
/// twin's room at the board's clock (bench time − `offset_s` = plan time), the LPS22HB (its
/// pressure set from the twin by [`twin_pressure`] before each I2C transaction) and the force
/// input at mid-scale.
pub fn twin_buses(twin: &Twin, stage: &Arc<Mutex<TwinStage>>, offset_s: f64, stream: u64) -> Buses {
    let mut buses = Buses::default();
    let noise: Vec<f64> = twin
        .cfg
        .sensors
        .iter()
        .filter(|s| s.recorded)
        .map(|s| s.noise_c)
        .collect();
    let n_sensors = stage.lock().unwrap().sensors().len();
    for (i, &noise_c) in noise.iter().enumerate().take(n_sensors) {
        let st = stage.clone();
        let source = TempSource(Arc::new(move |bench_s: f64| {
            st.lock().unwrap().spot_c(i, bench_s - offset_s)
        }));
        let chip = Max31856::new(20.0).following(source, noise_c, stream ^ (i as u64 + 1));
        buses.spi.push(Some(Box::new(chip)));
    }
    buses.i2c.insert(
        super::chips::lps22hb::ADDRESS,
        Box::new(Lps22hb::new(1013.25)),
    );
    buses.adc = vec![Some(2048), None, None, None];
    buses
}

/// Set the LPS22HB on `buses` to the twin's air pressure at plan time `plan_s`.
pub fn twin_pressure(buses: &mut Buses, stage: &Mutex<TwinStage>, plan_s: f64) {
    let p = stage.lock().unwrap().pressure_hpa(plan_s);
    if let Some(chip) = buses.i2c.get_mut(&super::chips::lps22hb::ADDRESS) {
        if let Some(baro) = chip_as_lps(chip.as_mut()) {
            baro.pressure_hpa = p;
        }
    }
}

/// The board's clock as the interferometer follows it: the QEMU board's [`BenchLink`], or the
/// emulated STM32 board's clock (the `stm32-bench` binary).
pub trait BoardTime: Send + Sync {
    /// Board time, s.
    fn now_s(&self) -> f64;
    /// Wait (up to `timeout`) until board time moved past generation `seen`; the current
    /// generation.
    fn wait_advanced(&self, seen: u64, timeout: Duration) -> u64;
    /// The board stopped for good.
    fn stopped(&self) -> bool;
}

impl BoardTime for BenchLink {
    fn now_s(&self) -> f64 {
        BenchLink::now_s(self)
    }
    fn wait_advanced(&self, seen: u64, timeout: Duration) -> u64 {
        BenchLink::wait_advanced(self, seen, timeout)
    }
    fn stopped(&self) -> bool {
        BenchLink::stopped(self)
    }
}

/// The twin as the interferometer: a TCP server on 127.0.0.1 (its port is returned) sending the
/// twin's measured positions in plan time (bench time − `offset_s`) as board time passes, none
/// from plan time `silent_from_s` on; it ends when `stop` is set or the board stops.
pub fn spawn_interferometer(
    time: Arc<dyn BoardTime>,
    stage: Arc<Mutex<TwinStage>>,
    offset_s: f64,
    silent_from_s: f64,
    stop: Arc<AtomicBool>,
) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("interferometer port");
    let port = listener.local_addr().expect("bound").port();
    std::thread::spawn(move || {
        serve_interferometer(listener, time, stage, offset_s, silent_from_s, stop)
    });
    port
}

impl VirtualBench {
    /// Boot the firmware with the twin around it. `traj` is the plan's schedule as dwells (plan
    /// time 0 at the twin's absolute time `start_abs_s`); the board boots at plan time
    /// `plan_at_boot_s` (≤ −[`Self::SETUP_S`] before a plan starts, so that configuration, upload
    /// and the sensors' first conversions fit before it).
    pub fn start(
        twin: &Twin,
        traj: &Trajectory,
        start_abs_s: f64,
        stream: u64,
        plan_at_boot_s: f64,
        faults: &Faults,
    ) -> Self {
        let rings = ring_ports();
        // in lockstep from the board's boot: it boots at the same instant every run
        let mut qemu = Qemu::start_lockstep_with_rings(&[], rings);
        super::core_split::board_started(qemu.pid());
        let link = qemu.link();
        // the set-up's commands too find the board awake while it has a core of its own
        link.set_idle_spin(super::core_split::idle_spin_turns());
        let clock = qemu.clock();
        let axes_n = twin.cfg.axes;
        let stage = Arc::new(Mutex::new(TwinStage::new(twin, traj, start_abs_s, stream)));
        let offset_s = -plan_at_boot_s;
        // an E-727 whose axes rest at the plan's first pose, servo on
        let ctl = twin_controller(
            traj,
            axes_n,
            stage.clone(),
            Arc::new(PlanClock {
                link: link.clone(),
                offset_s,
            }),
        );
        let stage_sim = if rings == 0 {
            StageSim::serve_controller(qemu.connect(1), ctl)
        } else {
            StageSim::on_ring(&link, 1, ctl)
        };

        // the sensor chips read the twin's room at the board's clock
        let buses = twin_buses(twin, &stage, offset_s, stream);
        let buses = Arc::new(Mutex::new(buses));
        let (b, st) = (buses.clone(), stage.clone());
        let open_tc = faults.thermocouple_open;
        link.attach_bus(Box::new(move |op, target, out, n_in, now_s| {
            let mut b = b.lock().unwrap();
            if let Some((cs, from_s)) = open_tc {
                if op == BusOp::Spi && usize::from(target) == cs && now_s - offset_s >= from_s {
                    if let Some(Some(chip)) = b.spi.get_mut(cs) {
                        if let Some(tc) = chip.any_mut().downcast_mut::<Max31856>() {
                            tc.open = true;
                        }
                    }
                }
            }
            if op == BusOp::I2c {
                twin_pressure(&mut b, &st, now_s - offset_s);
            }
            b.serve(op, target, out, n_in, now_s)
        }));

        let stop_reference = Arc::new(AtomicBool::new(false));
        let reference_port = spawn_interferometer(
            link.clone(),
            stage.clone(),
            offset_s,
            faults.reference_silent_from_s.unwrap_or(f64::INFINITY),
            stop_reference.clone(),
        );
        clock.lockstep();
        let sent = [Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0))];
        let mark = Arc::new(ReplyMark {
            link: link.clone(),
            replied: std::sync::atomic::AtomicU32::new(0),
            reading: AtomicU32::new(0),
        });
        Self {
            qemu,
            link,
            clock,
            stage,
            stage_sim,
            commands_seen: 0,
            sent,
            offset_s,
            reference_port,
            stop_reference,
            rings,
            mark,
        }
    }

    /// Plan time the bench needs before a plan starts (boot, settings, upload, warm-up), s.
    pub const SETUP_S: f64 = 60.0;

    /// The compensator's management port (a counted stream).
    pub fn management(&mut self) -> Box<dyn Port> {
        if self.rings & (1 << 3) != 0 {
            let r = RingPort::new(self.link.clone(), 3, PORT_READ_TIMEOUT);
            return counted(r, &self.sent[1], &self.mark);
        }
        let s =
            std::os::unix::net::UnixStream::connect(self.mgmt_path()).expect("management socket");
        s.set_read_timeout(Some(PORT_READ_TIMEOUT)).ok();
        counted(s, &self.sent[1], &self.mark)
    }

    /// The compensator's GCS port (a counted stream).
    pub fn gcs(&mut self) -> Box<dyn Port> {
        if self.rings & 1 != 0 {
            // the host opens the port: a new session on the board
            self.qemu.set_dtr(true);
            let r = RingPort::new(self.link.clone(), 0, PORT_READ_TIMEOUT);
            return counted(r, &self.sent[0], &self.mark);
        }
        let s = self.qemu.connect(0);
        // the host opens the port: a new session on the board
        self.qemu.set_dtr(true);
        s.set_read_timeout(Some(PORT_READ_TIMEOUT)).ok();
        counted(s, &self.sent[0], &self.mark)
    }

    /// Path of the board's management socket.
    fn mgmt_path(&self) -> String {
        let spec = self.qemu.mgmt_spec();
        spec.strip_prefix("unix:").expect("unix socket").to_string()
    }

    /// Opens the management and GCS ports again, as a host does after the compensator's USB
    /// ports went away and came back (the previous connections must be closed first: QEMU
    /// serves one client per port).
    pub fn port_opener(&self) -> PortOpener {
        let path = self.mgmt_path();
        let gcs_port = self.qemu.serial_port(0);
        let sent = self.sent.clone();
        let link = self.link.clone();
        let rings = self.rings;
        let mark = self.mark.clone();
        Box::new(move || {
            if rings != 0 {
                let m = RingPort::new(link.clone(), 3, PORT_READ_TIMEOUT);
                let g = RingPort::new(link.clone(), 0, PORT_READ_TIMEOUT);
                super::qemu::apply_line_state(
                    &link,
                    nanocal_interface::bench_link::LINE_HOST,
                    true,
                );
                return Ok((counted(m, &sent[1], &mark), counted(g, &sent[0], &mark)));
            }
            let m = std::os::unix::net::UnixStream::connect(&path)?;
            m.set_read_timeout(Some(PORT_READ_TIMEOUT))?;
            let g = TcpStream::connect(("127.0.0.1", gcs_port))?;
            g.set_nodelay(true)?;
            g.set_read_timeout(Some(PORT_READ_TIMEOUT))?;
            // the host opens the port again: a new session on the board
            super::qemu::apply_line_state(&link, nanocal_interface::bench_link::LINE_HOST, true);
            Ok((counted(m, &sent[1], &mark), counted(g, &sent[0], &mark)))
        })
    }

    /// The interferometer, as a reference specification.
    pub fn reference_spec(&self) -> String {
        format!("tcp:127.0.0.1:{}", self.reference_port)
    }

    /// The board's link (page, counters).
    pub fn link(&self) -> Arc<BenchLink> {
        self.link.clone()
    }

    /// The QEMU process (its id, for CPU figures).
    pub fn qemu(&self) -> &Qemu {
        &self.qemu
    }

    /// Every byte the bench and the controller sent to the board has been read by it, and the
    /// board is idle.
    fn settled(&self) -> bool {
        !self.undelivered() && self.link.idle_at_horizon()
    }

    /// Bytes sent to the board that it has not read yet (host link, management, stage link).
    fn undelivered(&self) -> bool {
        COUNTED
            .iter()
            .zip(&self.sent)
            .any(|(&p, sent)| self.link.rx_bytes(p) != sent.load(Ordering::Acquire) as u32)
            || self.link.rx_bytes(1) != self.stage_sim.bytes_out() as u32
    }

    /// Ring the board awake if its input has been stuck for [`STUCK_AFTER`]
    /// ([`BenchLink::wake_for_input`] says why it can be).
    fn wake_if_stuck(&self, since: &mut Option<Instant>) {
        if !self.undelivered() {
            *since = None;
            return;
        }
        let t = *since.get_or_insert_with(Instant::now);
        if t.elapsed() > STUCK_AFTER && self.link.wake_for_input() {
            *since = Some(Instant::now());
        }
    }

    /// Wait until the board has done everything it had to do at this instant (it may still be
    /// forwarding a corrected `MOV` after it answered the host) and the controller has acted on
    /// every byte the board sent it: it stamps each command with the board's clock, which must
    /// not move before.
    fn sync_stage(&mut self) -> Result<(), BenchError> {
        let start = Instant::now();
        let mut stuck_since = None;
        while !self.settled() || self.stage_sim.bytes_in() as u32 != self.link.tx_bytes(1) {
            self.link.pump();
            self.wake_if_stuck(&mut stuck_since);
            if start.elapsed() > Duration::from_secs(10) {
                return Err(BenchError::Other(format!(
                    "the stage controller took in {} of the {} bytes the board sent it",
                    self.stage_sim.bytes_in(),
                    self.link.tx_bytes(1)
                )));
            }
            std::thread::sleep(Duration::from_micros(20));
        }
        Ok(())
    }
}

impl Drop for VirtualBench {
    fn drop(&mut self) {
        super::core_split::board_stopped(self.qemu.pid());
        if std::env::var_os("NANOCAL_CAMPAIGN_PROFILE").is_some() {
            eprintln!("virtual bench crossings: {:?}", self.link.crossings());
            let (made, undone) = super::core_split::transitions();
            eprintln!("virtual bench core split: made {made}, undone {undone} time(s)");
        }
        if self.link.pokes() > 0 {
            eprintln!(
                "virtual bench: woke the board {} time(s) for input stuck on its way in (QEMU's UART)",
                self.link.pokes()
            );
        }
        self.stop_reference.store(true, Ordering::Release);
    }
}

fn chip_as_lps(chip: &mut dyn super::chips::I2cChip) -> Option<&mut Lps22hb> {
    chip.any_mut().downcast_mut::<Lps22hb>()
}

fn serve_interferometer(
    listener: TcpListener,
    link: Arc<dyn BoardTime>,
    stage: Arc<Mutex<TwinStage>>,
    offset_s: f64,
    silent_from_s: f64,
    stop: Arc<AtomicBool>,
) {
    let Ok((mut s, _)) = listener.accept() else {
        return;
    };
    s.set_nodelay(true).ok();
    let (period, first) = {
        let st = stage.lock().unwrap();
        (st.period_s(), -super::twin_stage::PRE_ROLL_S)
    };
    let _ = writeln!(
        s,
        "# nanocal virtual interferometer: the digital twin; t = plan time (s), position per axis (um)"
    );
    let mut k: u64 = 0;
    let mut seen = 0;
    let mut out = String::new();
    while !stop.load(Ordering::Acquire) && !link.stopped() {
        seen = link.wait_advanced(seen, Duration::from_millis(100));
        let now = link.now_s() - offset_s;
        out.clear();
        {
            let mut st = stage.lock().unwrap();
            let end = st.end_s();
            loop {
                let t = first + k as f64 * period;
                if t >= now || t > end || t >= silent_from_s {
                    break;
                }
                let m = st.measure(t);
                use std::fmt::Write as _;
                let _ = write!(out, "{t:.3}");
                for v in m {
                    let _ = write!(out, " {v:.6}");
                }
                out.push('\n');
                k += 1;
            }
        }
        if !out.is_empty() && s.write_all(out.as_bytes()).is_err() {
            return;
        }
    }
}

impl BenchDriver for VirtualBench {
    fn now_s(&self) -> f64 {
        self.link.now_s() - self.offset_s
    }

    fn wait_until(&mut self, t_s: f64, stop: &AtomicBool) -> Result<bool, BenchError> {
        if stop.load(Ordering::Acquire) {
            return Ok(false);
        }
        self.sync_stage()?;
        // a board with a core of its own watches for the bench's next command when idle (the
        // split may have been made or undone since the last step)
        self.link
            .set_idle_spin(super::core_split::idle_spin_turns());
        self.clock
            .advance_to(t_s + self.offset_s, Duration::from_secs(60))?;
        Ok(true)
    }

    fn exchange(&mut self, op: &mut (dyn FnMut() + Send)) -> Result<(), BenchError> {
        let mut result = Ok(());
        // nothing asked yet
        self.mark.mark();
        // the exchange's end wakes the loop below at once; it looks every EXCHANGE_LOOK
        // otherwise (a loop that woke every 20 µs took a core from the board and the op)
        let done = (Mutex::new(false), std::sync::Condvar::new());
        std::thread::scope(|sc| {
            let h = sc.spawn(|| {
                op();
                *done.0.lock().unwrap() = true;
                done.1.notify_all();
            });
            let mut idle_since: Option<Instant> = None;
            let mut stuck_since: Option<Instant> = None;
            // this loop's looks give way to QEMU's threads (and the op's)
            let mut board_first = BoardFirst::enter();
            while !h.is_finished() {
                board_first.look();
                self.link.pump();
                // the board has started to answer the newest request: it needs no more time,
                // and the fold it answered with must stay the one the next command meets
                let answered = self.mark.answered();
                // a board that waits for the stage's reply does not wait for its own time, nor
                // one whose host is still writing or working (only a host that waits in a read
                // waits for the board)
                if self.mark.host_reading()
                    && self.settled()
                    && self.stage_sim.bytes_in() as u32 == self.link.tx_bytes(1)
                {
                    // the board took the request in and waits: for its own time (a flash erase)
                    let since = *idle_since.get_or_insert_with(Instant::now);
                    let wait = if answered {
                        ANSWERED_GRACE
                    } else {
                        Duration::from_micros(50)
                    };
                    if since.elapsed() > wait {
                        self.link.count_nudge();
                        // straight to the board's next timer: nothing happens on the board
                        // before it (every byte is in, the executor idle), so the 10 ms
                        // nudges it took before only added advances and halts
                        let next = self
                            .clock
                            .next_alarm_ticks()
                            .unwrap_or_else(|| bl::s_to_ticks(self.link.now_s() + NUDGE_S));
                        if let Err(e) = self.clock.advance_to_ticks(next, Duration::from_secs(60)) {
                            result = Err(e.into());
                            break;
                        }
                        idle_since = None;
                    }
                } else {
                    idle_since = None;
                    self.wake_if_stuck(&mut stuck_since);
                }
                let g = done.0.lock().unwrap();
                if !*g {
                    let _ = done.1.wait_timeout(g, EXCHANGE_LOOK).unwrap();
                }
                board_first.rested();
            }
        });
        result
    }

    fn stage_commands(&mut self) -> Option<Vec<(f64, Vec<f64>)>> {
        if self.sync_stage().is_err() {
            return None;
        }
        let st = self.stage.lock().unwrap();
        let new = st.commands()[self.commands_seen..].to_vec();
        self.commands_seen = st.commands().len();
        Some(new)
    }
    fn usage(&self) -> Option<crate::campaign::bench::BenchUsage> {
        Some(crate::campaign::bench::BenchUsage {
            emulator_cpu_s: self.qemu.cpu_s(),
            bus_transactions: Some(self.link.transactions.load(Ordering::Relaxed)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_bench::link::Page;
    use std::os::unix::net::UnixStream;

    /// A port whose reads see whether the mark counts them as the host waiting.
    struct Probe {
        mark: Arc<ReplyMark>,
        seen: Vec<bool>,
    }

    impl Read for Probe {
        fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
            self.seen.push(self.mark.host_reading());
            b[0] = b'0';
            Ok(1)
        }
    }

    impl Write for Probe {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.seen.push(self.mark.host_reading());
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn the_host_counts_as_waiting_for_the_board_only_inside_a_read_of_its_port() {
        let path = std::env::temp_dir().join(format!("nanocal-mark-{}", std::process::id()));
        let (ours, _board) = UnixStream::pair().unwrap();
        let link = BenchLink::start(Page::create(&path).unwrap(), ours);
        let mark = Arc::new(ReplyMark {
            link: link.clone(),
            replied: std::sync::atomic::AtomicU32::new(0),
            reading: AtomicU32::new(0),
        });
        let sent = Arc::new(AtomicU64::new(0));
        let mut port = Counted {
            inner: Probe {
                mark: mark.clone(),
                seen: Vec::new(),
            },
            sent: sent.clone(),
            mark: mark.clone(),
        };
        assert!(!mark.host_reading());
        port.write_all(b"MOV 1 30\n").unwrap();
        assert!(!mark.host_reading(), "between two writes the host is busy");
        let mut b = [0u8; 4];
        assert_eq!(port.read(&mut b).unwrap(), 1);
        assert!(!mark.host_reading(), "the read is over");
        assert_eq!(port.inner.seen, [false, true], "writing: no; reading: yes");
        assert_eq!(sent.load(Ordering::Acquire), 9);
        link.shutdown();
    }
}
