//! The board-agnostic application: shared state and one async function per concern. Boards wrap
//! each in an `#[embassy_executor::task]` with their concrete link, sensor and storage types.
//!
//! ```text
//! host link ─▶ line assembler ─▶ Proxy (GCS parse, Fold::correct, format) ─▶ to_stage ─▶ stage link
//! host link ◀─ to_host ◀─ Proxy (Fold::inverse for POS?/MOV?) ◀─ line assembler ◀─ stage link
//! sensors ─▶ fault policy ─▶ lag filters ─▶ Model::fold (slow path) ─▶ Core.comp, Core.proxy.gate
//! management ─▶ upload / two-slot commit / KMZ / bypass / status
//! ```
//! The command path only takes the `core` lock for the time of one line; it never waits for the
//! sensor bus or flash.

mod links;
mod mgmt;
mod sensors;

pub use links::{host_link, stage_link};
pub use mgmt::management;
pub use sensors::{sensors, SensorBus};

use core::cell::RefCell;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, ThreadModeRawMutex};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use nanocal_compensator::fault::{Faults, Policy};
use nanocal_compensator::proxy::{FoldCorrector, Proxy};
use nanocal_compensator::slots::Active;
use nanocal_model::{Model, SlowInputs, MAX_TEMPS};

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

/// Bytes buffered toward each link.
pub const PIPE_LEN: usize = 512;

/// The model's fast path as the command path uses it.
pub type Comp = FoldCorrector;

/// What the command path needs, behind one short lock.
pub struct Core {
    /// The GCS proxy.
    pub proxy: Proxy,
    /// The model's fast path (None until a model is loaded).
    pub comp: Option<Comp>,
}

/// The model and everything the slow path and management need.
pub struct ModelState {
    /// The model in service.
    pub model: Option<Model>,
    /// Increases with every model change (the sensor task resets its lag filters on change).
    pub generation: u32,
    /// Storage slot of the model in service.
    pub active: Option<Active>,
    /// Slow inputs of the last fold.
    pub slow: SlowInputs,
    /// Sensor fault policy state.
    pub faults: Faults,
    /// Sensors configured on the board.
    pub sensors: u8,
    /// Slow inputs outside the envelope at the last fold.
    pub slow_outside: u32,
    /// Folds computed.
    pub folds: u32,
    /// Uploads accepted.
    pub uploads_ok: u32,
    /// Uploads rejected.
    pub uploads_rejected: u32,
    /// Result code of the last rejected upload.
    pub last_upload_error: u8,
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
    /// Ask the sensor task to refold now (model or KMZ changed).
    pub refold: Signal<Cs, ()>,
    /// Bytes for the host.
    pub to_host: Pipe<Cs, PIPE_LEN>,
    /// Bytes for the stage controller.
    pub to_stage: Pipe<Cs, PIPE_LEN>,
}

impl Shared {
    /// Fresh state: no model, all sensors unknown.
    pub fn new(sensors: u8, policy: Policy) -> Self {
        Self {
            core: Mutex::new(RefCell::new(Core {
                proxy: Proxy::default(),
                comp: None,
            })),
            model: Mutex::new(RefCell::new(ModelState {
                model: None,
                generation: 0,
                active: None,
                slow: SlowInputs::default(),
                faults: Faults::new(policy),
                sensors,
                slow_outside: 0,
                folds: 0,
                uploads_ok: 0,
                uploads_rejected: 0,
                last_upload_error: 0,
            })),
            refold: Signal::new(),
            to_host: Pipe::new(),
            to_stage: Pipe::new(),
        }
    }

    /// Put `model` in service (already stored): fold it at the current temperatures at once so
    /// the command path never runs an old fold against a new model, and tell the sensor task.
    pub fn install(&self, model: Model, active: Option<Active>) {
        let comp = self.model.lock(|m| {
            let mut m = m.borrow_mut();
            // the new model's lag filters start primed at the current temperatures
            for (k, spec) in model.lags().iter().enumerate() {
                let t = m.slow.temps_c[usize::from(spec.sensor).min(MAX_TEMPS - 1)];
                m.slow.lagged_c[k] = t;
            }
            let comp = Comp::new(&model, &m.slow);
            m.model = Some(model);
            m.active = active;
            m.generation = m.generation.wrapping_add(1);
            m.folds = m.folds.wrapping_add(1);
            comp
        });
        self.core.lock(|c| c.borrow_mut().comp = Some(comp));
        self.refold.signal(());
    }
}
