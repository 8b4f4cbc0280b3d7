//! `geometric_order`: the geometric error has terms of higher order in position than the
//! model's polynomial.

use serde::{Deserialize, Serialize};

use super::zeros;
use super::SimContext;
use crate::explain::contract::{self, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::Estimate;
use crate::explain::search::Search;

/// The effect's name.
pub const NAME: &str = "geometric_order";

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Coefficients (nm) of u⁴, u⁵, … of the scaled position.
    pub coeffs_nm: Vec<f64>,
}

impl Params {
    /// error = Σ c_j u^(4+j).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            let u = ctx.u[a][k];
            out[a][k] = self
                .coeffs_nm
                .iter()
                .enumerate()
                .map(|(j, c)| c * u.powi(4 + j as i32))
                .sum::<f64>()
                * 1e-3;
        }
        out
    }
}

/// The explain candidate: u⁴, u⁵ (and u⁶ with enough distinct poses).
pub struct Candidate;

fn distinct_poses(d: &Data, ch: usize) -> usize {
    let mut v: Vec<i64> = d.channels[ch].u.as_ref().map_or(Vec::new(), |u| {
        u.iter().map(|x| (x * 1e6).round() as i64).collect()
    });
    v.sort_unstable();
    v.dedup();
    v.len()
}

/// Share of the pose-dependent structure (a free offset per pose) the polynomial must carry.
const MIN_SHARE_OF_POSE_STRUCTURE: f64 = 0.5;
/// Most distinct poses for which the per-pose comparison is made.
const MAX_POSES_COMPARED: usize = 60;

/// One indicator column per distinct commanded pose of this axis but the first, when there
/// are few enough poses; on `rows` only (the search's rows: the comparison needs no more).
fn pose_indicators(d: &Data, ch: usize, rows: &[usize]) -> Option<Vec<Vec<f64>>> {
    let u = d.channels[ch].u.as_ref()?;
    let keys: Vec<i64> = u.iter().map(|x| (x * 1e6).round() as i64).collect();
    let mut poses = keys.clone();
    poses.sort_unstable();
    poses.dedup();
    if poses.len() > MAX_POSES_COMPARED {
        return None;
    }
    Some(
        poses[1..]
            .iter()
            .map(|p| {
                rows.iter()
                    .map(|&i| f64::from(u8::from(keys[i] == *p)))
                    .collect()
            })
            .collect(),
    )
}

/// The extension's regressor columns.
fn regressors(d: &Data, ch: usize) -> Vec<Vec<f64>> {
    let u = d.channels[ch].u.as_ref().unwrap();
    let top = if distinct_poses(d, ch) >= 9 { 6 } else { 5 };
    (4..=top)
        .map(|p| u.iter().map(|x| x.powi(p)).collect())
        .collect()
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the geometric error has more wiggles along the travel than the cubic polynomial can follow (higher-order terms in position)"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: position monomials of higher order (powers u⁴, u⁵, …, Factor::None)"
    }
    fn applies(&self, d: &Data, ch: usize) -> bool {
        d.channels[ch].u.is_some() && !d.against_simulation && distinct_poses(d, ch) >= 7
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let regs = regressors(s.d, s.ch);
        // a smooth higher-order shape must carry most of what depends on the pose at all: if a
        // free offset per pose explains far more, the structure sits at particular poses (a
        // defect, a scale error at one mark) and no polynomial is its name
        if let Some(poses) = pose_indicators(s.d, s.ch, &s.basis.rows) {
            let r0 = s.basis.rss();
            let refs: Vec<&[f64]> = regs.iter().map(|c| c.as_slice()).collect();
            let by_poly = r0 - s.basis.rss_with(&refs);
            let by_pose = r0 - s.basis.rss_with_gathered(poses);
            if by_poly < MIN_SHARE_OF_POSE_STRUCTURE * by_pose {
                return Ok(None);
            }
        }
        Ok(Some(Proposal::linear(regs)))
    }
    fn params(&self, _d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        f.coeffs
            .iter()
            .zip(f.se)
            .enumerate()
            .map(|(j, (c, s))| Estimate::new(&format!("u{}_nm", 4 + j), c * 1e3, s * 1e3))
            .collect()
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        _f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        Some(contract::BlobTerms {
            lags: Vec::new(),
            plays: Vec::new(),
            play: Vec::new(),
            terms: (4..=6)
                .map(|p| {
                    contract::term(
                        ctx.output,
                        contract::powers(ctx.output, p),
                        nanocal_model::Factor::None,
                        0,
                    )
                })
                .collect(),
        })
    }
}
