//! Validating a model on another recording, as the firmware would apply it.
//!
//! Each dwell of the validation recording (averaged as in training) is a visit of the pose
//! `x_T = cmd` (the target a user asked for). Without a model the stage goes to `meas`, so the
//! error is `meas − x_T`. With a model the firmware folds the dwell's temperatures into the
//! fast coefficients ([`nanocal_model::Model::fold`]) and maps positions through the f32 fast
//! path; the command that was sent corresponds to the calibrated position
//! `x̂ = fold.inverse(cmd)`, so the compensated error is `meas − x̂` (the stage is locally
//! linear over the size of the correction). Adaptive (KMZ): whenever the recording dwells at the
//! reference pose and at least `interval_s` have passed since the last update, λ_KMZ is
//! re-measured there ([`nanocal_model::Model::set_kmz_from_reference`]); those reference visits
//! are not counted in the statistics.
//!
//! Temperature and auxiliary channels map onto the model's inputs by their order in the file
//! (`temp_*` columns → Temp 0, 1, …; other channels → Aux 0, 1, …), the same convention as
//! [`crate::design`]. A model with lag filters (thermal lag) gets their outputs from the model
//! crate's own [`nanocal_model::LagBank`], run over the dwell-averaged temperatures in time
//! order (exact for a temperature held between dwells; dwells are short against the τ of
//! thermal lags).

use nanocal_model::{FastInputs, HysteresisState, LagBank, Model, SlowInputs, MAX_AXES};

use crate::dwell::Dwells;
use crate::iso9283::{
    distribution, max_over_poses, per_pose, space_robustness, time_robustness, ErrorDistribution,
    PoseStats,
};

/// Errors of a validation.
#[derive(Debug, thiserror::Error, PartialEq)]
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

/// One visit of a pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Visit {
    /// End of the dwell, s.
    pub t_s: f64,
    /// Target per axis, µm.
    pub target_um: Vec<f64>,
    /// Reached minus target per axis, µm (NaN if the inverse failed).
    pub error_um: Vec<f64>,
    /// Direction of approach per axis.
    pub dir: Vec<i8>,
    /// Index of the test (pass through the poses) this visit belongs to.
    pub test: usize,
    /// True if λ_KMZ was re-measured here (not counted).
    pub kmz_reference: bool,
    /// True if a temperature/aux input was outside the training envelope.
    pub outside_envelope: bool,
    /// Mean temperature of the visit over all `temp_*` channels, °C (NaN without any).
    pub mean_temp_c: f64,
}

/// Statistics of a validation.
#[derive(Debug, Clone)]
pub struct ValidationReport {
    /// The compensation evaluated.
    pub compensation: Compensation,
    /// Every visit (including KMZ reference visits).
    pub visits: Vec<Visit>,
    /// Per pose, both directions together.
    pub poses: Vec<PoseStats>,
    /// Per pose, forward approaches only (direction of axis 0 > 0).
    pub forward: Vec<PoseStats>,
    /// Per pose, backward approaches only.
    pub backward: Vec<PoseStats>,
    /// Max over poses: (accuracy, repeatability), µm.
    pub max_um: (f64, f64),
    /// Max over poses, forward only.
    pub max_forward_um: (f64, f64),
    /// Max over poses, backward only.
    pub max_backward_um: (f64, f64),
    /// Error distribution over the counted visits.
    pub distribution: ErrorDistribution,
    /// Space robustness R_s.
    pub r_s: f64,
    /// Time robustness R_t over the tests.
    pub r_t: f64,
    /// Number of tests (passes through the poses).
    pub tests: usize,
    /// Number of KMZ re-measurements.
    pub kmz_updates: usize,
    /// Counted visits with inputs outside the training envelope.
    pub outside_envelope: usize,
    /// Visits where the model's inverse did not converge.
    pub inverse_failures: usize,
}

