//! `periodic_nonlinearity`: the interferometer's error is periodic in position with the
//! fringe period λ/2 (316.4 nm for HeNe) and its harmonic λ/4 (polarisation mixing).

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::{Estimate, Theta};
use crate::explain::search::Search;

/// The effect's name.
pub const NAME: &str = "periodic_nonlinearity";

/// Fringe period of a HeNe interferometer, λ/2, nm.
pub const HENE_HALF_WAVELENGTH_NM: f64 = 316.4;

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Amplitude of the first harmonic (period λ/2), nm.
    pub amplitude_nm: f64,
    /// Phase of the first harmonic, rad.
    pub phase_rad: f64,
    /// Amplitude of the second harmonic (period λ/4), nm.
    pub second_harmonic_nm: f64,
}

impl Params {
    /// error = A sin(2πx/P + φ) + A₂ sin(4πx/P).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            let ph = std::f64::consts::TAU * ctx.pos_um[a][k] * 1e3 / HENE_HALF_WAVELENGTH_NM;
            out[a][k] = (self.amplitude_nm * (ph + self.phase_rad).sin()
                + self.second_harmonic_nm * (2.0 * ph).sin())
                * 1e-3;
        }
        out
    }
}

/// Fringe periods (λ/2) of common interferometer lasers, nm: HeNe 632.8, 532, 780, 1550 nm.
pub const PERIODS_NM: [f64; 4] = [HENE_HALF_WAVELENGTH_NM, 266.0, 390.0, 775.0];

/// The explain candidate: sin/cos of 2πx/P and 4πx/P of the measured position, P from a short list.
pub struct Candidate;

/// The fringe periods the recording can tell from geometry: the stage drifted through half a
/// fringe at the same commanded pose, or a fine scan (poses closer than a third of a period)
/// covered at least two periods.
fn periods(d: &Data, ch: usize) -> Vec<f64> {
    let range_nm = within_pose_range_nm(d, ch);
    let spacing_nm = fine_pose_spacing_nm(d, ch);
    let travel_nm = travel_nm(d, ch);
    PERIODS_NM
        .iter()
        .copied()
        .filter(|p| range_nm >= 0.5 * p || (spacing_nm <= p / 3.0 && travel_nm >= 2.0 * p))
        .collect()
}

/// sin/cos of the first two harmonics of the (noise-free) position for fringe period `p_nm`.
fn regressors(d: &Data, ch: usize, p_nm: f64) -> Vec<Vec<f64>> {
    let m = &d.channels[ch].position_est_um;
    let ph: Vec<f64> = m
        .iter()
        .map(|x| std::f64::consts::TAU * x * 1e3 / p_nm)
        .collect();
    vec![
        ph.iter().map(|v| v.sin()).collect(),
        ph.iter().map(|v| v.cos()).collect(),
        ph.iter().map(|v| (2.0 * v).sin()).collect(),
        ph.iter().map(|v| (2.0 * v).cos()).collect(),
    ]
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the interferometer's error repeats every fringe (λ/2, 316.4 nm for HeNe) and its half: polarisation mixing / ghost reflections"
    }
    fn deploy(&self) -> &'static str {
        "not in the blob (no periodic term in the shared model): correct in the interferometer's electronics (Heydemann) or note it in the uncertainty budget"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        !periods(d, ch).is_empty()
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        // the fringe period is one of a short list of lasers: the best of them
        let best = periods(s.d, s.ch)
            .into_iter()
            .map(|p| {
                let regs = regressors(s.d, s.ch, p);
                let refs: Vec<&[f64]> = regs.iter().map(|c| c.as_slice()).collect();
                (s.basis.rss_with(&refs), p, regs)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        Ok(best.map(|(_, p, regs)| Proposal {
            regs: regs.into_iter().map(std::sync::Arc::new).collect(),
            // a choice from a list, not a searched range: no bounds to hit
            thetas: vec![Theta {
                name: "period_nm".into(),
                value: p,
                sigma: 0.0,
                lo: 0.0,
                hi: f64::INFINITY,
            }],
            detail: contract::Detail::None,
            design: None,
            evidence_units: None,
        }))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let c = f.coeffs;
        let a1 = c[0].hypot(c[1]) * 1e3;
        let a2 = c[2].hypot(c[3]) * 1e3;
        let s1 = 0.5 * (f.se[0] + f.se[1]) * 1e3;
        let s2 = 0.5 * (f.se[2] + f.se[3]) * 1e3;
        vec![
            Estimate::new(
                "period_nm",
                f.proposal.theta().unwrap_or(HENE_HALF_WAVELENGTH_NM),
                0.0,
            ),
            Estimate::new("amplitude_nm", a1, s1),
            Estimate::new(
                "phase_rad",
                c[1].atan2(c[0]),
                if a1 > 0.0 { s1 / a1 } else { f64::NAN },
            ),
            Estimate::new("second_harmonic_nm", a2, s2),
        ]
    }
}

/// Median over commanded poses of how far the (noise-free) position wandered while the command
/// stayed, nm. A periodic error is only told apart from geometry (any function of the pose) when
/// the stage crossed a good part of a fringe at the same commanded pose (thermal drift).
fn within_pose_range_nm(d: &Data, ch: usize) -> f64 {
    let pos = &d.channels[ch].position_est_um;
    let cmds: Vec<&Vec<f64>> = d
        .channels
        .iter()
        .filter_map(|c| c.cmd_um.as_ref())
        .collect();
    let mut groups: std::collections::HashMap<Vec<i64>, (f64, f64)> =
        std::collections::HashMap::new();
    for (i, &p) in pos.iter().enumerate() {
        if !p.is_finite() {
            continue;
        }
        let key: Vec<i64> = cmds.iter().map(|c| (c[i] * 1e3).round() as i64).collect();
        let e = groups
            .entry(key)
            .or_insert((f64::INFINITY, f64::NEG_INFINITY));
        e.0 = e.0.min(p);
        e.1 = e.1.max(p);
    }
    let mut ranges: Vec<f64> = groups.values().map(|(lo, hi)| (hi - lo) * 1e3).collect();
    if ranges.is_empty() {
        return 0.0;
    }
    ranges.sort_by(f64::total_cmp);
    ranges[ranges.len() / 2]
}

/// Commanded travel of this axis, nm (0 when not commanded): a fine scan tells a periodic
/// error from a smooth function of position only over a few periods.
fn travel_nm(d: &Data, ch: usize) -> f64 {
    2.0 * d.channels[ch].half_range_um * 1e3 * f64::from(u8::from(d.channels[ch].u.is_some()))
}

/// Median spacing between neighbouring distinct commanded poses of this axis when there are at
/// least 20 of them (a fine scan samples a fringe at many phases even without drift), nm;
/// infinite otherwise.
fn fine_pose_spacing_nm(d: &Data, ch: usize) -> f64 {
    let Some(cmd) = &d.channels[ch].cmd_um else {
        return f64::INFINITY;
    };
    let mut poses: Vec<i64> = cmd.iter().map(|c| (c * 1e3).round() as i64).collect();
    poses.sort_unstable();
    poses.dedup();
    if poses.len() < 20 {
        return f64::INFINITY;
    }
    let mut gaps: Vec<i64> = poses.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_unstable();
    gaps[gaps.len() / 2] as f64
}
