//! `nanocal validate`: apply a model to another recording as the firmware would; ISO 9283.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use nanocal_model::Model;

use crate::dwell::{dwell_average, DwellOptions, Dwells};
use crate::recording::Recording;
use crate::validate::{comparison_table, validate, Compensation, ValidationReport};

/// Validate a model blob on a recording: no model, the model as fitted (static), and the model
/// with its offset re-measured at a reference pose (adaptive KMZ). Prints ISO 9283 accuracy and
/// repeatability per pose, the maximum over poses (forward and backward separately),
/// percentiles and the robustness indices R_s, R_t.
#[derive(Args, Debug, Clone)]
pub struct ValidateArgs {
    /// The model, the recording, and how to validate.
    #[command(flatten)]
    pub inputs: ValidationInputs,
    /// Also print the per-pose table of each compensation.
    #[arg(long)]
    pub per_pose: bool,
    /// Write the summary as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// What `validate` and `report` both read, and how they validate.
#[derive(Args, Debug, Clone)]
pub struct ValidationInputs {
    /// Model blob (from `nanocal fit`).
    pub model: PathBuf,
    /// Validation recording (CSV, shared layout).
    pub recording: PathBuf,
    /// Reference pose for KMZ, µm (one value per axis, comma separated).
    #[arg(long, value_delimiter = ',', default_value = "0")]
    pub reference_pose_um: Vec<f64>,
    /// Minimum interval between KMZ re-measurements at the reference pose, s.
    #[arg(long, default_value_t = 3600.0)]
    pub kmz_interval_s: f64,
    /// Average the last this many seconds of each dwell.
    #[arg(long, default_value_t = 10.0)]
    pub average_last_s: f64,
}

impl ValidationInputs {
    /// Reads the model and the recording's dwells, and validates three ways: no model, static,
    /// adaptive KMZ.
    pub fn validate_three_ways(&self) -> anyhow::Result<(Dwells, [ValidationReport; 3])> {
        let model = read_model(&self.model)?;
        let d = read_dwells(&self.recording, self.average_last_s)?;
        let bar = spinner("validating: no model, static, adaptive KMZ");
        let reports = three_ways(&model, &d, &self.reference_pose_um, self.kmz_interval_s)?;
        bar.finish_and_clear();
        Ok((d, reports))
    }
}

/// A spinner on stderr for long work (indicatif hides it when stderr is not a terminal).
pub fn spinner(message: impl Into<String>) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new_spinner();
    bar.set_message(message.into());
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Reads and decodes a model blob.
pub fn read_model(path: &Path) -> anyhow::Result<Model> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    nanocal_model::blob::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: not a valid model blob: {e}", path.display()))
}

/// Reads a recording and averages its dwells.
fn read_dwells(path: &Path, average_last_s: f64) -> anyhow::Result<Dwells> {
    let bar = spinner(format!("reading {}", path.display()));
    let rec = Recording::read_path(path)?;
    bar.finish_and_clear();
    let d = dwell_average(
        &rec,
        &DwellOptions {
            average_last_s,
            ..Default::default()
        },
    )
    .with_context(|| format!("{}", path.display()))?;
    Ok(d)
}

/// The three validations (no model, static, adaptive KMZ) of `model` on `d`.
fn three_ways(
    model: &Model,
    d: &Dwells,
    reference_um: &[f64],
    interval_s: f64,
) -> anyhow::Result<[ValidationReport; 3]> {
    Ok([
        validate(None, d, &Compensation::None)?,
        validate(Some(model), d, &Compensation::Static)?,
        validate(
            Some(model),
            d,
            &Compensation::Adaptive {
                reference_um: reference_um.to_vec(),
                interval_s,
            },
        )?,
    ])
}

/// Per-pose table (nm).
pub fn per_pose_table(r: &ValidationReport) -> String {
    use std::fmt::Write;
    let mut s = format!("{} — per pose (nm):\n", r.compensation.name());
    let _ = writeln!(
        s,
        "{:>12} {:>6} {:>10} {:>10} {:>10} {:>10}",
        "target_um", "n", "Acc", "Rep", "Acc_fwd", "Acc_bwd"
    );
    for p in &r.poses {
        let find = |v: &[crate::iso9283::PoseStats]| {
            v.iter()
                .find(|q| q.target_um == p.target_um)
                .map_or(f64::NAN, |q| q.accuracy_um * 1e3)
        };
        let _ = writeln!(
            s,
            "{:>12} {:>6} {:>10.1} {:>10.1} {:>10.1} {:>10.1}",
            p.target_um
                .iter()
                .map(|v| format!("{v}"))
                .collect::<Vec<_>>()
                .join(","),
            p.n,
            p.accuracy_um * 1e3,
            p.repeatability_um * 1e3,
            find(&r.forward),
            find(&r.backward)
        );
    }
    s
}

/// The summary of one validation as JSON (µm).
pub fn report_json(r: &ValidationReport) -> serde_json::Value {
    let poses: Vec<serde_json::Value> = r
        .poses
        .iter()
        .map(|p| {
            serde_json::json!({"target_um": p.target_um, "n": p.n, "accuracy_um": p.accuracy_um,
            "repeatability_um": p.repeatability_um, "mean_error_um": p.mean_error_um})
        })
        .collect();
    let d = &r.distribution;
    serde_json::json!({
        "compensation": r.compensation.name(),
        "max_accuracy_um": r.max_um.0, "max_repeatability_um": r.max_um.1,
        "max_accuracy_forward_um": r.max_forward_um.0, "max_accuracy_backward_um": r.max_backward_um.0,
        "max_repeatability_forward_um": r.max_forward_um.1, "max_repeatability_backward_um": r.max_backward_um.1,
        "rms_um": d.rms_um, "p50_um": d.p50_um, "p90_um": d.p90_um, "p95_um": d.p95_um, "max_um": d.max_um,
        "normal90_um": d.normal90_um, "r_s": r.r_s, "r_t": r.r_t, "tests": r.tests, "visits": d.n,
        "kmz_updates": r.kmz_updates, "outside_envelope_visits": r.outside_envelope,
        "inverse_failures": r.inverse_failures, "poses": poses,
    })
}

/// Runs `nanocal validate`.
pub fn run(args: ValidateArgs) -> anyhow::Result<()> {
    let (d, reports) = args.inputs.validate_three_ways()?;
    println!(
        "{} dwells, {} tests, KMZ re-measured {} times at {:?} µm",
        d.len(),
        reports[2].tests,
        reports[2].kmz_updates,
        args.inputs.reference_pose_um
    );
    print!(
        "{}",
        comparison_table(&[&reports[0], &reports[1], &reports[2]])
    );
    if reports[1].outside_envelope > 0 {
        println!(
            "note: {} of {} visits had temperature/aux inputs outside the training envelope",
            reports[1].outside_envelope, reports[1].distribution.n
        );
    }
    if args.per_pose {
        for r in &reports {
            print!("{}", per_pose_table(r));
        }
    }
    if let Some(path) = &args.json {
        let json = serde_json::Value::Array(reports.iter().map(report_json).collect());
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
