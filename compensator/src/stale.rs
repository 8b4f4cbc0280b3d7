//! Does the model in service still describe the stage? The device's own check, at two moments
//! that cost nothing per command:
//!
//! - **every KMZ re-measurement** (`SET_KMZ`: command `q` reached the reference pose, the
//!   reference measured `x`): the model predicts the command that reaches `x`; the λ change the
//!   re-measurement makes is `q − model(x)`, the model's prediction error there. A model that
//!   still holds keeps it inside its prediction interval: `|q − model(x)| ≤ k · s · √(1 + h(x))`
//!   (the fit's residual standard deviation `s` and leverage `h` at the KMZ point,
//!   [`nanocal_model::bound`]; `k` from the settings). Outside it the model is stale. An axis
//!   whose model carries no bound (a blob before format 3, or paper 000's adaptive model,
//!   Eq. 14, which has no temperature term and so predicts no drift: its λ change *is* its
//!   measurement of the drift) is not checked.
//! - **every fold**: a temperature the model reads more than the extrapolation margin beyond
//!   its training envelope (paper 000 §4.3.2: the static model "deteriorates" after 70 h
//!   because "the temperature afterwards changed out of the range of the training phase").
//!
//! Stale is latched with the time it rose until another model is loaded (the firmware makes a
//! new [`StaleCheck`]); the device keeps compensating — the flag says *refit or re-measure*,
//! it stops nothing.

use nanocal_interface::status::StaleReasons;
use nanocal_model::{Input, Model, SlowInputs, MAX_AXES};

/// What the KMZ check found on each axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KmzCheck {
    /// λ change the re-measurement makes, µm: the command minus the model's prediction at the
    /// measured position (0 on axes the model lacks).
    pub residual_um: [f32; MAX_AXES],
    /// `k` standard errors of prediction at the KMZ point, µm (NaN: no bound for the axis, or
    /// an axis the model lacks).
    pub limit_um: [f32; MAX_AXES],
}

impl KmzCheck {
    /// The model's prediction error at a KMZ re-measurement and its limit: command `q_cmd_um`
    /// reached the reference pose, the reference measured `x_meas_um`, the slow inputs are
    /// `slow`, approached without direction (as `SET_KMZ` maps it).
    pub fn of(
        model: &Model,
        q_cmd_um: &[f64; MAX_AXES],
        x_meas_um: &[f64; MAX_AXES],
        slow: &SlowInputs,
        k: f32,
    ) -> Self {
        let dir = [0i8; MAX_AXES];
        let predicted = model.eval_f64(x_meas_um, &dir, slow);
        let scaled = model.scale(x_meas_um, &dir, slow);
        let mut c = KmzCheck {
            residual_um: [0.0; MAX_AXES],
            limit_um: [f32::NAN; MAX_AXES],
        };
        for a in 0..model.axes() {
            c.residual_um[a] = (q_cmd_um[a] - predicted[a]) as f32;
            if let Some(l) = model.prediction_half_width_um(a, &scaled, k) {
                c.limit_um[a] = l;
            }
        }
        c
    }

    /// Some axis left its limit (an axis without a bound never does; a non-finite residual on
    /// a bounded axis does: the model cannot say where the stage is).
    pub fn outside(&self) -> bool {
        self.residual_um
            .iter()
            .zip(&self.limit_um)
            .any(|(r, l)| !l.is_nan() && (r.is_nan() || r.abs() > *l))
    }
}

/// Largest distance of a temperature `model` reads beyond its training envelope, °C (≤ 0:
/// every one inside; NaN when the model reads no temperature). A temperature that is not a
/// number (not read yet) counts as infinitely far.
pub fn envelope_excess_c(model: &Model, slow: &SlowInputs) -> f32 {
    let mut worst = f64::NAN;
    for t in 0..model.temps() {
        let (lo, hi) = model.envelope(Input::Temp(t as u8));
        let v = slow.temps_c[t];
        let e = if v.is_nan() {
            f64::INFINITY
        } else {
            (v - hi).max(lo - v)
        };
        worst = if worst.is_nan() { e } else { worst.max(e) };
    }
    worst as f32
}

/// The stale state of the model in service (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaleCheck {
    reasons: StaleReasons,
    since_ms: u32,
    last_kmz: Option<KmzCheck>,
    excess_c: f32,
}

impl Default for StaleCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl StaleCheck {
    /// A model just loaded: not stale, nothing checked yet.
    pub const fn new() -> Self {
        StaleCheck {
            reasons: StaleReasons::empty(),
            since_ms: 0,
            last_kmz: None,
            excess_c: f32::NAN,
        }
    }

    /// Why the model is stale (empty: it is not).
    pub fn reasons(&self) -> StaleReasons {
        self.reasons
    }

