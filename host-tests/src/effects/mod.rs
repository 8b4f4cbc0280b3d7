#![allow(clippy::needless_range_loop)] // index loops over several parallel series read clearer here
//! The effect library: each physical effect defined once, in one file, with everything that
//! belongs to it — how the digital twin produces it, which regressors and nonlinear parameters
//! explain it, its plain-words name and description, and which shared-model terms carry it into
//! the blob where the firmware can run it. Adding an effect is adding one file and one entry in
//! [`EffectSpec`] and [`candidates`].

pub mod air_refraction;
pub mod axis_coupling;
pub mod creep;
pub mod geometric_order;
pub mod hysteresis;
pub mod periodic_nonlinearity;
pub mod thermal_lag;
pub mod thermal_position_interaction;
pub mod unexplained_drift;

use serde::{Deserialize, Serialize};

use crate::explain::data::Data;
use crate::explain::search::Search;
use crate::explain::ExplainError;
use crate::twin::SimContext;

/// The names of the nine effects, as reports and JSON spell them.
pub const NAMES: [&str; 9] = [
    thermal_lag::NAME,
    hysteresis::NAME,
    creep::NAME,
    thermal_position_interaction::NAME,
    air_refraction::NAME,
    geometric_order::NAME,
    axis_coupling::NAME,
    periodic_nonlinearity::NAME,
    unexplained_drift::NAME,
];

/// A switched-on effect with its physical parameters, as the twin produces it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(tag = "name", rename_all = "snake_case")]
pub enum EffectSpec {
    /// See [`thermal_lag`].
    ThermalLag(thermal_lag::Params),
    /// See [`hysteresis`].
    Hysteresis(hysteresis::Params),
    /// See [`creep`].
    Creep(creep::Params),
    /// See [`thermal_position_interaction`].
    ThermalPositionInteraction(thermal_position_interaction::Params),
    /// See [`air_refraction`].
    AirRefraction(air_refraction::Params),
    /// See [`geometric_order`].
    GeometricOrder(geometric_order::Params),
    /// See [`axis_coupling`].
    AxisCoupling(axis_coupling::Params),
    /// See [`periodic_nonlinearity`].
    PeriodicNonlinearity(periodic_nonlinearity::Params),
    /// See [`unexplained_drift`].
    UnexplainedDrift(unexplained_drift::Params),
}

impl EffectSpec {
    /// The effect's name (one of [`NAMES`]).
    pub fn name(&self) -> &'static str {
        match self {
            Self::ThermalLag(_) => thermal_lag::NAME,
            Self::Hysteresis(_) => hysteresis::NAME,
            Self::Creep(_) => creep::NAME,
            Self::ThermalPositionInteraction(_) => thermal_position_interaction::NAME,
            Self::AirRefraction(_) => air_refraction::NAME,
            Self::GeometricOrder(_) => geometric_order::NAME,
            Self::AxisCoupling(_) => axis_coupling::NAME,
            Self::PeriodicNonlinearity(_) => periodic_nonlinearity::NAME,
            Self::UnexplainedDrift(_) => unexplained_drift::NAME,
        }
    }

    /// True when the effect acts on the interferometer reading rather than on the stage.
    pub fn is_interferometer(&self) -> bool {
        matches!(self, Self::AirRefraction(_) | Self::PeriodicNonlinearity(_))
    }

    /// The twin's production: an additive error per axis and sample, µm.
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        match self {
            Self::ThermalLag(p) => p.produce(ctx),
            Self::Hysteresis(p) => p.produce(ctx),
            Self::Creep(p) => p.produce(ctx),
            Self::ThermalPositionInteraction(p) => p.produce(ctx),
            Self::AirRefraction(p) => p.produce(ctx),
            Self::GeometricOrder(p) => p.produce(ctx),
            Self::AxisCoupling(p) => p.produce(ctx),
            Self::PeriodicNonlinearity(p) => p.produce(ctx),
            Self::UnexplainedDrift(p) => p.produce(ctx),
        }
    }
}

/// First-order lag (time constant `tau_s`) of a sampled series, exact for a held input between
/// samples; starts at `y0` (or the first sample). The shared model's filter, which the
/// firmware runs too (its arithmetic, bit for bit: see [`Lag`]).
pub fn lag_series(t_s: &[f64], x: &[f64], tau_s: f64, y0: Option<f64>) -> Vec<f64> {
    let mut out = vec![0.0; x.len()];
    lag_run(t_s, x, tau_s, y0, |k, y| out[k] = y);
    out
}

