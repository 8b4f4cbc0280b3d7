//! Mapping controller positions back to calibrated coordinates with forward evaluations only.
//!
//! The proxy nearly always knows a good start: the target it last sent, which the stage sits
//! at or moves towards. From there a chord method — Newton with the Jacobian held fixed —
//! converges in one or two steps, and each step is one fast-path evaluation (≈ 200
//! instructions for a 1-DoF model on the Cortex-M4F). The Jacobian comes from finite
//! differences of the same fast path and is kept: a calibration model is close to the identity
//! and its Jacobian varies slowly with position and temperature, so an old one still contracts
//! the error by orders of magnitude per step. When a step shrank by less than a factor 100
//! against the step before, or had to be shortened, it is taken afresh where the iteration
//! stands: from there the method is Newton's (with a finite-difference Jacobian). A step that
//! does not reduce the residual is halved (up to six times), so a start far from the answer or
//! a kink of the hysteresis banks does not throw the iteration off.
//!
//! The play operators stay frozen where the last command left them (a query does not move the
//! stage): every evaluation reads the proxy's hysteresis state and never advances it.
//!
//! Convergence is declared when a step is below 8 ε (|x| + |q| + 1) on every axis, or when the
//! model reproduces `q` within 4 ε (|q| + 1). The answer comes with δ at the last evaluation:
//! the caller forms `x = q − δ` in micros, which keeps the resolution an f32 position lacks on
//! a long stroke.

use super::corrector::Corrector;
use crate::gcs::MAP_AXES;
use nanocal_model::HysteresisState;

/// Steps before the inverse gives up (each is one fast-path evaluation, plus halvings).
const MAX_STEPS: usize = 16;
/// Halvings of a step that does not reduce the residual.
const MAX_HALVINGS: usize = 6;

/// The inverse Jacobian of the fast path, kept between replies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Jacobian {
    /// (∂q/∂x)⁻¹, taken at some recent calibrated point.
    inv: [[f32; MAP_AXES]; MAP_AXES],
}

/// Calibrated position for controller positions `q_um` (model axes `0..c.axes()`), starting at
/// `x0_um` (the last target) when known, else at `q_um`, with the play operators frozen in
/// `state`; and δ there. `cache` keeps the inverse Jacobian. `None` when the iteration does not
/// converge (the model folds back or is flat there) or meets a non-finite value.
pub(crate) fn invert<C: Corrector>(
    c: &C,
    q_um: &[f32; MAP_AXES],
    dir: &[i8; MAP_AXES],
    state: &HysteresisState,
    x0_um: Option<[f32; MAP_AXES]>,
    cache: &mut Option<Jacobian>,
) -> Option<([f32; MAP_AXES], [f32; MAP_AXES])> {
    let n = c.axes().min(MAP_AXES);
    if q_um[..n].iter().any(|v| !v.is_finite()) {
        return None;
    }
    // the largest residual in units of the rounding of q
    let residual = |f: &[f32; MAP_AXES]| {
        let mut norm = 0.0f32;
        for a in 0..n {
            let r = (f[a] - q_um[a]).abs() / (4.0 * f32::EPSILON * (q_um[a].abs() + 1.0));
            if r > norm || r.is_nan() {
                norm = r;
            }
        }
        norm
    };
    let mut x = x0_um.unwrap_or(*q_um);
    let mut cur = c.correct(&x, dir, state);
    let mut norm = residual(&cur.q_um);
    // take the Jacobian afresh when there is none, or when the kept one contracts the error by
    // less than a factor 100 per step (the last step against the one before)
    let mut refresh = cache.is_none();
    let mut last_step = f32::INFINITY;
    for _ in 0..MAX_STEPS {
        if norm <= 1.0 {
            // the model maps x to q within a few rounding steps of q: nothing closer exists in
            // f32 (this ends the iteration on a nearly flat, ill-conditioned model too)
            return Some((x, cur.delta_um));
        }
        if refresh {
            *cache = Some(Jacobian {
                inv: jacobian(c, &x, &cur.q_um, dir, state, n)?,
            });
        }
        let inv = cache.as_ref()?.inv;
        let mut s = [0.0f32; MAP_AXES];
        let mut converged = true;
        let mut step = 0.0f32;
        for a in 0..n {
            for b in 0..n {
                s[a] += inv[a][b] * (cur.q_um[b] - q_um[b]);
            }
            let tolerance = 8.0 * f32::EPSILON * (x[a].abs() + q_um[a].abs() + 1.0);
            converged &= s[a].abs() <= tolerance;
            step = step.max(s[a].abs());
        }
        if converged {
            for a in 0..n {
                x[a] -= s[a];
            }
            return Some((x, cur.delta_um));
        }
        // the step, halved while it does not reduce the residual
        let mut t = 1.0f32;
        for halving in 0..=MAX_HALVINGS {
            let mut trial = x;
            for a in 0..n {
                trial[a] -= t * s[a];
                if !trial[a].is_finite() {
                    return None;
                }
            }
            let next = c.correct(&trial, dir, state);
            let next_norm = residual(&next.q_um);
            if next_norm < norm || halving == MAX_HALVINGS {
                (x, cur, norm) = (trial, next, next_norm);
                break;
            }
            t *= 0.5;
        }
        refresh = t < 1.0 || step > 0.01 * last_step;
        last_step = t * step;
    }
    None
}

/// (∂q/∂x)⁻¹ at `x` by forward differences of the fast path (`f0` = its value at `x`), the
/// play operators frozen in `state`.
fn jacobian<C: Corrector>(
    c: &C,
    x: &[f32; MAP_AXES],
    f0: &[f32; MAP_AXES],
    dir: &[i8; MAP_AXES],
    state: &HysteresisState,
    n: usize,
) -> Option<[[f32; MAP_AXES]; MAP_AXES]> {
    let mut j = [[0.0f32; MAP_AXES]; MAP_AXES];
    for b in 0..n {
        // a step well above the f32 rounding of q, well below the model's curvature scale
        let h = 0.25 + x[b].abs() * (1.0 / 1024.0);
        let mut xh = *x;
        xh[b] += h;
        let h = xh[b] - x[b]; // the step actually taken
        let fh = c.correct(&xh, dir, state).q_um;
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
