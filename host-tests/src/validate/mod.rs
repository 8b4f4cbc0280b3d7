//! Validating a model on a recording, exactly as the inline compensator would have applied it.
//!
//! Each dwell of the validation recording is a visit of the commanded pose `cmd`. Without a
//! model the stage goes to `meas`, so the error is `meas − cmd`. With a model the device folds
//! its sensor readings at its own cadence ([`crate::device::device_path`]: readings averaged over the
//! fold period, lag filters, f32 readings) and maps targets through the f32 fast path; the user target for which the
//! device would have sent `cmd` is `x̂ = fold.inverse(cmd)` with the fold in force when the
//! move was sent (the start of the dwell), and the stage, having received `cmd`, went to
//! `meas`: the compensated error is `meas − x̂`. This is exact, not a linearisation:
//! `fold.correct(x̂) = cmd` to f32 rounding (`tests/validate_device.rs` sends `MOV x̂` through
//! the compensator's own GCS proxy and gets `cmd` back within 0.1 nm).
//!
//! Hysteresis: the device keeps its play operators' memory ([`HysteresisState`]) from command
//! to command, evaluates each command from it and steps it with the target that went out
//! (`nanocal_compensator::proxy`, end of `rewrite_move`). The validation does the same with the
//! same f32 code: `x̂` is the inverse with the memory frozen where the previous command left it,
//! then the memory is stepped to `x̂`. A dwell of another compensation (an interleaved
//! schedule) means another model was in service: the memory starts afresh, as the device's
//! does for a new model. A KMZ re-measurement compares with the model stepped from that memory.
//!
//! Adaptive (KMZ, paper 000 §3.4, Eq. 14): at the dwells whose [`Role`] is a KMZ
//! re-measurement — a plan's KMZ steps, or, in a recording of cycles, a visit of the reference
//! pose once `interval_s` has passed since the last — λ_KMZ is re-measured from the
//! difference of the reference readings at the KMZ pose ([`crate::data::kmz::KmzDrift`]). A KMZ that
//! is a visit of its test (the first visit of the test, at the reference pose) is counted as
//! paper 000's Eq. 17–18 count it: "λ_KMZ is only measured at the first zero position, so
//! λ_KMZ = −D₁(t)" — its error is evaluated with the λ_KMZ it gave, the drift of that visit
//! cancelled. A KMZ step of its own before a test is not a visit of the test.
//!
//! Visits are grouped into **tests** (paper 000 §4.2: a test is one block of cycles, 15 cycles
//! in 1.25 h): per test, Acc and Rep are the maxima over its poses (Eq. 6–7, ISO 9283
//! 7.2.1/7.2.2, forward and backward approaches separate poses), and over the tests R_s and R_t
//! (Eq. 20–21) in µm and µm/h ([`crate::validate::iso9283`]).

pub mod error_table;
pub mod iso9283;
pub mod procedure;

use nanocal_compensator::gcs;
use nanocal_compensator::proxy::{travel, Corrector, FoldCorrector};
use nanocal_model::{FastInputs, HysteresisState, Model, SlowInputs, MAX_AXES};

use crate::data::dwell::{dwell_average, DwellError, DwellOptions, Dwells};
use crate::data::recording::Recording;
use crate::device::device_path::{DeviceSlowPath, SensorStream, SlowPeriods};
use crate::validate::iso9283::{
    distribution, per_pose_approach, space_robustness_um, time_robustness_um_per_h,
    ErrorDistribution, TestStats,
};

/// Errors of a validation.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ValidateError {
    /// The model needs more channels than the recording has.
    #[error("the model uses {needed} {what} channels, the recording has {found}")]
    MissingChannels {
        /// Which channels.
        what: &'static str,
        /// Needed by the model.
        needed: usize,
        /// Present in the recording.
        found: usize,
    },
    /// The model's axes differ from the recording's.
    #[error("the model has {model} axes, the recording {recording}")]
    AxesMismatch {
        /// Model axes.
        model: usize,
        /// Recording axes.
        recording: usize,
    },
    /// The reference pose has the wrong number of coordinates.
    #[error("reference pose has {found} coordinates, expected {expected}")]
    BadReference {
        /// Axes.
        expected: usize,
        /// Found.
        found: usize,
    },
    /// The roles do not match the dwells.
    #[error("{found} roles given, expected one per dwell ({expected})")]
    BadSchedule {
        /// Dwells.
        expected: usize,
        /// Entries given.
        found: usize,
    },
    /// A compensation was asked for without a model.
    #[error("the {0} compensation needs a model")]
    NoModel(&'static str),
}

