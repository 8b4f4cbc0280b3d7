//! `nanocal campaign`: run a whole calibration on a bench through the compensator, or on the
//! virtual bench (`--virtual`: the QEMU firmware and the digital twin).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::campaign::run::Progress;
use crate::campaign::state::{BenchSpec, State, VirtualBoard};
use crate::campaign::{self, Config};
use crate::data::plan::{Plan, TestKind};

/// Run a calibration campaign: training with the compensator in bypass, the fit, validation
/// tests with each compensation in the compensator, KMZ re-measured at the interval, the report
/// and `explain` — on a bench (`--device`, `--gcs`, `--reference`) or on the virtual one
/// (`--virtual`). Everything is recorded as it goes in `--out`; a stopped campaign (Ctrl-C, a
/// host restart, an error) continues with `--resume --out DIR`.
#[derive(Args, Debug)]
pub struct CampaignArgs {
    /// The plan: a plan file (JSON, as `nanocal demo --print-plans` writes them) or a published
    /// plan's name: paper000-1dof, paper000-2dof, paper001-robot.
    pub plan: Option<String>,
    /// Folder for the recording, plan, state, models, report (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// The compensator's management port (`/dev/ttyACM1`, `tcp:HOST:PORT`, `unix:PATH`).
    #[arg(long)]
    pub device: Option<String>,
    /// The compensator's GCS port (what the lab's software talks to).
    #[arg(long)]
    pub gcs: Option<String>,
    /// The reference instrument: `tcp:HOST:PORT`, `serial:DEVICE[:BAUD]` (one line per sample:
    /// `t pos…`), or `file:PATH`/`PATH.csv` (a CSV its software appends to).
    #[arg(long)]
    pub reference: Option<String>,
    /// Unit of the reference's positions.
    #[arg(long, default_value = "um", value_parser = ["um", "nm", "mm"])]
    pub reference_unit: String,
    /// The reference stamps samples on this host's clock (else its own clock is mapped).
    #[arg(long)]
    pub reference_synchronized: bool,
    /// Run on the virtual bench: the QEMU firmware with the digital twin as controller, stage,
    /// interferometer and sensors.
    #[arg(long = "virtual")]
    pub virtual_bench: bool,
    /// The virtual bench's board: `qemu` (the QEMU firmware on mps2-an386, in this process) or
    /// `stm32` (the shipped STM32 image on the emulated B-L475E-IOT01A, in the `stm32-bench`
    /// process: it links GPL code, which this program does not). A resumed campaign keeps its
    /// board.
    #[arg(long, value_parser = ["qemu", "stm32"], requires = "virtual_bench")]
    pub board: Option<String>,
    /// Seed of the virtual bench's room and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Continue the campaign in `--out`.
    #[arg(long)]
    pub resume: bool,
    /// Set the compensator's sensor sample period, ms (the virtual bench: 1000 by default).
    #[arg(long)]
    pub sample_period_ms: Option<u16>,
    /// The validate-and-return loop (paper 001 §II step 5): after the validation, while the
    /// static model's worst test is above this accuracy, add what `explain` finds that the
    /// compensator can run (lag filters, play operators, interactions, temperature terms), fit
    /// the static model again on the training data and validate it in a block of tests; stop
    /// when met, when a loop no longer improves held-out accuracy, or when what remains needs a
    /// design change (which is printed). nm.
    #[arg(long)]
    pub target_accuracy_nm: Option<f64>,
    /// Tests in each loop's validation block (default: the plan's rounds).
    #[arg(long)]
    pub loop_tests: Option<usize>,
    /// Most loops of the validate-and-return loop.
    #[arg(long, default_value_t = 3)]
    pub max_loops: usize,
    /// Set the compensator's fold period, ms (1000..=10000; the readings of a period are
    /// averaged; the virtual bench: 5000 by default).
    #[arg(long)]
    pub fold_period_ms: Option<u16>,
    /// Where to leave the stage when stopping early, µm per axis (default: the plan's first pose).
    #[arg(long, value_delimiter = ',')]
    pub safe_pose_um: Option<Vec<f64>>,
    /// Names of the temperature channels, in chip-select order.
    #[arg(long, value_delimiter = ',')]
    pub sensor_names: Option<Vec<String>>,
    /// Candidate terms of the static model (as `nanocal fit --design`).
    #[arg(long)]
    pub design: Option<String>,
    /// A shorter plan: at most T training cycles, C cycles per test, R rounds (`T,C,R`).
    #[arg(long, value_delimiter = ',')]
    pub shorten: Option<Vec<usize>>,
    /// KMZ interval, s (default: the plan's).
    #[arg(long)]
    pub kmz_interval_s: Option<f64>,
    /// Skip `explain` at the end.
    #[arg(long)]
    pub no_explain: bool,
    /// Write the results as JSON here too.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Resolve a plan argument.
pub fn load_plan(arg: &str) -> anyhow::Result<Plan> {
    match arg {
        "paper000-1dof" => Ok(Plan::paper000_1dof()),
        "paper000-2dof" => Ok(Plan::paper000_2dof()),
        "paper001-robot" => Ok(Plan::paper001_robot()),
        path => {
            let text = std::fs::read_to_string(path).with_context(|| {
                format!("plan `{path}`: not a published plan's name (paper000-1dof, paper000-2dof, paper001-robot) nor a readable file")
            })?;
            serde_json::from_str(&text).with_context(|| format!("plan file {path}"))
        }
    }
}

struct Bars {
    bar: ProgressBar,
}

impl Progress for Bars {
    fn step(&mut self, k: usize, n: usize, what: &str) {
        if self.bar.length() != Some(n as u64) {
            self.bar.set_length(n as u64);
        }
        self.bar.set_position(k as u64);
        self.bar.set_message(what.to_string());
    }
    fn note(&mut self, text: &str) {
        self.bar.println(text);
    }
}

/// The virtual board the campaign runs on: `--board` with `--virtual` (QEMU by default), or on
/// `--resume` without `--virtual` the one the campaign's state names; None on a real bench.
pub fn board_of(args: &CampaignArgs) -> anyhow::Result<Option<VirtualBoard>> {
    if args.virtual_bench {
        return Ok(Some(match args.board.as_deref() {
            Some("stm32") => VirtualBoard::Stm32,
            _ => VirtualBoard::Qemu,
        }));
    }
    if args.resume && args.device.is_none() {
        if let Ok(st) = State::load(&args.out) {
            if let BenchSpec::Virtual { board, .. } = st.bench {
                return Ok(Some(board));
            }
        }
    }
    Ok(None)
}

/// Environment variable naming the `stm32-bench` binary (default: beside this executable).
pub const STM32_BENCH_ENV: &str = "NANOCAL_STM32_BENCH";

/// The `stm32-bench` binary: [`STM32_BENCH_ENV`], or beside this executable; a missing one is
/// an error saying how to build it.
fn stm32_bench_exe() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os(STM32_BENCH_ENV) {
        let p = PathBuf::from(p);
        anyhow::ensure!(
            p.is_file(),
            "{STM32_BENCH_ENV}={}: no such file",
            p.display()
        );
        return Ok(p);
    }
    let me = std::env::current_exe().context("where this executable is")?;
    let dir = me.parent().context("this executable's folder")?;
    let exe = dir.join(format!("stm32-bench{}", std::env::consts::EXE_SUFFIX));
    if exe.is_file() {
        return Ok(exe);
    }
    // a `cargo run --release` nanocal sits in …/release/, a debug one in …/debug/
    let release = if dir.ends_with("release") {
        " --release"
    } else {
        ""
    };
    anyhow::bail!(
        "the emulated STM32 board runs in its own program, `stm32-bench` (GPL-2.0: it links the Unicorn emulator, which this MIT/Apache program does not), and there is none at {} — build it with `cd host-tests && cargo build{release} -p nanocal-stm32-bench` (in the repository), or name it with {STM32_BENCH_ENV}",
        exe.display()
    )
}

