//! Mapping controller positions back to calibrated coordinates with forward evaluations only.
//!
//! The model's own inverse (`Fold::inverse`) runs Newton's method from `x = q` with a Jacobian
//! from dual numbers at every step: about 20,000 guest instructions for a 1-DoF model on the
//! Cortex-M4F. The proxy nearly always knows a far better start: the target it last sent, which
//! the stage sits at or moves towards. From there a chord method — Newton with the Jacobian held
//! fixed — converges in one or two steps, and each step is one fast-path evaluation (≈ 200
//! instructions for the 1-DoF model). The Jacobian comes from finite differences of the same
//! fast path and is kept: a calibration model is close to the identity and its Jacobian varies
//! slowly with position and temperature, so an old one still contracts the error by orders of
//! magnitude per step. When a step shrank by less than a factor 100 against the step before, it
//! is taken afresh where the iteration stands (once per reply: from there the method is
//! Newton's for a step, then the chord again).
//!
//! Convergence is declared by the criterion `Fold::inverse` uses (a step below
//! 8 ε (|x| + |q| + 1) on every axis), or when the model reproduces `q` within 4 ε (|q| + 1);
//! without convergence in [`MAX_STEPS`] steps the model's inverse decides.

use super::corrector::Corrector;
use crate::gcs::MAP_AXES;

/// Chord steps before the model's own inverse takes over (each is one fast-path evaluation).
const MAX_STEPS: usize = 8;

/// The inverse Jacobian of the fast path, kept between replies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Jacobian {
    /// (∂q/∂x)⁻¹, taken at some recent calibrated point.
    inv: [[f32; MAP_AXES]; MAP_AXES],
}

/// Calibrated position for controller positions `q_um` (model axes `0..c.axes()`), starting at
/// `x0_um` (the last target) when known, else at `q_um`. `cache` keeps the inverse Jacobian.
pub(crate) fn invert<C: Corrector>(
    c: &C,
    q_um: &[f32; MAP_AXES],
    dir: &[i8; MAP_AXES],
    x0_um: Option<[f32; MAP_AXES]>,
    cache: &mut Option<Jacobian>,
) -> Option<[f32; MAP_AXES]> {
    let n = c.axes().min(MAP_AXES);
    if q_um[..n].iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut x = x0_um.unwrap_or(*q_um);
    // take the Jacobian afresh when there is none, or when the kept one contracts the error by
    // less than a factor 100 per step (the last step against the one before)
    let mut refresh = cache.is_none();
    let mut refreshed = false;
    let mut last_step = f32::INFINITY;
    for _ in 0..MAX_STEPS {
        let f = c.correct(&x, dir).q_um;
        if refresh && !refreshed {
            *cache = Some(Jacobian {
                inv: jacobian(c, &x, &f, dir, n)?,
            });
            refreshed = true;
        }
        let inv = cache.as_ref()?.inv;
        let mut r = [0.0f32; MAP_AXES];
        let mut reproduced = true;
        for a in 0..n {
            r[a] = f[a] - q_um[a];
            reproduced &= r[a].abs() <= 4.0 * f32::EPSILON * (q_um[a].abs() + 1.0);
        }
        if reproduced {
            // the model maps x to q within a few rounding steps of q: nothing closer exists in
            // f32 (this ends the iteration on a nearly flat, ill-conditioned model too)
            return Some(x);
        }
        let mut converged = true;
        let mut step = 0.0f32;
        for a in 0..n {
            let mut s = 0.0f32;
            for b in 0..n {
                s += inv[a][b] * r[b];
            }
            x[a] -= s;
            if !x[a].is_finite() {
                return c.inverse(q_um, dir);
            }
            let tolerance = 8.0 * f32::EPSILON * (x[a].abs() + q_um[a].abs() + 1.0);
            converged &= s.abs() <= tolerance;
            step = step.max(s.abs());
        }
        if converged {
            return Some(x);
        }
        refresh = step > 0.01 * last_step;
        last_step = step;
    }
    c.inverse(q_um, dir)
}

/// (∂q/∂x)⁻¹ at `x` by forward differences of the fast path (`f0` = its value at `x`).
fn jacobian<C: Corrector>(
    c: &C,
    x: &[f32; MAP_AXES],
    f0: &[f32; MAP_AXES],
    dir: &[i8; MAP_AXES],
    n: usize,
) -> Option<[[f32; MAP_AXES]; MAP_AXES]> {
    let mut j = [[0.0f32; MAP_AXES]; MAP_AXES];
    for b in 0..n {
        // a step well above the f32 rounding of q, well below the model's curvature scale
        let h = 0.25 + x[b].abs() * (1.0 / 1024.0);
        let mut xh = *x;
        xh[b] += h;
        let h = xh[b] - x[b]; // the step actually taken
        let fh = c.correct(&xh, dir).q_um;
        for a in 0..n {
            j[a][b] = (fh[a] - f0[a]) / h;
        }
    }
    invert_matrix(&j, n)
}

/// Inverse of the leading n×n block (n ≤ 3) by cofactors; `None` when (nearly) singular.
fn invert_matrix(m: &[[f32; MAP_AXES]; MAP_AXES], n: usize) -> Option<[[f32; MAP_AXES]; MAP_AXES]> {
    let mut r = [[0.0f32; MAP_AXES]; MAP_AXES];
    match n {
        1 => {
            if m[0][0].abs() <= 1e-6 {
                return None;
            }
            r[0][0] = 1.0 / m[0][0];
        }
        2 => {
            let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
            if det.abs() <= 1e-6 {
                return None;
            }
            let d = 1.0 / det;
            r[0][0] = m[1][1] * d;
            r[0][1] = -m[0][1] * d;
            r[1][0] = -m[1][0] * d;
            r[1][1] = m[0][0] * d;
        }
        3 => {
            let c00 = m[1][1] * m[2][2] - m[1][2] * m[2][1];
            let c01 = m[1][2] * m[2][0] - m[1][0] * m[2][2];
            let c02 = m[1][0] * m[2][1] - m[1][1] * m[2][0];
            let det = m[0][0] * c00 + m[0][1] * c01 + m[0][2] * c02;
            if det.abs() <= 1e-6 {
                return None;
            }
            let d = 1.0 / det;
            r[0][0] = c00 * d;
            r[1][0] = c01 * d;
            r[2][0] = c02 * d;
            r[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * d;
            r[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * d;
            r[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * d;
            r[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * d;
            r[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * d;
            r[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * d;
        }
        _ => return None,
    }
    Some(r)
}
