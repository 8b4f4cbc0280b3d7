//! After the last step: the validation statistics twice — from what the stage really received
//! (the campaign's own table: each visit's error is the reference minus the target the campaign
//! asked the compensator for) and by the file-based `validate` of the same recording (which only
//! knows the commands and replays the compensator's fold to find the targets) — their agreement,
//! the report's plots, and `explain` on the validation steps with what to add when the accuracy
//! is not reached (paper 001 §II, step 5: back to step 1 with a richer model).

use super::run::{CampaignError, Models};
use crate::data::plan::{Phase, Plan, Step, TestKind};
use crate::data::recording::Recording;
use crate::device::device_path::SlowPeriods;
use crate::validate::procedure::ProcedureData;
use crate::validate::{validate_roles, Compensation, Role, ValidationOptions, ValidationReport};
use nanocal_model::Model;
use std::path::Path;

/// The campaign's results.
pub struct Analysis {
    /// Per compensation (in the plan's order): the table from what the stage received.
    pub campaign: Vec<ValidationReport>,
    /// The same from the file-based validation of the recording.
    pub file: Vec<ValidationReport>,
    /// Largest difference between the two over every test's Acc and Rep and the summaries,
    /// nm.
    pub max_difference_nm: f64,
    /// `explain` on the validation steps, as text.
    pub explain: Option<String>,
    /// What to add to the model, from `explain` (empty when it found nothing).
    pub advice: Vec<String>,
    /// Per model compensation, the jitter of the commands the stage received
    /// ([`command_jitter_nm`]), nm.
    pub jitter_nm: Vec<(TestKind, f64)>,
}

/// Jitter of the commands the stage received in the `kind` tests: the change of the command
/// between two consecutive visits of the same pose with the same approach (a turning point held
/// for a second step: 480 µm forward, 0 µm backward in paper 000's cycle), its RMS over √2 —
/// the scatter of a single command, nm. The two moves are one step (≈ 21 s) apart: the room
/// barely changes between them, the readings the device folds do — by their noise, through the
/// model's thermal terms. NaN without such a pair.
pub fn command_jitter_nm(data: &ProcedureData, kind: TestKind) -> f64 {
    let d = &data.data.dwells;
    let axes = d.axes.len();
    let of_kind =
        |i: usize| matches!(data.steps[i].phase, Phase::Test { kind: k, .. } if k == kind);
    let (mut ss, mut n) = (0.0, 0usize);
    for i in 1..data.steps.len() {
        let (a, b) = (&data.steps[i - 1], &data.steps[i]);
        if !(of_kind(i - 1) && of_kind(i)) || a.target_um != b.target_um || a.approach != b.approach
        {
            continue;
        }
        for ax in 0..axes {
            let c = d.cmd_um[ax][i] - d.cmd_um[ax][i - 1];
            if c.is_finite() {
                ss += c * c;
                n += 1;
            }
        }
    }
    if n == 0 {
        return f64::NAN;
    }
    (ss / n as f64 / 2.0).sqrt() * 1e3
}

fn kinds(plan: &Plan) -> Vec<TestKind> {
    let mut k: Vec<TestKind> = Vec::new();
    for t in &plan.validation.order {
        if !k.contains(t) {
            k.push(*t);
        }
    }
    k
}

fn compensation(kind: TestKind, plan: &Plan, axes: usize) -> Compensation {
    match kind {
        TestKind::NoModel => Compensation::None,
        TestKind::Static => Compensation::Static,
        TestKind::Adaptive => Compensation::Adaptive {
            reference_um: plan
                .validation
                .kmz
                .as_ref()
                .map_or(vec![0.0; axes], |k| k.reference_um.clone()),
            interval_s: plan
                .validation
                .kmz
                .as_ref()
                .map_or(f64::INFINITY, |k| k.interval_s),
        },
    }
}

