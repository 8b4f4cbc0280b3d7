//! The play (backlash) operator: the building block of rate-independent hysteresis.
//!
//! A Prandtl–Ishlinskii hysteresis model is a weighted sum of play operators with thresholds
//! spread over the stroke, `H[v](t) = Σ_i w_i · F_{r_i}[v](t)` (Kuhnen, "Modeling,
//! Identification and Compensation of Complex Hysteretic Nonlinearities", Eur. J. Control 9,
//! 2003, Eq. 2–3). Each play operator follows its input with a dead band of half-width `r`:
//!
//! ```text
//! y(t) = max(v(t) − r, min(v(t) + r, y(t⁻)))
//! ```
//!
//! It depends only on the order of the input's values, not on their rate, and it remembers
//! reversal points, so a weighted sum reproduces minor loops and amplitude changes. Explain
//! (which identifies the weights on the host) and the compensator's fast path (which runs them
//! per command) both step operators through this one function.

use core::ops::{Add, Sub};

/// One step of a play operator with threshold `threshold` (≥ 0): the new output for input
/// `input`, given the previous output `state`. NaN in, NaN out.
#[inline(always)]
pub fn play<T>(state: T, input: T, threshold: T) -> T
where
    T: Copy + PartialOrd + Add<Output = T> + Sub<Output = T>,
{
    let low = input - threshold;
    let high = input + threshold;
    if state < low {
        low
    } else if state > high {
        high
    } else {
        state
    }
}

#[cfg(test)]
mod tests {
    use super::play;

    /// Walk an input sequence through one operator.
    fn run(inputs: &[f64], r: f64) -> std::vec::Vec<f64> {
        let mut y = inputs[0];
        inputs
            .iter()
            .map(|&v| {
                y = play(y, v, r);
                y
            })
            .collect()
    }

    #[test]
    fn dead_band_then_follows_then_holds_at_reversal() {
        // Up 0 → 3, back to 1, up to 2: threshold 1.
        let y = run(&[0.0, 0.5, 1.0, 2.0, 3.0, 2.5, 2.0, 1.0, 1.5, 2.0], 1.0);
        // Starts at the input, stays inside the band until the input leaves it, then lags it by r.
        assert_eq!(y, [0.0, 0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0]);
    }

    #[test]
    fn rate_independent_same_values_same_outputs() {
        let slow = run(&[0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0], 0.7);
        let fast = run(&[0.0, 3.0, 0.0], 0.7);
        assert_eq!(slow[3], fast[1]);
        assert_eq!(slow[6], fast[2]);
    }

    #[test]
    fn zero_threshold_is_identity_and_f32_matches_f64() {
        let v = [0.3, -1.2, 4.5, 4.4];
        assert_eq!(run(&v, 0.0), v);
        let (mut a, mut b) = (0.0f32, 0.0f64);
        for &x in &v {
            a = play(a, x as f32, 0.25f32);
            b = play(b, x, 0.25);
            assert!((f64::from(a) - b).abs() < 1e-6);
        }
    }
}