/// [`lag_series`] at `rows` only (ascending): the filter still runs over every sample.
pub fn lag_series_at(
    t_s: &[f64],
    x: &[f64],
    tau_s: f64,
    y0: Option<f64>,
    rows: &[usize],
) -> Vec<f64> {
    let mut out = vec![0.0; rows.len()];
    let mut next = 0;
    lag_run(t_s, x, tau_s, y0, |k, y| {
        // rows ascending: every row is met once, in order
        while next < rows.len() && rows[next] == k {
            out[next] = y;
            next += 1;
        }
    });
    out
}

/// Runs the lag over the series, handing each sample's output to `emit(k, y)` in order.
fn lag_run(t_s: &[f64], x: &[f64], tau_s: f64, y0: Option<f64>, mut emit: impl FnMut(usize, f64)) {
    let mut filter = match y0 {
        Some(y0) if tau_s > 0.0 => Lag::starting_at(tau_s, y0),
        _ => Lag::new(tau_s),
    };
    for (k, &v) in x.iter().enumerate() {
        let y = match k {
            0 if y0.is_some() && tau_s > 0.0 => filter.state,
            0 => filter.update(v, f64::NAN),
            _ => filter.update(v, t_s[k] - t_s[k - 1]),
        };
        emit(k, y);
    }
}

/// The sample intervals of a time axis sorted into classes, found once for the many lag
/// filters `explain` runs over the same time stamps: a log's intervals take few distinct
/// values, so the filter's factor 1 − e^(−dt/τ) is worked out once per class and τ, and the
/// sample loop reads it by index — no interval to subtract, compare or look up per sample.
pub(crate) struct Intervals {
    /// Class of the interval ending at each sample (entry 0: the first sample, unused).
    class: Vec<u16>,
    /// The interval of each class, s (its bits are what [`Lag`] keys its factors by).
    dt_s: Vec<f64>,
}

/// Most classes [`Intervals`] keeps (a log with more distinct intervals runs [`Lag`] itself).
const MAX_INTERVAL_CLASSES: usize = 4096;

impl Intervals {
    /// The classes of `t_s`'s intervals, or None when it has more than
    /// [`MAX_INTERVAL_CLASSES`] distinct ones.
    pub(crate) fn of(t_s: &[f64]) -> Option<Self> {
        let mut class = vec![0u16; t_s.len()];
        let mut dt_s: Vec<f64> = Vec::new();
        let mut index: std::collections::HashMap<u64, u16> = Default::default();
        let (mut last_bits, mut last_class) = (None, 0u16);
        for k in 1..t_s.len() {
            let dt = t_s[k] - t_s[k - 1];
            let bits = dt.to_bits();
            if last_bits != Some(bits) {
                last_class = match index.get(&bits) {
                    Some(&c) => c,
                    None => {
                        if dt_s.len() >= MAX_INTERVAL_CLASSES {
                            return None;
                        }
                        let c = dt_s.len() as u16;
                        dt_s.push(dt);
                        index.insert(bits, c);
                        c
                    }
                };
                last_bits = Some(bits);
            }
            class[k] = last_class;
        }
        Some(Self { class, dt_s })
    }
}

/// [`lag_series_at`] on time stamps whose intervals are `iv` (from [`Intervals::of`] of the
/// same `t_s`): the same branches and arithmetic as [`Lag`], bit for bit.
pub(crate) fn lag_series_at_classes(
    iv: &Intervals,
    x: &[f64],
    tau_s: f64,
    y0: Option<f64>,
    rows: &[usize],
) -> Vec<f64> {
    let mut out = vec![0.0; rows.len()];
    let mut next = 0;
    lag_run_classes(iv, x, tau_s, y0, |k, y| {
        while next < rows.len() && rows[next] == k {
            out[next] = y;
            next += 1;
        }
    });
    out
}

/// [`lag_series`] on time stamps whose intervals are `iv` (see [`lag_series_at_classes`]).
pub(crate) fn lag_series_classes(
    iv: &Intervals,
    x: &[f64],
    tau_s: f64,
    y0: Option<f64>,
) -> Vec<f64> {
    let mut out = vec![0.0; x.len()];
    lag_run_classes(iv, x, tau_s, y0, |k, y| out[k] = y);
    out
}