/// Runs the campaign on the emulated STM32 board: the `stm32-bench` process with this
/// command line from `campaign` on; its exit status is ours.
fn run_stm32_process() -> anyhow::Result<()> {
    let exe = stm32_bench_exe()?;
    let args: Vec<std::ffi::OsString> = std::env::args_os()
        .skip(1)
        .skip_while(|a| a != "campaign")
        .collect();
    anyhow::ensure!(
        !args.is_empty(),
        "the STM32 campaign runs from the `nanocal campaign` command line"
    );
    // Ctrl-C reaches both processes (one process group): stm32-bench parks the stage and keeps
    // the campaign; this one waits for it
    let _ = ctrlc::set_handler(|| {});
    let status = std::process::Command::new(&exe)
        .args(&args)
        .status()
        .with_context(|| format!("running {}", exe.display()))?;
    if !status.success() {
        std::process::exit(status.code().unwrap_or(1));
    }
    Ok(())
}

/// Runs `nanocal campaign`.
pub fn run(args: CampaignArgs) -> anyhow::Result<()> {
    if board_of(&args)? == Some(VirtualBoard::Stm32) {
        return run_stm32_process();
    }
    if args.virtual_bench {
        // this process runs one board: it may give the board and the bench a core each
        crate::virtual_bench::core_split::allow();
    }
    run_on(args, None)
}

