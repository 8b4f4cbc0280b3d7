//! Continuous drives (one pose per sample), as a piezo under a voltage ramp or sine sees them:
//! a path through turning points, so that amplitude changes, minor loops and partly inverted
//! strokes can be produced on purpose.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::{Dwell, Trajectory};

/// A 1-axis drive through `turning_um` (in order), each leg a half cosine of
/// `samples_per_leg` samples (smooth at the turning points, like a sine), one sample every
/// `period_s`.
pub fn through_turning_points(
    turning_um: &[f64],
    samples_per_leg: usize,
    period_s: f64,
) -> Trajectory {
    let mut dwells = Vec::new();
    for w in turning_um.windows(2) {
        let (a, b) = (w[0], w[1]);
        for k in 0..samples_per_leg {
            let s = k as f64 / samples_per_leg as f64;
            let x = a + (b - a) * 0.5 * (1.0 - (std::f64::consts::PI * s).cos());
            dwells.push(Dwell {
                cmd_um: vec![x],
                dwell_s: period_s,
            });
        }
    }
    if let Some(&last) = turning_um.last() {
        dwells.push(Dwell {
            cmd_um: vec![last],
            dwell_s: period_s,
        });
    }
    Trajectory { dwells }
}

/// `legs + 1` turning points in [lo, hi] that alternate in direction with random amplitudes
/// (from a tenth of the stroke to all of it): minor loops inside major ones, partly inverted
/// strokes, an amplitude that changes all the time.
pub fn random_turning_points(lo: f64, hi: f64, legs: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let span = hi - lo;
    let mut p = vec![lo + 0.5 * span];
    let mut up = true;
    for _ in 0..legs {
        let cur = *p.last().unwrap_or(&lo);
        let room = if up { hi - cur } else { cur - lo };
        let step = rng.gen_range((0.1 * span).min(room)..=room.max(1e-9));
        p.push(if up { cur + step } else { cur - step });
        up = !up;
    }
    p
}