/// How the stage is driven.
#[derive(Debug, Clone, PartialEq)]
pub enum Compensation {
    /// No model: command = target.
    None,
    /// The model as fitted.
    Static,
    /// The model with its offset λ_KMZ re-measured at a reference pose.
    Adaptive {
        /// Reference pose per axis, µm (a commanded pose of the recording).
        reference_um: Vec<f64>,
        /// Minimum time between re-measurements, s.
        interval_s: f64,
    },
}

impl Compensation {
    /// A short name: `no model`, `static`, `adaptive KMZ`.
    pub fn name(&self) -> &'static str {
        match self {
            Compensation::None => "no model",
            Compensation::Static => "static",
            Compensation::Adaptive { .. } => "adaptive KMZ",
        }
    }
}

/// How visits are evaluated and grouped.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationOptions {
    /// The device's sample and fold periods ([`SlowPeriods::DEVICE`]: the board's defaults).
    pub slow: SlowPeriods,
    /// Cycles per test when tests are found from the recording (paper 000: 15).
    pub cycles_per_test: usize,
    /// `Time` of Eq. 21, h; `None`: from the start of the first test to the end of the last.
    pub time_h: Option<f64>,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        ValidationOptions {
            slow: SlowPeriods::DEVICE,
            cycles_per_test: 15,
            time_h: None,
        }
    }
}

/// What a validation reads: the dwells (visits) and the sensor samples the device saw.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationData {
    /// One entry per visit.
    pub dwells: Dwells,
    /// The slow channels as the device's sensors sampled them.
    pub sensors: SensorStream,
    /// The pose each visit was meant to reach, per axis per dwell, when a plan says it (else
    /// the commanded pose is taken as the pose asked for). A recording made through the
    /// compensator (`nanocal campaign`) commands the corrected pose: its visits are grouped by,
    /// and its refusals checked on, the plan's pose.
    pub poses_um: Option<Vec<Vec<f64>>>,
}

impl ValidationData {
    /// Dwell-averages `rec` and keeps its raw slow channels for the device's slow path.
    pub fn from_recording(rec: &Recording, opts: &DwellOptions) -> Result<Self, DwellError> {
        Ok(ValidationData {
            dwells: dwell_average(rec, opts)?,
            sensors: SensorStream::from_recording(rec),
            poses_um: None,
        })
    }

    /// Per-dwell data without a raw recording: the device sees each dwell's averaged channels
    /// from the start of the dwell.
    pub fn from_dwells(dwells: Dwells) -> Self {
        ValidationData {
            sensors: SensorStream::from_dwells(&dwells),
            dwells,
            poses_um: None,
        }
    }
}

/// One visit of a pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Visit {
    /// End of the dwell, s.
    pub t_s: f64,
    /// When the move was sent (start of the dwell), s.
    pub t_move_s: f64,
    /// Commanded pose per axis, µm.
    pub target_um: Vec<f64>,
    /// Reached minus target per axis, µm (NaN if the inverse failed).
    pub error_um: Vec<f64>,
    /// Direction of approach per axis.
    pub dir: Vec<i8>,
    /// Index of the test this visit belongs to.
    pub test: usize,
    /// True if λ_KMZ was re-measured here.
    pub kmz_reference: bool,
    /// True for a KMZ step of its own before its test: not a visit of the test, not counted.
    pub extra: bool,
    /// True if the device would have refused a move to the commanded pose (outside the
    /// training envelope, or its corrected command outside the travel): the stage would not
    /// have gone there (not counted).
    pub refused: bool,
    /// True if a temperature/aux input was outside the training envelope.
    pub outside_envelope: bool,
    /// Mean temperature of the visit over all `temp_*` channels, °C (NaN without any).
    pub mean_temp_c: f64,
    /// Index of the dwell in the validation data.
    pub dwell: usize,
    /// Where the stage went (the measured position), per axis, µm.
    pub reached_um: Vec<f64>,
    /// The slow inputs the device had in force when the move was sent.
    pub slow: SlowInputs,
}

impl Visit {
    /// Whether the visit counts in the statistics (a visit of its test, not refused, error
    /// finite).
    pub fn counted(&self) -> bool {
        !self.extra && !self.refused && self.error_um.iter().all(|e| e.is_finite())
    }
}

