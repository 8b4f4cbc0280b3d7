//! The candidate contract: what an effect hands explain (a [`Proposal`] of columns with its
//! searched [`Theta`]s, its physical [`Estimate`]s, its [`BlobTerms`]) and the [`Candidate`]
//! trait each effect implements. Explain owns it so that the arrows run
//! one way: the effects import explain's tools and this contract; this file imports no effect.

use serde::Serialize;

use super::data::Data;
use super::error::ExplainError;
use super::estimate::{Estimate, Theta};
use super::search::Search;

/// A lag term of the thermal lag effect: a temperature through a first-order lag.
#[derive(Clone, Debug, PartialEq)]
pub struct LagTerm {
    /// Index of the temperature (order of the `temp_` columns).
    pub sensor: usize,
    /// Time constant, with its search range.
    pub tau: Theta,
}

/// A bank of play operators of the hysteresis effect on one axis.
#[derive(Clone, Debug, PartialEq)]
pub struct PlayBank {
    /// The axis whose commanded position feeds the operators.
    pub axis: usize,
    /// The column that feeds the operators when it is not the axis' command (an auxiliary
    /// channel that carries the drive, e.g. the actuator voltage); None: the command.
    pub drive: Option<String>,
    /// Leading columns of the proposal that are a polynomial in that auxiliary drive (its
    /// static response), before the operators' columns.
    pub leading_poly: usize,
    /// Thresholds r_i of the operators kept (non-zero weight), in the drive's unit (µm for the
    /// command), ascending, ≥ 0.
    pub thresholds_um: Vec<f64>,
    /// +1: weights ≥ 0 (counter-clockwise loop: the response lags the command); −1: ≤ 0.
    pub sense: f64,
    /// Half of the drive's stroke (its minimum to its maximum over the rows the search sees),
    /// in the drive's unit (a full-stroke loop's amplitude).
    pub amplitude_um: f64,
    /// Standard deviation of the full-loop half-width per unit noise standard deviation
    /// (√(cᵀ(X⊥ᵀX⊥)⁻¹c) with X⊥ the operator columns beyond the rest of the model): the
    /// weights of neighbouring operators are strongly anti-correlated, so the half-width is
    /// known far better than each weight.
    pub half_width_per_noise: f64,
    /// RMS change of the half-width over other threshold grids, in µm of response: the part of
    /// its uncertainty the choice of grid brings.
    pub grid_spread_um: f64,
}

/// Candidate-specific structure of a proposal (what its columns mean).
#[derive(Clone, Debug, PartialEq)]
pub enum Detail {
    /// Plain columns.
    None,
    /// One column per lag term.
    Lags(Vec<LagTerm>),
    /// One column per play operator: F_r[x] − x.
    Play(PlayBank),
    /// One column whose coefficient moves with the first θ along its profile: the
    /// coefficient's change per unit of ln θ (the coefficient refitted at θ·e^±h). The
    /// coefficient's own standard error holds θ at its best value; with θ uncertain the
    /// coefficient's 1σ is √(se² + (dc/d ln θ · σ_θ/θ)²) — creep's γ against its t0.
    Coupled {
        /// d(coefficient)/d ln θ.
        dcoeff_dln_theta: f64,
    },
}

/// What a candidate proposes to add to the current model.
#[derive(Clone, Debug)]
pub struct Proposal {
    /// The extension's regressor columns (free coefficients). Shared, not copied: a column
    /// that already exists elsewhere (`unexplained_drift`'s cosines, kept with the data) joins
    /// a proposal without a copy of its million rows.
    pub regs: Vec<std::sync::Arc<Vec<f64>>>,
    /// The nonlinear parameters searched to build them (each counts as a parameter in the BIC).
    pub thetas: Vec<Theta>,
    /// What the columns mean.
    pub detail: Detail,
    /// A held-out design of the candidate's own (a time-only explanation is judged on gaps
    /// longer than its time scale); None: the standard design.
    pub design: Option<super::fit::Design>,
    /// Independent events behind the candidate's signature, when they are fewer to count from
    /// the residual than they are (each reversal of a drive measures a loop afresh, however
    /// slow the residual around it): the evidence counts at least these (never more than the
    /// round's independent rows).
    pub evidence_units: Option<f64>,
}

impl Proposal {
    /// Columns with no nonlinear parameter.
    pub fn linear(regs: Vec<Vec<f64>>) -> Self {
        Self {
            regs: regs.into_iter().map(std::sync::Arc::new).collect(),
            thetas: Vec::new(),
            detail: Detail::None,
            design: None,
            evidence_units: None,
        }
    }

    /// The first nonlinear parameter's value, if any.
    pub fn theta(&self) -> Option<f64> {
        self.thetas.first().map(|t| t.value)
    }

    /// Widen every nonlinear parameter's 1σ by `factor` (fewer independent rows than the
    /// search assumed).
    pub fn widen_sigmas(&mut self, factor: f64) {
        for t in self.thetas.iter_mut() {
            t.sigma *= factor;
        }
        if let Detail::Lags(terms) = &mut self.detail {
            for t in terms.iter_mut() {
                t.tau.sigma *= factor;
            }
        }
    }
}

/// What a candidate's parameter report can look at after its extension was fitted.
#[derive(Clone, Debug)]
pub struct Fitted<'a> {
    /// The accepted proposal.
    pub proposal: &'a Proposal,
    /// Coefficients of the proposal's regressors, µm per unit of the regressor.
    pub coeffs: &'a [f64],
    /// Their standard errors (inflated for autocorrelated residuals).
    pub se: &'a [f64],
    /// The residual's standard deviation with the same inflation, µm (σ of a linear
    /// combination of coefficients = this × its sensitivity).
    pub noise_sigma_um: f64,
}

