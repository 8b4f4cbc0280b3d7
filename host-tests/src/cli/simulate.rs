//! `nanocal simulate`: run the digital twin and write a recording (CSV, shared layout).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};

use crate::effects::EffectSpec;
use crate::twin::{examples, Trajectory, Twin, TwinConfig};

/// Which stage to simulate.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Preset {
    /// 1-DoF stage like the published one (0–500 µm, four sensors).
    Published1dof,
    /// 2-DoF stage (x, y over 0–80 µm).
    Published2dof,
}

/// Which trajectory to run.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum TrajectoryKind {
    /// Published training: 0:30:480 µm forward/backward (1-DoF) or the 0:10:80 µm grid (2-DoF).
    Training,
    /// Published validation poses, one cycle per hour.
    Validation,
    /// The stage stands still at its first pose (thermal-only recording).
    Standstill,
    /// Write both files of the bundled published example (training.csv, validation.csv) into --out.
    PublishedExample,
}

/// A published procedure the twin can run whole (training and validation).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum PublishedPlan {
    /// Paper 000's 1-DoF calibration (§4.2, §4.3.2) on its stage.
    Paper000_1dof,
    /// Paper 000's 2-DoF calibration (§5.2) on its stage.
    Paper000_2dof,
    /// Paper 001's delta robot (§IV.C, §VII.A).
    Paper001Robot,
}

/// Arguments of `nanocal simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Stage preset (ignored with --config).
    #[arg(long, value_enum, default_value = "published1dof")]
    pub preset: Preset,
    /// A full twin configuration as JSON (see `--print-config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the configuration as JSON and exit.
    #[arg(long)]
    pub print_config: bool,
    /// Trajectory.
    #[arg(long, value_enum, default_value = "training")]
    pub trajectory: TrajectoryKind,
    /// Number of cycles of the trajectory (training/validation) or hours (standstill).
    #[arg(long, default_value_t = 6)]
    pub cycles: usize,
    /// Dwell per pose, s.
    #[arg(long, default_value_t = 60.0)]
    pub dwell_s: f64,
    /// Sample period, s (overrides the preset).
    #[arg(long)]
    pub sample_period_s: Option<f64>,
    /// Record a barometric pressure column (hPa).
    #[arg(long)]
    pub pressure: bool,
    /// Switch an effect on: NAME:key=value,key=value (e.g. `thermal_lag:tau_s=1800`,
    /// `hysteresis:axis=0,half_width_nm=20,slope_nm=0`). Repeatable.
    #[arg(long = "effect")]
    pub effects: Vec<String>,
    /// Seed: the same seed gives the same recording.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run a published procedure whole on its twin and write training.csv, validation.csv and
    /// plan.json into --out (a directory); validate with `nanocal validate … --plan plan.json`.
    #[arg(long, value_enum)]
    pub plan: Option<PublishedPlan>,
    /// Output CSV file (a directory for --trajectory published-example and --plan).
    #[arg(short, long)]
    pub out: PathBuf,
}

/// Runs a published plan on its twin and writes the recordings and the plan.
fn run_published(which: PublishedPlan, seed: u64, out: &std::path::Path) -> Result<()> {
    use crate::data::plan::Plan;
    use crate::twin::delta::{DeltaConfig, DeltaTwin};
    use crate::twin::execute::run_plan;
    let start = examples::TRAINING_START_S;
    let (plan, run) = match which {
        PublishedPlan::Paper000_1dof => {
            let p = Plan::paper000_1dof();
            let r = run_plan(&examples::paper000_1dof_twin(seed), &p, start, 1, true);
            (p, r)
        }
        PublishedPlan::Paper000_2dof => {
            let p = Plan::paper000_2dof();
            let r = run_plan(&examples::paper000_2dof_twin(seed), &p, start, 2, true);
            (p, r)
        }
        PublishedPlan::Paper001Robot => {
            let p = Plan::paper001_robot();
            let twin = DeltaTwin::new(DeltaConfig::paper001(seed), 3.0 * 86_400.0, seed);
            let r = run_plan(&twin, &p, start, 4, false);
            (p, r)
        }
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (train, val) = run.split();
    for (name, rec) in [("training.csv", train), ("validation.csv", val)] {
        let p = out.join(name);
        let f = std::io::BufWriter::new(
            std::fs::File::create(&p).with_context(|| format!("creating {}", p.display()))?,
        );
        rec.write_csv(f)?;
        println!("wrote {} ({} rows)", p.display(), rec.rows());
    }
    let p = out.join("plan.json");
    std::fs::write(&p, serde_json::to_string_pretty(&plan)?)
        .with_context(|| format!("writing {}", p.display()))?;
    println!("wrote {}", p.display());
    Ok(())
}

/// Parse `NAME:key=value,...` into an effect specification.
pub fn parse_effect(s: &str) -> Result<EffectSpec> {
    let (name, rest) = s.split_once(':').unwrap_or((s, ""));
    let mut obj = serde_json::Map::new();
    obj.insert("name".into(), serde_json::Value::String(name.trim().into()));
    for kv in rest.split(',').filter(|kv| !kv.trim().is_empty()) {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("effect parameter `{kv}`: expected key=value"))?;
        let value: serde_json::Value = if v.contains(';') {
            serde_json::Value::Array(
                v.split(';')
                    .map(|x| x.trim().parse::<f64>().map(serde_json::Value::from))
                    .collect::<Result<_, _>>()
                    .with_context(|| {
                        format!("effect parameter `{kv}`: expected numbers separated by `;`")
                    })?,
            )
        } else {
            let f: f64 = v
                .trim()
                .parse()
                .with_context(|| format!("effect parameter `{kv}`: expected a number"))?;
            if k.trim() == "axis" || k.trim().ends_with("_axis") {
                serde_json::Value::from(f as u64)
            } else {
                serde_json::Value::from(f)
            }
        };
        obj.insert(k.trim().into(), value);
    }
    serde_json::from_value(serde_json::Value::Object(obj)).with_context(|| {
        format!(
            "effect `{s}`: expected one of {:?} with all its parameters",
            crate::effects::NAMES
        )
    })
}