/// Accuracy and repeatability of one compensation over its tests, µm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestSummary {
    /// Acc of the first test (paper 000 Fig. 11: T1/T2/T3).
    pub first_acc_um: f64,
    /// Median over tests of the test Acc.
    pub median_acc_um: f64,
    /// Largest test Acc.
    pub max_acc_um: f64,
    /// Smallest test Acc.
    pub min_acc_um: f64,
    /// Median over tests of the test Rep.
    pub median_rep_um: f64,
    /// Largest test Rep.
    pub max_rep_um: f64,
    /// Largest Acc over tests of the forward poses alone.
    pub max_acc_forward_um: f64,
    /// Largest Acc over tests of the backward poses alone.
    pub max_acc_backward_um: f64,
}

/// Statistics of a validation.
#[derive(Debug, Clone)]
pub struct ValidationReport {
    /// The compensation evaluated.
    pub compensation: Compensation,
    /// Every visit of this compensation's tests (including KMZ reference visits).
    pub visits: Vec<Visit>,
    /// Per test: poses (commanded pose and approach), Acc and Rep (Eq. 6–7).
    pub tests: Vec<TestStats>,
    /// Acc and Rep over the tests.
    pub summary: TestSummary,
    /// Space robustness R_s (Eq. 20), µm.
    pub r_s_um: f64,
    /// Time robustness R_t (Eq. 21), µm/h.
    pub r_t_um_per_h: f64,
    /// `Time` of Eq. 21, h.
    pub time_h: f64,
    /// Distribution of single-visit errors over the counted visits.
    pub distribution: ErrorDistribution,
    /// Number of KMZ re-measurements.
    pub kmz_updates: usize,
    /// Counted visits with inputs outside the training envelope.
    pub outside_envelope: usize,
    /// Visits where the model's inverse did not converge.
    pub inverse_failures: usize,
    /// Visits the device would have refused (see [`Visit::refused`]).
    pub refused: usize,
}

/// What a dwell is in a validation of one compensation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Not evaluated (e.g. another compensation's test in an interleaved schedule).
    Skip,
    /// A visit of test `n`.
    Visit(usize),
    /// The KMZ re-measurement at the reference pose, in test `test` (adaptive only); `counted`
    /// when it is a visit of the test (paper 000 Eq. 18), not when it is a step of its own.
    Kmz {
        /// The test.
        test: usize,
        /// Counted as a visit of the test.
        counted: bool,
    },
}

/// Roles of the dwells of a recording that is a sequence of cycles: a cycle starts whenever the
/// command returns to the first pose, every `cycles_per_test` cycles make a test; for an
/// adaptive compensation a visit of the reference pose is a KMZ re-measurement when at least
/// `interval_s` have passed since the last one (the first is always).
pub fn roles_from_cycles(d: &Dwells, cycles_per_test: usize, comp: &Compensation) -> Vec<Role> {
    let k = d.axes.len();
    let pose = |i: usize| -> Vec<f64> { (0..k).map(|a| d.cmd_um[a][i]).collect() };
    let first = if d.is_empty() { Vec::new() } else { pose(0) };
    let mut cycle = 0usize;
    let mut last_kmz: Option<f64> = None;
    (0..d.len())
        .map(|i| {
            if i > 0 && pose(i) == first && pose(i - 1) != first {
                cycle += 1;
            }
            let test = cycle / cycles_per_test.max(1);
            if let Compensation::Adaptive {
                reference_um,
                interval_s,
            } = comp
            {
                let at_ref = reference_um.len() == k
                    && (0..k).all(|a| (d.cmd_um[a][i] - reference_um[a]).abs() < 1e-9);
                let due = last_kmz.is_none_or(|t0| d.t_end_s[i] - t0 >= interval_s - 1e-9);
                if at_ref && due && (0..k).all(|a| d.meas_um[a][i].is_finite()) {
                    last_kmz = Some(d.t_end_s[i]);
                    return Role::Kmz {
                        test,
                        counted: true,
                    };
                }
            }
            Role::Visit(test)
        })
        .collect()
}

