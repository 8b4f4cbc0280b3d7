//! `nanocal validate`: apply a model to another recording as the firmware would; ISO 9283 per
//! test, robustness indices.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use nanocal_model::Model;

use crate::data::dwell::DwellOptions;
use crate::data::recording::Recording;
use crate::device::device_path::{SlowPeriods, DEVICE_FOLD_PERIOD_S, DEVICE_SAMPLE_PERIOD_S};
use crate::validate::iso9283::TestStats;
use crate::validate::{
    comparison_table, validate, Compensation, ValidationData, ValidationOptions, ValidationReport,
};

/// Validate a model blob on a recording: no model, the model as fitted (static), and its
/// geometric part with the offset re-measured at a reference pose (adaptive KMZ, paper 000
/// Eq. 14). Visits are grouped into tests
/// of `--cycles-per-test` cycles; per test, ISO 9283 accuracy and repeatability of every pose
/// (forward and backward approaches separate) and their maxima (paper 000 Eq. 2–7); over the
/// tests the robustness indices R_s (µm) and R_t (µm/h) of Eq. 20–21.
#[derive(Args, Debug, Clone)]
pub struct ValidateArgs {
    /// The model, the recording, and how to validate.
    #[command(flatten)]
    pub inputs: ValidationInputs,
    /// Also print the per-pose table of each compensation's first and worst test.
    #[arg(long)]
    pub per_pose: bool,
    /// Write the results as JSON here: per compensation `r_s_um`, `r_t_um_per_h` and every
    /// test's per-pose Acc and Rep.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The fit report of the model (`nanocal fit --json`): with it, the table and the JSON say
    /// how often the static compensation's measured error fell inside the fit's 95 % prediction
    /// interval (coverage).
    #[arg(long)]
    pub fit_json: Option<PathBuf>,
    /// Write one self-contained HTML report here (table, uncertainty and coverage, explain's
    /// findings, plots inline as SVG, provenance, the exact command; prints on A4).
    #[arg(long)]
    pub report: Option<PathBuf>,
}

/// One line per fact of a fit report's uncertainty: per axis the prediction interval and the
/// held-out accuracy, then the collinearity warnings.
pub fn uncertainty_lines(fit: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    for ax in fit["axes"].as_array().into_iter().flatten() {
        let name = ax["axis"].as_str().unwrap_or("?");
        let pi = &ax["prediction_interval_95_training_um"];
        if let (Some(lo), Some(hi)) = (pi["min"].as_f64(), pi["max"].as_f64()) {
            out.push(format!(
                "axis {name}: 95 % prediction interval of the correction over the training envelope ± {:.1} … {:.1} nm; training RMS {:.1} nm",
                lo * 1e3,
                hi * 1e3,
                ax["rmse_um"].as_f64().unwrap_or(f64::NAN) * 1e3
            ));
        }
        let ho = &ax["held_out_um"];
        if let Some(rms) = ho["rms"].as_f64() {
            out.push(format!(
                "axis {name}: held-out accuracy over {} blocks of time: RMS {:.1} nm, max |error| {:.1} nm",
                ho["blocks"].as_u64().unwrap_or(0),
                rms * 1e3,
                ho["max_abs"].as_f64().unwrap_or(f64::NAN) * 1e3
            ));
        }
    }
    for w in fit["temperature_vif"]["warnings"]
        .as_array()
        .into_iter()
        .flatten()
    {
        if let Some(w) = w.as_str() {
            out.push(w.to_string());
        }
    }
    out
}

