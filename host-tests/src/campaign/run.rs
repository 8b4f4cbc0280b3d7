//! The campaign's steps: drive the stage through the compensator along the plan, record as it
//! goes, fit at the end of training, switch the compensator between the validation tests'
//! compensations, re-measure the KMZ, and survive what a bench of days meets.
//!
//! Per step `k` (plan time `t_k`):
//! 1. let time run to `t_k`; the reference samples before `t_k` complete step `k − 1` (its rows
//!    are written, and a KMZ step sends its measurement to the compensator);
//! 2. commit the recording and the state (a resume restarts at step `k`);
//! 3. read the compensator's status; a reset is noticed here (the mode is set again, a lost
//!    model uploaded again), a failed sensor stops the campaign;
//! 4. `MOV` the target, then `ERR?`: a refusal stops the campaign with the compensator's reason;
//!    with a model in service, read the status again: the same fold counter as before the move
//!    means the move was corrected with that fold, whose temperatures and aux inputs the rows of
//!    step `k` carry; otherwise the move is sent again (see `move_with_known_fold`);
//! 5. set the compensator up for step `k + 1` (bypass, model, λ_KMZ) during `k`'s hold, while
//!    the stage stands still.

use super::bench::{BenchDriver, BenchError, ReferenceReader};
use super::gcs::{GcsError, GcsLink};
use super::recorder::{Recorder, RecorderError, Row};
use super::reference::ReferenceError;
use super::state::{Interruption, Stage, StaleEvent, State, StateError, UploadedModel};
use crate::data::plan::{Phase, Plan, Step, TestKind};
use crate::device::{Client, DeviceError};
use crate::fit::{adaptive_from_static, encode_blob};
use nanocal_interface::status::{ChannelStatus, Flags, Status};
use nanocal_interface::GcsErrorCode;
use nanocal_model::{Model, ModelBuilder, MAX_AXES};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// GCS error 2, "unknown command": the controller executed nothing of the line.
const GCS_UNKNOWN_COMMAND: i32 = 2;