/// Validates `model` (ignored for [`Compensation::None`]) on every dwell of `data`, tests and
/// KMZ re-measurements found from the cycles ([`roles_from_cycles`]).
pub fn validate(
    model: Option<&Model>,
    data: &ValidationData,
    comp: &Compensation,
    opts: &ValidationOptions,
) -> Result<ValidationReport, ValidateError> {
    let roles = roles_from_cycles(&data.dwells, opts.cycles_per_test, comp);
    validate_roles(model, data, comp, &roles, opts)
}

/// Validates `model` on the dwells as `roles` assigns them (one role per dwell).
pub fn validate_roles(
    model: Option<&Model>,
    data: &ValidationData,
    comp: &Compensation,
    roles: &[Role],
    opts: &ValidationOptions,
) -> Result<ValidationReport, ValidateError> {
    let d = &data.dwells;
    if roles.len() != d.len() {
        return Err(ValidateError::BadSchedule {
            expected: d.len(),
            found: roles.len(),
        });
    }
    let k = d.axes.len();
    let mut model: Option<Model> = match comp {
        Compensation::None => None,
        _ => Some(model.ok_or(ValidateError::NoModel(comp.name()))?.clone()),
    };
    if let Some(m) = &model {
        check_inputs(m, k, &data.sensors)?;
    }
    if let Compensation::Adaptive { reference_um, .. } = comp {
        if reference_um.len() != k {
            return Err(ValidateError::BadReference {
                expected: k,
                found: reference_um.len(),
            });
        }
    }
    let stream = &data.sensors;
    let lags = model.as_ref().map_or(Vec::new(), |m| m.lags().to_vec());
    let mut device = DeviceSlowPath::new(&lags, stream, opts.slow);
    let temps: Vec<&[f64]> = d
        .channels
        .iter()
        .filter(|c| c.0.starts_with("temp_"))
        .map(|c| c.1.as_slice())
        .collect();
    let mut visits = Vec::new();
    let mut kmz_updates = 0;
    let mut inverse_failures = 0;
    // the device's play-operator memory, as the commands sent left it
    let mut hyst = HysteresisState::new();
    let mut kmz_drift = crate::data::kmz::KmzDrift::default();
    for (i, role) in roles.iter().enumerate() {
        let (test, kmz, extra) = match *role {
            Role::Skip => {
                // another model was in service for this dwell: the device's memory restarts
                hyst.reset();
                continue;
            }
            Role::Visit(n) => (n, false, false),
            Role::Kmz { test, counted } => (test, true, !counted),
        };
        let slow = device.slow_at(d.t_start_s[i]);
        let mut q = [0.0; MAX_AXES];
        let mut x = [0.0; MAX_AXES];
        let mut dir = [0i8; MAX_AXES];
        for a in 0..k {
            q[a] = d.cmd_um[a][i];
            x[a] = d.meas_um[a][i];
            dir[a] = d.dir[a][i];
        }
        // fast inputs as the device reads them with the command
        let fast = data.sensors.fast_at(d.t_start_s[i]);
        let q32 = q.map(|v| v as f32);
        let mut kmz_reference = false;
        if kmz {
            match (comp, model.as_mut()) {
                (Compensation::Adaptive { .. }, Some(m))
                    if x[..k].iter().all(|v| v.is_finite()) =>
                {
                    // the reference move went out with the fold in force before the update
                    let before = FoldCorrector::new(m, &slow);
                    let sent = before.fold.inverse(&q32, &dir, &fast, &hyst).ok();
                    kmz_drift.measure(m, &q, &x, &dir, &slow, &hyst.into());
                    if let Some(xh) = sent {
                        before.fold.step(&xh, &mut hyst);
                    }
                    kmz_updates += 1;
                    kmz_reference = true;
                }
                // a KMZ step of another compensation, or without a measurement: not a visit
                _ => continue,
            }
        }
        let mut pose = q;
        if let Some(p) = &data.poses_um {
            for a in 0..k {
                pose[a] = p[a][i];
            }
        }
        let mut refused = false;
        let (error_um, outside) = match &model {
            None => ((0..k).map(|a| x[a] - q[a]).collect::<Vec<f64>>(), false),
            Some(m) => {
                let device = FoldCorrector::new(m, &slow);
                let outside = device.fold.slow_outside_envelope() != 0;
                // the user asks for the pose itself: would the device take that move?
                refused = refuses(&device, &pose.map(|v| v as f32), &dir, &fast, &hyst, k);
                // the play operators frozen where the last command left them
                match device.fold.inverse(&q32, &dir, &fast, &hyst) {
                    Ok(xh) => {
                        if !kmz_reference {
                            // the command for x̂ went out: the memory follows it
                            device.fold.step(&xh, &mut hyst);
                        }
                        ((0..k).map(|a| x[a] - f64::from(xh[a])).collect(), outside)
                    }
                    Err(_) => {
                        inverse_failures += 1;
                        // where the stage went is not known to the model: start afresh
                        hyst.reset();
                        (vec![f64::NAN; k], outside)
                    }
                }
            }
        };
        visits.push(Visit {
            t_s: d.t_end_s[i],
            t_move_s: d.t_start_s[i],
            target_um: pose[..k].to_vec(),
            error_um,
            dir: dir[..k].to_vec(),
            test,
            kmz_reference,
            extra,
            refused,
            outside_envelope: outside,
            mean_temp_c: if temps.is_empty() {
                f64::NAN
            } else {
                temps.iter().map(|c| c[i]).sum::<f64>() / temps.len() as f64
            },
            dwell: i,
            reached_um: x[..k].to_vec(),
            slow,
        });
    }
    Ok(summarise(
        comp.clone(),
        visits,
        kmz_updates,
        inverse_failures,
        opts.time_h,
    ))
}

