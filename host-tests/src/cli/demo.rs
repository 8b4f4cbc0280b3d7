//! `nanocal demo`: the published procedures of paper 000, like for like, on the digital twin:
//! the 1-DoF stage at stable temperature (§4.3.1), the 1-DoF calibration and five-day
//! validation (§4.2, §4.3.2), and the 2-DoF calibration (§5.2) — each printed beside the
//! paper's figures, with recordings, plans, model blobs and plots.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::data::dwell::Dwells;
use crate::data::plan::{Plan, TestKind};
use crate::data::recording::Recording;
use crate::device::device_path::{SlowPeriods, DEVICE_FOLD_PERIOD_S, DEVICE_SAMPLE_PERIOD_S};
use crate::fit::design::DesignSpec;
use crate::fit::{
    adaptive_from_static, encode_blob, fit_dwells, parameter_count, FitOptions, FitReport,
    Selection,
};
use crate::numerics::stepwise::StepwiseOptions;
use crate::report::write_report;
use crate::twin::examples::{self, TRAINING_START_S};
use crate::twin::execute::{run_plan, PlanRun};
use crate::twin::Columns;
use crate::validate::iso9283::{per_pose_approach, TestStats};
use crate::validate::procedure::ProcedureData;
use crate::validate::ValidationReport;

/// Run paper 000's published procedures on the digital twin and print this project's figures
/// beside the paper's: (1) one test at stable temperature (accuracy, repeatability);
/// (2) the 1-DoF calibration — training 0:30:480 µm, 67 cycles of 34 steps (2 s rise + 20 s
/// hold, mean of the last 5 s, 13.9 h), static model (Eq. 11, stepwise) and adaptive model
/// (Eq. 14: its geometric part + KMZ), then five days of validation tests (15 cycles each) in
/// the order no model, adaptive, static with the KMZ re-measured every 3.75 h: Acc and Rep per
/// test, R_s, R_t; (3) the 2-DoF calibration — 0:10:80 µm grid, 12 cycles, Eq. 22, validation
/// at P0…P5. Writes the recordings, the plans (JSON), the model blobs and plots.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Folder for recordings, plans, model blobs and plots (created if needed).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seed of the simulated rooms and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Interval between KMZ re-measurements at 0 µm, s (paper 000: 3.75 h).
    #[arg(long, default_value_t = 3.75 * 3600.0)]
    pub kmz_interval_s: f64,
    /// The device's fold period, s: its readings are averaged over a period and the model
    /// folded once a period (the device's default, 5 s; paper 001 §VI: "each 5-10 seconds").
    #[arg(long, default_value_t = DEVICE_FOLD_PERIOD_S)]
    pub fold_period_s: f64,
    /// The device's sensor sample period, s (the device's default, 0.25 s).
    #[arg(long, default_value_t = DEVICE_SAMPLE_PERIOD_S)]
    pub sample_period_s: f64,
    /// Print each procedure's plan as JSON and exit.
    #[arg(long)]
    pub print_plans: bool,
}

/// Paper 000's figures for the 1-DoF procedure, quoted from its text, Table 2 and Fig. 10–12.
mod paper {
    /// (compensation, Acc of its first test T1/T2/T3 in nm, max − min of that test in nm,
    /// the five-day accuracy as the text gives it, R_s µm, R_t µm/h).
    pub const ONE_DOF: [(&str, f64, f64, &str, f64, f64); 3] = [
        ("no model", 650.0, 300.0, "0.4–1 µm", 0.3476, 0.0058),
        ("adaptive KMZ", 43.0, 35.0, "< 100 nm", 0.0493, 0.0005),
        ("static", 95.0, 40.0, "< 400 nm for 70 h", 0.0577, 0.0029),
    ];
}

fn bar(len: u64) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} {msg}").expect("static template"),
    );
    bar
}