/// [`lag_run`] with the intervals' classes: what [`Lag::update`] does for each kind of
/// interval — a non-finite one restarts at the reading, one ≤ 0 holds, a positive one
/// smooths with its class's factor (computed as [`Lag`] computes it).
fn lag_run_classes(
    iv: &Intervals,
    x: &[f64],
    tau_s: f64,
    y0: Option<f64>,
    mut emit: impl FnMut(usize, f64),
) {
    if x.is_empty() {
        return;
    }
    debug_assert_eq!(iv.class.len(), x.len());
    // the factor per class; NaN marks a restart (non-finite interval), 0 with `hold` a hold
    const RESTART: u8 = 1;
    const HOLD: u8 = 2;
    let kind: Vec<u8> = iv
        .dt_s
        .iter()
        .map(|&dt| {
            if tau_s <= 0.0 || !dt.is_finite() {
                RESTART
            } else if dt > 0.0 {
                0
            } else {
                HOLD
            }
        })
        .collect();
    let alpha: Vec<f64> = iv
        .dt_s
        .iter()
        .zip(&kind)
        .map(|(&dt, &k)| {
            if k == 0 {
                1.0 - libm::exp(-dt / tau_s)
            } else {
                0.0
            }
        })
        .collect();
    // the first sample as [`lag_run`] takes it
    let mut state = match y0 {
        Some(y0) if tau_s > 0.0 => y0,
        _ => x[0],
    };
    emit(0, state);
    for k in 1..x.len() {
        let c = iv.class[k] as usize;
        match kind[c] {
            0 => state += alpha[c] * (x[k] - state),
            RESTART => state = x[k],
            _ => {}
        }
        emit(k, state);
    }
}

/// Entries of [`Lag`]'s table of smoothing factors (64: the slot is a hash's top 6 bits).
const LAG_ALPHAS: usize = 64;

/// The shared model's [`nanocal_model::LagFilter`] (the same states, branches and arithmetic)
/// with its smoothing factor 1 − e^(−dt/τ) kept per sample interval. The model's filter keeps
/// only the last interval's; a log's intervals take a few values (the differences of a 1 kHz
/// clock differ in their last bits), and the factor is a function of the interval alone, so
/// keeping each computes the same numbers with far fewer exponentials. `explain` runs lag
/// filters over every sample of a million-row log hundreds of times.
struct Lag {
    tau_s: f64,
    state: f64,
    primed: bool,
    last_dt_s: f64,
    alpha: f64,
    /// (bits of dt, factor), direct-mapped; u64::MAX (a NaN, never an interval): empty.
    alphas: [(u64, f64); LAG_ALPHAS],
}

impl Lag {
    fn new(tau_s: f64) -> Self {
        Lag {
            tau_s,
            state: 0.0,
            primed: false,
            last_dt_s: f64::NAN,
            alpha: 1.0,
            alphas: [(u64::MAX, 0.0); LAG_ALPHAS],
        }
    }

    fn starting_at(tau_s: f64, y0: f64) -> Self {
        Lag {
            state: y0,
            primed: true,
            ..Lag::new(tau_s)
        }
    }

    #[inline]
    fn update(&mut self, x: f64, dt_s: f64) -> f64 {
        if !self.primed || self.tau_s <= 0.0 || !dt_s.is_finite() {
            self.state = x;
            self.primed = true;
        } else if dt_s > 0.0 {
            if dt_s != self.last_dt_s {
                let bits = dt_s.to_bits();
                // Fibonacci hashing: intervals differ in middle bits of the mantissa (the
                // low ones are zero for differences of large time stamps)
                let slot = (bits.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize;
                self.alpha = if self.alphas[slot].0 == bits {
                    self.alphas[slot].1
                } else {
                    let a = 1.0 - libm::exp(-dt_s / self.tau_s);
                    self.alphas[slot] = (bits, a);
                    a
                };
                self.last_dt_s = dt_s;
            }
            self.state += self.alpha * (x - self.state);
        }
        self.state
    }
}

pub(crate) fn zeros(ctx: &SimContext) -> Vec<Vec<f64>> {
    vec![vec![0.0; ctx.t_s.len()]; ctx.cfg.axes]
}

/// A parameter estimate with its 1σ uncertainty (NaN when not known).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Estimate {
    /// Name with unit suffix (`tau_s`, `half_width_nm`, …).
    pub name: String,
    /// Value.
    pub value: f64,
    /// 1σ uncertainty.
    pub sigma: f64,
}