/// Runs `nanocal campaign` on a bench `open_bench` opens (None: as the arguments say — a real
/// bench or the QEMU one); the `stm32-bench` binary gives its emulated board here.
pub fn run_on(
    args: CampaignArgs,
    open_bench: Option<campaign::OpenBench<'_>>,
) -> anyhow::Result<()> {
    // read once: on --resume it loads the campaign's state file
    let board = board_of(&args)?;
    let plan = match (&args.plan, args.resume) {
        (Some(p), _) => {
            let mut plan = load_plan(p)?;
            if let Some(s) = &args.shorten {
                anyhow::ensure!(s.len() == 3, "--shorten takes T,C,R (three numbers)");
                plan = plan.shortened(s[0], s[1], s[2]);
            }
            if let (Some(i), Some(k)) = (args.kmz_interval_s, plan.validation.kmz.as_mut()) {
                k.interval_s = i;
            }
            Some(plan)
        }
        (None, true) => None,
        (None, false) => {
            anyhow::bail!("give a plan (a file or a published plan's name) or --resume")
        }
    };
    let to_um = match args.reference_unit.as_str() {
        "nm" => 1e-3,
        "mm" => 1e3,
        _ => 1.0,
    };
    let bench = if args.virtual_bench {
        Some(BenchSpec::Virtual {
            seed: args.seed,
            board: board.unwrap_or_default(),
        })
    } else {
        match (&args.device, &args.gcs, &args.reference) {
            (Some(d), Some(g), Some(r)) => Some(BenchSpec::Real {
                device: d.clone(),
                gcs: g.clone(),
                reference: r.clone(),
                reference_to_um: to_um,
                reference_synchronized: args.reference_synchronized,
            }),
            (None, None, None) if args.resume => None,
            _ => anyhow::bail!("a bench needs --device, --gcs and --reference (or --virtual)"),
        }
    };
    let design = args
        .design
        .as_deref()
        .map(crate::fit::design::DesignSpec::parse)
        .transpose()
        .map_err(|e| anyhow::anyhow!("--design: {e}"))?;
    let cfg = Config {
        plan,
        out: args.out.clone(),
        bench,
        sample_period_ms: args.sample_period_ms,
        fold_period_ms: args.fold_period_ms,
        safe_pose_um: args.safe_pose_um.clone(),
        sensor_names: args.sensor_names.clone(),
        design,
        explain: !args.no_explain,
        target_accuracy_nm: args.target_accuracy_nm,
        loop_tests: args.loop_tests,
        max_loops: args.max_loops,
        resume: args.resume,
        faults: Default::default(),
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        // a second Ctrl-C is not caught: the first one is being handled (the stage parks)
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::Release));
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} {msg:28} [{bar:30}] {pos}/{len} steps, {elapsed} elapsed, ETA {eta}",
        )
        .expect("static template"),
    );
    let mut progress = Bars { bar };
    // the CLI chooses the bench: the campaign opens real ones, the QEMU board is opened here
    let mut qemu_bench = crate::virtual_bench::campaign_bench::opener(Default::default());
    let open_bench = match open_bench {
        Some(f) => Some(f),
        None if board == Some(VirtualBoard::Qemu) => Some(&mut qemu_bench as _),
        None => None,
    };
    let outcome = match open_bench {
        Some(f) => campaign::run_on(&cfg, f, stop.clone(), &mut progress),
        None => campaign::run(&cfg, stop.clone(), &mut progress),
    };
    progress.bar.finish_and_clear();
    let o = outcome.map_err(|e| {
        anyhow::anyhow!(
            "{e}\n(everything recorded so far is in {}; continue with `nanocal campaign --resume --out {}`)",
            args.out.display(),
            args.out.display()
        )
    })?;
    print_outcome(&o, &args.out);
    let html = html_report(&o, &args.out)?;
    let report = args.out.join("report.html");
    std::fs::write(&report, html).with_context(|| format!("writing {}", report.display()))?;
    println!("wrote {}", report.display());
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&json(&o))?)?;
    }
    Ok(())
}

