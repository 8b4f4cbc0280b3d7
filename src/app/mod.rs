//! The board-agnostic application: shared state and one async function per concern. Boards wrap
//! each in an `#[embassy_executor::task]` with their concrete link, bus and storage types.
//!
//! ```text
//! host link ─▶ line assembler ─▶ Proxy (GCS parse, Fold::correct, format) ─▶ to_stage ─▶ stage link
//! host link ◀─ to_host ◀─ Proxy (Fold::inverse_from for POS?/MOV?) ◀─ line assembler ◀─ stage link
//! sensors ─▶ drivers ─▶ fault policy ─▶ lag filters ─▶ Model::fold ─▶ Core.comp, Core.proxy.gate
//! management ─▶ upload / store / KMZ / bypass / settings / status
//! supervisor ─▶ fold freshness, status LED, watchdog
//! ```
//! The command path only takes the `core` lock for the time of one line; it never waits for the
//! sensor bus or flash (flash erases run on bank 2 while code runs from bank 1, and the store
//! awaits the controller instead of spinning).

mod links;
mod mgmt;
mod sensors;
mod supervisor;

pub use links::{host_link, stage_link};
pub use mgmt::{load_settings, management, VERSION};
pub use sensors::{sensors, InputBus};
pub use supervisor::{supervisor, Board};

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, ThreadModeRawMutex};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use nanocal_compensator::fault::{Faults, Policy, MAX_CHANNELS};
use nanocal_compensator::gcs::AxisMap;
use nanocal_compensator::inputs::{self, FastSamples};
use nanocal_compensator::proxy::{FoldCorrector, FollowConfig, Gate, Proxy};
use nanocal_compensator::stale::StaleCheck;
use nanocal_interface::identity::{ResetCause, Site};
use nanocal_interface::mgmt::Refusal;
use nanocal_interface::settings::Settings;
use nanocal_model::{Model, SlowInputs, StageSerial, MAX_AUX};

/// Reads at least one byte into `buf`. An error or end of input (host unplugged, a UART
/// framing error) is retried after a short pause instead of ending the task: the compensator
/// keeps serving when the link comes back.
pub(crate) async fn read_some<R: embedded_io_async::Read>(rx: &mut R, buf: &mut [u8]) -> usize {
    loop {
        match rx.read(buf).await {
            Ok(n) if n > 0 => return n,
            _ => embassy_time::Timer::after_millis(5).await,
        }
    }
}

/// Bytes buffered toward each link (a line or a reply's part; the proxy's output waits for room,
/// so this bounds throughput, not what can be sent).
pub const PIPE_LEN: usize = 256;

/// The model's fast path as the command path uses it.
pub type Comp = FoldCorrector;

/// What the command path needs, behind one short lock.
pub struct Core {
    /// The GCS proxy.
    pub proxy: Proxy,
    /// The model's fast path (None until a model is loaded and every input it uses has a
    /// valid reading).
    pub comp: Option<Comp>,
    /// When `comp` was folded, ms since boot.
    pub folded_at_ms: u32,
    /// The latest samples of the model's fast inputs.
    pub fast: FastSamples,
    /// Oldest fast sample a command may be corrected with, ms (set by the sensor task).
    pub fast_stale_ms: u32,
    /// The fold `comp` came from ([`ModelState::folds`] then).
    pub comp_fold: u32,
    /// The fold that corrected the last move forwarded (0: none yet).
    pub move_fold: u32,
}

impl Core {
    /// The proxy, and the fast path for this call into it with the fast inputs' latest samples
    /// (callers go through [`Self::drive`], which notes the fold a move met).
    fn proxy_and_comp(&mut self, now_ms: u32) -> (&mut Proxy, Option<&Comp>) {
        if let Some(c) = self.comp.as_mut() {
            self.fast.apply(c, now_ms, self.fast_stale_ms);
        }
        (&mut self.proxy, self.comp.as_ref())
    }

    /// Run `f` on the proxy with the fast path (as [`Self::proxy_and_comp`]); a move it
    /// corrects is noted with the fold it met (reported as `move_fold` in the status).
    pub fn drive<R>(&mut self, now_ms: u32, f: impl FnOnce(&mut Proxy, Option<&Comp>) -> R) -> R {
        let moves = self.proxy.counters.moves;
        let (proxy, comp) = self.proxy_and_comp(now_ms);
        let r = f(proxy, comp);
        if self.proxy.counters.moves != moves && self.comp.is_some() {
            self.move_fold = self.comp_fold;
        }
        r
    }
}

/// Who the device is.
#[derive(Clone, Copy)]
pub struct Identity {
    /// Chip UID.
    pub uid: [u8; 12],
    /// Why it last reset.
    pub reset_cause: ResetCause,
    /// Where, when the firmware recorded it (a panic's line, an ECC error's address).
    pub reset_site: Site<'static>,
}

