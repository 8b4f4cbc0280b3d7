//! `creep`: after each step the position keeps moving in the direction of the step,
//! ∝ step × log(1 + t/t0).

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::search::Search;

/// The effect's name.
pub const NAME: &str = "creep";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Creep per unit of log(1 + t/t0), as a fraction of the step (e.g. 0.001 = 1 nm per µm).
    pub gamma: f64,
    /// Time scale of the logarithm, s.
    pub t0_s: f64,
}

/// Σ over past steps of step_um × log(1 + (t − t_step)/t0), µm per unit γ.
pub fn creep_basis(t_s: &[f64], steps: &[(usize, f64)], t0_s: f64) -> Vec<f64> {
    let mut out = vec![0.0; t_s.len()];
    for &(k0, dq) in steps {
        // The move happens between samples k0-1 and k0: take the midpoint as the step time.
        let ts = if k0 > 0 {
            0.5 * (t_s[k0 - 1] + t_s[k0])
        } else {
            t_s[0]
        };
        for k in k0..t_s.len() {
            out[k] += dq * (1.0 + (t_s[k] - ts) / t0_s).ln();
        }
    }
    out
}

impl Params {
    /// error = γ Σ Δq log(1 + (t − t_k)/t0).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let b = creep_basis(&ctx.t_s, &ctx.steps[self.axis], self.t0_s);
        for (o, v) in out[self.axis].iter_mut().zip(b) {
            *o = self.gamma * v;
        }
        out
    }
}

/// Creep basis on the recording's own time base; O(n·steps) additions for even sampling.
fn basis(d: &Data, steps: &[(usize, f64)], t0_s: f64) -> Vec<f64> {
    match d.uniform_dt_s {
        Some(dt) => {
            let n = d.rows();
            let table: Vec<f64> = (0..n)
                .map(|j| (1.0 + (j as f64 + 0.5) * dt / t0_s).ln())
                .collect();
            let mut out = vec![0.0; n];
            for &(k0, dq) in steps {
                for (o, l) in out[k0..].iter_mut().zip(&table) {
                    *o += dq * l;
                }
            }
            out
        }
        None => creep_basis(&d.t_s, steps, t0_s),
    }
}

/// The explain candidate: Σ step × log(1 + t/t0) over past moves, t0 searched between a tenth
/// of a sample interval and the median dwell (beyond either end it is an offset per move or a
/// line in time, not creep).
pub struct Candidate;

/// Median duration of a dwell (time between moves), s.
fn median_dwell_s(d: &Data, steps: &[(usize, f64)]) -> f64 {
    let mut starts: Vec<f64> = std::iter::once(d.t_s[0])
        .chain(steps.iter().map(|s| d.t_s[s.0]))
        .chain(std::iter::once(*d.t_s.last().unwrap_or(&0.0)))
        .collect::<Vec<f64>>()
        .windows(2)
        .map(|w| w[1] - w[0])
        .collect();
    crate::explain::stats::median(&mut starts)
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "after each move the stage keeps creeping in the direction of the move, slower and slower (∝ step × log(1 + t/t0))"
    }
    fn deploy(&self) -> &'static str {
        "not in the blob: it needs the history of moves; shorten dwells before reading, or let the adaptive KMZ offset absorb it"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        let c = &d.channels[ch];
        // creep shows only where the drive steps and then holds a pose; the basis costs rows ×
        // moves additions per evaluation
        c.u.is_some()
            && c.has_dwells
            && c.steps.len() >= 3
            && (c.steps.len() as f64) * (d.rows() as f64) <= 3e8
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let steps = &s.d.channels[s.ch].steps;
        let lo = (0.1 * s.d.median_dt_s).max(1e-3);
        let hi = median_dwell_s(s.d, steps).max(10.0 * lo);
        let mut p = contract::one_theta(s, "t0_s", lo, hi, 8, |t0| vec![basis(s.d, steps, t0)]);
        // γ's standard error holds t0 at its best value, but γ and t0 trade off (a longer t0
        // flattens the start of every dwell's logarithm, and a larger γ makes up for it): how
        // far γ moves along t0's profile is part of γ's uncertainty (hidden γ 1.1000·10⁻³,
        // t0 8.0 s came back 1.1101·10⁻³ ± 0.3 % with t0 = 8.5 ± 0.9 s, 3.3σ off)
        if let Some(t0) = p.theta() {
            let h = 0.05f64;
            let gamma_at = |t: f64| {
                let col = basis(s.d, steps, t);
                let (r, b, _) = s.basis.reduce(&[&col]);
                if r[0][0] > 0.0 {
                    b[0] / r[0][0]
                } else {
                    f64::NAN
                }
            };
            let slope = (gamma_at(t0 * h.exp()) - gamma_at(t0 * (-h).exp())) / (2.0 * h);
            if slope.is_finite() {
                p.detail = contract::Detail::Coupled {
                    dcoeff_dln_theta: slope,
                };
            }
        }
        Ok(Some(p))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let t0 = &f.proposal.thetas[0];
        // t0 beyond the dwells: each dwell shows only the start of the logarithm, where
        // log(1 + t/t0) ≈ t/t0, so only γ/t0 is determined and the γ fitted with t0 held at the
        // top of its range is a lower bound of |γ| (a larger true t0 needs a larger γ), not
        // a value ± σ (hidden creep with t0 = 200 s behind 60 s dwells came back at 0.70 of its
        // γ, 16 stated σ away)
        let se = if gamma_is_a_bound(t0) {
            f64::NAN
        } else {
            match f.proposal.detail {
                // t0's share, where its profile gives it a finite σ (on a bound, or with a
                // flat profile, γ keeps its own: at the bottom it is the slope in log t)
                contract::Detail::Coupled { dcoeff_dln_theta }
                    if t0.sigma_unless_bound().is_finite() =>
                {
                    f.se[0].hypot(dcoeff_dln_theta * t0.sigma / t0.value)
                }
                _ => f.se[0],
            }
        };
        vec![
            Estimate::new("gamma", f.coeffs[0], se),
            t0.estimate(),
            Estimate::new(
                "nm_per_um_per_decade",
                f.coeffs[0] * std::f64::consts::LN_10 * 1e3,
                se * std::f64::consts::LN_10 * 1e3,
            ),
        ]
    }
    fn summary(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> String {
        let t0 = &f.proposal.thetas[0];
        if gamma_is_a_bound(t0) {
            format!(
                "t0 at the top of its searched range (the median dwell, {}): the dwells show only the start of the logarithm, where only γ/t0 is determined — |γ| ≥ {} (a lower bound, no σ), γ/t0 ≈ {}/s",
                crate::explain::units::duration(t0.hi),
                crate::explain::units::sig3(f.coeffs[0].abs()),
                crate::explain::units::sig3(f.coeffs[0] / t0.value)
            )
        } else {
            String::new()
        }
    }
}

/// Whether t0 sits at the top of its searched range, where γ is only a lower bound of its
/// magnitude (see [`Candidate`]'s parameters). At the bottom γ stays an estimate: for
/// t ≫ t0, log(1 + t/t0) ≈ log t − log t0 and γ is the slope in log t (the offset per move
/// is a term linear in the position, which the baseline carries).
fn gamma_is_a_bound(t0: &crate::explain::estimate::Theta) -> bool {
    t0.value >= t0.hi * 0.97
}