fn temp_and_aux(d: &Dwells) -> (Vec<&[f64]>, Vec<&[f64]>) {
    let temps = d
        .channels
        .iter()
        .filter(|c| c.0.starts_with("temp_"))
        .map(|c| c.1.as_slice())
        .collect();
    let aux = d
        .channels
        .iter()
        .filter(|c| !c.0.starts_with("temp_"))
        .map(|c| c.1.as_slice())
        .collect();
    (temps, aux)
}

/// Validates `model` (ignored for [`Compensation::None`]) on the dwells `d`.
pub fn validate(
    model: Option<&Model>,
    d: &Dwells,
    comp: &Compensation,
) -> Result<ValidationReport, ValidateError> {
    let k = d.axes.len();
    let (temps, aux) = temp_and_aux(d);
    let mut model: Option<Model> = match comp {
        Compensation::None => None,
        _ => model.cloned(),
    };
    if let Some(m) = &model {
        if m.axes() != k {
            return Err(ValidateError::AxesMismatch {
                model: m.axes(),
                recording: k,
            });
        }
        if m.temps() > temps.len() {
            return Err(ValidateError::MissingChannels {
                what: "temperature",
                needed: m.temps(),
                found: temps.len(),
            });
        }
        if m.aux() > aux.len() {
            return Err(ValidateError::MissingChannels {
                what: "auxiliary",
                needed: m.aux(),
                found: aux.len(),
            });
        }
    }
    if let Compensation::Adaptive { reference_um, .. } = comp {
        if reference_um.len() != k {
            return Err(ValidateError::BadReference {
                expected: k,
                found: reference_um.len(),
            });
        }
    }
    let target = |i: usize| -> Vec<f64> { (0..k).map(|a| d.cmd_um[a][i]).collect() };
    let first = if d.is_empty() { Vec::new() } else { target(0) };
    let mut visits = Vec::with_capacity(d.len());
    let mut test = 0usize;
    let mut last_kmz: Option<f64> = None;
    let mut kmz_updates = 0;
    let mut inverse_failures = 0;
    let mut lags = model.as_ref().map(|m| LagBank::new(m.lags()));
    for i in 0..d.len() {
        let tgt = target(i);
        if i > 0 && tgt == first && target(i - 1) != first {
            test += 1;
        }
        let mut slow = SlowInputs::default();
        for (t, col) in temps.iter().enumerate().take(nanocal_model::MAX_TEMPS) {
            slow.temps_c[t] = col[i];
        }
        for (n, col) in aux.iter().enumerate().take(nanocal_model::MAX_AUX) {
            slow.aux[n] = col[i];
        }
        if let Some(bank) = lags.as_mut() {
            let dt_s = if i == 0 {
                0.0
            } else {
                d.t_end_s[i] - d.t_end_s[i - 1]
            };
            let temps_c = slow.temps_c;
            bank.update(&temps_c, dt_s, &mut slow.lagged_c);
        }
        let mean_temp_c = if temps.is_empty() {
            f64::NAN
        } else {
            temps.iter().map(|c| c[i]).sum::<f64>() / temps.len() as f64
        };
        let mut q = [0.0; MAX_AXES];
        let mut x = [0.0; MAX_AXES];
        let mut dir = [0i8; MAX_AXES];
        for a in 0..k {
            q[a] = d.cmd_um[a][i];
            x[a] = d.meas_um[a][i];
            dir[a] = d.dir[a][i];
        }
        let mut kmz_reference = false;
        if let (
            Compensation::Adaptive {
                reference_um,
                interval_s,
            },
            Some(m),
        ) = (comp, model.as_mut())
        {
            let at_ref = (0..k).all(|a| (q[a] - reference_um[a]).abs() < 1e-9);
            let due = last_kmz.is_none_or(|t0| d.t_end_s[i] - t0 >= interval_s - 1e-9);
            if at_ref && due && x[..k].iter().all(|v| v.is_finite()) {
                m.set_kmz_from_reference(&q, &x, &dir, &slow);
                last_kmz = Some(d.t_end_s[i]);
                kmz_updates += 1;
                kmz_reference = true;
            }
        }
        let (error_um, outside) = match &model {
            None => ((0..k).map(|a| x[a] - q[a]).collect::<Vec<f64>>(), false),
            Some(m) => {
                let fold = m.fold(&slow);
                let q32 = [q[0] as f32, q[1] as f32, q[2] as f32];
                // Fast aux inputs at their recorded values; hysteresis from a fresh state.
                let fast = FastInputs {
                    aux: slow.aux.map(|v| v as f32),
                };
                match fold.inverse(&q32, &dir, &fast, &HysteresisState::new()) {
                    Ok(xh) => (
                        (0..k).map(|a| x[a] - xh[a] as f64).collect(),
                        fold.slow_outside_envelope() != 0,
                    ),
                    Err(_) => {
                        inverse_failures += 1;
                        (vec![f64::NAN; k], fold.slow_outside_envelope() != 0)
                    }
                }
            }
        };
        visits.push(Visit {
            t_s: d.t_end_s[i],
            target_um: tgt,
            error_um,
            dir: dir[..k].to_vec(),
            test,
            kmz_reference,
            outside_envelope: outside,
            mean_temp_c,
        });
    }
    Ok(summarise(
        comp.clone(),
        visits,
        kmz_updates,
        inverse_failures,
    ))
}