/// Whether the compensator's proxy refuses a move to `x_um` with this fold: its rule
/// (`nanocal_compensator::proxy`, `rewrite_move` and `travel`) — target outside the training
/// envelope, or corrected command outside the stage travel by more than the proxy's clamp
/// ([`travel::CLAMP_UM`]: a command up to 0.1 µm outside goes out as the end of the travel, and
/// the recording's `cmd` is then that end). The command is formed as the proxy forms it, the
/// target in micros plus δ; a NaN command (a fast input not supplied) is outside. A recording
/// does not carry the controller's `TMN?`/`TMX?`, so only the model's travel is checked.
fn refuses(
    device: &FoldCorrector,
    x_um: &[f32; MAX_AXES],
    dir: &[i8; MAX_AXES],
    fast: &FastInputs,
    hyst: &HysteresisState,
    k: usize,
) -> bool {
    let c = device.fold.evaluate(x_um, dir, fast, hyst);
    c.outside_envelope & ((1u8 << k) - 1) != 0
        || (0..k).any(|a| {
            let (lo, hi) = device.travel_um(a);
            if c.q_um[a] >= lo && c.q_um[a] <= hi {
                return false;
            }
            let (Some(x), Some(d)) = (
                gcs::f32_to_micros(x_um[a]),
                gcs::f32_to_micros(c.delta_um[a]),
            ) else {
                return true;
            };
            let model = travel::model_travel_micros(lo, hi);
            matches!(
                travel::edge(x.saturating_add(d), model, (None, None)),
                travel::Edge::Outside(_)
            )
        })
}

fn check_inputs(m: &Model, axes: usize, s: &SensorStream) -> Result<(), ValidateError> {
    if m.axes() != axes {
        return Err(ValidateError::AxesMismatch {
            model: m.axes(),
            recording: axes,
        });
    }
    if m.temps() > s.temps.len() {
        return Err(ValidateError::MissingChannels {
            what: "temperature",
            needed: m.temps(),
            found: s.temps.len(),
        });
    }
    if m.aux() > s.aux.len() {
        return Err(ValidateError::MissingChannels {
            what: "auxiliary",
            needed: m.aux(),
            found: s.aux.len(),
        });
    }
    Ok(())
}