/// The largest difference of two reports' per-test Acc/Rep and summary figures, nm.
pub fn difference_nm(a: &ValidationReport, b: &ValidationReport) -> f64 {
    let mut d: f64 = 0.0;
    if a.tests.len() != b.tests.len() {
        return f64::INFINITY;
    }
    let mut diff = |x: f64, y: f64| {
        if x.is_nan() && y.is_nan() {
            return;
        }
        d = d.max((x - y).abs() * 1e3);
    };
    for (x, y) in a.tests.iter().zip(&b.tests) {
        diff(x.accuracy_um, y.accuracy_um);
        diff(x.repeatability_um, y.repeatability_um);
    }
    let (s, t) = (&a.summary, &b.summary);
    diff(s.first_acc_um, t.first_acc_um);
    diff(s.median_acc_um, t.median_acc_um);
    diff(s.max_acc_um, t.max_acc_um);
    diff(s.median_rep_um, t.median_rep_um);
    diff(s.max_rep_um, t.max_rep_um);
    diff(a.r_s_um, b.r_s_um);
    diff(a.r_t_um_per_h, b.r_t_um_per_h);
    d
}

/// How the file-based validation replays the device's folds. A campaign's rows carry, for each
/// step, the inputs of the fold that corrected its move (the status after the move names that
/// fold: the readings averaged over its fold period), held over the step: read at every row,
/// one reading a fold, they are that fold whatever the device's periods. Ticking at the
/// device's fold period instead starts from the first row, and a tick seconds before a step's
/// first row replays the previous step's fold (measured 9.5 nm with a 5 s period). A model with
/// lag filters needs the device's own folds (its filters run once a fold): the recorded
/// averages, one a fold period.
fn replay_periods(rec: &Recording, models: &[&Model], device: SlowPeriods) -> SlowPeriods {
    let fold_period_s = device.fold_s;
    if models.iter().any(|m| !m.lags().is_empty()) {
        return fold_period_s.into();
    }
    let Some(t) = rec.time_s() else {
        return fold_period_s.into();
    };
    let mut dt: Vec<f64> = t
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    if dt.is_empty() {
        return fold_period_s.into();
    }
    dt.sort_by(f64::total_cmp);
    // the rows' interval; never longer than the device's period
    dt[dt.len() / 2].min(fold_period_s).into()
}

/// The rows of `rec` from plan time `t0_s` on (a model uploaded then primes its lag filters on
/// the readings from then, as the device does).
pub fn recording_from(rec: &Recording, t0_s: f64) -> Result<Recording, CampaignError> {
    let t = rec.time_s().unwrap_or(&[]);
    let first = t.partition_point(|&v| v < t0_s);
    let cols = rec
        .names()
        .iter()
        .map(|n| {
            let c = rec.column(n).unwrap_or(&[]);
            (n.clone(), c[first.min(c.len())..].to_vec())
        })
        .collect();
    Recording::from_columns(cols).map_err(|e| CampaignError::Fit(e.to_string()))
}

/// The `kind` tests of `data` twice: from what the stage received (each visit's error is the
/// reference minus the target the campaign asked the compensator for) and by the file-based
/// validation with `model` (which only knows the commands and replays the device's folds with
/// `replay`).
pub fn two_tables(
    data: &ProcedureData,
    plan: &Plan,
    kind: TestKind,
    model: Option<&Model>,
    replay: SlowPeriods,
) -> Result<(ValidationReport, ValidationReport), CampaignError> {
    let err = |e: String| CampaignError::Fit(e);
    let axes = plan.training.axes();
    let kmz = plan.validation.kmz.as_ref();
    let f = data
        .validate(kind, model, kmz, replay)
        .map_err(|e| err(e.to_string()))?;
    // what the stage received is in the recording; the campaign knows what it asked for
    let mut asked = data.clone();
    for (i, s) in data.steps.iter().enumerate() {
        for a in 0..axes {
            asked.data.dwells.cmd_um[a][i] = s.target_um[a];
        }
    }
    // a KMZ that is the first visit of its test is a reading in bypass, not a compensated
    // move: paper 000 counts it with its drift cancelled by the λ_KMZ it gives (Eq. 17–18),
    // which is the evaluation of the file-based validation — the campaign's table takes it,
    // as a visit of its test (without a model a KMZ role is no visit at all)
    let mut roles = asked.roles(kind);
    for v in f.visits.iter().filter(|v| v.kmz_reference && !v.extra) {
        let d = &mut asked.data.dwells;
        if let Some(i) = d.t_start_s.iter().position(|&t| t == v.t_move_s) {
            for a in 0..axes {
                d.cmd_um[a][i] = d.meas_um[a][i] - v.error_um[a];
            }
            if let Some(r) = roles.get_mut(i) {
                *r = Role::Visit(v.test);
            }
        }
    }
    let opts = ValidationOptions {
        slow: replay,
        cycles_per_test: 1,
        time_h: Some(data.validation_h()),
    };
    let mut c = validate_roles(None, &asked.data, &Compensation::None, &roles, &opts)
        .map_err(|e| err(e.to_string()))?;
    c.compensation = compensation(kind, plan, axes);
    Ok((c, f))
}