fn write_csv(path: &Path, c: &Columns) -> anyhow::Result<Recording> {
    let rec = c.to_recording()?;
    rec.write_path(path)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(rec)
}

fn write_json(path: &Path, v: &impl serde::Serialize) -> anyhow::Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)?)
        .with_context(|| format!("writing {}", path.display()))
}

impl DemoArgs {
    /// The device's slow-path periods as given.
    fn periods(&self) -> SlowPeriods {
        SlowPeriods {
            sample_s: self.sample_period_s,
            fold_s: self.fold_period_s,
        }
    }
}

/// Writes `dir/report.html` ([`crate::report::html_report`]) for one of the demo's stages: its
/// validation table and plots, the files in `dir` it rests on with their CRC, the command.
fn demo_html(
    dir: &std::path::Path,
    what: &str,
    reports: &[&crate::validate::ValidationReport],
    files: &[&str],
) -> anyhow::Result<()> {
    use crate::report::html_report::{command_line, file_fingerprint, inline_plots, ReportContent};
    let mut provenance: Vec<(String, String)> = files
        .iter()
        .map(|f| (f.to_string(), file_fingerprint(&dir.join(f))))
        .collect();
    provenance.push((
        "tool".into(),
        format!("nanocal {}", env!("CARGO_PKG_VERSION")),
    ));
    let content = ReportContent {
        title: format!("nanocal demo: {what}, the published procedure on the digital twin"),
        command: command_line(),
        provenance,
        table: crate::validate::comparison_table(reports),
        coverage: None,
        uncertainty: Vec::new(),
        explain: None,
        explain_absent:
            "the demo compares with the papers; run `nanocal explain` on validation.csv".into(),
        device: None,
        plots: inline_plots(reports)?,
    };
    let path = dir.join("report.html");
    std::fs::write(&path, content.render())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Runs `nanocal demo`.
pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let one = Plan::paper000_1dof();
    let mut one = one;
    if let Some(k) = one.validation.kmz.as_mut() {
        k.interval_s = args.kmz_interval_s;
    }
    let two = Plan::paper000_2dof();
    if args.print_plans {
        let robot = Plan::paper001_robot();
        println!("{}", serde_json::to_string_pretty(&[&one, &two, &robot])?);
        return Ok(());
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = bar(10);

    bar.set_message("1-DoF at stable temperature (§4.3.1)");
    let stable = stable_test(args.seed)?;
    bar.inc(1);

    bar.set_message("1-DoF: simulating the published procedure (≈ 133 h)");
    let run1 = run_plan(
        &examples::paper000_1dof_twin(args.seed),
        &one,
        TRAINING_START_S,
        1,
        true,
    );
    bar.inc(1);
    bar.set_message("1-DoF: writing recordings and plan");
    let dir1 = args.out.join("1dof");
    std::fs::create_dir_all(&dir1)?;
    let rec1 = write_recordings(&dir1, &run1, &one)?;
    bar.inc(1);
    bar.set_message("1-DoF: fitting the static model (stepwise, Eq. 11)");
    let data1 = ProcedureData::new(&rec1, &run1.steps, 0.0)?;
    let train1 = data1.training();
    let st = fit(&train1, DesignSpec::published_static(), 0x0003_0001)?;
    let ad = adaptive_from_static(&st.model).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    std::fs::write(dir1.join("static.blob"), encode_blob(&st.model))?;
    std::fs::write(dir1.join("adaptive.blob"), encode_blob(&ad))?;
    bar.inc(1);
    bar.set_message("1-DoF: validating 93 tests as the device would");
    let kmz = one.validation.kmz.as_ref();
    let v1 = [
        data1.validate(TestKind::NoModel, None, kmz, args.periods())?,
        data1.validate(TestKind::Adaptive, Some(&ad), kmz, args.periods())?,
        data1.validate(TestKind::Static, Some(&st.model), kmz, args.periods())?,
    ];
    bar.inc(1);
    bar.set_message("1-DoF: plots");
    let files1 = write_report(&dir1, &[&v1[0], &v1[1], &v1[2]])?;
    demo_html(
        &dir1,
        "paper 000, 1-DoF stage",
        &[&v1[0], &v1[1], &v1[2]],
        &[
            "training.csv",
            "validation.csv",
            "plan.json",
            "static.blob",
            "adaptive.blob",
        ],
    )?;
    bar.inc(1);

    bar.set_message("2-DoF: simulating the published procedure (≈ 29 h)");
    let run2 = run_plan(
        &examples::paper000_2dof_twin(args.seed),
        &two,
        TRAINING_START_S,
        2,
        true,
    );
    let dir2 = args.out.join("2dof");
    std::fs::create_dir_all(&dir2)?;
    let rec2 = write_recordings(&dir2, &run2, &two)?;
    bar.inc(1);
    bar.set_message("2-DoF: fitting Eq. 22 (stepwise) and validating");
    let data2 = ProcedureData::new(&rec2, &run2.steps, 0.0)?;
    let train2 = data2.training();
    let fit2 = fit(&train2, DesignSpec::published_2dof(), 0x0003_0003)?;
    std::fs::write(dir2.join("eq22.blob"), encode_blob(&fit2.model))?;
    let v2 = [
        data2.validate(TestKind::NoModel, None, None, args.periods())?,
        data2.validate(TestKind::Static, Some(&fit2.model), None, args.periods())?,
    ];
    bar.inc(1);
    let files2 = write_report(&dir2, &[&v2[0], &v2[1]])?;
    demo_html(
        &dir2,
        "paper 000, 2-DoF stage",
        &[&v2[0], &v2[1]],
        &["training.csv", "validation.csv", "plan.json", "eq22.blob"],
    )?;
    bar.inc(1);
    bar.set_message("robot (paper 001): simulating, fitting stepwise, validating");
    let robot = robot(&args, &args.out.join("robot"))?;
    bar.inc(1);
    bar.finish_and_clear();

    println!("Paper 000 (Tan, Clévy, Chaillet), published procedures on the digital twin\n");
    println!("1. One test at stable temperature (§4.3.1, Fig. 10): no model, 15 cycles after a training cycle");
    println!(
        "   this project: Acc {:.0} nm, Rep {:.0} nm (Eq. 3's σ as ISO 9283's S_l; {:.0} nm with σ of the positions), mean |Acc forward − Acc backward| {:.0} nm over the {} positions reached both ways",
        stable.accuracy_um * 1e3,
        stable.repeatability_um * 1e3,
        stable.repeatability_position_sigma_um * 1e3,
        forward_backward_gap_um(&stable).0 * 1e3,
        forward_backward_gap_um(&stable).1
    );
    println!("   paper 000:    Acc ≈ 350 nm,  Rep ≈ 35 nm, forward − backward ≈ 10 nm\n");

    println!(
        "2. 1-DoF calibration: training {} cycles × {} steps ({:.1} h), {} validation tests of {} cycles over {:.1} h, KMZ every {:.2} h",
        one.training.cycles,
        one.training.cycle_um.len(),
        one.training.duration_s() / 3600.0,
        one.tests(),
        one.validation.test.cycles,
        data1.validation_h(),
        args.kmz_interval_s / 3600.0
    );
    print!("{}", fit_summary(&st));
    print!("{}", table1(&st));
    let tp = training_phase(&train1);
    println!(
        "   training phase, no model: pose accuracies {:.0}–{:.0} nm (paper: ≈ 150 – > 450 nm)",
        tp.0 * 1e3,
        tp.1 * 1e3
    );
    print!("{}", one_dof_table(&v1));
    print!("{}", device_notes(&v1));
    println!();

    println!(
        "3. 2-DoF calibration (§5.2): training {} cycles × {} poses ({:.1} h), Eq. 22 (n1 = n2 = 3, {} temperatures), {} tests of {} cycles at P0…P5 over {:.1} h",
        two.training.cycles,
        two.training.cycle_um.len(),
        two.training.duration_s() / 3600.0,
        fit2.frame.temps.len(),
        two.tests(),
        two.validation.test.cycles,
        data2.validation_h()
    );
    print!("{}", fit_summary(&fit2));
    print!("{}", two_dof_table(&v2, &train2));
    print!("{}", device_notes(&v2));
    println!();
    print!("{robot}");
    println!();
    print!("{}", easier_or_harder());
    println!();
    println!(
        "wrote {} and {}: training.csv, validation.csv, plan.json, model blobs, report.html and {} plot files",
        dir1.display(),
        dir2.display(),
        files1.len() + files2.len()
    );
    Ok(())
}

/// Writes `training.csv`, `validation.csv` and `plan.json`; returns the whole recording.
fn write_recordings(dir: &Path, run: &PlanRun, plan: &Plan) -> anyhow::Result<Recording> {
    let (train, val) = run.split();
    write_csv(&dir.join("training.csv"), &train)?;
    write_csv(&dir.join("validation.csv"), &val)?;
    write_json(&dir.join("plan.json"), plan)?;
    Ok(run.recording.to_recording()?)
}

/// Stepwise (MATLAB defaults) among the candidates of `spec`, as paper 000 §3.3 trains.
fn fit(d: &Dwells, spec: DesignSpec, id: u32) -> anyhow::Result<FitReport> {
    Ok(fit_dwells(
        d,
        &FitOptions {
            spec,
            selection: Selection::Stepwise(StepwiseOptions::default()),
            dwell: Default::default(),
            id,
        },
    )?)
}

fn fit_summary(f: &FitReport) -> String {
    let mut s = String::new();
    for ax in &f.axes {
        let chosen: Vec<&str> = ax
            .candidates
            .iter()
            .zip(&ax.selected)
            .filter(|(_, sel)| **sel)
            .map(|(c, _)| c.name.as_str())
            .collect();
        s += &format!(
            "   fit {}: {} of {} terms ({}), training RMS {:.1} nm over {} steps\n",
            ax.axis,
            chosen.len(),
            ax.candidates.len(),
            chosen.join(" "),
            ax.rmse_um * 1e3,
            f.dwells
        );
    }
    s
}

/// Smallest and largest pose accuracy over the whole training, no model (paper 000 Fig. 11 TP).
fn training_phase(d: &Dwells) -> (f64, f64) {
    let k = d.axes.len();
    let t: Vec<Vec<f64>> = (0..d.len())
        .map(|i| (0..k).map(|a| d.cmd_um[a][i]).collect())
        .collect();
    let dir: Vec<Vec<i8>> = (0..d.len())
        .map(|i| (0..k).map(|a| d.dir[a][i]).collect())
        .collect();
    let e: Vec<Vec<f64>> = (0..d.len())
        .map(|i| (0..k).map(|a| d.meas_um[a][i] - d.cmd_um[a][i]).collect())
        .collect();
    let poses = per_pose_approach(&t, &dir, &e);
    let acc = poses.iter().map(|p| p.accuracy_um);
    (
        acc.clone().fold(f64::INFINITY, f64::min),
        acc.fold(0.0, f64::max),
    )
}

/// One no-model test at stable temperature (§4.3.1): the validation cycle, 15 cycles, after one
/// cycle of the training trajectory (the stage has moved before: 0 µm is reached backward).
fn stable_test(seed: u64) -> anyhow::Result<TestStats> {
    let mut plan = Plan::paper000_1dof().shortened(1, 15, 1);
    plan.validation.order = vec![TestKind::NoModel];
    let run = run_plan(
        &examples::paper000_1dof_controlled_twin(seed),
        &plan,
        TRAINING_START_S,
        3,
        true,
    );
    let data = ProcedureData::new(&run.recording.to_recording()?, &run.steps, 0.0)?;
    let r = data.validate(TestKind::NoModel, None, None, SlowPeriods::DEVICE)?;
    r.tests
        .into_iter()
        .next()
        .context("the stable-temperature test has no visits")
}

/// Mean over the positions reached both ways of |Acc forward − Acc backward|, µm, and how many
/// positions that is.
fn forward_backward_gap_um(t: &TestStats) -> (f64, usize) {
    let gaps: Vec<f64> = t
        .poses
        .iter()
        .filter(|p| p.approach.first() == Some(&1))
        .filter_map(|f| {
            t.poses
                .iter()
                .find(|b| b.target_um == f.target_um && b.approach.first() == Some(&-1))
                .map(|b| (f.accuracy_um - b.accuracy_um).abs())
        })
        .collect();
    (
        gaps.iter().sum::<f64>() / gaps.len().max(1) as f64,
        gaps.len(),
    )
}

/// The static model's coefficients in the paper's basis beside Table 1 (paper 000 §4.3.2):
/// a_1 … a_3 on x³, x², x; b_1 … b_4 on the four temperatures; λ (µm). Stepwise selects among
/// these raw candidates, so a term it drops is that power of x itself.
fn table1(f: &FitReport) -> String {
    use crate::papers::published::one_dof::{A, B_UM_PER_C, LAMBDA_UM};
    let Some(ax) = f.axes.first() else {
        return String::new();
    };
    let coeff = |name: &str| {
        ax.candidates
            .iter()
            .position(|c| c.name == name)
            .map(|j| (ax.coeff_um[j], ax.selected[j]))
    };
    let cell = |v: Option<(f64, bool)>| match v {
        Some((c, true)) => format!("{c:>+12.4e}"),
        Some((_, false)) => format!("{:>12}", "(dropped)"),
        None => format!("{:>12}", "–"),
    };
    let mut s = String::from(
        "   coefficients in the paper's basis (Eq. 11: q = a1·x³ + a2·x² + a3·x + Σ bi·ti + λ) beside Table 1:\n",
    );
    type Row = (String, Option<(f64, bool)>, f64);
    let mut rows: Vec<Row> = vec![
        ("a1 (x³)".into(), coeff("x^3"), A[0]),
        ("a2 (x²)".into(), coeff("x^2"), A[1]),
        ("a3 (x)".into(), coeff("x"), A[2]),
    ];
    for (i, t) in f.frame.temps.iter().enumerate().take(4) {
        rows.push((format!("b{} ({t})", i + 1), coeff(t), B_UM_PER_C[i]));
    }
    let b_sum: Option<f64> = rows[3..]
        .iter()
        .map(|(_, got, _)| got.map(|(c, kept)| if kept { c } else { 0.0 }))
        .sum();
    rows.push(("λ (µm)".into(), Some((ax.offset_um, true)), LAMBDA_UM));
    let paper_b_sum: f64 = B_UM_PER_C.iter().sum();
    for (name, got, paper) in rows {
        s += &format!("     {name:<18} {}   Table 1: {paper:>+12.4e}\n", cell(got));
    }
    if let Some(b_sum) = b_sum {
        s += &format!(
            "     {:<18} {b_sum:>+12.4e}   Table 1: {paper_b_sum:>+12.4e}\n",
            "Σ b (µm/°C)"
        );
    }
    s += "     (the four temperatures follow the room together, so the data fix the b's sum far better than each b;\n      the twin adds an unsensed table at 0.3 µm/°C with a 3 h lag; a and λ describe the twin's own geometry\n      and the interferometer's zero, not the paper's stage)\n";
    s
}

/// Largest test accuracy among the tests that end within `hours` of the start of validation.
fn max_acc_within(r: &ValidationReport, t0_s: f64, hours: f64) -> f64 {
    r.tests
        .iter()
        .filter(|t| t.t_end_s - t0_s <= hours * 3600.0)
        .map(|t| t.accuracy_um)
        .fold(f64::NAN, f64::max)
}

fn one_dof_table(v: &[ValidationReport; 3]) -> String {
    use std::fmt::Write;
    let t0 = v
        .iter()
        .filter_map(|r| r.tests.first())
        .map(|t| t.t_start_s)
        .fold(f64::INFINITY, f64::min);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "   {:<13}|{:>7} {:>7} {:>9} {:>8} {:>8} {:>8} {:>8} {:>9} |{:>6} {:>6} {:>18} {:>7} {:>7}",
        "",
        "Acc_T",
        "spread",
        "Acc≤70h",
        "Acc_max",
        "Acc_med",
        "Rep_med",
        "R_s µm",
        "R_t µm/h",
        "Acc_T",
        "spread",
        "five days",
        "R_s µm",
        "R_t µm/h"
    );
    let _ = writeln!(
        s,
        "   {:<13}|{:^78}|{:^50}",
        "compensation", "this project (nm unless stated)", "paper 000"
    );
    for (r, p) in v.iter().zip(paper::ONE_DOF) {
        let m = &r.summary;
        let spread = r
            .tests
            .first()
            .map_or(f64::NAN, |t| t.accuracy_um - t.min_accuracy_um());
        let _ = writeln!(
            s,
            "   {:<13}|{:>7.0} {:>7.0} {:>9.0} {:>8.0} {:>8.0} {:>8.0} {:>8.4} {:>9.4} |{:>6.0} {:>6.0} {:>18} {:>7.4} {:>7.4}",
            r.compensation.name(),
            m.first_acc_um * 1e3,
            spread * 1e3,
            max_acc_within(r, t0, 70.0) * 1e3,
            m.max_acc_um * 1e3,
            m.median_acc_um * 1e3,
            m.median_rep_um * 1e3,
            r.r_s_um,
            r.r_t_um_per_h,
            p.1,
            p.2,
            p.3,
            p.4,
            p.5
        );
    }
    let _ = writeln!(
        s,
        "   (Acc_T: Acc of the compensation's first test (T1/T2/T3), spread: its max − min over poses; Acc≤70h: worst test\n    within the first 70 h; Acc_max/med over all {} tests each; Acc = max over a test's 14 poses of ISO 9283 AP,\n    Rep = max of RP; R_s, R_t: Eq. 20–21 with Time = the whole validation)",
        v[0].tests.len()
    );
    s
}