fn summarise(
    compensation: Compensation,
    visits: Vec<Visit>,
    kmz_updates: usize,
    inverse_failures: usize,
    time_h: Option<f64>,
) -> ValidationReport {
    let counted: Vec<&Visit> = visits.iter().filter(|v| v.counted()).collect();
    let mut ids: Vec<usize> = visits.iter().map(|v| v.test).collect();
    ids.sort_unstable();
    ids.dedup();
    let pose_stats = |sel: &[&&Visit]| {
        let t: Vec<Vec<f64>> = sel.iter().map(|v| v.target_um.clone()).collect();
        let a: Vec<Vec<i8>> = sel.iter().map(|v| v.dir.clone()).collect();
        let e: Vec<Vec<f64>> = sel.iter().map(|v| v.error_um.clone()).collect();
        per_pose_approach(&t, &a, &e)
    };
    let mut tests = Vec::new();
    let mut fwd = Vec::new();
    let mut bwd = Vec::new();
    for id in ids {
        let all: Vec<&Visit> = visits.iter().filter(|v| v.test == id).collect();
        let sel: Vec<&&Visit> = counted.iter().filter(|v| v.test == id).collect();
        if sel.is_empty() {
            continue;
        }
        let t_start = all.iter().map(|v| v.t_move_s).fold(f64::INFINITY, f64::min);
        let t_end = all.iter().map(|v| v.t_s).fold(f64::NEG_INFINITY, f64::max);
        let poses = pose_stats(&sel);
        let worst = |sign: i8| {
            poses
                .iter()
                .filter(|p| p.approach.first().is_some_and(|&d| d.signum() == sign))
                .map(|p| p.accuracy_um)
                .fold(f64::NAN, f64::max)
        };
        fwd.push(worst(1));
        bwd.push(worst(-1));
        tests.push(TestStats::new(id, t_start, t_end, poses));
    }
    let time_h = time_h.unwrap_or_else(|| match (tests.first(), tests.last()) {
        (Some(a), Some(b)) => (b.t_end_s - a.t_start_s) / 3600.0,
        _ => f64::NAN,
    });
    let acc: Vec<f64> = tests.iter().map(|t| t.accuracy_um).collect();
    let rep: Vec<f64> = tests.iter().map(|t| t.repeatability_um).collect();
    let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
    let summary = TestSummary {
        first_acc_um: acc.first().copied().unwrap_or(f64::NAN),
        median_acc_um: crate::validate::iso9283::percentile(&acc, 50.0),
        max_acc_um: max(&acc),
        min_acc_um: acc.iter().copied().fold(f64::NAN, f64::min),
        median_rep_um: crate::validate::iso9283::percentile(&rep, 50.0),
        max_rep_um: max(&rep),
        max_acc_forward_um: max(&fwd),
        max_acc_backward_um: max(&bwd),
    };
    let errors: Vec<Vec<f64>> = counted.iter().map(|v| v.error_um.clone()).collect();
    ValidationReport {
        r_s_um: space_robustness_um(&tests),
        r_t_um_per_h: time_robustness_um_per_h(&tests, time_h),
        time_h,
        summary,
        distribution: distribution(&errors),
        kmz_updates,
        outside_envelope: counted.iter().filter(|v| v.outside_envelope).count(),
        inverse_failures,
        refused: visits.iter().filter(|v| v.refused).count(),
        tests,
        visits,
        compensation,
    }
}

/// A plain-text table comparing several validations (one row each), values in nm (R_s in nm,
/// R_t in nm/h).
pub fn comparison_table(reports: &[&ValidationReport]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<14} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9} {:>7}",
        "compensation",
        "tests",
        "Acc_T1",
        "Acc_med",
        "Acc_max",
        "Acc_fwd",
        "Acc_bwd",
        "Rep_med",
        "Rep_max",
        "R_s",
        "R_t",
        "visits"
    );
    for r in reports {
        let nm = |v: f64| v * 1e3;
        let m = &r.summary;
        let _ = writeln!(
            s,
            "{:<14} {:>6} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>9.2} {:>7}",
            r.compensation.name(),
            r.tests.len(),
            nm(m.first_acc_um),
            nm(m.median_acc_um),
            nm(m.max_acc_um),
            nm(m.max_acc_forward_um),
            nm(m.max_acc_backward_um),
            nm(m.median_rep_um),
            nm(m.max_rep_um),
            nm(r.r_s_um),
            nm(r.r_t_um_per_h),
            r.distribution.n
        );
    }
    let _ = writeln!(
        s,
        "(nm; per test Acc = max over its poses of ISO 9283 AP, Rep = max of RP = l̄ + 3·S_l \
         (paper 000 Eq. 2–7), forward and backward separate poses; T1 = first test, med/max over \
         tests; R_s in nm, R_t in nm/h (Eq. 20–21))"
    );
    s
}

/// How often the measured error fell inside the fit's prediction interval.
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    /// Nominal level of the interval (e.g. 0.95).
    pub level: f64,
    /// Counted visit-axes whose |error| was inside the interval.
    pub inside: usize,
    /// Counted visit-axes evaluated.
    pub n: usize,
    /// Median half-width of the interval at the visits, µm.
    pub median_half_width_um: f64,
}

impl Coverage {
    /// Measured coverage, 0…1 (NaN without visits).
    pub fn fraction(&self) -> f64 {
        self.inside as f64 / self.n as f64
    }
}