/// Errors of a campaign. Every one leaves what was recorded on disk and the state to resume from.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CampaignError {
    /// The compensator's management channel.
    #[error("compensator: {0}")]
    Device(#[from] DeviceError),
    /// The GCS link.
    #[error("{0}")]
    Gcs(#[from] GcsError),
    /// The reference instrument.
    #[error("{0}")]
    Reference(#[from] ReferenceError),
    /// The bench's time.
    #[error("{0}")]
    Bench(#[from] BenchError),
    /// The recording.
    #[error("{0}")]
    Recorder(#[from] RecorderError),
    /// The state file.
    #[error("{0}")]
    State(#[from] StateError),
    /// A pose of the plan lies outside the stage's travel.
    #[error("step {step}: pose {pose_um} µm on axis {axis} is outside the stage's travel [{min}, {max}] (TMN?/TMX?); fix the plan or the controller's limits")]
    OutsideTravel {
        /// First step with that pose.
        step: usize,
        /// GCS axis.
        axis: String,
        /// The pose.
        pose_um: f64,
        /// Travel minimum.
        min: f64,
        /// Travel maximum.
        max: f64,
    },
    /// The compensator or the controller refused a move.
    #[error(
        "step {step} (plan time {t_s:.0} s): `{command}` refused with GCS error {code} ({meaning})"
    )]
    Refused {
        /// Step.
        step: usize,
        /// Plan time.
        t_s: f64,
        /// The command.
        command: String,
        /// `ERR?` code.
        code: i32,
        /// What it means.
        meaning: String,
    },
    /// A temperature sensor or aux input failed mid-campaign.
    #[error("step {step} (plan time {t_s:.0} s): {what}; the recording up to step {step} is kept — fix it and run again with --resume")]
    SensorFault {
        /// Step.
        step: usize,
        /// Plan time.
        t_s: f64,
        /// Which input and how.
        what: String,
    },
    /// Fitting the models failed.
    #[error("fit at the end of training: {0}")]
    Fit(String),
    /// The compensator did not come back ready.
    #[error("step {step}: the compensator is not ready ({what})")]
    NotReady {
        /// Step.
        step: usize,
        /// What it reports.
        what: String,
    },
    /// Ctrl-C.
    #[error("interrupted at step {step} (plan time {t_s:.0} s); the stage is at the safe pose, everything recorded is kept; continue with --resume")]
    Interrupted {
        /// Step under way.
        step: usize,
        /// Plan time.
        t_s: f64,
    },
}

/// What a GCS error code answered to the campaign's `ERR?` means: the codes the compensator
/// raises itself (9001–9016, and PI's 1, 7, 15 and 22) from the one table both the firmware and the
/// host use ([`GcsErrorCode`]), the other PI codes a campaign meets from PI's own list.
pub fn gcs_meaning(code: i32) -> &'static str {
    if let Some(e) = GcsErrorCode::from_code(code) {
        return e.meaning();
    }
    match code {
        0 => "no error",
        2 => "unknown command",
        5 => "servo off or axis not referenced",
        10 => "stopped by command",
        _ => "an error of the controller: see its manual's error codes",
    }
}

/// The compensator's configuration a step needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mode {
    /// Commands pass untouched.
    pub bypass: bool,
    /// The model that must be in service (None: whichever).
    pub model: Option<TestKind>,
}

/// The mode of a step: training, KMZ and no-model tests in bypass (the command is the target;
/// a KMZ step keeps the adaptive model loaded for the measurement it sends), the model tests
/// compensated.
pub fn mode_of(phase: Phase) -> Mode {
    match phase {
        Phase::Training
        | Phase::Test {
            kind: TestKind::NoModel,
            ..
        } => Mode {
            bypass: true,
            model: None,
        },
        Phase::Kmz { .. } => Mode {
            bypass: true,
            model: Some(TestKind::Adaptive),
        },
        Phase::Test { kind, .. } => Mode {
            bypass: false,
            model: Some(kind),
        },
    }
}

/// Model ids the campaign gives its static and adaptive models.
pub const MODEL_IDS: (u32, u32) = (0x0CA1_0001, 0x0CA1_0002);

/// The fitted models.
pub struct Models {
    /// Static model (Eq. 11).
    pub static_model: Model,
    /// Adaptive model (Eq. 14), λ_KMZ as fitted.
    pub adaptive: Model,
}

impl Models {
    /// Read the blobs from `dir`.
    pub fn load(dir: &Path) -> Result<Models, CampaignError> {
        let read = |name: &str| -> Result<Model, CampaignError> {
            let b = std::fs::read(dir.join(name))
                .map_err(|e| CampaignError::Fit(format!("{name}: {e}")))?;
            nanocal_model::blob::decode(&b).map_err(|e| CampaignError::Fit(format!("{name}: {e}")))
        };
        Ok(Models {
            static_model: read("static.blob")?,
            adaptive: read("adaptive.blob")?,
        })
    }

    /// The plan's models: the static model before any loop of the validate-and-return loop
    /// refitted it (`static-0.blob`, written when the first loop starts), and the adaptive one.
    pub fn load_plan(dir: &Path) -> Result<Models, CampaignError> {
        let mut m = Models::load(dir)?;
        if let Ok(b) = std::fs::read(dir.join(static_blob(0))) {
            m.static_model = nanocal_model::blob::decode(&b)
                .map_err(|e| CampaignError::Fit(format!("{}: {e}", static_blob(0))))?;
        }
        Ok(m)
    }

    /// The adaptive model with `kmz_um` as its λ_KMZ (what the compensator must hold).
    pub fn adaptive_with(&self, kmz_um: Option<&[f64]>) -> Model {
        let Some(k) = kmz_um else {
            return self.adaptive.clone();
        };
        let mut m = self.adaptive.clone();
        for (a, v) in k.iter().enumerate().take(m.axes()) {
            m.set_kmz_offset_um(a, *v);
        }
        m
    }
}

/// File name of the static model of loop `l` of the validate-and-return loop (0: the plan's).
pub fn static_blob(l: usize) -> String {
    format!("static-{l}.blob")
}

/// Fits the static model (stepwise among `spec`'s candidates, as paper 000 §3.3 trains) and
/// derives the adaptive one (Eq. 14) from the training steps recorded so far; writes the blobs.
pub fn fit_models(
    dir: &Path,
    recording: &Path,
    steps: &[Step],
    spec: crate::fit::design::DesignSpec,
) -> Result<Models, CampaignError> {
    use crate::fit::{fit_dwells, FitOptions, Selection};
    let fit_err = |e: String| CampaignError::Fit(e);
    let rec = crate::data::recording::Recording::read_path(recording)
        .map_err(|e| fit_err(e.to_string()))?;
    let training: Vec<Step> = steps
        .iter()
        .filter(|s| s.phase == Phase::Training)
        .cloned()
        .collect();
    let data = crate::validate::procedure::ProcedureData::new(&rec, &training, 0.0)
        .map_err(|e| fit_err(e.to_string()))?;
    let fit = fit_dwells(
        &data.training(),
        &FitOptions {
            spec,
            selection: Selection::Stepwise(crate::numerics::stepwise::StepwiseOptions::default()),
            dwell: Default::default(),
            id: MODEL_IDS.0,
        },
    )
    .map_err(|e| fit_err(e.to_string()))?;
    let adaptive = adaptive_from_static(&fit.model).map_err(|e| fit_err(format!("{e:?}")))?;
    let adaptive = ModelBuilder::from_model(&adaptive)
        .id(MODEL_IDS.1)
        .build()
        .map_err(|e| fit_err(format!("{e:?}")))?;
    let write = |name: &str, m: &Model| {
        std::fs::write(dir.join(name), encode_blob(m)).map_err(|e| fit_err(format!("{name}: {e}")))
    };
    write("static.blob", &fit.model)?;
    write("adaptive.blob", &adaptive)?;
    Ok(Models {
        static_model: fit.model,
        adaptive,
    })
}

/// What the campaign talks to.
pub struct Links {
    /// The bench's time (and, on the virtual bench, what the stage received).
    pub driver: Box<dyn BenchDriver>,
    /// The compensator's management channel.
    pub device: Client,
    /// The compensator's GCS port.
    pub gcs: GcsLink,
    /// The reference instrument.
    pub reference: ReferenceReader,
    /// Opens the compensator's two ports again, when they went away (a device reset on USB
    /// re-enumerates both); `None`: they cannot be reopened.
    pub reopen: Option<Reopen>,
}

impl Links {
    /// The bench's time and the management channel, for one exchange.
    fn management(&mut self) -> (&mut dyn BenchDriver, &mut Client) {
        (self.driver.as_mut(), &mut self.device)
    }

    /// The bench's time and the GCS port, for one exchange.
    fn gcs_port(&mut self) -> (&mut dyn BenchDriver, &mut GcsLink) {
        (self.driver.as_mut(), &mut self.gcs)
    }

    /// Replace both port handles with gone ones (the old ones close: a serial device or QEMU's
    /// socket serves one client).
    fn drop_ports(&mut self) {
        self.device = Client::new(Box::new(GonePort), "gone", Duration::from_secs(1));
        self.gcs = GcsLink::new(Box::new(GonePort), "gone");
    }
}

/// Opens (management, GCS) to the compensator again.
pub type Reopen = Box<dyn FnMut() -> Result<(Client, GcsLink), CampaignError> + Send>;

/// How long the campaign tries to reopen the compensator's ports after they went away: a reset
/// and USB enumeration take a few seconds; a board that stays away is an error.
const REOPEN_WITHIN: Duration = Duration::from_secs(30);

/// A port that is gone (what the campaign's handles become when the compensator's USB ports go
/// away, staged by [`Runner::ports_lost_before_step`]).
struct GonePort;

impl std::io::Read for GonePort {
    fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
        Err(std::io::ErrorKind::BrokenPipe.into())
    }
}