/// Run the subcommand.
pub fn run(args: SimulateArgs) -> Result<()> {
    if let Some(which) = args.plan {
        return run_published(which, args.seed, &args.out);
    }
    if let TrajectoryKind::PublishedExample = args.trajectory {
        let (train, val) = examples::published_1dof(args.seed);
        std::fs::create_dir_all(&args.out)
            .with_context(|| format!("creating {}", args.out.display()))?;
        for (name, rec) in [("training.csv", train), ("validation.csv", val)] {
            let p = args.out.join(name);
            let f = std::io::BufWriter::new(
                std::fs::File::create(&p).with_context(|| format!("creating {}", p.display()))?,
            );
            rec.write_csv(f)?;
            println!("wrote {} ({} rows)", p.display(), rec.rows());
        }
        return Ok(());
    }
    let mut cfg = match &args.config {
        Some(p) => serde_json::from_str(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("{}: not a twin configuration", p.display()))?,
        None => match args.preset {
            Preset::Published1dof => TwinConfig::published_1dof(),
            Preset::Published2dof => TwinConfig::published_2dof(),
        },
    };
    if let Some(sp) = args.sample_period_s {
        cfg.sample_period_s = sp;
    }
    cfg.record_pressure |= args.pressure;
    for e in &args.effects {
        cfg.effects.push(parse_effect(e)?);
    }
    if args.print_config {
        println!("{}", serde_json::to_string_pretty(&cfg)?);
        return Ok(());
    }
    if cfg.axes == 0 || cfg.axes > 3 {
        bail!("axes: expected 1 to 3, found {}", cfg.axes);
    }
    let traj = match (args.trajectory, cfg.axes) {
        (TrajectoryKind::Training, 1) => {
            Trajectory::published_training_1dof(args.dwell_s, args.cycles)
        }
        (TrajectoryKind::Training, _) => Trajectory::published_grid_2dof(args.dwell_s, args.cycles),
        (TrajectoryKind::Validation, 1) => Trajectory::published_validation_1dof(
            args.dwell_s,
            args.cycles,
            3600.0 - 13.0 * args.dwell_s,
        ),
        (TrajectoryKind::Validation, _) => Trajectory::published_validation_2dof(
            args.dwell_s,
            args.cycles,
            3600.0 - 6.0 * args.dwell_s,
        ),
        (TrajectoryKind::Standstill, n) => {
            Trajectory::standstill(vec![0.0; n], args.cycles as f64 * 3600.0)
        }
        (TrajectoryKind::PublishedExample, _) => unreachable!(),
    };
    let twin = Twin::new(cfg, traj.duration_s() + 2.0 * 86_400.0, args.seed);
    let rec = twin.simulate(&traj, examples::TRAINING_START_S, 1);
    let f = std::io::BufWriter::new(
        std::fs::File::create(&args.out)
            .with_context(|| format!("creating {}", args.out.display()))?,
    );
    rec.write_csv(f)?;
    println!(
        "wrote {} ({} rows, {} columns)",
        args.out.display(),
        rec.rows(),
        rec.columns.len()
    );
    Ok(())
}
