//! `nanocal campaign`: a whole calibration on a bench, through the compensator — the published
//! procedure (paper 000 §4.2, Fig. 8; paper 001 §II) as one command: the training trajectory
//! with the compensator in bypass, the fit, the validation tests with each compensation in the
//! compensator, the KMZ re-measured at the reference pose and sent to it, the statistics, the
//! report and `explain`. A campaign of days survives a host restart (its state is on disk,
//! [`state`]) and a compensator reset (noticed in its status; the mode and model are set again).
//!
//! The same code runs a real bench (wall clock, the lab's reference instrument) and a virtual
//! one (the QEMU firmware in lockstep with the digital twin): it opens real benches itself
//! ([`run`]) and takes any other from its caller as a [`bench::BenchDriver`] with its ports
//! ([`run_on`]; the CLI opens the virtual bench).

pub mod analysis;
pub mod bench;
pub mod gcs;
pub mod loops;
pub mod recorder;
pub mod reference;
pub mod run;
pub mod state;

use crate::data::plan::{Plan, Step};
use crate::device::Client;
use bench::{ReferenceReader, WallClock};
use gcs::GcsLink;
use nanocal_interface::settings::{AuxSource, Settings};
use recorder::{Layout, Recorder};
use reference::{ClockMap, ClockMode};
use run::{CampaignError, Links, Progress, Reopen, Runner};
use state::{BenchSpec, Stage, State};
pub use state::{LoopRecord, LoopState, LoopStop};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// File name of the campaign's recording in its folder.
pub const RECORDING: &str = "recording.csv";
/// File name of the plan in the campaign's folder.
pub const PLAN: &str = "plan.json";
/// The compensator's sample period on the virtual bench unless told otherwise, ms: four times
/// the STM32 default (250 ms) — each sample cycle costs the emulated board bus transactions.
pub const VIRTUAL_SAMPLE_PERIOD_MS: u16 = 1000;
/// The compensator's fold period on the virtual bench unless told otherwise, ms: the device's
/// default (paper 001 §VI: "each 5-10 seconds"), five readings averaged.
pub const VIRTUAL_FOLD_PERIOD_MS: u16 = nanocal_interface::settings::DEFAULT_FOLD_PERIOD_MS;
/// Plan time between the end of the set-up and the first step on a real bench, s.
const REAL_LEAD_S: f64 = 5.0;

/// A campaign to run.
pub struct Config {
    /// The plan (ignored on resume: the campaign's own `plan.json` is used).
    pub plan: Option<Plan>,
    /// The campaign's folder.
    pub out: PathBuf,
    /// The bench (on resume: as stored unless given).
    pub bench: Option<BenchSpec>,
    /// The compensator's sample period to set, ms (None: as configured; the virtual bench:
    /// [`VIRTUAL_SAMPLE_PERIOD_MS`]).
    pub sample_period_ms: Option<u16>,
    /// The compensator's fold period to set, ms (None: as configured; the virtual bench:
    /// [`VIRTUAL_FOLD_PERIOD_MS`]).
    pub fold_period_ms: Option<u16>,
    /// Where to leave the stage when stopping early (default: the plan's first pose).
    pub safe_pose_um: Option<Vec<f64>>,
    /// Names of the temperature channels (default: the twin's on the virtual bench, else
    /// `cs0`, `cs1`, …).
    pub sensor_names: Option<Vec<String>>,
    /// Candidate terms of the static model (default by axes: paper 000's 1-DoF or Eq. 22).
    pub design: Option<crate::fit::design::DesignSpec>,
    /// Run `explain` at the end.
    pub explain: bool,
    /// The desired accuracy of the validate-and-return loop (paper 001 §II step 5): the worst
    /// static test's Acc, nm ([`loops`]); None: no loop.
    pub target_accuracy_nm: Option<f64>,
    /// Tests in each loop's validation block (default: the plan's rounds).
    pub loop_tests: Option<usize>,
    /// Most loops.
    pub max_loops: usize,
    /// Continue the campaign in `out`.
    pub resume: bool,
    /// Faults to stage (tests; none by default).
    pub faults: Faults,
}

/// Faults a test stages, to see the campaign meet them (none by default). A bench's own faults
/// (instruments that fail) are staged by whoever opens that bench.
#[derive(Debug, Clone, Default)]
pub struct Faults {
    /// The compensator is reset (its management `RESET`, the firmware's own software reset)
    /// during the hold before this step: the campaign must notice it in the status and set it
    /// up again.
    pub reset_before_step: Option<usize>,
    /// The compensator resets during the hold before this step and the campaign's handles on
    /// its ports die, as when a USB device resets and enumerates again: the campaign must
    /// reopen both ports and set the device up again.
    pub ports_lost_before_step: Option<usize>,
}