impl Estimate {
    /// A named estimate.
    pub fn new(name: &str, value: f64, sigma: f64) -> Self {
        Self {
            name: name.into(),
            value,
            sigma,
        }
    }
}

/// A nonlinear parameter a candidate searched (τ, t0, a time scale), with its 1σ from the
/// profile of the residual sum of squares and the range it was searched in.
#[derive(Clone, Debug, PartialEq)]
pub struct Theta {
    /// Name with unit suffix (`tau_s`, `t0_s`, …).
    pub name: String,
    /// Best value.
    pub value: f64,
    /// 1σ (infinite when the profile is flat, NaN when not known).
    pub sigma: f64,
    /// Bottom of the searched range.
    pub lo: f64,
    /// Top of the searched range.
    pub hi: f64,
}

impl Theta {
    /// A sentence when the value sits on a bound of its searched range (within 3 %): then it
    /// is a bound, not an estimate.
    pub fn bound_note(&self) -> Option<String> {
        if self.value >= self.hi * 0.97 {
            Some(format!(
                "{} at the top of the searched range ({}): a lower bound",
                self.name,
                crate::explain::units::sig3(self.hi)
            ))
        } else if self.value <= self.lo * 1.03 {
            Some(format!(
                "{} at the bottom of the searched range ({}): an upper bound",
                self.name,
                crate::explain::units::sig3(self.lo)
            ))
        } else {
            None
        }
    }

    /// As an estimate (value ± σ); on a bound of the searched range it is a bound, not a
    /// value ± σ: its σ is then NaN (not known), and [`Theta::bound_note`] says which bound.
    pub fn estimate(&self) -> Estimate {
        Estimate::new(&self.name, self.value, self.sigma_unless_bound())
    }

    /// σ, or NaN when the value sits on a bound of its searched range.
    pub fn sigma_unless_bound(&self) -> f64 {
        if self.bound_note().is_some() {
            f64::NAN
        } else {
            self.sigma
        }
    }
}

/// A lag term of [`thermal_lag`]: a temperature through a first-order lag.
#[derive(Clone, Debug, PartialEq)]
pub struct LagTerm {
    /// Index of the temperature (order of the `temp_` columns).
    pub sensor: usize,
    /// Time constant, with its search range.
    pub tau: Theta,
}

/// A bank of play operators of [`hysteresis`] on one axis.
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
    /// Half of the drive's stroke (robust: 0.5th to 99.5th percentile), in the drive's unit (a
    /// full-stroke loop's amplitude).
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
}

/// What a candidate proposes to add to the current model.
#[derive(Clone, Debug)]
pub struct Proposal {
    /// The extension's regressor columns (free coefficients).
    pub regs: Vec<Vec<f64>>,
    /// The nonlinear parameters searched to build them (each counts as a parameter in the BIC).
    pub thetas: Vec<Theta>,
    /// What the columns mean.
    pub detail: Detail,
    /// A held-out design of the candidate's own (a time-only explanation is judged on gaps
    /// longer than its time scale); None: the standard design.
    pub design: Option<crate::explain::fit::Design>,
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
            regs,
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
    /// One of [`NAMES`].
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
    /// The extension of the current model (see [`crate::explain::search::Search`]): its
    /// nonlinear parameters searched, its columns built; None when there is nothing to add.
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError>;
    /// The physical parameters from the fitted coefficients.
    fn params(&self, d: &Data, ch: usize, f: &Fitted) -> Vec<Estimate>;
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

/// The library of candidates explain tests, in a fixed order.
pub fn candidates() -> Vec<&'static dyn Candidate> {
    vec![
        &thermal_lag::Candidate,
        &hysteresis::Candidate,
        &creep::Candidate,
        &thermal_position_interaction::Candidate,
        &air_refraction::Candidate,
        &geometric_order::Candidate,
        &axis_coupling::Candidate,
        &periodic_nonlinearity::Candidate,
        &unexplained_drift::Candidate,
    ]
}