/// The prediction bands of `model`, one per axis, from a fit report written by `nanocal fit
/// --json`; an error naming the file when it does not belong to the model.
pub fn read_bands(
    path: &Path,
    model: &Model,
) -> anyhow::Result<Vec<crate::numerics::uncertainty::PredictionBand>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let id = v["model_id"].as_u64();
    if id != Some(u64::from(model.id())) {
        anyhow::bail!(
            "{}: fit report of model id {:?}, but the blob's id is {}",
            path.display(),
            id,
            model.id()
        );
    }
    let axes = v["axes"]
        .as_array()
        .with_context(|| format!("{}: no `axes` array (not a fit report)", path.display()))?;
    if axes.len() != model.axes() {
        anyhow::bail!(
            "{}: {} axes, the model has {}",
            path.display(),
            axes.len(),
            model.axes()
        );
    }
    axes.iter()
        .enumerate()
        .map(|(a, ax)| {
            if let Some(e) = ax["prediction_band_error"].as_str() {
                anyhow::bail!("{}: axis {a} has no prediction band: {e}", path.display());
            }
            let band: crate::numerics::uncertainty::PredictionBand =
                serde_json::from_value(ax["prediction_band"].clone()).with_context(|| {
                    format!("{}: axis {a}: bad `prediction_band`", path.display())
                })?;
            let terms = model
                .terms()
                .iter()
                .filter(|t| t.output as usize == a)
                .count();
            if band.regressors() != terms {
                anyhow::bail!(
                    "{}: axis {a}: the band has {} regressors, the model {terms} terms: not this model's fit",
                    path.display(),
                    band.regressors()
                );
            }
            Ok(band)
        })
        .collect()
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
    /// Minimum interval between KMZ re-measurements at the reference pose, s (paper 000:
    /// 3.75 h).
    #[arg(long, default_value_t = 13_500.0)]
    pub kmz_interval_s: f64,
    /// Average the last this many seconds of each dwell (paper 000: 5 s).
    #[arg(long, default_value_t = 5.0)]
    pub average_last_s: f64,
    /// Cycles per test (paper 000: 15); a cycle starts when the command returns to the first
    /// pose.
    #[arg(long, default_value_t = 15)]
    pub cycles_per_test: usize,
    /// The device's fold period, s: the readings of a period are averaged and the model folded
    /// once a period (the device's default: 5 s).
    #[arg(long, default_value_t = DEVICE_FOLD_PERIOD_S)]
    pub fold_period_s: f64,
    /// The device's sensor sample period, s (the device's default: 0.25 s).
    #[arg(long, default_value_t = DEVICE_SAMPLE_PERIOD_S)]
    pub sample_period_s: f64,
    /// `Time` of R_t (Eq. 21), h; default: from the start of the first test to the end of the
    /// last.
    #[arg(long)]
    pub time_h: Option<f64>,
    /// The plan the recording followed (JSON, e.g. from `nanocal simulate --plan`): its steps
    /// make the visits (step times = the recording's `t`), its tests and their compensations
    /// the statistics, its KMZ steps the re-measurements (instead of cycles and intervals).
    #[arg(long)]
    pub plan: Option<PathBuf>,
}

impl ValidationInputs {
    /// The device's slow-path periods as given.
    fn periods(&self) -> SlowPeriods {
        SlowPeriods {
            sample_s: self.sample_period_s,
            fold_s: self.fold_period_s,
        }
    }

    /// Reads the model and the recording, and validates three ways: no model, static, adaptive
    /// KMZ.
    pub fn validate_three_ways(&self) -> anyhow::Result<(ValidationData, [ValidationReport; 3])> {
        let model = read_model(&self.model)?;
        let bar = spinner(format!("reading {}", self.recording.display()));
        let rec = Recording::read_path(&self.recording)?;
        bar.finish_and_clear();
        if let Some(path) = &self.plan {
            return self.validate_plan(&model, &rec, path);
        }
        let data = ValidationData::from_recording(
            &rec,
            &DwellOptions {
                average_last_s: self.average_last_s,
                ..Default::default()
            },
        )
        .with_context(|| format!("{}", self.recording.display()))?;
        let opts = ValidationOptions {
            slow: self.periods(),
            cycles_per_test: self.cycles_per_test,
            time_h: self.time_h,
        };
        let bar = spinner("validating: no model, static, adaptive KMZ");
        let kmz = Compensation::Adaptive {
            reference_um: self.reference_pose_um.clone(),
            interval_s: self.kmz_interval_s,
        };
        let reports = [
            validate(None, &data, &Compensation::None, &opts)?,
            validate(Some(&model), &data, &Compensation::Static, &opts)?,
            validate(Some(&adaptive(&model)?), &data, &kmz, &opts)?,
        ];
        bar.finish_and_clear();
        Ok((data, reports))
    }
}

impl ValidationInputs {
    /// Validates as the plan at `path` says: the validation steps of its schedule, each test with
    /// the compensation the plan gave it (tests of other compensations are left out of that
    /// compensation's statistics), KMZ at its KMZ steps.
    fn validate_plan(
        &self,
        model: &Model,
        rec: &Recording,
        path: &Path,
    ) -> anyhow::Result<(ValidationData, [ValidationReport; 3])> {
        use crate::data::plan::{Phase, Plan, TestKind};
        use crate::validate::procedure::ProcedureData;
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let plan: Plan = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a plan", path.display()))?;
        let steps: Vec<_> = plan
            .schedule()
            .into_iter()
            .filter(|s| s.phase != Phase::Training)
            .collect();
        let data = ProcedureData::new(rec, &steps, 0.0).with_context(|| {
            format!(
                "{} does not follow the validation of {}",
                self.recording.display(),
                path.display()
            )
        })?;
        let kmz = plan.validation.kmz.as_ref();
        let p = self.periods();
        let reports = [
            data.validate(TestKind::NoModel, None, kmz, p)?,
            data.validate(TestKind::Static, Some(model), kmz, p)?,
            data.validate(TestKind::Adaptive, Some(&adaptive(model)?), kmz, p)?,
        ];
        Ok((data.data, reports))
    }
}