/// Where a channel sits in the shared model, for [`Candidate::blob_terms`].
#[derive(Clone, Debug, PartialEq)]
pub struct BlobContext {
    /// Output axis (model index) of the channel.
    pub output: u8,
    /// Axes of the model.
    pub axes: u8,
    /// Temperature inputs of the model (model Temp index = order in the recording).
    pub temps: u8,
    /// Aux index of the barometric pressure, if the model has it.
    pub pressure_aux: Option<u8>,
}

/// One play operator as explain identified it: the positioning error it carries is
/// `weight × (F_r[x] − x)` with x the axis' commanded position in µm and F_r the play operator
/// of threshold r ([`nanocal_model::play::play`]) started at the first command. The blob
/// declares the same thresholds ([`BlobTerms::plays`]); the correction's weights are the
/// fit's to set (to first order, −weight on `F_r` plus a linear term).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PlayOperator {
    /// Axis whose commanded position feeds the operator.
    pub axis: u8,
    /// Threshold r, µm (≥ 0).
    pub threshold_um: f64,
    /// Weight (dimensionless, µm of error per µm of F_r[x] − x); all weights of an axis share
    /// one sign.
    pub weight: f64,
}

/// The shared-model terms that carry an effect into the blob: shapes with coefficient 0 (the
/// host's fit sets them in the model's scaling) and the lag filters they need.
#[derive(Clone, Debug, PartialEq)]
pub struct BlobTerms {
    /// Lag filters to declare first, (sensor, τ in s); `Factor::Lagged(k)` in `terms` counts
    /// from the first of these (add the model's existing lag count).
    pub lags: Vec<(u8, f64)>,
    /// Term shapes.
    pub terms: Vec<nanocal_model::Term>,
    /// Play operators to declare first, (axis, threshold in µm), grouped by axis, thresholds
    /// ascending (`ModelBuilder::play`); `Factor::Play(k)` in `terms` counts from the first of
    /// these (add the model's existing operator count).
    pub plays: Vec<(u8, f64)>,
    /// The identified operators with their fitted (error) weights, for a person and the fit.
    pub play: Vec<PlayOperator>,
}

/// A term shape with coefficient 0.
pub fn term(
    output: u8,
    powers: [u8; 3],
    factor: nanocal_model::Factor,
    direction: u8,
) -> nanocal_model::Term {
    nanocal_model::Term {
        output,
        powers,
        factor,
        direction,
        coeff: 0.0,
    }
}

/// `[0, 0, 0]` with `p` on `axis`.
pub fn powers(axis: u8, p: u8) -> [u8; 3] {
    let mut out = [0; 3];
    out[axis as usize] = p;
    out
}

/// An effect as explain tests it: a model extension with physical parameters.
pub trait Candidate: Sync {
    /// One of the effects' `NAMES`.
    fn name(&self) -> &'static str;
    /// What the effect is, in plain words, for a person.
    fn description(&self) -> &'static str;
    /// Where the compensator can run it: which shared-model terms carry it into the blob, or why not.
    fn deploy(&self) -> &'static str;
    /// Whether the recording can show this effect on channel `ch`.
    fn applies(&self, d: &Data, ch: usize) -> bool;
    /// True for an explanation through time alone (no recorded channel): tried only when no
    /// candidate that explains through recorded channels passes.
    fn time_only(&self) -> bool {
        false
    }
    /// The extension of the current model (see [`Search`]): its
    /// nonlinear parameters searched, its columns built; None when there is nothing to add.
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError>;
    /// The physical parameters from the fitted coefficients.
    fn params(&self, d: &Data, ch: usize, f: &Fitted) -> Vec<Estimate>;
    /// The parameters of a refit on part of the rows (a jackknife replicate, `rep`) under the
    /// names the fit on all rows (`full`) gave them, so that each is compared with its own
    /// kind: by default [`Candidate::params`] of the replicate (its names do not depend on
    /// what the search found).
    fn replicate_params(&self, d: &Data, ch: usize, _full: &Fitted, rep: &Fitted) -> Vec<Estimate> {
        self.params(d, ch, rep)
    }
    /// A sentence on the fitted effect for a person (the sense of a loop, which sensor lags
    /// how), or empty.
    fn summary(&self, _d: &Data, _ch: usize, _f: &Fitted) -> String {
        String::new()
    }
    /// The shared-model terms that let the firmware run the fitted effect, or `None` when the
    /// compensator cannot (see [`Candidate::deploy`]).
    fn blob_terms(&self, _ctx: &BlobContext, _f: &Fitted) -> Option<BlobTerms> {
        None
    }
}

/// A candidate with one nonlinear parameter θ searched on a log scale over [lo, hi]: the
/// columns `make(θ)` that fit best, with θ's 1σ and range.
pub fn one_theta(
    s: &Search,
    name: &str,
    lo: f64,
    hi: f64,
    points: usize,
    make: impl Fn(f64) -> Vec<Vec<f64>> + Sync,
) -> Proposal {
    let (theta, _) = s.minimise(name, (lo, hi), points, true, |th| {
        let regs = make(th);
        let refs: Vec<&[f64]> = regs.iter().map(|c| c.as_slice()).collect();
        s.basis.rss_with(&refs)
    });
    Proposal {
        regs: make(theta.value)
            .into_iter()
            .map(std::sync::Arc::new)
            .collect(),
        thetas: vec![theta],
        detail: Detail::None,
        design: None,
        evidence_units: None,
    }
}