/// What the device did besides compensating: refused moves, folds outside the envelope.
fn device_notes(v: &[ValidationReport]) -> String {
    let parts: Vec<String> = v
        .iter()
        .filter(|r| r.compensation != crate::validate::Compensation::None)
        .map(|r| {
            format!(
                "{}: {} of {} moves refused, {} folds with temperatures outside the training range",
                r.compensation.name(),
                r.refused,
                r.visits.len(),
                r.outside_envelope
            )
        })
        .collect();
    format!("   device: {}\n", parts.join("; "))
}

fn two_dof_table(v: &[ValidationReport; 2], train: &Dwells) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let tp = training_phase(train);
    let _ = writeln!(
        s,
        "   training phase, no model: worst pose accuracy {:.0} nm (paper: > 1.4 µm)",
        tp.1 * 1e3
    );
    let _ = writeln!(
        s,
        "   {:<10} {:>6} {:>9} {:>9} {:>9} {:>8} {:>8} |  paper 000",
        "", "tests", "Acc_min", "Acc_med", "Acc_max", "< 200 nm", "< 500 nm"
    );
    let paper = [
        "≈ 1.2–1.4 µm all day",
        "most < 200 nm, all < 500 nm (1400 → 200 nm)",
    ];
    for (r, p) in v.iter().zip(paper) {
        let m = &r.summary;
        let share = |lim: f64| {
            r.tests.iter().filter(|t| t.accuracy_um < lim).count() as f64
                / r.tests.len().max(1) as f64
        };
        let _ = writeln!(
            s,
            "   {:<10} {:>6} {:>9.0} {:>9.0} {:>9.0} {:>7.0}% {:>7.0}% |  {}",
            r.compensation.name(),
            r.tests.len(),
            m.min_acc_um * 1e3,
            m.median_acc_um * 1e3,
            m.max_acc_um * 1e3,
            100.0 * share(0.2),
            100.0 * share(0.5),
            p
        );
    }
    let _ = writeln!(
        s,
        "   (nm; per test, 2-D accuracy = max over P0…P5 of ISO 9283 AP = ‖barycentre − pose‖)"
    );
    s
}