    /// Whether the model is stale.
    pub fn is_stale(&self) -> bool {
        !self.reasons.is_empty()
    }

    /// Uptime when it first became stale, ms (0 while it is not).
    pub fn since_ms(&self) -> u32 {
        self.since_ms
    }

    /// The last KMZ check, if any since the model was loaded.
    pub fn last_kmz(&self) -> Option<KmzCheck> {
        self.last_kmz
    }

    /// The envelope excess at the last fold, °C ([`envelope_excess_c`]; NaN before one).
    pub fn excess_c(&self) -> f32 {
        self.excess_c
    }

    fn raise(&mut self, reason: StaleReasons, now_ms: u32) {
        if self.reasons.is_empty() {
            // uptime 0 is "not stale" on the wire: a rise in the first millisecond reads as 1
            self.since_ms = now_ms.max(1);
        }
        self.reasons.insert(reason);
    }

    /// A KMZ re-measurement was checked ([`KmzCheck::of`]) at uptime `now_ms`; true when it
    /// made the model stale.
    pub fn kmz(&mut self, check: KmzCheck, now_ms: u32) -> bool {
        self.last_kmz = Some(check);
        let out = check.outside();
        if out {
            self.raise(StaleReasons::KMZ_OUTSIDE_INTERVAL, now_ms);
        }
        out
    }