fn nm(v: f64) -> String {
    format!("{:.1}", v * 1e3)
}

fn print_outcome(o: &campaign::Outcome, out: &std::path::Path) {
    let a = &o.analysis;
    println!(
        "campaign {}: {} steps over {:.1} h of plan time; {} KMZ re-measurements; {} compensator resets",
        o.plan.name,
        o.plan.schedule().len(),
        o.plan.schedule().last().map_or(0.0, |s| s.t_end_s()) / 3600.0,
        o.state.kmz_updates,
        o.state.device_resets
    );
    print!("{}", stale_lines(&o.state.stale));
    println!("\nfrom what the stage received (the campaign's targets vs the reference):");
    let rows: Vec<&crate::validate::ValidationReport> = a.campaign.iter().collect();
    print!("{}", crate::validate::comparison_table(&rows));
    println!(
        "\nfile-based `validate` of the same recording agrees within {:.4} nm (every test's Acc and Rep, R_s, R_t)",
        a.max_difference_nm
    );
    if a.campaign
        .iter()
        .any(|r| r.compensation.name() == TestKind::Static.name())
    {
        let worst = a
            .campaign
            .iter()
            .filter(|r| r.compensation.name() != TestKind::NoModel.name())
            .map(|r| r.summary.max_acc_um)
            .fold(f64::NAN, f64::max);
        println!("largest test accuracy with a model: {} nm", nm(worst));
    }
    if !a.jitter_nm.is_empty() {
        let j: Vec<String> = a
            .jitter_nm
            .iter()
            .map(|(k, v)| format!("{} {v:.1} nm", k.name()))
            .collect();
        println!(
            "command jitter (scatter of a pose's command between its visits, fold period {} ms, sample period {} ms): {}",
            o.state.fold_period_ms,
            o.state.sample_period_ms,
            j.join(", ")
        );
    }
    if !a.advice.is_empty() {
        println!("\nexplain on the validation steps — what the model leaves out (paper 001 §II step 5: add it and train again):");
        for l in &a.advice {
            println!("  - {l}");
        }
    } else if a.explain.is_some() {
        println!("\nexplain on the validation steps found nothing more the model could carry.");
    }
    if let Some(lp) = &o.state.loops {
        print!("{}", loops_table(lp));
    }
    if let Some(c) = o.qemu_cpu_s {
        println!(
            "\nwall {:.1} s; QEMU CPU {:.1} s; {} bus transactions",
            o.wall_s,
            c,
            o.bus_transactions.unwrap_or(0)
        );
    } else {
        println!("\nwall {:.1} s", o.wall_s);
    }
    println!(
        "wrote {}: recording.csv, plan.json, campaign.json, static.blob, adaptive.blob, report/{}",
        out.display(),
        if a.explain.is_some() {
            ", explain.txt"
        } else {
            ""
        }
    );
}