/// The model and everything the slow path and management need.
pub struct ModelState {
    /// The model in service.
    pub model: Option<Model>,
    /// The CRC-32 its blob carries (the content hash the status reports; 0 without a model).
    pub model_crc32: u32,
    /// Increases with every model change (the sensor task restarts its lag filters on change).
    pub generation: u32,
    /// Slow inputs of the last fold: the readings averaged over the fold period.
    pub slow: SlowInputs,
    /// Temperature fault policy state.
    pub faults: Faults,
    /// Aux-input fault policy state.
    pub aux_faults: Faults<MAX_AUX>,
    /// Slow inputs outside the envelope at the last fold.
    pub slow_outside: u32,
    /// Whether the model in service still holds (KMZ residuals, envelope); a new model
    /// starts afresh.
    pub stale: StaleCheck,
    /// Folds computed.
    pub folds: u32,
    /// Uploads accepted.
    pub uploads_ok: u32,
    /// Uploads rejected.
    pub uploads_rejected: u32,
    /// Result code of the last rejected upload.
    pub last_upload_error: Option<Refusal>,
    /// Sensor chips found without their configuration and reconfigured.
    pub sensor_reconfigs: u32,
    /// Every input the model uses has a valid reading (lag filters primed).
    pub inputs_ready: bool,
    /// `model` was received but is not in the store yet: it is not folded (no move uses it)
    /// until the store has it ([`Shared::release`]).
    pub pending: bool,
}

impl ModelState {
    /// The model in service: `None` without one, and while it is `pending` (not folded, no
    /// move uses it, until the store has it).
    pub fn in_service(&self) -> Option<&Model> {
        self.model.as_ref().filter(|_| !self.pending)
    }
}

/// Mutex for state shared between tasks of the one thread-mode executor (no interrupt masking).
pub type M = ThreadModeRawMutex;
/// Mutex for signals and pipes (wakers may come from interrupts).
pub type Cs = CriticalSectionRawMutex;

/// Everything the tasks share.
pub struct Shared {
    /// Command-path state.
    pub core: Mutex<M, RefCell<Core>>,
    /// Slow-path and management state.
    pub model: Mutex<M, RefCell<ModelState>>,
    /// Settings in force.
    pub settings: Mutex<M, RefCell<Settings>>,
    /// Sources the board found.
    pub board: Mutex<M, RefCell<inputs::Board>>,
    /// Identity.
    pub identity: Identity,
    /// Ask the sensor task to refold now (model or KMZ changed).
    pub refold: Signal<Cs, ()>,
    /// Settings changed: the sensor task reconfigures its chips.
    pub settings_changed: Signal<Cs, ()>,
    /// A model was released: the fast sampler looks again at which inputs it must sample.
    pub model_released: Signal<Cs, ()>,
    /// Bytes for the host.
    pub to_host: Pipe<Cs, PIPE_LEN>,
    /// Bytes for the stage controller.
    pub to_stage: Pipe<Cs, PIPE_LEN>,
    /// The host has the GCS port open (USB DTR; always true on links without line state).
    pub host_connected: AtomicBool,
    /// The host closed or opened the GCS port: the host link drops what belongs to the old
    /// connection.
    pub host_hangup: Signal<Cs, ()>,
    /// The host closed the management port (its line state, where the board has it): a frame
    /// still arriving is dropped at once.
    pub mgmt_hangup: Signal<Cs, ()>,
    /// Bytes were queued for the stage controller: the stage link watches for its reply.
    pub stage_sent: Signal<Cs, ()>,
    /// Heartbeat of the sensor task (ms since boot of its last completed cycle).
    pub sensor_beat_ms: AtomicU32,
    /// The link and management tasks, busy or idle ([`task`]): the supervisor stops petting the
    /// watchdog when one stays busy past its limit.
    pub beats: [Beat; task::COUNT],
    /// Flash double words that failed ECC on read.
    pub flash_ecc_errors: AtomicU32,
    /// Host sessions so far (incremented at every open and close of the GCS port): bytes read
    /// in one session are never handed to the proxy in the next, and the host pump drops what
    /// belongs to an older one.
    pub host_session: AtomicU32,
    /// A host session ended: the host pump's write in progress is cancelled.
    pub host_cancel: Signal<Cs, ()>,
    /// Bytes for the host dropped because it did not read them.
    pub host_bytes_dropped: AtomicU32,
    /// The host link is writing a line of the host's toward the stage controller: a re-issued
    /// held target (`links`, following) must not cut into it.
    pub host_to_stage: AtomicBool,
}

