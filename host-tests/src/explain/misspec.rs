//! Misspecification checks: after naming, each named effect is tested against a flexible
//! alternative in the coordinate it lives in. A listed name is kept only if the data need its
//! form; structure that a flexible form carries and no listed form explains is reported as
//! such — "not in the library" — never handed to the nearest listed name. Physically senseless
//! parameters are a finding too.
//!
//! The alternatives: a temperature² term per sensor (a nonlinear thermal response) for the
//! effects that explain slow structure (a lag can bend a logistic temperature rise enough to
//! soak up a parabola; a smooth function of time or of the weather can too); the dead path an
//! air-refraction fit implies, against the interferometer's geometry.

use serde::Serialize;

use super::data::Data;

/// Structure a flexible alternative carries that no listed form explains.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Misfit {
    /// The coordinate the structure lives in (`temp_stage²`, `pressure`, …).
    pub coordinate: String,
    /// What it is, in words.
    pub description: String,
    /// Held-out RMS the alternative explains, nm.
    pub rms_nm: f64,
    /// Listed names withdrawn because the alternative fits as well without them.
    pub withdrawn: Vec<&'static str>,
    /// The numbers behind it.
    pub evidence: String,
}

/// Named effects the temperature² alternative is tried against: those that explain slow
/// structure through a smooth coordinate.
pub const SMOOTH_EFFECTS: [&str; 3] = [
    crate::effects::thermal_lag::NAME,
    crate::effects::unexplained_drift::NAME,
    crate::effects::air_refraction::NAME,
];

/// A held-out RMS within this factor of another counts as "as good".
pub const AS_GOOD: f64 = 1.02;

/// One column per temperature sensor: its square about its mean, (T − T̄)².
pub fn temperature_squares(d: &Data) -> Vec<Vec<f64>> {
    d.temps
        .iter()
        .map(|(_, t)| {
            let m = t.iter().sum::<f64>() / t.len().max(1) as f64;
            t.iter().map(|v| (v - m) * (v - m)).collect()
        })
        .collect()
}

/// The sensor whose square carries most of a fit (|coefficient| × spread of its column).
pub fn main_square(d: &Data, squares: &[Vec<f64>], coeffs: &[f64]) -> String {
    let spread = |c: &[f64]| {
        let m = c.iter().sum::<f64>() / c.len().max(1) as f64;
        (c.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / c.len().max(1) as f64).sqrt()
    };
    let best = (0..squares.len().min(coeffs.len()))
        .max_by(|&a, &b| {
            (coeffs[a].abs() * spread(&squares[a]))
                .total_cmp(&(coeffs[b].abs() * spread(&squares[b])))
        })
        .unwrap_or(0);
    d.temps
        .get(best)
        .map_or("a temperature".into(), |t| t.0.clone())
}

/// The words for a nonlinear temperature response in `sensor`.
pub fn nonlinear_thermal(
    sensor: &str,
    withdrawn: &[&'static str],
    rms_nm: f64,
    evidence: String,
) -> Misfit {
    let mut description = format!(
        "structure in {sensor} that no listed form explains (a nonlinear temperature response? a term in {sensor}² carries it)"
    );
    if !withdrawn.is_empty() {
        description.push_str(&format!(
            "; {} fitted it too, but not better than the square does without {}: not named",
            withdrawn.join(" and "),
            if withdrawn.len() > 1 { "them" } else { "it" }
        ));
    }
    Misfit {
        coordinate: format!("{sensor}²"),
        description,
        rms_nm,
        withdrawn: withdrawn.to_vec(),
        evidence,
    }
}