/// Log-spaced grid of `k` values from `lo` to `hi`.
pub fn log_grid(lo: f64, hi: f64, k: usize) -> Vec<f64> {
    if !(hi > lo && lo > 0.0) || k < 2 {
        return vec![lo.max(hi)];
    }
    (0..k)
        .map(|i| lo * (hi / lo).powf(i as f64 / (k - 1) as f64))
        .collect()
}

/// A candidate with one nonlinear parameter θ searched on a log scale over [lo, hi]: the
/// columns `make(θ)` that fit best, with θ's 1σ and range.
pub fn one_theta(
    s: &Search,
    name: &str,
    lo: f64,
    hi: f64,
    points: usize,
    make: impl Fn(f64) -> Vec<Vec<f64>>,
) -> Proposal {
    let (theta, _) = s.minimise(name, (lo, hi), points, true, |th| {
        let regs = make(th);
        let refs: Vec<&[f64]> = regs.iter().map(|c| c.as_slice()).collect();
        s.basis.rss_with(&refs)
    });
    Proposal {
        regs: make(theta.value),
        thetas: vec![theta],
        detail: Detail::None,
        design: None,
        evidence_units: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The series as the shared model's filter gives it, step by step.
    fn with_model_filter(t_s: &[f64], x: &[f64], tau_s: f64, y0: Option<f64>) -> Vec<f64> {
        let mut filter = match y0 {
            Some(y0) if tau_s > 0.0 => nanocal_model::LagFilter::starting_at(tau_s, y0),
            _ => nanocal_model::LagFilter::new(tau_s),
        };
        x.iter()
            .enumerate()
            .map(|(k, &v)| match k {
                0 if y0.is_some() && tau_s > 0.0 => filter.value(),
                0 => filter.update(v, f64::NAN),
                _ => filter.update(v, t_s[k] - t_s[k - 1]),
            })
            .collect()
    }

    #[test]
    fn lag_series_is_the_model_filter_bit_for_bit() {
        // a 1 kHz clock far from zero (intervals differing in their last bits, more distinct
        // intervals than the table holds), irregular gaps, a repeated and a backward time
        // stamp, a missing one, and a missing reading
        let mut t: Vec<f64> = (0..20_000)
            .map(|k| 1000.0 + k as f64 * 1e-3 + ((k * k) % 1009) as f64 * 1e-9)
            .collect();
        for k in (0..t.len()).step_by(97) {
            t[k] += ((k * 7919) % 13) as f64 * 1.3e-4;
        }
        t[500] = t[499];
        t[900] = t[899] - 0.01;
        t[1200] = f64::NAN;
        let mut x: Vec<f64> = (0..t.len())
            .map(|k| 21.0 + (k as f64 * 1e-3).sin() + ((k * 31) % 7) as f64 * 1e-3)
            .collect();
        x[19_990] = f64::NAN;
        let distinct: std::collections::HashSet<u64> =
            t.windows(2).map(|w| (w[1] - w[0]).to_bits()).collect();
        assert!(
            distinct.len() > 2 * LAG_ALPHAS,
            "{} intervals",
            distinct.len()
        );
        for tau in [0.0, -1.0, 2e-3, 0.7, 120.0, 1e6] {
            for y0 in [None, Some(20.5)] {
                let ours = lag_series(&t, &x, tau, y0);
                let model = with_model_filter(&t, &x, tau, y0);
                for (k, (a, b)) in ours.iter().zip(&model).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "τ {tau}, y0 {y0:?}, sample {k}");
                }
                let rows: Vec<usize> = (0..t.len()).step_by(7).collect();
                let at = lag_series_at(&t, &x, tau, y0, &rows);
                for (r, a) in rows.iter().zip(&at) {
                    assert_eq!(a.to_bits(), model[*r].to_bits(), "τ {tau}, row {r}");
                }
                let iv = Intervals::of(&t).expect("fewer intervals than the classes hold");
                let classed = lag_series_classes(&iv, &x, tau, y0);
                for (k, (a, b)) in classed.iter().zip(&model).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "classes: τ {tau}, y0 {y0:?}, {k}");
                }
                let at = lag_series_at_classes(&iv, &x, tau, y0, &rows);
                for (r, a) in rows.iter().zip(&at) {
                    assert_eq!(
                        a.to_bits(),
                        model[*r].to_bits(),
                        "classes: τ {tau}, row {r}"
                    );
                }
            }
        }
    }
}