impl std::io::Write for GonePort {
    fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
        Err(std::io::ErrorKind::BrokenPipe.into())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Err(std::io::ErrorKind::BrokenPipe.into())
    }
}

/// `s` shows `want` loaded, with its λ_KMZ: the model the campaign uploaded last
/// (`uploaded`, its id and blob CRC as the device confirmed them) is in service, and it is
/// `want`. The id alone is not enough: a model of an earlier campaign (or an earlier fit) on
/// the device has the same id and other coefficients; the blob's CRC tells them apart.
fn serves(s: &Status, want: &Model, uploaded: Option<UploadedModel>) -> bool {
    s.flags.contains(Flags::MODEL)
        && s.model_id == want.id()
        && uploaded.is_some_and(|u| u.model_id == s.model_id && u.model_crc32 == s.model_crc32)
        && (0..want.axes()).all(|a| (s.kmz_um[a] - want.kmz_offset_um(a)).abs() < 1e-9)
}

/// True for an error that says the port itself is gone (not a slow or refusing device).
fn port_gone(e: &CampaignError) -> bool {
    matches!(
        e,
        CampaignError::Device(DeviceError::Io { .. })
            | CampaignError::Gcs(GcsError::Io { .. } | GcsError::Open(_))
    )
}

/// Progress report of the steps (the CLI draws it).
pub trait Progress {
    /// Step `k` of `n` starts; `what` names the phase and test.
    fn step(&mut self, k: usize, n: usize, what: &str);
    /// A note (a reset seen, a model uploaded, a KMZ).
    fn note(&mut self, text: &str);
}

/// No progress report (for the tests).
#[cfg(feature = "test-support")]
pub struct Quiet;

#[cfg(feature = "test-support")]
impl Progress for Quiet {
    fn step(&mut self, _k: usize, _n: usize, _what: &str) {}
    fn note(&mut self, _text: &str) {}
}

/// The steps of a campaign.
pub struct Runner<'a> {
    /// The campaign's folder.
    pub dir: PathBuf,
    /// The plan.
    pub plan: &'a Plan,
    /// Its schedule.
    pub steps: Vec<Step>,
    /// The state (saved at the start of a step, at most once a second).
    pub state: State,
    /// Links to the bench.
    pub links: Links,
    /// GCS axis identifiers, per plan axis.
    pub axes: Vec<String>,
    /// Design of the static model.
    pub spec: crate::fit::design::DesignSpec,
    recorder: Recorder,
    stop: Arc<AtomicBool>,
    models: Option<Models>,
    status: Option<Status>,
    /// Command in force (what the stage received), µm.
    cmd_um: Vec<f64>,
    temps: Vec<f32>,
    aux: Vec<f32>,
    /// Reference samples of the current step's averaging window.
    window: Vec<Vec<f64>>,
    /// Wall time spent per part of a step (`NANOCAL_CAMPAIGN_PROFILE=1` prints it).
    profile: Profile,
    /// Reset the compensator during the hold before this step (a staged fault, for tests).
    pub reset_before_step: Option<usize>,
    /// With that reset, the campaign's port handles die, as a USB device's do when it
    /// resets and enumerates again (a staged fault, for tests).
    pub ports_lost_before_step: Option<usize>,
    /// Wall time of the last state save.
    saved_at: std::time::Instant,
}

/// Longest wall time between two saves of the state during the steps.
const SAVE_EVERY: Duration = Duration::from_secs(1);

/// Wall time per part of the steps, s.
#[derive(Debug, Default, Clone, Copy)]
pub struct Profile {
    /// Letting the bench's time run.
    pub wait_s: f64,
    /// Reading the reference and writing rows.
    pub collect_s: f64,
    /// Status reads (wherever they happen).
    pub status_s: f64,
    /// Setting the compensator up (bypass, uploads, KMZ).
    pub setup_s: f64,
    /// `MOV` + `ERR?` (and what sets the compensator up for the step, besides status reads).
    pub mov_s: f64,
    /// Recording commits and state saves.
    pub save_s: f64,
}

fn describe(phase: Phase, plan: &Plan) -> String {
    match phase {
        Phase::Training => "training".into(),
        Phase::Kmz { test, visit: true } => {
            format!("KMZ, first visit of test {}/{}", test + 1, plan.tests())
        }
        Phase::Kmz { test, .. } => format!("KMZ before test {}/{}", test + 1, plan.tests()),
        Phase::Test { test, kind } => {
            format!("test {}/{} ({})", test + 1, plan.tests(), kind.name())
        }
    }
}