    /// A fold at uptime `now_ms` read temperatures `excess_c` beyond the envelope
    /// ([`envelope_excess_c`]); more than `margin_c` makes the model stale (true returned).
    pub fn fold(&mut self, excess_c: f32, margin_c: f32, now_ms: u32) -> bool {
        self.excess_c = excess_c;
        let out = excess_c > margin_c;
        if out {
            self.raise(StaleReasons::BEYOND_ENVELOPE, now_ms);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nanocal_model::{AxisBound, Factor, ModelBuilder};

    /// q = x + 2·T (scaled: T centred on 21 °C, half range 1 °C), trained at 20..22 °C, with a
    /// bound of s = 10 nm on the axis' two terms.
    fn model(bound: bool) -> Model {
        let mut b = ModelBuilder::new(1, 1, 0)
            .unwrap()
            .trained_range(Input::Axis(0), 0.0, 100.0)
            .trained_range(Input::Temp(0), 20.0, 22.0);
        b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
        b.add_raw_term(0, [0, 0, 0], Factor::Temp(0), 0, 2.0)
            .unwrap();
        let mut m = b.build().unwrap();
        if bound {
            // an orthonormal design: R = I, h(z) = ‖z‖², centred at 0, scale 1
            let r = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0];
            let b = AxisBound::new(0.010, 2.0, &[0.0, 0.0], &[1.0, 1.0], &r).unwrap();
            m.set_bound(0, Some(b)).unwrap();
        }
        m
    }

    fn slow(t_c: f64) -> SlowInputs {
        let mut s = SlowInputs::default();
        s.temps_c[0] = t_c;
        s
    }

    fn at(model: &Model, x: f64, t_c: f64, error_um: f64, k: f32) -> KmzCheck {
        let mut xm = [0.0; MAX_AXES];
        xm[0] = x;
        let mut q = model.eval_f64(&xm, &[0; MAX_AXES], &slow(t_c));
        q[0] += error_um;
        KmzCheck::of(model, &q, &xm, &slow(t_c), k)
    }

    #[test]
    fn the_residual_is_the_lambda_change_the_kmz_makes() {
        let m = model(true);
        let c = at(&m, 50.0, 21.0, 0.025, 3.0);
        assert!((c.residual_um[0] - 0.025).abs() < 1e-6);
        // and is exactly what SET_KMZ moves λ_KMZ by
        let mut after = m.clone();
        let mut xm = [0.0; MAX_AXES];
        xm[0] = 50.0;
        let mut q = m.eval_f64(&xm, &[0; MAX_AXES], &slow(21.0));
        q[0] += 0.025;
        after.set_kmz_from_reference(&q, &xm, &[0; MAX_AXES], &slow(21.0));
        assert!((after.kmz_offset_um(0) - f64::from(c.residual_um[0])).abs() < 1e-9);
    }

    #[test]
    fn the_limit_is_k_standard_errors_of_prediction_at_the_kmz_point() {
        let m = model(true);
        // at x = 0 (scaled −1) and T = 21 °C (scaled 0): z = (1, −1, 0), h = 2
        let c = at(&m, 0.0, 21.0, 0.0, 3.0);
        let want = 3.0 * 0.010 * (1.0f32 + 2.0).sqrt();
        assert!((c.limit_um[0] - want).abs() < 1e-7, "{:?}", c.limit_um);
        assert!(c.limit_um[1].is_nan() && c.limit_um[2].is_nan());
    }

    #[test]
    fn a_kmz_inside_k_sigma_leaves_the_model_in_service_and_one_outside_makes_it_stale() {
        let m = model(true);
        let limit = 3.0 * 0.010 * 3.0f64.sqrt(); // 52 nm at x = 0, 21 °C
        let mut s = StaleCheck::new();
        assert!(!s.kmz(at(&m, 0.0, 21.0, 0.9 * limit, 3.0), 1_000));
        assert!(!s.kmz(at(&m, 0.0, 21.0, -0.9 * limit, 3.0), 2_000));
        assert!(!s.is_stale());
        assert!(s.kmz(at(&m, 0.0, 21.0, -1.1 * limit, 3.0), 3_000));
        assert_eq!(s.reasons(), StaleReasons::KMZ_OUTSIDE_INTERVAL);
        assert_eq!(s.since_ms(), 3_000);
        // latched: a later good KMZ does not clear it, nor move the time it rose
        assert!(!s.kmz(at(&m, 0.0, 21.0, 0.0, 3.0), 4_000));
        assert!(s.is_stale());
        assert_eq!(s.since_ms(), 3_000);
        // k is the setting's: the same error within 4 σ is fine
        let mut wide = StaleCheck::new();
        assert!(!wide.kmz(at(&m, 0.0, 21.0, -1.1 * limit, 4.0), 3_000));
    }

    #[test]
    fn a_model_without_a_bound_is_not_checked_at_the_kmz() {
        let m = model(false);
        let mut s = StaleCheck::new();
        let c = at(&m, 0.0, 21.0, 5.0, 3.0);
        assert!(c.limit_um[0].is_nan());
        assert!(!s.kmz(c, 1_000));
        assert!(!s.is_stale());
        assert_eq!(s.last_kmz().map(|k| k.residual_um), Some(c.residual_um));
    }

    #[test]
    fn a_residual_that_is_not_a_number_on_a_bounded_axis_is_outside() {
        let m = model(true);
        let mut c = at(&m, 0.0, 21.0, 0.0, 3.0);
        c.residual_um[0] = f32::NAN;
        assert!(c.outside());
    }

    #[test]
    fn temperatures_beyond_the_envelope_by_more_than_the_margin_make_the_model_stale() {
        let m = model(true);
        assert_eq!(envelope_excess_c(&m, &slow(21.0)), -1.0);
        assert!((envelope_excess_c(&m, &slow(22.05)) - 0.05).abs() < 1e-6);
        assert!((envelope_excess_c(&m, &slow(19.8)) - 0.2).abs() < 1e-6);
        assert_eq!(envelope_excess_c(&m, &slow(f64::NAN)), f32::INFINITY);
        let mut s = StaleCheck::new();
        assert!(!s.fold(envelope_excess_c(&m, &slow(22.05)), 0.1, 500));
        assert!(!s.fold(envelope_excess_c(&m, &slow(21.5)), 0.1, 600));
        assert!(!s.is_stale());
        assert!(s.fold(envelope_excess_c(&m, &slow(19.8)), 0.1, 700));
        assert_eq!(s.reasons(), StaleReasons::BEYOND_ENVELOPE);
        assert_eq!(s.since_ms(), 700);
        // back inside: still stale (latched), the excess reported is the last fold's
        assert!(!s.fold(envelope_excess_c(&m, &slow(21.0)), 0.1, 800));
        assert!(s.is_stale() && s.excess_c() == -1.0);
        // both reasons accumulate; the time is the first rise
        assert!(s.kmz(at(&m, 0.0, 21.0, 1.0, 3.0), 900));
        assert!(s.reasons().contains(StaleReasons::BEYOND_ENVELOPE));
        assert!(s.reasons().contains(StaleReasons::KMZ_OUTSIDE_INTERVAL));
        assert_eq!(s.since_ms(), 700);
        // a margin of 0: any excursion counts
        let mut strict = StaleCheck::new();
        assert!(strict.fold(envelope_excess_c(&m, &slow(22.05)), 0.0, 1));
    }

    #[test]
    fn a_model_without_temperatures_has_no_envelope_excess_and_never_goes_stale_by_it() {
        let m = ModelBuilder::new(1, 0, 0)
            .unwrap()
            .trained_range(Input::Axis(0), 0.0, 100.0)
            .build()
            .unwrap();
        let e = envelope_excess_c(&m, &slow(35.0));
        assert!(e.is_nan());
        let mut s = StaleCheck::new();
        assert!(!s.fold(e, 0.0, 1));
        assert!(!s.is_stale());
    }

    #[test]
    fn a_rise_at_uptime_zero_still_reads_as_stale_on_the_wire() {
        let mut s = StaleCheck::new();
        s.fold(1.0, 0.1, 0);
        assert_eq!(s.since_ms(), 1);
    }
}
