//! A published procedure's recording, analysed as the plan says: the training steps for the
//! fit, and each validation test with the compensation the plan gave it — ISO 9283 per test,
//! R_s and R_t over each compensation's tests, `Time` = the whole validation (paper 000 Fig. 12:
//! five days for all three compensations).
//!
//! The recording may come from the digital twin ([`crate::twin::execute::run_plan`]) or from a
//! bench that ran the same [`Plan`]: only the recording and the plan's schedule are read.

use nanocal_model::Model;

use crate::data::dwell::{step_average, DwellError, Dwells};
use crate::data::plan::{KmzPlan, Phase, Step, TestKind};
use crate::data::recording::Recording;
use crate::device::device_path::{SensorStream, SlowPeriods};
use crate::validate::{
    validate_roles, Compensation, Role, ValidateError, ValidationData, ValidationOptions,
    ValidationReport,
};

/// A recording cut into the steps of its plan.
#[derive(Debug, Clone)]
pub struct ProcedureData {
    /// The plan's steps.
    pub steps: Vec<Step>,
    /// One dwell per step, measurement averaged over the step's last seconds, the step's
    /// direction of approach; and the raw slow channels the device saw.
    pub data: ValidationData,
}

impl ProcedureData {
    /// Cuts `rec` into `steps` (the recording's `t` = the plan's time + `t_offset_s`).
    pub fn new(rec: &Recording, steps: &[Step], t_offset_s: f64) -> Result<Self, DwellError> {
        Ok(ProcedureData {
            steps: steps.to_vec(),
            data: ValidationData {
                dwells: step_average(rec, steps, t_offset_s)?,
                sensors: SensorStream::from_recording(rec),
                poses_um: Some(
                    (0..steps.first().map_or(0, |s| s.target_um.len()))
                        .map(|a| steps.iter().map(|s| s.target_um[a]).collect())
                        .collect(),
                ),
            },
        })
    }

    /// The training dwells (for the fit).
    pub fn training(&self) -> Dwells {
        self.data
            .dwells
            .filter(|i| self.steps[i].phase == Phase::Training)
    }

    /// The role of every dwell in the validation of the `kind` tests.
    pub fn roles(&self, kind: TestKind) -> Vec<Role> {
        let kind_of = |test: usize| {
            self.steps.iter().find_map(|s| match s.phase {
                Phase::Test { test: t, kind } if t == test => Some(kind),
                _ => None,
            })
        };
        self.steps
            .iter()
            .map(|s| match s.phase {
                Phase::Test { test, kind: k } if k == kind => Role::Visit(test),
                Phase::Kmz { test, visit } if kind_of(test) == Some(kind) => Role::Kmz {
                    test,
                    counted: visit,
                },
                _ => Role::Skip,
            })
            .collect()
    }

    /// Duration of the validation (first validation step's start to the last one's end), h.
    pub fn validation_h(&self) -> f64 {
        let v: Vec<&Step> = self
            .steps
            .iter()
            .filter(|s| s.phase != Phase::Training)
            .collect();
        match (v.first(), v.last()) {
            (Some(a), Some(b)) => (b.t_end_s() - a.t_start_s) / 3600.0,
            _ => f64::NAN,
        }
    }

    /// Validates the `kind` tests: no model, the static `model`, or the adaptive `model`
    /// (already reduced to Eq. 14, see [`crate::fit::adaptive_from_static`]) re-measured at the
    /// plan's KMZ steps, the device's slow path with `periods` (a single period: one reading a
    /// fold). `Time` of R_t is the whole validation.
    pub fn validate(
        &self,
        kind: TestKind,
        model: Option<&Model>,
        kmz: Option<&KmzPlan>,
        periods: impl Into<SlowPeriods>,
    ) -> Result<ValidationReport, ValidateError> {
        let axes = self.data.dwells.axes.len();
        let comp = match kind {
            TestKind::NoModel => Compensation::None,
            TestKind::Static => Compensation::Static,
            TestKind::Adaptive => Compensation::Adaptive {
                reference_um: kmz.map_or(vec![0.0; axes], |k| k.reference_um.clone()),
                interval_s: kmz.map_or(f64::INFINITY, |k| k.interval_s),
            },
        };
        let opts = ValidationOptions {
            slow: periods.into(),
            cycles_per_test: 1,
            time_h: Some(self.validation_h()),
        };
        validate_roles(model, &self.data, &comp, &self.roles(kind), &opts)
    }
}