impl<'a> Runner<'a> {
    /// A runner over `links`, recording into `recorder`, starting at `state.next_step`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        dir: &Path,
        plan: &'a Plan,
        steps: Vec<Step>,
        state: State,
        links: Links,
        axes: Vec<String>,
        spec: crate::fit::design::DesignSpec,
        recorder: Recorder,
        stop: Arc<AtomicBool>,
    ) -> Result<Self, CampaignError> {
        let models = if state.model_ids.is_some() {
            Some(Models::load(dir)?)
        } else {
            None
        };
        let n = plan.training.axes();
        let first = steps
            .get(state.next_step.saturating_sub(1))
            .map(|s| s.target_um.clone())
            .unwrap_or(vec![f64::NAN; n]);
        Ok(Self {
            dir: dir.to_path_buf(),
            plan,
            steps,
            state,
            links,
            axes,
            spec,
            recorder,
            stop,
            models,
            status: None,
            cmd_um: first,
            temps: Vec::new(),
            aux: Vec::new(),
            window: Vec::new(),
            profile: Profile::default(),
            reset_before_step: None,
            ports_lost_before_step: None,
            saved_at: std::time::Instant::now(),
        })
    }

    /// Where the wall time went.
    pub fn profile(&self) -> Profile {
        self.profile
    }

    /// The stage's travel covers every pose of the plan (asked of the controller through the
    /// compensator: `TMN?`/`TMX?` pass through).
    pub fn check_travel(&mut self) -> Result<(), CampaignError> {
        let mut lims = None;
        let (gcs, axes) = (&mut self.links.gcs, &self.axes);
        let mut op = || {
            lims = Some(
                gcs.axis_values("TMN?", axes)
                    .and_then(|lo| gcs.axis_values("TMX?", axes).map(|hi| (lo, hi))),
            )
        };
        self.links.driver.exchange(&mut op)?;
        let (lo, hi) = lims.expect("ran")?;
        for (k, s) in self.steps.iter().enumerate() {
            for (a, &p) in s.target_um.iter().enumerate() {
                if !(p >= lo[a] && p <= hi[a]) {
                    return Err(CampaignError::OutsideTravel {
                        step: k,
                        axis: self.axes[a].clone(),
                        pose_um: p,
                        min: lo[a],
                        max: hi[a],
                    });
                }
            }
        }
        Ok(())
    }

    fn t_now(&self) -> f64 {
        self.links.driver.now_s()
    }

    /// Write the state now.
    pub fn save(&mut self) -> Result<(), CampaignError> {
        self.state.save(&self.dir)?;
        self.saved_at = std::time::Instant::now();
        Ok(())
    }

    /// Read the models from the campaign's folder again (a loop of the validate-and-return
    /// loop refitted the static one).
    pub fn reload_models(&mut self) -> Result<(), CampaignError> {
        self.models = Some(Models::load(&self.dir)?);
        Ok(())
    }

    /// Run one exchange with the management channel (see [`Self::exchange`]).
    fn device<T: Send>(
        &mut self,
        f: impl FnMut(&mut Client) -> Result<T, DeviceError> + Send,
    ) -> Result<T, CampaignError> {
        self.exchange(Links::management, f)
    }

    /// Run one exchange on the GCS link (see [`Self::exchange`]).
    fn gcs<T: Send>(
        &mut self,
        f: impl FnMut(&mut GcsLink) -> Result<T, GcsError> + Send,
    ) -> Result<T, CampaignError> {
        self.exchange(Links::gcs_port, f)
    }

    /// Run `f` on the link `on` picks, as one exchange of the bench; if the port is gone,
    /// reopen both ports and run it once more (every exchange the campaign makes can be
    /// repeated: absolute moves, reads, uploads from the start, a KMZ from the same
    /// measurement).
    fn exchange<L: Send, T: Send, E: Send>(
        &mut self,
        on: fn(&mut Links) -> (&mut dyn BenchDriver, &mut L),
        mut f: impl FnMut(&mut L) -> Result<T, E> + Send,
    ) -> Result<T, CampaignError>
    where
        CampaignError: From<E>,
    {
        let (driver, link) = on(&mut self.links);
        match exchange_on(driver, link, &mut f) {
            Err(e) if port_gone(&e) && self.reopen_ports(&e)? => {
                let (driver, link) = on(&mut self.links);
                exchange_on(driver, link, &mut f)
            }
            r => r,
        }
    }

    /// `MOV` (`line`) and its `ERR?`: the controller's error code.
    fn send_move(&mut self, line: &str) -> Result<i32, CampaignError> {
        self.gcs(|g| {
            g.send(line)?;
            g.error()
        })
    }

    /// The compensator's ports went away (`why`): open both again, trying for
    /// [`REOPEN_WITHIN`]. Ok(false): they cannot be reopened here (the error stands). The
    /// next status read sees the device's reset and sets it up again.
    fn reopen_ports(&mut self, why: &CampaignError) -> Result<bool, CampaignError> {
        let Some(mut reopen) = self.links.reopen.take() else {
            return Ok(false);
        };
        // the old handles close first
        self.links.drop_ports();
        let start = std::time::Instant::now();
        let opened = loop {
            match reopen() {
                Err(_) if start.elapsed() < REOPEN_WITHIN => {
                    std::thread::sleep(Duration::from_millis(500));
                }
                r => break r,
            }
        };
        self.links.reopen = Some(reopen);
        let (device, gcs) = opened?;
        self.links.device = device;
        self.links.gcs = gcs;
        let k = self.state.next_step;
        self.state.interruptions.push(Interruption {
            step: k,
            plan_time_s: self.t_now(),
            what: format!(
                "the compensator's ports went away ({why}); reopened after {:.1} s",
                start.elapsed().as_secs_f64()
            ),
        });
        Ok(true)
    }

    /// Write the rows of every reference sample before `t_end_s` (they belong to the step under
    /// way); keeps the samples of its averaging window.
    fn collect(&mut self, t_end_s: f64, window_from_s: f64) -> Result<(), CampaignError> {
        let now = self.t_now();
        // A sample at a step's start (within rounding: steps start at sums of non-integer
        // durations, samples come on whole periods) is the next step's first row, as
        // `dwell::step_average` reads the recording (rows from `t_start − STEP_EDGE_S`): written here
        // with the previous step's command, the file-based validation took that command for
        // the next step's (a no-model → static test boundary at pose 0 made 250 nm of
        // repeatability on the emulated STM32 board, whose moves land milliseconds after the
        // step's start). Before, the sample went one way or the other by when it arrived.
        let samples = self
            .links
            .reference
            .until(t_end_s - crate::data::dwell::STEP_EDGE_S, now)?;
        for (t, pos) in samples {
            if t < 0.0 {
                continue; // before the plan
            }
            if t >= window_from_s {
                self.window.push(pos.clone());
            }
            self.recorder.row(&Row {
                t_s: t,
                cmd_um: &self.cmd_um,
                meas_um: &pos,
                temps_c: &self.temps,
                aux: &self.aux,
            })?;
        }
        Ok(())
    }

    /// Mean of the averaging window's samples per axis.
    fn window_mean(&self) -> Option<Vec<f64>> {
        if self.window.is_empty() {
            return None;
        }
        let n = self.window.len() as f64;
        let k = self.window[0].len();
        Some(
            (0..k)
                .map(|a| self.window.iter().map(|p| p[a]).sum::<f64>() / n)
                .collect(),
        )
    }

    /// Step `k` is over (its window collected): a KMZ step computes λ_KMZ from its reading
    /// (paper 000 §3.4: the difference of two readings at the KMZ pose,
    /// [`crate::data::kmz::KmzDrift`]) and sends it to the compensator.
    fn finish(&mut self, k: usize) -> Result<(), CampaignError> {
        if let Phase::Kmz { .. } = self.steps[k].phase {
            let x = self.window_mean().ok_or_else(|| CampaignError::NotReady {
                step: k,
                what: "no reference sample in the KMZ step's averaging window".into(),
            })?;
            let models = self.models.as_ref().ok_or_else(|| {
                CampaignError::Fit("a KMZ step before the models were fitted".into())
            })?;
            let mut q = [0.0; MAX_AXES];
            let mut xm = [0.0; MAX_AXES];
            let mut dir = [0i8; MAX_AXES];
            let n = x.len();
            q[..n].copy_from_slice(&self.cmd_um[..n]);
            xm[..n].copy_from_slice(&x);
            dir[..n].copy_from_slice(&self.steps[k].approach[..n]);
            let mut model = models.adaptive_with(self.state.kmz_um.as_deref());
            let mut drift = crate::data::kmz::KmzDrift::new(self.state.kmz_first);
            let slow = nanocal_model::SlowInputs::default();
            let kmz = drift.measure(
                &mut model,
                &q,
                &xm,
                &dir,
                &slow,
                &nanocal_model::HysteresisState::new(),
            );
            let (rq, rx) = crate::data::kmz::set_kmz_request(&model, &kmz, &xm, &slow);
            let held = self.device(move |c| c.set_kmz(rq, rx))?;
            self.state.kmz_first = drift.first();
            self.state.kmz_um = Some(held[..n].to_vec());
            self.state.kmz_updates += 1;
        }
        Ok(())
    }

    /// Read the status; notice a reset; stop on a failed input.
    fn read_status(&mut self, k: usize) -> Result<Status, CampaignError> {
        let t0 = std::time::Instant::now();
        let s = self.device(|c| c.status())?;
        self.profile.status_s += t0.elapsed().as_secs_f64();
        if let Some(prev) = &self.status {
            if s.uptime_ms < prev.uptime_ms {
                self.state.device_resets += 1;
                self.state.interruptions.push(Interruption {
                    step: k,
                    plan_time_s: self.t_now(),
                    what: format!("compensator reset (cause code {})", s.reset_cause),
                });
            }
        }
        self.note_stale(k, &s);
        self.status = Some(s);
        Ok(s)
    }

    /// Record a rise of `MODEL_STALE` the first time a status shows it, with the plan time of
    /// the rise (the device's uptime at the rise mapped onto the plan's clock).
    fn note_stale(&mut self, k: usize, s: &Status) {
        if !s.flags.contains(Flags::MODEL_STALE) {
            return;
        }
        let seen =
            |e: &StaleEvent| e.model_crc32 == s.model_crc32 && e.since_ms == s.stale_since_ms;
        if self.state.stale.iter().any(seen) {
            return;
        }
        let ago_s = f64::from(s.uptime_ms.wrapping_sub(s.stale_since_ms)) / 1000.0;
        let kind = match self.state.model_ids {
            Some((st, _)) if st == s.model_id => Some(TestKind::Static),
            Some((_, ad)) if ad == s.model_id => Some(TestKind::Adaptive),
            _ => None,
        };
        let model = kind.map_or_else(
            || format!("{:#010x}", s.model_id),
            |t| {
                if t == TestKind::Static {
                    "static".into()
                } else {
                    "adaptive".into()
                }
            },
        );
        // the step the model serves: a model is set up during the hold of the step before its
        // test, so the status may show it (and its rise) one step early
        let serves = (k..self.steps.len())
            .find(|&j| kind.is_some() && mode_of(self.steps[j].phase).model == kind)
            .unwrap_or(k);
        let event = StaleEvent {
            rose_s: self.t_now() - ago_s,
            step: serves,
            during: describe(self.steps[serves].phase, self.plan),
            model,
            model_crc32: s.model_crc32,
            reasons: s.stale.to_string(),
            envelope_excess_c: Some(s.envelope_excess_c).filter(|v| v.is_finite()),
            since_ms: s.stale_since_ms,
        };
        self.state.stale.push(event);
    }

    /// Every input the recording carries has a reading (Ok(false): some have none yet, as
    /// after a reset); a failed one is an error.
    fn inputs_ok(&self, k: usize, s: &Status) -> Result<bool, CampaignError> {
        let t_s = self.steps[k].t_start_s;
        let mut ready = true;
        let layout = &self.state.layout;
        let temps = layout.temps.iter().enumerate().map(|(i, n)| {
            (
                format!("temperature sensor temp_{n} (chip-select {i})"),
                s.sensor_bits[i],
                s.temps_c[i],
            )
        });
        let aux = layout
            .aux
            .iter()
            .enumerate()
            .map(|(i, n)| (format!("aux input {n}"), s.aux_bits[i], s.aux[i]));
        for (what, bits, v) in temps.chain(aux) {
            match bits.state {
                ChannelStatus::Failed => {
                    return Err(CampaignError::SensorFault {
                        step: k,
                        t_s,
                        what: format!(
                            "{what} failed ({})",
                            bits.last_fault
                                .map_or_else(|| "no valid reading".into(), |f| f.to_string())
                        ),
                    })
                }
                ChannelStatus::NotRead => ready = false,
                _ if !v.is_finite() => ready = false,
                _ => {}
            }
        }
        Ok(ready)
    }

    /// The status once every input has a reading (waits on the bench's time, a few sample
    /// periods at most).
    fn ready_status(&mut self, k: usize) -> Result<Status, CampaignError> {
        let until = self.t_now() + 4.0 * f64::from(self.state.sample_period_ms) / 1000.0 + 5.0;
        loop {
            let s = self.read_status(k)?;
            if self.inputs_ok(k, &s)? {
                return Ok(s);
            }
            if self.t_now() > until {
                return Err(CampaignError::SensorFault {
                    step: k,
                    t_s: self.steps[k].t_start_s,
                    what: "a temperature or aux input has no reading".into(),
                });
            }
            let t = self.t_now() + 0.1;
            if !self.links.driver.wait_until(t, &self.stop)? {
                return Err(CampaignError::Interrupted {
                    step: k,
                    t_s: self.t_now(),
                });
            }
        }
    }

    /// The model `kind` as it must be in service now (the adaptive one with the λ_KMZ last
    /// measured).
    fn wanted_model(&self, kind: TestKind) -> Result<Model, CampaignError> {
        let models = self.models.as_ref().ok_or_else(|| {
            CampaignError::Fit("a model test before the models were fitted".into())
        })?;
        Ok(match kind {
            TestKind::Adaptive => models.adaptive_with(self.state.kmz_um.as_deref()),
            _ => models.static_model.clone(),
        })
    }

    /// `s` shows the compensator in `mode`, ready for moves: bypass as the mode says, and the
    /// model it needs in service with the λ_KMZ last measured and every input read.
    fn set_up_for(&self, s: &Status, mode: Mode) -> bool {
        if s.flags.contains(Flags::BYPASS) != mode.bypass {
            return false;
        }
        let Some(kind) = mode.model else {
            return true;
        };
        let Ok(want) = self.wanted_model(kind) else {
            return false;
        };
        !s.flags.contains(Flags::WARMING_UP) && serves(s, &want, self.state.uploaded)
    }

    /// The move of a step with one status read instead of two, when the compensator reports
    /// which fold corrected its last move ([`Flags::MOVE_FOLD`], firmware since 2026-11): send
    /// the move and its `ERR?`, then read the status; it is the step's if the device is still
    /// set up for `mode` (no reset), every input has a reading, and the move met the fold the
    /// status shows (`move_fold == folds`; in bypass no fold touches the move). `None`: any of
    /// that is not so — then the step takes the full path (status, set-up, move again), which
    /// says what is wrong. The status read before the move is the previous step's: the device
    /// was set up for this step at its end.
    fn quick_move(
        &mut self,
        k: usize,
        mode: Mode,
        line: &str,
    ) -> Result<Option<(i32, Status)>, CampaignError> {
        let Some(prev) = self.status else {
            return Ok(None);
        };
        if !prev.flags.contains(Flags::MOVE_FOLD) || !self.set_up_for(&prev, mode) {
            return Ok(None);
        }
        let resets = self.state.device_resets;
        let code = self.send_move(line)?;
        let s = self.read_status(k)?;
        let ours = code == 0
            && self.state.device_resets == resets
            && self.inputs_ok(k, &s)?
            && self.set_up_for(&s, mode)
            && (mode.bypass || (s.folds != 0 && s.move_fold == s.folds));
        Ok(ours.then_some((code, s)))
    }

    /// Put the compensator in `mode` (upload the model it needs — the adaptive one with the
    /// λ_KMZ last measured — and set bypass), and wait until it can take moves.
    fn apply(&mut self, k: usize, mode: Mode) -> Result<(), CampaignError> {
        let mut s = match self.status {
            Some(s) => s,
            None => self.read_status(k)?,
        };
        if let Some(kind) = mode.model {
            let want = self.wanted_model(kind)?;
            if !serves(&s, &want, self.state.uploaded) {
                let blob = encode_blob(&want);
                // the device confirms the blob's CRC (`Client::upload`)
                let c = self.device(move |c| c.upload(&blob))?;
                self.state.uploaded = Some(UploadedModel {
                    model_id: c.model_id,
                    model_crc32: c.model_crc32,
                });
                s = self.read_status(k)?;
            }
            // the first fold of a new model waits for every input's reading
            let until = self.t_now() + 2.0 * f64::from(self.state.sample_period_ms) / 1000.0 + 5.0;
            while s.flags.contains(Flags::WARMING_UP) {
                if self.t_now() > until {
                    return Err(CampaignError::NotReady {
                        step: k,
                        what: "the model's inputs never got a valid reading".into(),
                    });
                }
                let t = self.t_now() + 0.1;
                if !self.links.driver.wait_until(t, &self.stop)? {
                    break;
                }
                s = self.read_status(k)?;
            }
        }
        if s.flags.contains(Flags::BYPASS) != mode.bypass {
            let on = mode.bypass;
            self.device(move |c| c.bypass(on))?;
            s = self.read_status(k)?;
        }
        self.status = Some(s);
        Ok(())
    }

    /// Send `line` (a `MOV`) and its `ERR?`, and return the error code with a status whose
    /// fold is the one the move was corrected with. `before` is the status read just before.
    ///
    /// The recording's temperatures and aux inputs of a step must be the inputs of the fold
    /// the compensator corrected the move with, or the file-based `validate` replays another
    /// correction. A status read before the move is that fold only if no fold ran in
    /// between; the sensor task folds on its own clock, so one may run while the move is on
    /// its way (measured: a fold between the two in a few steps per test, moving the static
    /// model's table by 2-18 nm). So the status is read again after the move: the same fold
    /// counter means no fold ran between the two readings, and the move was corrected with
    /// that fold; otherwise the same move is sent again (the stage takes the last target;
    /// the fold just ran, so the next is a sample period away) — what a real bench does too.
    /// In bypass no fold touches the move and the status read before it is recorded.
    fn move_with_known_fold(
        &mut self,
        k: usize,
        mode: Mode,
        line: &str,
        mut before: Status,
    ) -> Result<(i32, Status), CampaignError> {
        const ATTEMPTS: usize = 8;
        for _ in 0..ATTEMPTS {
            let code = self.send_move(line)?;
            if code == GCS_UNKNOWN_COMMAND {
                // the controller did not execute the line (garbled on the way, e.g. by a reset
                // of the compensator mid-line): nothing moved, so the same move is sent again
                eprintln!("step {k}: the controller did not understand `{line}` (GCS error 2); sent again");
                before = self.read_status(k)?;
                continue;
            }
            if code != 0 || mode.bypass {
                return Ok((code, before));
            }
            let after = self.read_status(k)?;
            if after.folds == before.folds && after.uptime_ms >= before.uptime_ms {
                return Ok((code, after));
            }
            before = after;
        }
        Err(CampaignError::NotReady {
            step: k,
            what: format!(
                "each of {ATTEMPTS} tries of the move was either not understood by the controller (GCS error 2) or had a fold run during it (which fold corrected it is unknown)"
            ),
        })
    }

    fn gcs_target(&self, target: &[f64]) -> String {
        let mut line = String::from("MOV");
        for (a, v) in target.iter().enumerate() {
            line += &format!(" {} {v:.6}", self.axes[a]);
        }
        line
    }

    /// The stage's command for the rows of step `k`: what the controller received (virtual
    /// bench), the target itself in bypass, else the compensator's correction replayed from its
    /// status (a real bench cannot see the stage link).
    fn stage_command(&mut self, k: usize, mode: Mode) -> Vec<f64> {
        let step = &self.steps[k];
        if let Some(cmds) = self.links.driver.stage_commands() {
            if let Some((_, c)) = cmds.last() {
                return c.clone();
            }
            return self.cmd_um.clone();
        }
        if mode.bypass {
            return step.target_um.clone();
        }
        let (Some(models), Some(s)) = (&self.models, &self.status) else {
            return vec![f64::NAN; step.target_um.len()];
        };
        let m = match mode.model {
            Some(TestKind::Adaptive) => models.adaptive_with(self.state.kmz_um.as_deref()),
            _ => models.static_model.clone(),
        };
        let mut slow = nanocal_model::SlowInputs::default();
        for (i, t) in s.temps_c.iter().enumerate().take(self.temps.len()) {
            slow.temps_c[i] = f64::from(*t);
        }
        for (i, v) in s.aux.iter().enumerate().take(self.aux.len()) {
            slow.aux[i] = f64::from(*v);
        }
        use nanocal_compensator::proxy::Corrector;
        let fold = nanocal_compensator::proxy::FoldCorrector::new(&m, &slow);
        let mut x = [0f32; MAX_AXES];
        let mut dir = [0i8; MAX_AXES];
        for a in 0..step.target_um.len() {
            x[a] = step.target_um[a] as f32;
            dir[a] = step.approach[a];
        }
        // play operators from a fresh state (the published models have none; a model with
        // them needs the device's memory, which only the virtual bench can see)
        let c = fold.correct(&x, &dir, &nanocal_model::HysteresisState::new());
        (0..step.target_um.len())
            .map(|a| f64::from(c.q_um[a]))
            .collect()
    }

    fn note(&self, progress: &mut dyn Progress, text: String) {
        progress.note(&text);
    }

    /// Leave the stage at the safe pose (through the compensator; in bypass if it refuses).
    pub fn park(&mut self) -> Result<(), CampaignError> {
        let line = self.gcs_target(&self.state.safe_pose_um.clone());
        if self.send_move(&line)? != 0 {
            self.device(|c| c.bypass(true))?;
            self.send_move(&line)?;
        }
        Ok(())
    }

    fn interrupted(&mut self, k: usize, what: &str) -> Result<(), CampaignError> {
        self.recorder.sync()?;
        self.state.interruptions.push(Interruption {
            step: k,
            plan_time_s: self.t_now(),
            what: what.to_string(),
        });
        self.save()
    }

    /// Run the steps from `state.next_step` to the end.
    pub fn run(&mut self, progress: &mut dyn Progress) -> Result<(), CampaignError> {
        let r = self.run_steps(progress);
        if let Err(e) = &r {
            let k = self.state.next_step;
            let what = match e {
                CampaignError::Interrupted { .. } => "Ctrl-C".to_string(),
                e => e.to_string(),
            };
            // keep what was recorded and leave the stage somewhere safe, whatever happened
            let _ = self.interrupted(k, &what);
            if !matches!(
                e,
                CampaignError::Device(_) | CampaignError::Gcs(_) | CampaignError::Bench(_)
            ) {
                let _ = self.park();
            }
        }
        r
    }

    fn run_steps(&mut self, progress: &mut dyn Progress) -> Result<(), CampaignError> {
        let n = self.steps.len();
        let start = self.state.next_step;
        if start == 0 || self.status.is_none() {
            let k = start.min(n.saturating_sub(1));
            self.read_status(k)?;
        }
        for k in start..n {
            let step = self.steps[k].clone();
            progress.step(k, n, &describe(step.phase, self.plan));
            let mut clock = std::time::Instant::now();
            let mut lap = |slot: &mut f64| {
                let now = std::time::Instant::now();
                *slot += (now - clock).as_secs_f64();
                clock = now;
            };
            let waited = self.links.driver.wait_until(step.t_start_s, &self.stop)?;
            lap(&mut self.profile.wait_s);
            if !waited || self.stop.load(Ordering::Acquire) {
                return Err(CampaignError::Interrupted {
                    step: k,
                    t_s: self.t_now(),
                });
            }
            if k > 0 && k == start {
                // a resumed campaign: the rows before step k are on disk (and step k − 1's KMZ
                // was sent); what the instrument sent of that time since is not a second row
                let now = self.t_now();
                self.links
                    .reference
                    .until(step.t_start_s - crate::data::dwell::STEP_EDGE_S, now)?;
            } else if k > 0 {
                let prev = &self.steps[k - 1];
                let from = prev.t_end_s() - prev.average_last_s;
                self.collect(step.t_start_s, from)?;
                lap(&mut self.profile.collect_s);
                self.finish(k - 1)?;
                lap(&mut self.profile.setup_s);
            } else {
                self.links.reference.discard_before(0.0);
            }
            self.window.clear();
            self.state.recording_bytes = self.recorder.commit()?;
            self.state.next_step = k;
            // the state file at most once a second of wall time: a step of the virtual bench
            // takes milliseconds, and rewriting the file for each cost more than a tenth of the
            // published campaign's wall time. A crash loses at most that second's steps (resume
            // re-runs them); a stop or an error writes it at once (`interrupted`).
            if k == start || self.saved_at.elapsed() >= SAVE_EVERY {
                self.save()?;
            }
            lap(&mut self.profile.save_s);
            if step.phase != Phase::Training && self.models.is_none() {
                progress.note("fitting the static and adaptive models");
                let rec = self.recorder.path().to_path_buf();
                let models = fit_models(&self.dir, &rec, &self.steps, self.spec.clone())?;
                self.state.model_ids = Some((models.static_model.id(), models.adaptive.id()));
                self.models = Some(models);
                self.save()?;
            }
            let before = self.state.device_resets;
            let status_before_s = self.profile.status_s;
            let mode = mode_of(step.phase);
            let line = self.gcs_target(&step.target_um);
            let (code, s) = match self.quick_move(k, mode, &line)? {
                Some(done) => done,
                None => {
                    let s = self.ready_status(k)?;
                    if self.state.device_resets != before {
                        self.note(
                            progress,
                            format!("step {k}: the compensator reset; setting it up again"),
                        );
                    }
                    self.apply(k, mode)?;
                    let s = self.status.unwrap_or(s);
                    self.move_with_known_fold(k, mode, &line, s)?
                }
            };
            self.temps = s.temps_c[..self.state.layout.temps.len()].to_vec();
            self.aux = s.aux[..self.state.layout.aux.len()].to_vec();
            if code != 0 {
                let t_s = self.t_now();
                if code == GcsErrorCode::SensorFault.code() {
                    return Err(CampaignError::SensorFault {
                        step: k,
                        t_s,
                        what: "the compensator refuses moves: a sensor the model needs has failed or its fold is stale (GCS 9002)".into(),
                    });
                }
                return Err(CampaignError::Refused {
                    step: k,
                    t_s,
                    command: line,
                    code,
                    meaning: gcs_meaning(code).into(),
                });
            }
            self.cmd_um = self.stage_command(k, mode);
            lap(&mut self.profile.mov_s);
            // the status reads are counted apart
            self.profile.mov_s -= self.profile.status_s - status_before_s;
            if let Some(next) = self.steps.get(k + 1) {
                let m = mode_of(next.phase);
                // a KMZ measurement needs bypass until it is sent; else set up for the next step now
                let keep_bypass = matches!(step.phase, Phase::Kmz { .. });
                if (m.bypass || !keep_bypass) && next.phase != Phase::Training {
                    if m.model.is_some() && self.models.is_none() {
                        continue; // fitted at the next step's start
                    }
                    self.apply(k, m)?;
                }
            }
            if self.reset_before_step == Some(k + 1) {
                // a staged fault, during the hold: the firmware resets once its reply is out
                // and boots while the bench's time runs to the next step
                self.reset_before_step = None;
                self.device(|c| c.reset())?;
            }
            if self.ports_lost_before_step == Some(k + 1) {
                self.ports_lost_before_step = None;
                self.device(|c| c.reset())?;
                self.links.drop_ports();
            }
        }
        // the last step's end
        if let Some(last) = self.steps.last().cloned() {
            if !self.links.driver.wait_until(last.t_end_s(), &self.stop)? {
                return Err(CampaignError::Interrupted {
                    step: n - 1,
                    t_s: self.t_now(),
                });
            }
            self.collect(last.t_end_s(), last.t_end_s() - last.average_last_s)?;
            self.finish(n - 1)?;
        }
        self.state.recording_bytes = self.recorder.sync()?;
        self.state.next_step = n;
        self.state.stage = Stage::Analysis;
        self.save()?;
        Ok(())
    }
}

/// Run `f` on `link` as one exchange of the bench (on the virtual bench: with the board's clock
/// held while the host talks to it).
fn exchange_on<L: Send, T: Send, E: Send>(
    driver: &mut dyn BenchDriver,
    link: &mut L,
    f: impl FnOnce(&mut L) -> Result<T, E> + Send,
) -> Result<T, CampaignError>
where
    CampaignError: From<E>,
{
    let mut out = None;
    let mut f = Some(f);
    let mut op = || {
        if let Some(f) = f.take() {
            out = Some(f(link));
        }
    };
    driver.exchange(&mut op)?;
    Ok(out.expect("the exchange ran")?)
}