/// Coverage of the prediction interval of `model`'s fit (`bands`: one per axis, over the
/// model's own terms, from [`crate::fit::AxisFit::band`]) by the counted visits of `report`.
///
/// The band is of the command `q̂(x)` at the reached position `x`; the position error of a
/// visit is `x − x̂` with `q̂(x̂) = q`, so `x − x̂ ≈ (q̂(x) − q) / q̂′(x)`: the interval in
/// position is the command interval divided by the local slope `∂q̂_a/∂x_a` (central difference
/// of the f64 model, ±0.01 µm).
pub fn coverage(
    report: &ValidationReport,
    model: &Model,
    bands: &[crate::numerics::uncertainty::PredictionBand],
    level: f64,
) -> Result<Coverage, crate::numerics::uncertainty::UncertaintyError> {
    let mut inside = 0;
    let mut n = 0;
    let mut widths = Vec::new();
    for v in report.visits.iter().filter(|v| v.counted()) {
        let k = v.reached_um.len();
        let mut x = [0.0; MAX_AXES];
        let mut dir = [0i8; MAX_AXES];
        x[..k].copy_from_slice(&v.reached_um[..k]);
        dir[..k].copy_from_slice(&v.dir[..k]);
        let scaled = model.scale(&x, &dir, &v.slow);
        for (a, band) in bands.iter().enumerate().take(k) {
            if !v.error_um[a].is_finite() {
                continue;
            }
            let row = crate::fit::band_regressors(model, a, &scaled);
            let h = band.half_width(&row, level)?;
            let step = 0.01;
            let (mut lo, mut hi) = (x, x);
            lo[a] -= step;
            hi[a] += step;
            let slope = (model.eval_f64(&hi, &dir, &v.slow)[a]
                - model.eval_f64(&lo, &dir, &v.slow)[a])
                / (2.0 * step);
            let h_pos = h / slope.abs();
            widths.push(h_pos);
            n += 1;
            if v.error_um[a].abs() <= h_pos {
                inside += 1;
            }
        }
    }
    widths.sort_by(f64::total_cmp);
    Ok(Coverage {
        level,
        inside,
        n,
        median_half_width_um: widths.get(widths.len() / 2).copied().unwrap_or(f64::NAN),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nanocal_model::{Factor, Input, ModelBuilder};

    /// 1 axis, travel 0…500 µm, command = target + `offset_um`.
    fn offset_model(offset_um: f64) -> Model {
        let mut b = ModelBuilder::new(1, 0, 0)
            .unwrap()
            .trained_range(Input::Axis(0), -10.0, 510.0)
            .travel_um(0, 0.0, 500.0);
        b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
        b.add_raw_term(0, [0; 3], Factor::None, 0, offset_um)
            .unwrap();
        b.build().unwrap()
    }

    /// The corrected command at `x_um`, and whether validation counts the move as refused.
    fn at(m: &Model, x_um: f32) -> (f32, bool) {
        let device = FoldCorrector::new(m, &SlowInputs::default());
        let mut x = [0.0f32; MAX_AXES];
        x[0] = x_um;
        let dir = [0i8; MAX_AXES];
        let hyst = HysteresisState::default();
        let q = device
            .fold
            .evaluate(&x, &dir, &FastInputs::NONE, &hyst)
            .q_um[0];
        (q, refuses(&device, &x, &dir, &FastInputs::NONE, &hyst, 1))
    }

    #[test]
    fn commands_just_outside_the_travel_are_clamped_as_the_device_does_and_further_out_refused() {
        for (offset_um, x_um, refused) in [
            // the case: a correction of −0.05 µm at 0 on a travel that starts at 0
            (-0.05, 0.0, false),
            (0.05, 500.0, false),
            (-0.2, 0.0, true),
            (0.2, 500.0, true),
            (-0.2, 250.0, false),
        ] {
            let m = offset_model(offset_um);
            let (q, got) = at(&m, x_um);
            assert_eq!(
                got, refused,
                "offset {offset_um} µm at {x_um} µm: command {q} µm, refused {got}"
            );
        }
        // the command really left the travel in the clamped cases (else the test shows nothing)
        assert!(at(&offset_model(-0.05), 0.0).0 < 0.0);
        assert!(at(&offset_model(0.05), 500.0).0 > 500.0);
    }
}