/// The adaptive model of paper 000's Eq. 14 from a fitted blob: its geometric part + λ_KMZ.
fn adaptive(model: &Model) -> anyhow::Result<Model> {
    crate::fit::adaptive_from_static(model)
        .map_err(|e| anyhow::anyhow!("building the adaptive model (Eq. 14): {e:?}"))
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

/// Per-pose table of one test (nm).
pub fn per_pose_table(name: &str, t: &TestStats) -> String {
    use std::fmt::Write;
    let mut s = format!(
        "{name} — test {} ({:.2}–{:.2} h), per pose (nm):\n",
        t.index + 1,
        t.t_start_s / 3600.0,
        t.t_end_s / 3600.0
    );
    let _ = writeln!(
        s,
        "{:>14} {:>9} {:>5} {:>9} {:>9}",
        "target_um", "approach", "n", "Acc", "Rep"
    );
    for p in &t.poses {
        let approach = match p.approach.first() {
            Some(d) if *d > 0 => "forward",
            Some(d) if *d < 0 => "backward",
            _ => "-",
        };
        let _ = writeln!(
            s,
            "{:>14} {:>9} {:>5} {:>9.1} {:>9.1}",
            p.target_um
                .iter()
                .map(|v| format!("{v}"))
                .collect::<Vec<_>>()
                .join(","),
            approach,
            p.n,
            p.accuracy_um * 1e3,
            p.repeatability_um * 1e3,
        );
    }
    s
}

/// One test as JSON (µm).
pub fn test_json(t: &TestStats) -> serde_json::Value {
    let poses: Vec<serde_json::Value> = t
        .poses
        .iter()
        .map(|p| {
            serde_json::json!({"target_um": p.target_um, "approach": p.approach, "n": p.n,
            "accuracy_um": p.accuracy_um, "repeatability_um": p.repeatability_um,
            "mean_error_um": p.mean_error_um})
        })
        .collect();
    serde_json::json!({"test": t.index, "t_start_s": t.t_start_s, "t_end_s": t.t_end_s,
        "accuracy_um": t.accuracy_um, "repeatability_um": t.repeatability_um, "poses": poses})
}

/// The results of one validation as JSON (µm, µm/h).
pub fn report_json(r: &ValidationReport) -> serde_json::Value {
    let d = &r.distribution;
    let m = &r.summary;
    serde_json::json!({
        "compensation": r.compensation.name(),
        "r_s_um": r.r_s_um, "r_t_um_per_h": r.r_t_um_per_h, "time_h": r.time_h,
        "first_test_accuracy_um": m.first_acc_um, "median_test_accuracy_um": m.median_acc_um,
        "max_test_accuracy_um": m.max_acc_um, "min_test_accuracy_um": m.min_acc_um,
        "median_test_repeatability_um": m.median_rep_um, "max_test_repeatability_um": m.max_rep_um,
        "max_test_accuracy_forward_um": m.max_acc_forward_um,
        "max_test_accuracy_backward_um": m.max_acc_backward_um,
        "visits": d.n, "rms_um": d.rms_um, "p90_um": d.p90_um, "max_um": d.max_um,
        "kmz_updates": r.kmz_updates, "outside_envelope_visits": r.outside_envelope,
        "inverse_failures": r.inverse_failures,
        "tests": r.tests.iter().map(test_json).collect::<Vec<_>>(),
    })
}

/// Runs `nanocal validate`.
pub fn run(args: ValidateArgs) -> anyhow::Result<()> {
    let (data, reports) = args.inputs.validate_three_ways()?;
    println!(
        "{} dwells, {} tests of {} cycles, KMZ re-measured {} times at {:?} µm",
        data.dwells.len(),
        reports[0].tests.len(),
        args.inputs.cycles_per_test,
        reports[2].kmz_updates,
        args.inputs.reference_pose_um
    );
    print!(
        "{}",
        comparison_table(&[&reports[0], &reports[1], &reports[2]])
    );
    let mut fit_report = serde_json::Value::Null;
    let coverage = match &args.fit_json {
        Some(path) => {
            let model = read_model(&args.inputs.model)?;
            let bands = read_bands(path, &model)?;
            fit_report = serde_json::from_str(&std::fs::read_to_string(path)?)?;
            let c = crate::validate::coverage(&reports[1], &model, &bands, 0.95)?;
            println!(
                "coverage of the fit's 95 % prediction interval (static): {:.1} % of {} visit-axes inside (nominal 95 %; median half-width {:.1} nm)",
                100.0 * c.fraction(),
                c.n,
                c.median_half_width_um * 1e3
            );
            Some(c)
        }
        None => None,
    };
    if reports[1].outside_envelope > 0 {
        println!(
            "note: {} of {} visits had temperature/aux inputs outside the training envelope",
            reports[1].outside_envelope, reports[1].distribution.n
        );
    }
    if args.per_pose {
        for r in &reports {
            let worst = r
                .tests
                .iter()
                .max_by(|a, b| a.accuracy_um.total_cmp(&b.accuracy_um));
            for t in r.tests.first().into_iter().chain(worst) {
                print!("{}", per_pose_table(r.compensation.name(), t));
            }
        }
    }
    if let Some(path) = &args.json {
        let mut all: Vec<serde_json::Value> = reports.iter().map(report_json).collect();
        if let Some(c) = &coverage {
            all[1]["prediction_interval_coverage"] = serde_json::json!({
                "nominal": c.level, "measured": c.fraction(), "inside": c.inside,
                "visit_axes": c.n, "median_half_width_um": c.median_half_width_um});
        }
        let json = serde_json::Value::Array(all);
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.report {
        let bar = spinner("report.html: plots and explain");
        let html = html_report(&args, &data, &reports, coverage, &fit_report)?;
        bar.finish_and_clear();
        std::fs::write(path, html).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// The self-contained HTML report of a validation ([`crate::report::html_report`]).
fn html_report(
    args: &ValidateArgs,
    data: &crate::validate::ValidationData,
    reports: &[ValidationReport; 3],
    coverage: Option<crate::validate::Coverage>,
    fit_report: &serde_json::Value,
) -> anyhow::Result<String> {
    use crate::report::html_report::{command_line, file_fingerprint, inline_plots, ReportContent};
    let model = read_model(&args.inputs.model)?;
    let explain = if data.dwells.len() >= 50 {
        let rec = data.dwells.to_recording();
        let d = crate::explain::Data::from_recording(&rec, None)
            .map_err(|e| anyhow::anyhow!("explain: {e}"))?;
        let r = crate::explain::explain(&d, &crate::explain::Settings::default())
            .map_err(|e| anyhow::anyhow!("explain: {e}"))?;
        let findings = r
            .effects()
            .map(|e| {
                format!(
                    "{} on {}: {} — {} (held-out RMS {:.0} → {:.0} nm)",
                    e.name, e.channel, e.description, e.deploy, e.rms_before_nm, e.rms_after_nm
                )
            })
            .collect();
        Some((findings, r.to_text()))
    } else {
        None
    };
    let mut provenance = vec![
        ("model".to_string(), file_fingerprint(&args.inputs.model)),
        ("model id".to_string(), format!("0x{:08x}", model.id())),
        (
            "recording".to_string(),
            file_fingerprint(&args.inputs.recording),
        ),
        (
            "tool".to_string(),
            format!("nanocal {}", env!("CARGO_PKG_VERSION")),
        ),
    ];
    if let Some(p) = &args.fit_json {
        provenance.push(("fit report".to_string(), file_fingerprint(p)));
    }
    if let Some(p) = &args.inputs.plan {
        provenance.push(("plan".to_string(), file_fingerprint(p)));
    }
    let content = ReportContent {
        title: format!(
            "nanocal validation of {} on {}",
            args.inputs
                .model
                .file_name()
                .map_or(String::new(), |s| s.to_string_lossy().into_owned()),
            args.inputs
                .recording
                .file_name()
                .map_or(String::new(), |s| s.to_string_lossy().into_owned())
        ),
        command: command_line(),
        provenance,
        table: comparison_table(&[&reports[0], &reports[1], &reports[2]]),
        coverage,
        uncertainty: uncertainty_lines(fit_report),
        explain,
        explain_absent: "fewer than 50 validation dwells".into(),
        device: None,
        plots: inline_plots(&[&reports[0], &reports[1], &reports[2]])?,
    };
    Ok(content.render())
}