/// The validate-and-return loop, one loop a row: what was added, the accuracy it started from,
/// before and after on its own block of tests (held out), and why it stopped.
pub fn loops_table(lp: &campaign::LoopState) -> String {
    use crate::campaign::state::BlockAccuracy;
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\nvalidate and return (paper 001 §II step 5), desired accuracy {:.0} nm (worst static test), blocks of {} tests:",
        lp.target_nm, lp.tests_per_block
    );
    let _ = writeln!(
        s,
        "  {:<4} {:<48} {:>9} {:>8} {:>15} {:>15} {:>8}",
        "loop",
        "added (explain; deployable in the blob)",
        "terms",
        "from nm",
        "before mean/max",
        "after mean/max",
        "agree"
    );
    let f = |v: Option<BlockAccuracy>| {
        v.map_or("–".to_string(), |x| {
            format!("{:.1}/{:.1}", x.mean_nm, x.worst_nm)
        })
    };
    for (i, l) in lp.loops.iter().enumerate() {
        let names: Vec<&str> = l.added.iter().map(|e| e.name.as_str()).collect();
        let (g, t, o) = l.parameters;
        let _ = writeln!(
            s,
            "  {:<4} {:<48} {:>9} {:>8.1} {:>15} {:>15} {:>8}",
            i + 1,
            names.join(", "),
            format!("{g}+{t}+{o}"),
            l.acc_from_nm,
            f(l.before),
            f(l.after),
            l.agreement_nm.map_or("–".into(), |v| format!("{v:.2}"))
        );
        for e in &l.evidence {
            let _ = writeln!(s, "       {e}");
        }
    }
    let _ = writeln!(
        s,
        "  (nm. from: the static model's worst test on the validation the loop started from; before/after: the model without and with the loop's terms on the loop's own block of tests, never used for a fit — mean over its tests of the test accuracy (Eq. 21's numerator) / the worst test; after through the firmware, before open loop on the same commands; agree: |firmware table − file-based validate|; terms geometric+thermal+other, offsets excluded)"
    );
    let stop = match &lp.stop {
        None => "not stopped yet (continue with --resume)".to_string(),
        Some(campaign::LoopStop::TargetMet { acc_nm }) => {
            format!("stopped: the desired accuracy is met ({acc_nm:.1} nm)")
        }
        Some(campaign::LoopStop::NoImprovement {
            before_nm,
            after_nm,
            advice,
        }) => {
            let mut t = format!(
                "stopped: the last loop did not improve held-out accuracy (mean test {before_nm:.1} → {after_nm:.1} nm); its model is not kept (static.blob is the one before)"
            );
            for a in advice {
                t += &format!("\n    - {a}");
            }
            t
        }
        Some(campaign::LoopStop::MaxLoops) => "stopped: --max-loops reached".to_string(),
        Some(campaign::LoopStop::DesignChange { advice }) => {
            let mut t =
                String::from("stopped: what remains needs a design change (paper 001 §II step 0):");
            for a in advice {
                t += &format!("\n    - {a}");
            }
            t
        }
    };
    let _ = writeln!(s, "  {stop}");
    s
}