/// The candidate terms of the robot's stepwise fit: per motor, every monomial of degree ≤ 3 in
/// the three motor coordinates (19), every temperature (10) and every temperature × the motor's
/// own coordinate (10) — 117 candidates for the three motors.
pub const ROBOT_CANDIDATES: &str = "poly=3 cross=3 temps temp_x_pos";

/// Paper 001's split as candidates: per motor 15 geometric and 11 thermal terms, 78 for the
/// three motors (§VII.A: "78 parameters (45 geometric and 33 thermal)").
pub const ROBOT_PAPER_SPLIT: &str = "paper001";

/// Paper 001 on the delta-robot twin: run the plan, fit stepwise among [`ROBOT_CANDIDATES`],
/// validate, and report the selected terms and the 90 % figure per motor coordinate.
fn robot(args: &DemoArgs, dir: &Path) -> anyhow::Result<String> {
    use crate::twin::delta::{DeltaConfig, DeltaTwin};
    use crate::validate::iso9283::ninety_percent_per_axis;
    use std::fmt::Write;
    let plan = Plan::paper001_robot();
    let twin = DeltaTwin::new(DeltaConfig::paper001(args.seed), 3.0 * 86_400.0, args.seed);
    let run = run_plan(&twin, &plan, TRAINING_START_S, 4, false);
    std::fs::create_dir_all(dir)?;
    let rec = write_recordings(dir, &run, &plan)?;
    let data = ProcedureData::new(&rec, &run.steps, 0.0)?;
    let train = data.training();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "4. Robot of paper 001 (delta, flexure hinges, 10 nm encoders, ≈ 1 cm³, 7 + 3 temperature sensors): training {} cycles × {} poses ({:.1} h), validation {} other poses, {} tests over {:.1} h",
        plan.training.cycles,
        plan.training.cycle_um.len(),
        plan.training.duration_s() / 3600.0,
        plan.validation.test.cycle_um.len(),
        plan.tests(),
        data.validation_h()
    );
    let p = args.periods();
    let none = data.validate(TestKind::NoModel, None, None, p)?;
    let errors = |r: &ValidationReport| -> Vec<Vec<f64>> {
        r.visits
            .iter()
            .filter(|v| v.counted())
            .map(|v| v.error_um.clone())
            .collect()
    };
    let ninety = |r: &ValidationReport| -> String {
        let n90 = ninety_percent_per_axis(&errors(r));
        let cells: Vec<String> = n90
            .iter()
            .zip(&data.data.dwells.axes)
            .map(|(n, a)| {
                format!(
                    "{a} ±{:.0} / {:.0}",
                    n.normal90_um * 1e3,
                    n.empirical90_um * 1e3
                )
            })
            .collect();
        format!(
            "{}   ({} visits{})",
            cells.join(", "),
            n90.first().map_or(0, |n| n.n),
            if r.refused > 0 {
                format!(", {} refused", r.refused)
            } else {
                String::new()
            }
        )
    };
    let _ = writeln!(
        s,
        "   parameters counted as paper 001 counts them (terms, offsets excluded); 90 % of the validation set per motor\n   coordinate, nm: 1.645σ / empirical P90 of |error|   | paper 001: 78 (45 geometric + 33 thermal), ±70 nm"
    );
    let _ = writeln!(s, "     {:<44} {}", "no model", ninety(&none));
    let variants = [
        (
            "the paper's split, all 78 fitted",
            ROBOT_PAPER_SPLIT,
            Selection::Fixed,
            "robot-78.blob",
        ),
        (
            "stepwise among the paper's split",
            ROBOT_PAPER_SPLIT,
            Selection::Stepwise(StepwiseOptions::default()),
            "robot-78-stepwise.blob",
        ),
        (
            "stepwise among 117 (degree ≤ 3, T, T×own)",
            ROBOT_CANDIDATES,
            Selection::Stepwise(StepwiseOptions::default()),
            "robot.blob",
        ),
    ];
    for (name, spec, selection, blob) in variants {
        let opts = FitOptions {
            spec: DesignSpec::parse(spec)?,
            selection,
            dwell: Default::default(),
            id: 0x0001_0003,
        };
        let fit = match fit_dwells(&train, &opts) {
            Ok(f) => f,
            Err(e) => {
                let _ = writeln!(
                    s,
                    "   the robot's model cannot be built yet: {e:#}\n   (the recording, {} training and {} validation steps, is in {})",
                    train.len(),
                    data.data.dwells.len() - train.len(),
                    dir.display()
                );
                return Ok(s);
            }
        };
        std::fs::write(dir.join(blob), encode_blob(&fit.model))?;
        let stat = data.validate(TestKind::Static, Some(&fit.model), None, p)?;
        let n = parameter_count(&fit);
        let label = format!(
            "{name}: {} = {} + {}",
            n.geometric + n.thermal + n.other,
            n.geometric,
            n.thermal
        );
        let _ = writeln!(s, "     {label:<44} {}", ninety(&stat));
    }
    Ok(s)
}