/// What a finished campaign reports.
pub struct Outcome {
    /// The statistics and their agreement.
    pub analysis: analysis::Analysis,
    /// The plan.
    pub plan: Plan,
    /// The state at the end.
    pub state: State,
    /// Wall time of this run, s.
    pub wall_s: f64,
    /// QEMU's CPU time (virtual bench), s.
    pub qemu_cpu_s: Option<f64>,
    /// Bus transactions served (virtual bench).
    pub bus_transactions: Option<u64>,
}

/// The twin of a plan on the virtual bench: paper 000's 1-DoF or 2-DoF stage by the number of
/// axes (the delta robot of paper 001 has its own twin type, not on the bench yet).
pub fn virtual_twin(plan: &Plan, seed: u64) -> Result<crate::twin::Twin, CampaignError> {
    use crate::twin::examples;
    match plan.training.axes() {
        1 => Ok(examples::paper000_1dof_twin(seed)),
        2 => Ok(examples::paper000_2dof_twin(seed)),
        n => Err(CampaignError::Fit(format!(
            "the virtual bench has twins for 1- and 2-axis stages; this plan has {n} axes"
        ))),
    }
}

/// Opens a real bench: the compensator's ports, the reference instrument, the wall clock.
fn open_real(
    spec: &BenchSpec,
    plan: &Plan,
    steps: &[Step],
    resume_at: usize,
) -> Result<Links, CampaignError> {
    let plan_start = steps.get(resume_at).map_or(0.0, |s| s.t_start_s);
    match spec {
        BenchSpec::Virtual { .. } => Err(CampaignError::NotReady {
            step: resume_at,
            what: "a virtual bench is opened by the caller: `nanocal campaign --virtual` starts it (in a program, give `virtual_bench::campaign_bench::opener` to `campaign::run_on`)".into(),
        }),
        BenchSpec::Real {
            device,
            gcs,
            reference: r,
            reference_to_um,
            reference_synchronized,
        } => {
            let (device_spec, gcs_spec) = (device.clone(), gcs.clone());
            let reopen: Reopen =
                Box::new(move || Ok((Client::open(&device_spec)?, GcsLink::open(&gcs_spec)?)));
            let device = Client::open(device)?;
            let gcs = GcsLink::open(gcs)?;
            let src = reference::open(r, plan.training.axes(), *reference_to_um)?;
            let mode = if *reference_synchronized {
                ClockMode::Synchronized
            } else {
                ClockMode::Instrument
            };
            Ok(Links {
                driver: Box::new(WallClock::new(plan_start - REAL_LEAD_S)),
                device,
                gcs,
                reference: ReferenceReader::new(src, ClockMap::new(mode)),
                reopen: Some(reopen),
            })
        }
    }
}