/// The campaign's self-contained `report.html` ([`crate::report::html_report`]): the table from what
/// the stage received, the compensator's `MODEL_STALE` rises, explain's advice, the plots,
/// the files with their CRC and the command.
pub fn html_report(o: &campaign::Outcome, out: &std::path::Path) -> anyhow::Result<String> {
    use crate::report::html_report::{command_line, file_fingerprint, inline_plots, ReportContent};
    let a = &o.analysis;
    let rows: Vec<&crate::validate::ValidationReport> = a.campaign.iter().collect();
    let mut provenance: Vec<(String, String)> = [
        campaign::RECORDING,
        campaign::PLAN,
        "campaign.json",
        "static.blob",
        "adaptive.blob",
    ]
    .iter()
    .map(|f| (f.to_string(), file_fingerprint(&out.join(f))))
    .collect();
    provenance.push((
        "tool".into(),
        format!("nanocal {}", env!("CARGO_PKG_VERSION")),
    ));
    let mut device: Vec<String> = stale_lines(&o.state.stale)
        .lines()
        .map(str::to_string)
        .collect();
    device.push(format!(
        "{} KMZ re-measurements sent; {} compensator resets seen",
        o.state.kmz_updates, o.state.device_resets
    ));
    let content = ReportContent {
        title: format!("nanocal campaign {}", o.plan.name),
        command: command_line(),
        provenance,
        table: crate::validate::comparison_table(&rows),
        coverage: None,
        uncertainty: vec![format!(
            "file-based `validate` of the same recording agrees within {:.4} nm",
            a.max_difference_nm
        )],
        explain: a.explain.clone().map(|text| (a.advice.clone(), text)),
        explain_absent: "the campaign ran with --no-explain".into(),
        device: Some(device),
        plots: inline_plots(&rows)?,
    };
    Ok(content.render())
}

/// The compensator's `MODEL_STALE` rises, one line each (one line saying so when none rose).
pub fn stale_lines(events: &[campaign::state::StaleEvent]) -> String {
    if events.is_empty() {
        return "MODEL_STALE: never raised\n".into();
    }
    let mut o = String::new();
    for e in events {
        o += &format!(
            "MODEL_STALE on the {} model at {:.1} h of plan time ({}): {}{}\n",
            e.model,
            e.rose_s / 3600.0,
            e.during,
            e.reasons,
            e.envelope_excess_c
                .map(|v| format!(" (temperatures {v:+.3} °C beyond the envelope)"))
                .unwrap_or_default()
        );
    }
    o
}

fn json(o: &campaign::Outcome) -> serde_json::Value {
    let rep = |r: &crate::validate::ValidationReport| {
        serde_json::json!({
            "compensation": r.compensation.name(),
            "tests": r.tests.len(),
            "acc_per_test_um": r.tests.iter().map(|t| t.accuracy_um).collect::<Vec<_>>(),
            "rep_per_test_um": r.tests.iter().map(|t| t.repeatability_um).collect::<Vec<_>>(),
            "acc_first_um": r.summary.first_acc_um,
            "acc_max_um": r.summary.max_acc_um,
            "r_s_um": r.r_s_um,
            "r_t_um_per_h": r.r_t_um_per_h,
        })
    };
    serde_json::json!({
        "plan": o.plan.name,
        "campaign": o.analysis.campaign.iter().map(rep).collect::<Vec<_>>(),
        "validate": o.analysis.file.iter().map(rep).collect::<Vec<_>>(),
        "max_difference_nm": o.analysis.max_difference_nm,
        "kmz_updates": o.state.kmz_updates,
        "device_resets": o.state.device_resets,
        "model_stale": o.state.stale,
        "wall_s": o.wall_s,
        "qemu_cpu_s": o.qemu_cpu_s,
        "bus_transactions": o.bus_transactions,
        "advice": o.analysis.advice,
        "loops": o.state.loops,
        "fold_period_ms": o.state.fold_period_ms,
        "sample_period_ms": o.state.sample_period_ms,
        "command_jitter_nm": o.analysis.jitter_nm.iter().map(|(k, v)| (k.name(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    })
}
