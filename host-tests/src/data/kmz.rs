//! λ_KMZ as paper 000 §3.4 measures it: from the difference of two readings of the reference
//! instrument at the KMZ pose.
//!
//! §3.4: "The KMZ is reached and the measurement of the sensor is recorded. After a period of
//! time, the KMZ is re-reached again and the new measurement is recorded. The drift in this
//! period is the difference of two measurements of the sensor. The thermal drift is compensated
//! by adding the calculated difference of the two measurements." Eq. 16 models the stage as
//! `x_m = P(q_T) + q_T + λ_KMZ + D(t)`: a command moves the stage by as much (slope 1), and the
//! drift `D` adds. So, with `x₁` read at the first re-measurement under command `q₁` and `x_k`
//! under `q_k`, the drift since the first is `D_k − D₁ = (x_k − q_k) − (x₁ − q₁)` (with the
//! same command each time — the campaign reaches the KMZ in bypass — simply `x_k − x₁`), and
//!
//! `λ_KMZ,k = λ_KMZ,1 − [(x_k − q_k) − (x₁ − q₁)]`.
//!
//! The first re-measurement sets `λ_KMZ,1` so that the model maps `x₁` to `q₁` (the model was
//! fitted in the reference instrument's frame: its prediction at the KMZ command is the reading
//! the training recorded there, and the difference to it is the drift `D₁` of Eq. 17,
//! `λ_KMZ = −D₁`). [`nanocal_model::Model::set_kmz_from_reference`] would re-zero the model at
//! every re-measurement instead, through its own slope at the reading (`1.005` for paper 000's
//! Table 1: 0.5 % of the drift since the first, a few nm over the five days).

use nanocal_model::{HysteresisState, Model, SlowInputs, MAX_AXES};
use serde::{Deserialize, Serialize};

/// The first KMZ re-measurement: what later ones are differences to.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KmzReading {
    /// The command that reached the KMZ pose, µm per axis.
    pub q_cmd_um: [f64; MAX_AXES],
    /// The reference instrument's reading there, µm per axis.
    pub x_meas_um: [f64; MAX_AXES],
    /// λ_KMZ it gave, µm per axis.
    pub kmz_um: [f64; MAX_AXES],
}

/// The KMZ re-measurements of one adaptive model (see the module doc).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KmzDrift {
    first: Option<KmzReading>,
}

impl KmzDrift {
    /// A tracker that continues from `first` (a resumed campaign), or starts afresh.
    pub fn new(first: Option<KmzReading>) -> Self {
        KmzDrift { first }
    }

    /// The first re-measurement, once made.
    pub fn first(&self) -> Option<KmzReading> {
        self.first
    }

    /// Command `q_cmd_um` reached the KMZ pose and the reference read `x_meas_um`: sets λ_KMZ
    /// of `model` (the first time so that the model maps the reading to the command, with its
    /// play operators stepped from `state` and the slow inputs `slow`; afterwards by the drift
    /// since then) and returns it.
    pub fn measure(
        &mut self,
        model: &mut Model,
        q_cmd_um: &[f64; MAX_AXES],
        x_meas_um: &[f64; MAX_AXES],
        dir: &[i8; MAX_AXES],
        slow: &SlowInputs,
        state: &HysteresisState<f64>,
    ) -> [f64; MAX_AXES] {
        let axes = model.axes();
        match self.first {
            None => {
                model.set_kmz_from_reference_with_state(q_cmd_um, x_meas_um, dir, slow, state);
                let mut kmz_um = [0.0; MAX_AXES];
                for (a, k) in kmz_um.iter_mut().enumerate().take(axes) {
                    *k = model.kmz_offset_um(a);
                }
                self.first = Some(KmzReading {
                    q_cmd_um: *q_cmd_um,
                    x_meas_um: *x_meas_um,
                    kmz_um,
                });
                kmz_um
            }
            Some(f) => {
                let mut kmz_um = [0.0; MAX_AXES];
                for a in 0..axes {
                    let drift = (x_meas_um[a] - q_cmd_um[a]) - (f.x_meas_um[a] - f.q_cmd_um[a]);
                    kmz_um[a] = f.kmz_um[a] - drift;
                    model.set_kmz_offset_um(a, kmz_um[a]);
                }
                kmz_um
            }
        }
    }
}

/// The management `SET_KMZ` request (`q_cmd`, `x_meas`) that leaves a device holding `model`
/// (any λ_KMZ) with exactly `kmz_um`: the device moves λ_KMZ so that its model maps `x_meas`
/// to `q_cmd` (`Model::set_kmz_from_reference`, no sign of approach, its own slow inputs —
/// none for paper 000's adaptive model, Eq. 14), so `q_cmd` is what the model with `kmz_um`
/// sends for `x_meas`.
pub fn set_kmz_request(
    model: &Model,
    kmz_um: &[f64; MAX_AXES],
    x_meas_um: &[f64; MAX_AXES],
    slow: &SlowInputs,
) -> ([f64; MAX_AXES], [f64; MAX_AXES]) {
    let mut m = model.clone();
    for (a, k) in kmz_um.iter().enumerate().take(m.axes()) {
        m.set_kmz_offset_um(a, *k);
    }
    let q = m.eval_f64(x_meas_um, &[0; MAX_AXES], slow);
    (q, *x_meas_um)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nanocal_model::{Factor, Input, ModelBuilder};

    fn model() -> Model {
        // q = 1.005·x (+ λ): a slope other than 1
        let mut b = ModelBuilder::new(1, 0, 0)
            .unwrap()
            .trained_range(Input::Axis(0), 0.0, 480.0);
        b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.005)
            .unwrap();
        b.offset_um(0, 10.0).build().unwrap()
    }

    #[test]
    fn the_device_request_leaves_exactly_the_wanted_offset() {
        let m = model();
        let slow = SlowInputs::default();
        let (q, x) = set_kmz_request(&m, &[0.37, 0.0, 0.0], &[0.1, 0.0, 0.0], &slow);
        let mut device = m.clone();
        device.set_kmz_offset_um(0, -4.0);
        device.set_kmz_from_reference(&q, &x, &[0; MAX_AXES], &slow);
        assert!((device.kmz_offset_um(0) - 0.37).abs() < 1e-12);
    }
}