/// Set the compensator up for the campaign; the recording's layout and the compensator's
/// (sample, fold) periods, ms.
fn configure(
    links: &mut Links,
    cfg: &Config,
    spec: &BenchSpec,
    plan: &Plan,
    axes: usize,
) -> Result<(Layout, u16, u16), CampaignError> {
    let mut settings: Option<Result<Settings, crate::device::DeviceError>> = None;
    {
        let dev = &mut links.device;
        links.driver.exchange(&mut || {
            settings = Some(dev.identify().and_then(|_| dev.config()));
        })?;
    }
    let mut s = settings.expect("ran")?;
    let twin_names = match spec {
        BenchSpec::Virtual { seed, .. } => {
            let twin = virtual_twin(plan, *seed)?;
            let names: Vec<String> = twin
                .cfg
                .sensors
                .iter()
                .filter(|c| c.recorded)
                .map(|c| c.name.clone())
                .collect();
            for (i, slot) in s.sensors.iter_mut().enumerate() {
                *slot = (i < names.len()).then_some(nanocal_compensator::sensor::Chip::K);
            }
            s.aux = Default::default();
            s.sample_period_ms = cfg.sample_period_ms.unwrap_or(VIRTUAL_SAMPLE_PERIOD_MS);
            s.fold_period_ms = cfg.fold_period_ms.unwrap_or(VIRTUAL_FOLD_PERIOD_MS);
            Some(names)
        }
        BenchSpec::Real { .. } => {
            if let Some(p) = cfg.sample_period_ms {
                s.sample_period_ms = p;
            }
            if let Some(p) = cfg.fold_period_ms {
                s.fold_period_ms = p;
            }
            None
        }
    };
    {
        let (dev, s2) = (&mut links.device, s);
        let mut r = None;
        links
            .driver
            .exchange(&mut || r = Some(dev.set_config(&s2)))?;
        r.expect("ran")?;
    }
    let n = s
        .sensors
        .iter()
        .rposition(|c| c.is_some())
        .map_or(0, |i| i + 1);
    if s.sensors[..n].iter().any(|c| c.is_none()) {
        return Err(CampaignError::NotReady {
            step: 0,
            what: "the compensator's temperature channels have gaps (a model's temperature i is chip-select i): configure them contiguously from CS0".into(),
        });
    }
    let names = cfg
        .sensor_names
        .clone()
        .or(twin_names)
        .unwrap_or_else(|| (0..n).map(|i| format!("cs{i}")).collect());
    if names.len() != n {
        return Err(CampaignError::NotReady {
            step: 0,
            what: format!("{} sensor names for {n} temperature channels", names.len()),
        });
    }
    let m = s
        .aux
        .iter()
        .rposition(|a| *a != AuxSource::None)
        .map_or(0, |i| i + 1);
    let aux = s.aux[..m]
        .iter()
        .enumerate()
        .map(|(i, a)| match a {
            AuxSource::AirPressure => "pressure".to_string(),
            AuxSource::Force { .. } => "force".to_string(),
            _ => format!("aux{i}"),
        })
        .collect();
    let layout = Layout {
        axes: crate::twin::AXIS_NAMES[..axes]
            .iter()
            .map(|a| a.to_string())
            .collect(),
        temps: names,
        aux,
    };
    Ok((layout, s.sample_period_ms, s.fold_period_ms))
}

/// Opens a bench the caller supplies (see [`run_on`]): given the bench's specification (as
/// given, or as the resumed campaign's state holds it), the plan, the steps the bench
/// will play (the plan's, and every block a validate-and-return loop may add) and the step the
/// campaign starts at (after a resume), the bench's driver, the compensator's two ports, the
/// reference instrument and how to reopen the ports.
pub type OpenBench<'a> =
    &'a mut dyn FnMut(&BenchSpec, &Plan, &[Step], usize) -> Result<Links, CampaignError>;

/// Run (or resume) a campaign on a real bench (a virtual one: [`run_on`] with the bench's
/// opener).
pub fn run(
    cfg: &Config,
    stop: Arc<AtomicBool>,
    progress: &mut dyn Progress,
) -> Result<Outcome, CampaignError> {
    run_inner(cfg, None, stop, progress)
}

/// Run (or resume) a campaign on a bench the caller opens: any [`bench::BenchDriver`] with
/// its ports and reference (issue 20: "campaign takes any bench driver"). `cfg.bench` is what
/// the state records and what the compensator is configured for (a virtual bench's twin names
/// its sensors), as in [`run`]; only opening the bench is the caller's.
pub fn run_on(
    cfg: &Config,
    open_bench: OpenBench<'_>,
    stop: Arc<AtomicBool>,
    progress: &mut dyn Progress,
) -> Result<Outcome, CampaignError> {
    run_inner(cfg, Some(open_bench), stop, progress)
}