/// The tasks with heartbeats ([`Shared::beats`]) and how long each may stay busy.
pub mod task {
    /// Host link, host → proxy (waits for room toward the stage controller).
    pub const HOST_IN: usize = 0;
    /// Stage link, controller → proxy (never waits for the host).
    pub const STAGE_IN: usize = 1;
    /// Stage link, proxy → controller (waits for the UART to send).
    pub const STAGE_OUT: usize = 2;
    /// Management: one request, store writes included.
    pub const MGMT: usize = 3;
    /// Tasks with a heartbeat.
    pub const COUNT: usize = 4;
    /// How long each may stay busy, ms: 256 bytes at 1 200 Bd take 2.1 s; a store write with
    /// its erases ~0.2 s.
    pub const LIMIT_MS: [u32; COUNT] = [5_000, 5_000, 5_000, 5_000];
    /// Names, for the log.
    pub const NAMES: [&str; COUNT] = [
        "host link",
        "stage link (in)",
        "stage link (out)",
        "management",
    ];
}

/// A task's heartbeat: since when it has been busy (0: idle).
pub struct Beat(AtomicU32);

/// Busy until dropped.
pub struct Busy<'a>(&'a Beat);

impl Beat {
    /// Idle.
    pub const fn new() -> Self {
        Self(AtomicU32::new(0))
    }

    /// Busy from `now_ms` until the guard is dropped.
    pub fn busy(&self, now_ms: u32) -> Busy<'_> {
        self.0.store(now_ms | 1, Ordering::Relaxed);
        Busy(self)
    }

    /// How long it has been busy at `now_ms` (0 when idle).
    pub fn busy_for_ms(&self, now_ms: u32) -> u32 {
        match self.0.load(Ordering::Relaxed) {
            0 => 0,
            since => now_ms.wrapping_sub(since),
        }
    }
}

impl Default for Beat {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for Busy<'_> {
    fn drop(&mut self) {
        self.0 .0.store(0, Ordering::Relaxed);
    }
}

impl Shared {
    /// Fresh state: no model, all sensors unknown, the given settings.
    pub fn new(settings: Settings, identity: Identity) -> Self {
        let aux_policy = Policy {
            min_c: f32::MIN,
            max_c: f32::MAX,
            ..Policy::default()
        };
        Self {
            core: Mutex::new(RefCell::new(Core {
                proxy: fresh_proxy(&settings),
                comp: None,
                folded_at_ms: 0,
                fast: FastSamples::new(),
                fast_stale_ms: 0,
                comp_fold: 0,
                move_fold: 0,
            })),
            model: Mutex::new(RefCell::new(ModelState {
                model: None,
                model_crc32: 0,
                generation: 0,
                // no input read yet: the status shows none until the first fold
                slow: SlowInputs {
                    temps_c: [f64::NAN; nanocal_model::MAX_TEMPS],
                    aux: [f64::NAN; MAX_AUX],
                    ..SlowInputs::default()
                },
                faults: Faults::new(Policy::default()),
                aux_faults: Faults::new(aux_policy),
                slow_outside: 0,
                stale: StaleCheck::new(),
                folds: 0,
                uploads_ok: 0,
                uploads_rejected: 0,
                last_upload_error: None,
                sensor_reconfigs: 0,
                inputs_ready: false,
                pending: false,
            })),
            settings: Mutex::new(RefCell::new(settings)),
            board: Mutex::new(RefCell::new(inputs::Board::default())),
            identity,
            refold: Signal::new(),
            settings_changed: Signal::new(),
            model_released: Signal::new(),
            to_host: Pipe::new(),
            to_stage: Pipe::new(),
            host_connected: AtomicBool::new(true),
            host_hangup: Signal::new(),
            mgmt_hangup: Signal::new(),
            stage_sent: Signal::new(),
            sensor_beat_ms: AtomicU32::new(0),
            beats: [const { Beat::new() }; task::COUNT],
            flash_ecc_errors: AtomicU32::new(0),
            host_session: AtomicU32::new(0),
            host_cancel: Signal::new(),
            host_bytes_dropped: AtomicU32::new(0),
            host_to_stage: AtomicBool::new(false),
        }
    }