/// Validate the plan's part of the campaign in `dir` (its recording, the plan's steps `steps`
/// and the plan's models — before any loop refitted the static one); `periods` are the
/// compensator's sample and fold periods during the campaign.
pub fn analyse(
    dir: &Path,
    plan: &Plan,
    steps: &[Step],
    periods: SlowPeriods,
    run_explain: bool,
) -> Result<Analysis, CampaignError> {
    let err = |e: String| CampaignError::Fit(e);
    let rec = Recording::read_path(dir.join(super::RECORDING)).map_err(|e| err(e.to_string()))?;
    let data = ProcedureData::new(&rec, steps, 0.0).map_err(|e| err(e.to_string()))?;
    let models = Models::load_plan(dir)?;
    let replay = replay_periods(&rec, &[&models.static_model, &models.adaptive], periods);
    let mut campaign = Vec::new();
    let mut file = Vec::new();
    let mut max_difference_nm: f64 = 0.0;
    for kind in kinds(plan) {
        let model = match kind {
            TestKind::NoModel => None,
            TestKind::Static => Some(&models.static_model),
            TestKind::Adaptive => Some(&models.adaptive),
        };
        let (c, f) = two_tables(&data, plan, kind, model, replay)?;
        max_difference_nm = max_difference_nm.max(difference_nm(&c, &f));
        campaign.push(c);
        file.push(f);
    }
    let jitter_nm = kinds(plan)
        .into_iter()
        .filter(|k| *k != TestKind::NoModel)
        .map(|k| (k, command_jitter_nm(&data, k)))
        .collect();
    let (explain, advice) = if run_explain {
        let report = explain_report(&data).map_err(err)?;
        (
            report.as_ref().map(|r| r.to_text()),
            report.as_ref().map_or(Vec::new(), advice_lines),
        )
    } else {
        (None, Vec::new())
    };
    Ok(Analysis {
        campaign,
        file,
        max_difference_nm,
        explain,
        advice,
        jitter_nm,
    })
}

/// One line per effect explain named: what, where, how the compensator runs it, and the
/// held-out evidence.
pub fn advice_lines(report: &crate::explain::Report) -> Vec<String> {
    report
        .effects()
        .map(|e| {
            format!(
                "{} on {}: {} — {} (held-out RMS {:.0} → {:.0} nm)",
                e.name, e.channel, e.description, e.deploy, e.rms_before_nm, e.rms_after_nm
            )
        })
        .collect()
}

/// `explain` on the validation steps of `data` (one row per step: the averaged window, the
/// command the stage received, the compensator's temperatures); `None` with fewer than 50.
pub fn explain_report(data: &ProcedureData) -> Result<Option<crate::explain::Report>, String> {
    let validation = data
        .data
        .dwells
        .filter(|i| data.steps[i].phase != Phase::Training);
    if validation.len() < 50 {
        return Ok(None);
    }
    let rec = validation.to_recording();
    let d = crate::explain::Data::from_recording(&rec, None).map_err(|e| e.to_string())?;
    crate::explain::explain(&d, &crate::explain::Settings::default())
        .map(Some)
        .map_err(|e| e.to_string())
}
