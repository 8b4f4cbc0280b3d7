//! The stage travel at its ends: the one rule the proxy applies to a corrected command, and the
//! host's validation with it (`nanocal::validate`).
//!
//! A corrected command must lie inside the stage travel the model states (the blob's travel,
//! command space) and inside the controller's own limits (`TMN?`/`TMX?`, read at start-up).
//! Near an end the correction can step just outside: a model whose correction at 0 µm is
//! −0.05 µm, on a controller whose travel starts at 0, would make `MOV 1 0` and `GOH` (which is
//! `MOV` to 0) impossible. So a command at most [`CLAMP_UM`] outside is **clamped** to the end
//! of the travel — the stage goes as far as it can, the proxy records (and `MOV?` reports)
//! the calibrated position of the clamped command, not the target asked for — and a command
//! further out is **refused**, naming which travel it left: the model's (GCS code 7, as a
//! controller says it) or the controller's (the compensator's own code, see
//! [`super::GcsErrorCode::OutsideControllerTravel`]).
//!
//! 0.1 µm is the resolution of a stage's travel specification, well inside a corrected
//! command's distance from its target at the ends (tens of µm with thermal drift), and small
//! against the errors a calibration removes — but larger than the accuracy a calibration
//! reaches: the clamped target is then off by up to 0.1 µm, which is why the proxy reports it.

use crate::gcs;

/// How far outside the travel a corrected command is clamped to it, µm.
pub const CLAMP_UM: f64 = 0.1;
/// [`CLAMP_UM`] in micros (millionths of a µm).
pub const CLAMP_MICROS: i64 = 100_000;

/// Which travel a command is outside of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Limit {
    /// The stage travel the model states (the blob's).
    Model,
    /// The controller's `TMN?`/`TMX?`.
    Controller,
}

/// A corrected command against the travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edge {
    /// Inside: sent as it is.
    Inside,
    /// Up to [`CLAMP_UM`] outside: sent as this end of the travel (micros).
    Clamped(i64),
    /// Further outside (or no travel left where the two meet): refused.
    Outside(Limit),
}

/// The model's travel `(min, max)` (µm, f32 as the fold holds it) in micros; a non-finite
/// end leaves no travel.
pub fn model_travel_micros(lo_um: f32, hi_um: f32) -> (i64, i64) {
    match (gcs::f32_to_micros(lo_um), gcs::f32_to_micros(hi_um)) {
        (Some(lo), Some(hi)) => (lo, hi),
        _ => (i64::MAX, i64::MIN),
    }
}

/// Command `q` (micros) against the model's travel `model` and the controller's limits
/// `controller` (micros, `None` where the controller did not tell them).
pub fn edge(q: i64, model: (i64, i64), controller: (Option<i64>, Option<i64>)) -> Edge {
    let (mlo, mhi) = model;
    if q < mlo.saturating_sub(CLAMP_MICROS) || q > mhi.saturating_add(CLAMP_MICROS) {
        return Edge::Outside(Limit::Model);
    }
    let clo = controller.0.unwrap_or(i64::MIN);
    let chi = controller.1.unwrap_or(i64::MAX);
    if q < clo.saturating_sub(CLAMP_MICROS) || q > chi.saturating_add(CLAMP_MICROS) {
        return Edge::Outside(Limit::Controller);
    }
    let (lo, hi) = (mlo.max(clo), mhi.min(chi));
    if lo > hi {
        Edge::Outside(Limit::Controller)
    } else if q < lo {
        Edge::Clamped(lo)
    } else if q > hi {
        Edge::Clamped(hi)
    } else {
        Edge::Inside
    }
}

/// The command the proxy forms for calibrated target `x` (micros) from the fast path's
/// deviation `delta_um`: `x + δ` in micros (see [`super::Corrected::delta_um`]); `None` for a
/// non-finite δ.
pub fn command_micros(x: i64, delta_um: f32) -> Option<i64> {
    Some(x.saturating_add(gcs::f32_to_micros(delta_um)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_are_clamped_within_the_tolerance_and_refused_beyond() {
        let model = (-20_000_000, 520_000_000);
        let ctl = (Some(0), Some(500_000_000));
        assert_eq!(edge(250_000_000, model, ctl), Edge::Inside);
        assert_eq!(edge(-54_871, model, ctl), Edge::Clamped(0));
        assert_eq!(edge(500_100_000, model, ctl), Edge::Clamped(500_000_000));
        assert_eq!(edge(-100_001, model, ctl), Edge::Outside(Limit::Controller));
        assert_eq!(edge(520_100_001, model, ctl), Edge::Outside(Limit::Model));
        // no controller limits known: the model's travel alone
        assert_eq!(
            edge(-20_050_000, model, (None, None)),
            Edge::Clamped(-20_000_000)
        );
        // no overlap
        assert_eq!(
            edge(10, (0, 10), (Some(20), Some(30))),
            Edge::Outside(Limit::Controller)
        );
    }
}