fn easier_or_harder() -> String {
    [
        "Where the simulation is easier or harder than the published experiments:",
        "- easier: the twin's thermal drift is linear in its spot temperatures (Table 1's coefficients plus an",
        "  unsensed table, 0.3 µm/°C with a 3 h lag): when the room leaves the training range (1.3 °C over the last",
        "  two days) the static model keeps extrapolating well; the paper's, under 400 nm for 70 h, deteriorated then;",
        "- easier: the stage's geometry never changes (no wear, no re-mounting), the interferometer has no dead-path",
        "  or cosine error beyond what is modelled and is zeroed once without drift (paper 000: ≤ 41 nm uncertainty),",
        "  sensors never fail, and every test runs exactly on schedule;",
        "- easier: the 2-DoF validation steps and test length are the 1-DoF ones (not published for 2-DoF);",
        "- easier: the robot twin's errors are what its kinematics and titanium expansion produce — smooth, so a",
        "  cubic in motor coordinates and linear temperature terms nearly capture them; its residual is its",
        "  positioning scatter (15 nm), encoder resolution (10 nm) and interferometer noise; the real robot's",
        "  flexure hinges, parasitic rotations and gradients inside its parts are not simulated;",
        "- harder: the stages carry physics the published models cannot see — the structure lags its sensors by",
        "  20 min, the stroke changes 50 ppm/°C (a KMZ at 0 µm cannot measure it), a part of the loop has no",
        "  sensor — and the device reads type K thermocouples through a MAX31856 (≈ 16 mK noise a reading); it",
        "  averages them over its fold period (5 s, 20 readings) as paper 001 §VI does;",
        "- different: the 2 s rise is modelled as a step (the twin's stage has no transient); the validation is",
        "  evaluated open loop — the target for which the device sends the recorded command — instead of",
        "  driving the stage through the model (equivalent to f32 rounding, see tests/validate_device.rs).",
    ]
    .map(|l| format!("{l}\n"))
    .concat()
}