fn run_inner(
    cfg: &Config,
    mut open_bench: Option<OpenBench<'_>>,
    stop: Arc<AtomicBool>,
    progress: &mut dyn Progress,
) -> Result<Outcome, CampaignError> {
    let wall = Instant::now();
    let dir = &cfg.out;
    std::fs::create_dir_all(dir).map_err(|e| CampaignError::NotReady {
        step: 0,
        what: format!("{}: {e}", dir.display()),
    })?;
    let (plan, prior) = if cfg.resume {
        let st = State::load(dir)?;
        let text =
            std::fs::read_to_string(dir.join(PLAN)).map_err(|e| CampaignError::NotReady {
                step: 0,
                what: format!("{}: {e}", dir.join(PLAN).display()),
            })?;
        let plan: Plan = serde_json::from_str(&text).map_err(|e| CampaignError::NotReady {
            step: 0,
            what: format!("{}: {e}", dir.join(PLAN).display()),
        })?;
        (plan, Some(st))
    } else {
        if dir.join(state::FILE).exists() {
            return Err(CampaignError::NotReady {
                step: 0,
                what: format!(
                    "{} already holds a campaign: continue it with --resume, or choose another --out",
                    dir.display()
                ),
            });
        }
        let plan = cfg.plan.clone().ok_or_else(|| CampaignError::NotReady {
            step: 0,
            what: "no plan".into(),
        })?;
        (plan, None)
    };
    let axes = plan.training.axes();
    // the schedule so far: the plan's, and the blocks of the loops started
    let steps = loops::schedule(&plan, prior.as_ref().and_then(|s| s.loops.as_ref()));
    let spec = cfg
        .bench
        .clone()
        .or_else(|| prior.as_ref().map(|s| s.bench.clone()))
        .ok_or_else(|| CampaignError::NotReady {
            step: 0,
            what: "no bench: give --device/--gcs/--reference or --virtual".into(),
        })?;
    let resume_at = prior.as_ref().map_or(0, |s| s.next_step);
    // a loop decision still to make needs the bench too
    let pending = |s: &State| {
        s.loops
            .as_ref()
            .is_some_and(|l| l.stop.is_none() && l.decided <= l.loops.len())
    };
    let mut state = match &prior {
        Some(s) if s.stage != Stage::Steps && !pending(s) => s.clone(),
        _ => {
            // the virtual bench's twin plays every block the loop may add
            let bench_steps = match cfg.target_accuracy_nm.or(prior
                .as_ref()
                .and_then(|s| s.loops.as_ref().map(|l| l.target_nm)))
            {
                Some(_) => {
                    let (blocks, tests) = match prior.as_ref().and_then(|s| s.loops.as_ref()) {
                        Some(l) => (l.max_loops, l.tests_per_block),
                        None => (
                            cfg.max_loops,
                            cfg.loop_tests.unwrap_or(plan.validation.rounds),
                        ),
                    };
                    plan.schedule_with_blocks(blocks, tests)
                }
                None => steps.clone(),
            };
            let mut links = match open_bench.as_mut() {
                Some(f) => f(&spec, &plan, &bench_steps, resume_at)?,
                None => open_real(&spec, &plan, &bench_steps, resume_at)?,
            };
            let (layout, period, fold) = configure(&mut links, cfg, &spec, &plan, axes)?;
            links
                .reference
                .first(links.driver.now_s(), Duration::from_secs(10))?;
            let state = match prior.clone() {
                Some(mut s) => {
                    if s.layout != layout {
                        return Err(CampaignError::NotReady {
                            step: s.next_step,
                            what: format!(
                                "the compensator's channels ({}) differ from the campaign's ({})",
                                layout.header(),
                                s.layout.header()
                            ),
                        });
                    }
                    s.bench = spec.clone();
                    s.sample_period_ms = period;
                    s.fold_period_ms = fold;
                    s
                }
                None => State {
                    version: state::VERSION,
                    bench: spec.clone(),
                    layout: layout.clone(),
                    sample_period_ms: period,
                    fold_period_ms: fold,
                    safe_pose_um: cfg.safe_pose_um.clone().unwrap_or_else(|| {
                        steps
                            .first()
                            .map_or(vec![0.0; axes], |s| s.target_um.clone())
                    }),
                    next_step: 0,
                    recording_bytes: 0,
                    stage: Stage::Steps,
                    model_ids: None,
                    uploaded: None,
                    kmz_um: None,
                    kmz_first: None,
                    kmz_updates: 0,
                    device_resets: 0,
                    interruptions: Vec::new(),
                    stale: Vec::new(),
                    loops: cfg.target_accuracy_nm.map(|target_nm| state::LoopState {
                        target_nm,
                        tests_per_block: cfg.loop_tests.unwrap_or(plan.validation.rounds),
                        max_loops: cfg.max_loops,
                        loops: Vec::new(),
                        decided: 0,
                        stop: None,
                    }),
                },
            };
            let rec_path = dir.join(RECORDING);
            let recorder = if prior.is_some() {
                Recorder::resume(&rec_path, &state.layout, state.recording_bytes)?
            } else {
                std::fs::write(
                    dir.join(PLAN),
                    serde_json::to_string_pretty(&plan).unwrap_or_default(),
                )
                .map_err(|e| CampaignError::NotReady {
                    step: 0,
                    what: format!("{}: {e}", dir.join(PLAN).display()),
                })?;
                Recorder::create(&rec_path, &state.layout)?
            };
            state.save(dir)?;
            let gcs_axes: Vec<String> = (1..=axes).map(|a| a.to_string()).collect();
            let design = cfg.design.clone().unwrap_or_else(|| match axes {
                2 => crate::fit::design::DesignSpec::published_2dof(),
                _ => crate::fit::design::DesignSpec::published_static(),
            });
            let mut runner = Runner::new(
                dir,
                &plan,
                steps.clone(),
                state,
                links,
                gcs_axes,
                design,
                recorder,
                stop,
            )?;
            runner.reset_before_step = cfg.faults.reset_before_step;
            runner.ports_lost_before_step = cfg.faults.ports_lost_before_step;
            if prior.is_none() {
                if let Err(e) = runner.check_travel() {
                    // nothing ran: leave no campaign behind, so the fixed plan can start here
                    drop(runner);
                    for f in [state::FILE, PLAN, RECORDING] {
                        let _ = std::fs::remove_file(dir.join(f));
                    }
                    return Err(e);
                }
            }
            let periods = crate::device::device_path::SlowPeriods {
                sample_s: f64::from(runner.state.sample_period_ms) / 1000.0,
                fold_s: f64::from(runner.state.fold_period_ms) / 1000.0,
            };
            let r = run_with_loops(&mut runner, dir, &plan, periods, progress);
            if std::env::var_os("NANOCAL_CAMPAIGN_PROFILE").is_some() {
                eprintln!("campaign profile (wall s): {:?}", runner.profile());
            }
            let usage = runner.links.driver.usage().unwrap_or_default();
            let (qemu_cpu, txns) = (usage.emulator_cpu_s, usage.bus_transactions);
            r?;
            let mut st = runner.state.clone();
            st.interruptions.retain(|_| true);
            drop(runner);
            return finish(cfg, dir, plan, st, wall, qemu_cpu, txns, progress);
        }
    };
    state.stage = Stage::Analysis;
    finish(cfg, dir, plan, state, wall, None, None, progress)
}