fn summarise(
    compensation: Compensation,
    visits: Vec<Visit>,
    kmz_updates: usize,
    inverse_failures: usize,
) -> ValidationReport {
    let counted: Vec<&Visit> = visits
        .iter()
        .filter(|v| !v.kmz_reference && v.error_um.iter().all(|e| e.is_finite()))
        .collect();
    let stats = |f: &dyn Fn(&Visit) -> bool| -> Vec<PoseStats> {
        let sel: Vec<&&Visit> = counted.iter().filter(|v| f(v)).collect();
        let t: Vec<Vec<f64>> = sel.iter().map(|v| v.target_um.clone()).collect();
        let e: Vec<Vec<f64>> = sel.iter().map(|v| v.error_um.clone()).collect();
        per_pose(&t, &e)
    };
    let poses = stats(&|_| true);
    let forward = stats(&|v| v.dir.first().is_some_and(|&d| d > 0));
    let backward = stats(&|v| v.dir.first().is_some_and(|&d| d < 0));
    let tests = visits.iter().map(|v| v.test + 1).max().unwrap_or(0);
    let per_test: Vec<Vec<PoseStats>> = (0..tests).map(|t| stats(&|v| v.test == t)).collect();
    let errors: Vec<Vec<f64>> = counted.iter().map(|v| v.error_um.clone()).collect();
    ValidationReport {
        max_um: max_over_poses(&poses),
        max_forward_um: max_over_poses(&forward),
        max_backward_um: max_over_poses(&backward),
        distribution: distribution(&errors),
        r_s: space_robustness(&poses),
        r_t: time_robustness(&per_test),
        tests,
        kmz_updates,
        outside_envelope: counted.iter().filter(|v| v.outside_envelope).count(),
        inverse_failures,
        poses,
        forward,
        backward,
        visits,
        compensation,
    }
}

/// A plain-text table comparing several validations (one row each), values in nm.
pub fn comparison_table(reports: &[&ValidationReport]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<14} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>6} {:>6} {:>7}",
        "compensation",
        "Acc_max",
        "Rep_max",
        "Acc_fwd",
        "Acc_bwd",
        "RMS",
        "P90",
        "1.645σ",
        "R_s",
        "R_t",
        "visits"
    );
    for r in reports {
        let nm = |v: f64| v * 1e3;
        let _ = writeln!(
            s,
            "{:<14} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>6.2} {:>6.2} {:>7}",
            r.compensation.name(),
            nm(r.max_um.0),
            nm(r.max_um.1),
            nm(r.max_forward_um.0),
            nm(r.max_backward_um.0),
            nm(r.distribution.rms_um),
            nm(r.distribution.p90_um),
            nm(r.distribution.normal90_um),
            r.r_s,
            r.r_t,
            r.distribution.n
        );
    }
    let _ = writeln!(s, "(nm; Acc/Rep per ISO 9283 as adapted for 1-D stages, max over poses; P90 = 90th percentile of |error|)");
    s
}