    /// Take `model` as the model of the device, not yet in service: the previous one is out of
    /// service at once, and `model` runs only once it is released ([`Shared::release`], when the
    /// store has it) and every input it uses has a valid reading: until the sensor task folds
    /// it, moves are refused and replies pass unmapped (never a fold at 0 °C temperatures that
    /// were never read).
    /// `crc32` is the CRC its blob carries (`nanocal_model::blob::stored_crc`).
    pub fn stage(&self, model: Model, crc32: u32) {
        let serial = model.provenance().stage_serial;
        self.model.lock(|m| {
            let mut m = m.borrow_mut();
            m.model = Some(model);
            m.model_crc32 = crc32;
            m.generation = m.generation.wrapping_add(1);
            m.stale = StaleCheck::new();
            m.inputs_ready = false;
            m.pending = true;
        });
        self.core.lock(|c| {
            let mut c = c.borrow_mut();
            c.comp = None;
            c.proxy.gate = Gate::SensorFault;
            // the memory of the play operators and the fast samples were the old model's, and
            // so was the command of a held target: it is not followed with the new one
            c.proxy.reset_hysteresis();
            c.proxy.cancel_follow();
            c.fast.clear();
        });
        self.check_stage(serial);
    }

    /// The provenance check's model side: the stage serial the model in service was fitted on
    /// (`None`: no model or none recorded) and the settings' `allow_other_stage`, for the
    /// proxy, which compares them with the controller's `*IDN?` before correcting a move.
    pub fn check_stage(&self, serial: Option<StageSerial>) {
        let allow = self.settings.lock(|s| s.borrow().allow_other_stage);
        self.core
            .lock(|c| c.borrow_mut().proxy.set_stage(serial, allow));
    }

    /// The staged model is in the store: the sensor task may fold it.
    pub fn release(&self) {
        self.model.lock(|m| m.borrow_mut().pending = false);
        self.refold.signal(());
        self.model_released.signal(());
    }

    /// No model (the staged one could not be stored and none is stored).
    pub fn clear_model(&self) {
        self.model.lock(|m| {
            let mut m = m.borrow_mut();
            m.model = None;
            m.model_crc32 = 0;
            m.generation = m.generation.wrapping_add(1);
            m.stale = StaleCheck::new();
            m.inputs_ready = false;
            m.pending = false;
        });
        self.core.lock(|c| c.borrow_mut().comp = None);
        self.check_stage(None);
    }

    /// Used channels (temperatures) of the model in service.
    pub fn used_temps(&self) -> usize {
        self.model
            .lock(|m| m.borrow().model.as_ref().map(|x| x.temps()).unwrap_or(0))
            .min(MAX_CHANNELS + 1)
    }
}

/// A proxy with the settings' axis names and following, nothing else remembered.
pub fn fresh_proxy(settings: &Settings) -> Proxy {
    let mut p = Proxy::new(AxisMap::new(&settings.axis_names));
    p.set_follow(follow_config(settings));
    p
}

/// The settings' *held targets follow the model*, as the proxy takes it.
pub fn follow_config(s: &Settings) -> FollowConfig {
    FollowConfig {
        threshold_nm: s.follow_nm,
        interval_ms: u32::from(s.follow_interval_ms),
        max_step_nm: s.follow_step_nm,
    }
}

/// Aux inputs the status reports.
pub const AUX: usize = MAX_AUX;

/// Milliseconds since boot (wraps after 49 days; every comparison uses `wrapping_sub`).
pub fn now_ms() -> u32 {
    embassy_time::Instant::now().as_millis() as u32
}

/// The store's flash has handed over `total` double words that failed ECC since start-up (as
/// corrupt: a torn write), for the status.
pub fn note_flash_ecc_errors(sh: &Shared, total: u32) {
    sh.flash_ecc_errors.store(total, Ordering::Relaxed);
}

/// The host closed the GCS port (USB DTR dropped), or opened it: drop the bytes queued for it
/// (and cancel the one being written) and start a new host session in the proxy (no
/// half-received line, queued line, pending error or reply still due carries over to the next
/// connection: the replies the controller still sends for the old one are read and dropped, so
/// the pairing with the controller stays exact,
/// [`nanocal_compensator::proxy::Proxy::new_session`]); what the proxy read of the controller,
/// bypass, the move gate and the counters stay.
pub fn end_host_session(sh: &Shared) {
    sh.host_session.fetch_add(1, Ordering::AcqRel);
    sh.to_host.clear();
    sh.host_cancel.signal(());
    sh.core.lock(|c| c.borrow_mut().proxy.new_session());
}

/// Tell the application the host's line state (USB CDC SET_CONTROL_LINE_STATE, DTR bit): a
/// fall ends the host session, a rise starts a new one (nothing received while the port was
/// closed belongs to it).
pub fn host_line_state(sh: &Shared, dtr: bool) {
    let was = sh.host_connected.swap(dtr, Ordering::Relaxed);
    if was != dtr {
        end_host_session(sh);
        sh.host_hangup.signal(());
    }
}

/// Tell the application the management port's line state (DTR, as [`host_line_state`]): a
/// fall drops a management frame still arriving (the next connection starts clean).
pub fn mgmt_line_state(sh: &Shared, dtr: bool) {
    if !dtr {
        sh.mgmt_hangup.signal(());
    }
}
