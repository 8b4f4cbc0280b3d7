//! The virtual bench on the emulated B-L475E-IOT01A: the shipped STM32 image with the digital
//! twin around it in the same three roles as on the QEMU board
//! (`nanocal::virtual_bench::bench`) — the E-727 and the twin's stage on UART4, the
//! interferometer on TCP, the temperature chips (and the LPS22HB) on SPI1/I2C2 — and the
//! compensator's two USB CDC ports as the campaign's management and GCS links.
//!
//! **Time is the board's**, as in the rig ([`crate::rig`]): plan time `t` is board time
//! `t + offset`; the campaign's [`BenchDriver::wait_until`] runs the board to there, and an
//! exchange runs it only while a port read waits for the reply (the board pauses right after it
//! hands bytes to the host), so every byte reaches the board at a known board time and the run
//! is the same on an idle and on a loaded machine.

use crate::rig::{Chips, Port, Stage, Stm32};
use nanocal::campaign::bench::{BenchDriver, BenchError, ReferenceReader};
use nanocal::campaign::gcs::GcsLink;
use nanocal::campaign::reference::{self, ClockMap, ClockMode};
use nanocal::campaign::run::{CampaignError, Links};
use nanocal::campaign::state::{BenchSpec, VirtualBoard};
use nanocal::data::plan::{Plan, Step};
use nanocal::device::Client;
use nanocal::virtual_bench::bench::{
    spawn_interferometer, twin_buses, twin_controller, twin_pressure, BoardTime,
};
use nanocal::virtual_bench::twin_stage::TwinStage;
use nanocal::virtual_bench::{Buses, Clock as PlanTime, ManualClock};
use nanocal_stm32_board::{Clock, SensorBus, PS};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Plan time the board boots before the plan starts (boot, USB enumeration, settings, upload,
/// the sensors' first conversions), s — the QEMU bench's.
pub const SETUP_S: f64 = nanocal::virtual_bench::bench::VirtualBench::SETUP_S;

/// Board time a port read waits for the compensator's reply: a reply that needs the board's
/// own time (a flash erase during an upload) comes within it.
const REPLY_WITHIN_S: f64 = 10.0;

fn ps(s: f64) -> u64 {
    (s * PS as f64).round() as u64
}

/// Board time as the controller's clock shows it: plan time (board time − `offset_s`).
struct Offset {
    board: ManualClock,
    offset_s: f64,
}

impl PlanTime for Offset {
    fn now_s(&self) -> f64 {
        self.board.now_s() - self.offset_s
    }
}

/// The board's clock as the interferometer follows it: the board pauses between the instants
/// the campaign lets it reach, and the interferometer looks each millisecond (of wall time)
/// whether it moved.
struct BoardClock(Arc<Clock>);

impl BoardTime for BoardClock {
    fn now_s(&self) -> f64 {
        self.0.last_pause().now_ps as f64 / PS as f64
    }
    fn wait_advanced(&self, seen: u64, timeout: Duration) -> u64 {
        let t0 = std::time::Instant::now();
        loop {
            let now = self.0.last_pause().now_ps;
            if now != seen || self.0.stopped() || t0.elapsed() >= timeout {
                return now;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    fn stopped(&self) -> bool {
        self.0.stopped()
    }
}

/// The sensor buses with the LPS22HB reading the twin's air pressure at the board's time.
struct TwinBus {
    chips: Chips,
    stage: Arc<Mutex<TwinStage>>,
    offset_s: f64,
}

impl TwinBus {
    fn pressure_at(&self, now_s: f64) {
        twin_pressure(
            &mut self.chips.0.lock().unwrap(),
            &self.stage,
            now_s - self.offset_s,
        );
    }
}

impl SensorBus for TwinBus {
    fn spi_select(&mut self, cs: usize, now_s: f64) {
        self.chips.spi_select(cs, now_s)
    }
    fn spi_exchange(&mut self, cs: usize, mosi: u8) -> u8 {
        self.chips.spi_exchange(cs, mosi)
    }
    fn spi_deselect(&mut self, cs: usize, now_s: f64) {
        self.chips.spi_deselect(cs, now_s)
    }
    fn i2c_present(&mut self, addr: u8) -> bool {
        self.chips.i2c_present(addr)
    }
    fn i2c_write(&mut self, addr: u8, data: &[u8], now_s: f64) {
        self.pressure_at(now_s);
        self.chips.i2c_write(addr, data, now_s)
    }
    fn i2c_read(&mut self, addr: u8, n: usize, now_s: f64) -> Vec<u8> {
        self.pressure_at(now_s);
        self.chips.i2c_read(addr, n, now_s)
    }
    fn adc(&mut self, ch: u8) -> Option<u16> {
        self.chips.adc(ch)
    }
}

/// The virtual bench on the emulated STM32 board.
pub struct Stm32Bench {
    board: Stm32,
    stage: Arc<Mutex<TwinStage>>,
    /// Commands already handed to the campaign.
    commands_seen: usize,
    /// Board time of plan time 0, s.
    offset_s: f64,
    reference_port: u16,
    stop_reference: Arc<AtomicBool>,
}

impl Stm32Bench {
    /// Power the board on with the twin of `plan` (seed `seed`) around it, for the campaign's
    /// `steps` from step `resume_at` on: the board boots [`SETUP_S`] of plan time before that
    /// step starts.
    pub fn start(
        plan: &Plan,
        steps: &[Step],
        resume_at: usize,
        seed: u64,
    ) -> Result<Self, CampaignError> {
        let twin = nanocal::campaign::virtual_twin(plan, seed)?;
        let traj = nanocal::twin::execute::trajectory(steps);
        let plan_start = steps.get(resume_at).map_or(0.0, |s| s.t_start_s);
        let offset_s = SETUP_S - plan_start;
        let stage = Arc::new(Mutex::new(TwinStage::new(
            &twin,
            &traj,
            nanocal::twin::examples::TRAINING_START_S,
            seed,
        )));
        let board_time = ManualClock::new();
        let ctl = twin_controller(
            &traj,
            twin.cfg.axes,
            stage.clone(),
            Arc::new(Offset {
                board: board_time.clone(),
                offset_s,
            }),
        );
        let buses: Arc<Mutex<Buses>> =
            Arc::new(Mutex::new(twin_buses(&twin, &stage, offset_s, seed)));
        let bus = Arc::new(Mutex::new(TwinBus {
            chips: Chips(buses.clone()),
            stage: stage.clone(),
            offset_s,
        }));
        let board = Stm32::start_on(buses, bus, Stage::with_controller(ctl, board_time), None);
        // the USB cable is in from power-on (the host enumerates the board once it is up)
        board.usb.attach();
        let stop_reference = Arc::new(AtomicBool::new(false));
        let reference_port = spawn_interferometer(
            Arc::new(BoardClock(board.clock().clone())),
            stage.clone(),
            offset_s,
            f64::INFINITY,
            stop_reference.clone(),
        );
        Ok(Self {
            board,
            stage,
            commands_seen: 0,
            offset_s,
            reference_port,
            stop_reference,
        })
    }

    /// The compensator's CDC port `k` (0: GCS, 1: management), once the board has enumerated;
    /// its reads run the board (a reply within [`REPLY_WITHIN_S`] of board time).
    fn port(&self, k: usize) -> Port {
        let mut p = self.board.port(k);
        p.reply_within_s = REPLY_WITHIN_S;
        p
    }

    /// The campaign's links on this bench: the driver, management (CDC port 1), GCS (CDC port
    /// 0) and the interferometer. The ports cannot be reopened (the emulated board's USB
    /// resets are not staged by a campaign).
    pub fn links(self, axes: usize) -> Result<Links, CampaignError> {
        let device = Client::new(
            Box::new(self.port(1)),
            "stm32:management",
            // a guard against an emulator hang only: the port gives up in board time
            Duration::from_secs(3600),
        );
        let mut gcs = GcsLink::new(Box::new(self.port(0)), "stm32:gcs");
        gcs.timeout = Duration::from_secs(3600);
        let spec = format!("tcp:127.0.0.1:{}", self.reference_port);
        let src = reference::open(&spec, axes, 1.0)?;
        let reference = ReferenceReader::new(src, ClockMap::new(ClockMode::Synchronized));
        Ok(Links {
            driver: Box::new(self),
            device,
            gcs,
            reference,
            reopen: None,
        })
    }

    /// What the emulated board has done so far.
    pub fn status(&self) -> nanocal_stm32_board::Status {
        self.board.status()
    }
}

impl Drop for Stm32Bench {
    fn drop(&mut self) {
        self.stop_reference.store(true, Ordering::Release);
    }
}

impl BenchDriver for Stm32Bench {
    fn now_s(&self) -> f64 {
        self.board.now_s() - self.offset_s
    }

    fn wait_until(&mut self, t_s: f64, stop: &AtomicBool) -> Result<bool, BenchError> {
        if stop.load(Ordering::Acquire) {
            return Ok(false);
        }
        let end = ps(t_s + self.offset_s);
        let clock = self.board.clock().clone();
        // the board pauses by itself after it hands the host bytes: run on to the end
        while clock.last_pause().now_ps < end {
            clock.run_to(end);
            if clock.stopped() {
                return Err(BenchError::Other(format!(
                    "the emulated board stopped: {:?}",
                    self.board.status().halt
                )));
            }
        }
        Ok(true)
    }

    fn exchange(&mut self, op: &mut (dyn FnMut() + Send)) -> Result<(), BenchError> {
        // the ports' reads run the board while they wait (see [`crate::rig::Port`])
        op();
        if self.board.clock().stopped() {
            return Err(BenchError::Other(format!(
                "the emulated board stopped: {:?}",
                self.board.status().halt
            )));
        }
        Ok(())
    }

    fn stage_commands(&mut self) -> Option<Vec<(f64, Vec<f64>)>> {
        // the controller runs on the board's thread, which is paused: it has acted on every
        // byte the board sent. The campaign asks after the move's `ERR?` and a status read: the
        // move was always there by then (a campaign of 4 training cycles that waited up to
        // 50 ms of board time for a late one never found one)
        let st = self.stage.lock().unwrap();
        let new = st.commands()[self.commands_seen..].to_vec();
        self.commands_seen = st.commands().len();
        Some(new)
    }
}

/// Opens the STM32 bench for [`nanocal::campaign::run_on`]: the twin's seed is the bench
/// specification's (a resumed campaign's is its state's).
pub fn open(
    spec: &BenchSpec,
    plan: &Plan,
    steps: &[Step],
    resume_at: usize,
) -> Result<Links, CampaignError> {
    let seed = match spec {
        BenchSpec::Virtual {
            seed,
            board: VirtualBoard::Stm32,
        } => *seed,
        other => {
            return Err(CampaignError::NotReady {
                step: resume_at,
                what: format!(
                    "the STM32 bench runs virtual campaigns on the stm32 board, not {other:?}"
                ),
            })
        }
    };
    Stm32Bench::start(plan, steps, resume_at, seed)?.links(plan.training.axes())
}