/// Run the steps, and after each validation the validate-and-return loop's decision
/// ([`loops::decide`]): a new block of steps runs on the same bench until the loop stops.
fn run_with_loops(
    runner: &mut Runner,
    dir: &Path,
    plan: &Plan,
    periods: crate::device::device_path::SlowPeriods,
    progress: &mut dyn Progress,
) -> Result<(), CampaignError> {
    loop {
        if runner.state.stage == Stage::Steps {
            runner.run(progress)?;
        }
        let pending = runner
            .state
            .loops
            .as_ref()
            .is_some_and(|l| l.stop.is_none() && l.decided <= l.loops.len());
        if !pending {
            return Ok(());
        }
        progress
            .note("validate-and-return (paper 001 §II step 5): validating, explaining, refitting");
        let spec = runner.spec.clone();
        let steps = runner.steps.clone();
        match loops::decide(dir, plan, &steps, &spec, periods, &mut runner.state)? {
            loops::Decision::Block(new_steps) => {
                runner.steps = new_steps;
                runner.state.stage = Stage::Steps;
                runner.reload_models()?;
            }
            loops::Decision::Stop => {}
        }
        runner.save()?;
    }
}

#[allow(clippy::too_many_arguments)]
fn finish(
    cfg: &Config,
    dir: &Path,
    plan: Plan,
    mut state: State,
    wall: Instant,
    qemu_cpu_s: Option<f64>,
    bus_transactions: Option<u64>,
    progress: &mut dyn Progress,
) -> Result<Outcome, CampaignError> {
    progress.note("validating: the table from the stage's commands and the file-based validate");
    let periods = crate::device::device_path::SlowPeriods {
        sample_s: f64::from(state.sample_period_ms) / 1000.0,
        fold_s: f64::from(state.fold_period_ms) / 1000.0,
    };
    let analysis = analysis::analyse(dir, &plan, &plan.schedule(), periods, cfg.explain)?;
    let reports: Vec<&crate::validate::ValidationReport> = analysis.file.iter().collect();
    crate::report::write_report(&dir.join("report"), &reports)
        .map_err(|e| CampaignError::Fit(format!("report plots: {e}")))?;
    if let Some(text) = &analysis.explain {
        let _ = std::fs::write(dir.join("explain.txt"), text);
    }
    state.stage = Stage::Done;
    state.save(dir)?;
    Ok(Outcome {
        analysis,
        plan,
        state,
        wall_s: wall.elapsed().as_secs_f64(),
        qemu_cpu_s,
        bus_transactions,
    })
}
