//! `thermal_lag`: the structure follows first-order lags of the sensed temperatures instead of
//! the readings themselves — each sensor with its own time constant, and a second (possibly
//! opposite-signed) time constant where the data support it (a compensated probe's internal
//! compensation answering later than the expansion it fights).

use serde::{Deserialize, Serialize};

use super::SimContext;
use super::{
    lag_many_at_classes, lag_series, lag_series_at, lag_series_at_classes, lag_series_classes,
    zeros, Intervals,
};
use crate::explain::contract::{self, Detail, LagTerm, Proposal};
use crate::explain::data::Data;
use crate::explain::error::ExplainError;
use crate::explain::estimate::{Estimate, Theta};
use crate::explain::fit::{bartlett_n_eff, cross_validate_score, gather};
use crate::explain::parallel::in_parallel;
use crate::explain::search::{dot, log_grid, Basis, Search};
use crate::explain::units::{duration, sig3};

/// The effect's name.
pub const NAME: &str = "thermal_lag";

/// Twin parameters.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Time constant of the structure behind the sensed spots, s.
    pub tau_s: f64,
    /// Time constants per sensor, s (empty: `tau_s` for every sensor).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sensor_tau_s: Vec<f64>,
    /// A second, slower response, s: the structure's displacement per sensor becomes
    /// k·[(1 + g)·lag_τ₁(T) − g·lag_τ₂(T)] — it overshoots and rebounds for g > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_tau_s: Option<f64>,
    /// g of the second response (see `second_tau_s`).
    #[serde(default)]
    pub second_gain: f64,
}

impl Params {
    /// One time constant for every sensor.
    pub fn common(tau_s: f64) -> Self {
        Self {
            tau_s,
            ..Self::default()
        }
    }

    /// Replaces the drift Σ kᵢ·Tᵢ with Σ kᵢ·lag_τᵢ(Tᵢ) (plus the second response) on every axis.
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        for (i, spot) in ctx.spot_c.iter().enumerate() {
            let tau = self.sensor_tau_s.get(i).copied().unwrap_or(self.tau_s);
            let first = lag_series(&ctx.t_s, spot, tau, None);
            let response: Vec<f64> = match self.second_tau_s {
                Some(t2) => {
                    let g = self.second_gain;
                    let second = lag_series(&ctx.t_s, spot, t2, None);
                    first
                        .iter()
                        .zip(&second)
                        .map(|(a, b)| (1.0 + g) * a - g * b)
                        .collect()
                }
                None => first,
            };
            for (a, o) in out.iter_mut().enumerate() {
                let k = ctx.thermal_um_per_c[a][i];
                for (j, v) in o.iter_mut().enumerate() {
                    *v += k * (response[j] - spot[j]);
                }
            }
        }
        out
    }
}

/// The explain candidate: lag terms lag_τ(Tᵢ) added one at a time (forward selection), each
/// with its own τ searched between the shortest lag the record resolves for that sensor (two
/// samples, no less than its report interval) and half the record; a sensor may take a second
/// term with a τ at least 3× apart. A term joins only if it lowers the BIC by
/// [`MIN_TERM_BIC`] (counting the rows that are independent for it and the noise left after
/// it), fits better than a zero-phase smoothing of the same sensor (its delay, not its
/// denoising, must explain), and improves held-out prediction; then every τ is refined with
/// the others fixed.
pub struct Candidate;

/// BIC drop a further lag term must bring (two parameters: its gain and its τ).
pub const MIN_TERM_BIC: f64 = 10.0;
/// Most lag terms (the shared model's lag filters).
pub const MAX_TERMS: usize = nanocal_model::MAX_LAGS;
/// BIC advantage a lag must have over its zero-phase twin (2: positive evidence).
const TWIN_BIC: f64 = 2.0;
/// Two time constants of one sensor must differ by at least this factor.
const DISTINCT: f64 = 3.0;

/// Grid points per sensor in the screening of each forward step.
const SCREEN_POINTS: usize = 12;
/// Sensors whose best grid point is refined between grid points in each forward step.
const REFINE_SENSORS: usize = 3;
/// Most rounds of refining every τ with the others fixed and pruning again.
const REFINE_SWEEPS: usize = 4;
/// Relative drop of held-out RMS a further lag term must bring.
const MIN_TERM_CV_GAIN: f64 = 0.005;

/// A lag column on the screening grid, orthogonal to the current model.
struct Screened {
    sensor: usize,
    tau: f64,
    perp: Vec<f64>,
    norm0: f64,
}

impl Screened {
    /// Drop of the residual sum of squares if this column joined the model.
    fn gain(&self, r: &[f64]) -> f64 {
        let nn = dot(&self.perp, &self.perp);
        if nn <= (1e-9 * self.norm0).powi(2) {
            return 0.0;
        }
        let c = dot(&self.perp, r);
        c * c / nn
    }
}

/// Whether τ keeps clear of the time constants `taken` by the same sensor.
fn clear(taken: &[f64], tau: f64) -> bool {
    taken
        .iter()
        .all(|&t| tau > t * DISTINCT || tau < t / DISTINCT)
}

/// One sweep of coordinate descent: each term's τ searched over its whole range with the other
/// terms fixed (with its 1σ when `sigma`).
fn refine(s: &Search, cache: &LagCache, terms: &mut [LagTerm], cols: &mut [Vec<f64>], sigma: bool) {
    for j in 0..terms.len() {
        let mut b = s.basis.clone();
        for (k, c) in cols.iter().enumerate() {
            if k != j {
                b.add_column(c);
            }
        }
        let taken: Vec<f64> = terms
            .iter()
            .enumerate()
            .filter(|(k, t)| *k != j && t.sensor == terms[j].sensor)
            .map(|(_, t)| t.tau.value)
            .collect();
        if let Some((tau, _)) = best_tau(s, cache, &b, terms[j].sensor, &taken, sigma, None) {
            cols[j] = lag_column(s.d, terms[j].sensor, tau.value);
            terms[j].tau = tau;
        }
    }
}

/// Evidence for a set of lag columns on top of the model: the BIC change (two parameters per
/// term) counting the rows that are independent for what the set adds and the noise it leaves
/// ([`bartlett_n_eff`]) — smooth terms explaining a smooth leftover count for little.
fn set_evidence(s: &Search, cols: &[&Vec<f64>]) -> f64 {
    let mut b = s.basis.clone();
    for c in cols {
        b.add_column(c);
    }
    let added: Vec<f64> = s
        .basis
        .residual()
        .iter()
        .zip(b.residual())
        .map(|(a, r)| a - r)
        .collect();
    let n_eff = bartlett_n_eff(&added, b.residual()).min(s.n_eff);
    n_eff * (b.rss() / s.basis.rss()).max(1e-300).ln() + 2.0 * cols.len() as f64 * n_eff.ln()
}

/// Backward elimination on the finished set by its evidence ([`set_evidence`]): drop the term
/// whose removal improves the set's evidence most, while one does. Forward selection judged
/// each term with the round's effective sample size; terms that only make sense together (a
/// response and its opposite-signed rebound) are judged together here.
fn prune(s: &Search, terms: &mut Vec<LagTerm>, cols: &mut Vec<Vec<f64>>) {
    let mut current = set_evidence(s, &cols.iter().collect::<Vec<_>>());
    while terms.len() > 1 {
        let best = (0..terms.len())
            .map(|j| {
                let rest: Vec<&Vec<f64>> = cols
                    .iter()
                    .enumerate()
                    .filter(|(k, _)| *k != j)
                    .map(|(_, c)| c)
                    .collect();
                (j, set_evidence(s, &rest))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((j, e)) if e < current => {
                terms.remove(j);
                cols.remove(j);
                current = e;
            }
            _ => break,
        }
    }
}

/// A sentence when term `j`'s τ sits on the [`DISTINCT`] separation from another τ of the
/// same sensor (within 3 %): the pair is held apart by the search, the data would put them
/// closer, so neither value is an estimate of its own.
fn held_apart_note(terms: &[LagTerm], j: usize) -> Option<String> {
    let t = terms[j].tau.value;
    let other = terms
        .iter()
        .enumerate()
        .find(|(k, o)| {
            let r = if o.tau.value > t {
                o.tau.value / t
            } else {
                t / o.tau.value
            };
            *k != j && o.sensor == terms[j].sensor && r < DISTINCT * 1.03
        })?
        .1;
    Some(format!(
        "held {DISTINCT}× apart from this sensor's other τ ({}): the data would put them closer, so neither is an estimate of its own",
        duration(other.tau.value)
    ))
}

/// A lag term moves the prediction by at most this many times the thermal displacement the
/// temperatures explain statically (see [`drop_implausible`]).
const MAX_TERM_OF_STATIC: f64 = 5.0;

fn std_dev(v: &[f64]) -> f64 {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt()
}

/// Physical plausibility: a delay redistributes the thermal response in time; it does not
/// create displacement far beyond what the same temperatures explain statically. A term whose
/// contribution (|gain| × spread of its lagged temperature) exceeds [`MAX_TERM_OF_STATIC`] ×
/// the spread of the static thermal fit (the response on the temperatures alone) is cancelling
/// against other terms — a numerical fit of something else, not a lag: the worst such term is
/// dropped and the rest refitted, until none is left.
fn drop_implausible(
    s: &Search,
    terms: &mut Vec<LagTerm>,
    cols: &mut Vec<Vec<f64>>,
) -> Result<(), ExplainError> {
    let rows = &s.basis.rows;
    let temps: Vec<Vec<f64>> = s.d.temps.iter().map(|(_, t)| gather(t, rows)).collect();
    let trefs: Vec<&[f64]> = temps.iter().map(|c| c.as_slice()).collect();
    let y = gather(s.y, rows);
    let stat = crate::numerics::linalg::lstsq(&trefs, &y, true)?;
    let fitted: Vec<f64> = y.iter().zip(&stat.residuals).map(|(a, r)| a - r).collect();
    let scale = std_dev(&fitted);
    while !terms.is_empty() {
        let g: Vec<Vec<f64>> = s
            .model
            .iter()
            .map(|c| gather(c, rows))
            .chain(cols.iter().map(|c| gather(c, rows)))
            .collect();
        let refs: Vec<&[f64]> = g.iter().map(|c| c.as_slice()).collect();
        let ls = crate::numerics::linalg::lstsq(&refs, &y, true)?;
        let m = s.model.len();
        let worst = (0..terms.len())
            .map(|j| {
                let c = ls.coeffs[m + j].abs() * std_dev(&g[m + j]);
                (j, c)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((j, c)) if c > MAX_TERM_OF_STATIC * scale => {
                terms.remove(j);
                cols.remove(j);
            }
            _ => break,
        }
    }
    Ok(())
}

/// The same sensor smoothed like a lag of τ but without its delay: the lag run forwards and
/// then backwards in time with τ/√2 (a two-sided exponential kernel with the lag's standard
/// deviation τ and the lag's shape, centred on the sample). Diagnostic only (it uses later
/// readings): it tells a delay from mere denoising.
///
/// Taken at `rows` (ascending) only; `rev_t` is the time reversed and negated.
fn zero_phase_twin(cache: &LagCache, sensor: usize, tau_s: f64, rows: &[usize]) -> Vec<f64> {
    let d = cache.d;
    let t = tau_s / 2f64.sqrt();
    let mut rev_x = match &cache.fwd {
        Some(iv) => lag_series_classes(iv, &d.temps[sensor].1, t, None),
        None => lag_series(&d.t_s, &d.temps[sensor].1, t, None),
    };
    rev_x.reverse();
    // the backward pass at the reversed rows (ascending in reversed time), then back in order
    let n = d.rows();
    let rev_rows: Vec<usize> = rows.iter().rev().map(|&r| n - 1 - r).collect();
    let mut back = match &cache.rev {
        Some(iv) => lag_series_at_classes(iv, &rev_x, t, None, &rev_rows),
        None => lag_series_at(&cache.rev_t, &rev_x, t, None, &rev_rows),
    };
    back.reverse();
    back
}

/// The lag of temperature `sensor`: the shared model's causal filter on the readings, as the
/// compensator runs it.
fn lag_column(d: &Data, sensor: usize, tau_s: f64) -> Vec<f64> {
    lag_series(&d.t_s, &d.temps[sensor].1, tau_s, None)
}

/// Most lag columns a [`LagCache`] keeps (each is one value per fitted row: ≤ 100,000).
const CACHED_COLUMNS: usize = 160;

/// Lag columns on the fitted rows, each (sensor, τ) filtered once per proposal: the searches
/// come back to the same τ (the screening grid is the whole-range refinement's grid; sweeps
/// that have settled repeat their golden-section points), and every filter runs over every
/// sample of the record while the searches need only the fitted rows. The values are the
/// filter's, bit for bit.
struct LagCache<'a> {
    d: &'a Data,
    rows: &'a [usize],
    /// (A mutex: the searches of several sensors run side by side and share what is kept.)
    cols: std::sync::Mutex<std::collections::HashMap<(usize, u64), Vec<f64>>>,
    /// Lags a search said it was about to ask for ([`LagCache::ahead`]), per sensor only the
    /// last such set (one of a golden-section step's two next points is never asked for).
    soon: std::sync::Mutex<std::collections::HashMap<(usize, u64), Vec<f64>>>,
    /// Time reversed and negated, for the backward pass of [`zero_phase_twin`].
    rev_t: Vec<f64>,
    /// The classes of `d.t_s`'s intervals and of `rev_t`'s (None: too many distinct ones).
    fwd: Option<Intervals>,
    rev: Option<Intervals>,
}

impl<'a> LagCache<'a> {
    fn new(d: &'a Data, rows: &'a [usize]) -> Self {
        let rev_t: Vec<f64> = d.t_s.iter().rev().map(|x| -x).collect();
        let rev = Intervals::of(&rev_t);
        Self {
            d,
            rows,
            cols: Default::default(),
            soon: Default::default(),
            rev_t,
            fwd: Intervals::of(&d.t_s),
            rev,
        }
    }

    /// [`lag_column`] on the fitted rows.
    fn on_rows(&self, sensor: usize, tau_s: f64) -> Vec<f64> {
        let key = (sensor, tau_s.to_bits());
        if let Some(c) = self.kept().get(&key) {
            return c.clone();
        }
        let soon = self
            .soon
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&key);
        if let Some(g) = soon {
            let mut cols = self.kept();
            if cols.len() < CACHED_COLUMNS {
                cols.insert(key, g.clone());
            }
            return g;
        }
        let d = self.d;
        let g = match &self.fwd {
            Some(iv) => lag_series_at_classes(iv, &d.temps[sensor].1, tau_s, None, self.rows),
            None => lag_series_at(&d.t_s, &d.temps[sensor].1, tau_s, None, self.rows),
        };
        let mut cols = self.kept();
        if cols.len() < CACHED_COLUMNS {
            cols.insert(key, g.clone());
        }
        g
    }

    /// The kept columns (a worker's panic leaves them as they were: each entry is whole).
    fn kept(&self) -> std::sync::MutexGuard<'_, std::collections::HashMap<(usize, u64), Vec<f64>>> {
        self.cols.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Fill the cache with `sensor`'s lags at every τ of `taus` not yet kept, the filters
    /// run side by side ([`lag_many_at_classes`]: the same values as [`LagCache::on_rows`]
    /// computes one at a time).
    fn prefill(&self, sensor: usize, taus: &[f64]) {
        let Some(iv) = &self.fwd else {
            return;
        };
        let missing: Vec<f64> = {
            let cols = self.kept();
            taus.iter()
                .copied()
                .filter(|&t| t > 0.0 && !cols.contains_key(&(sensor, t.to_bits())))
                .collect()
        };
        if missing.is_empty() {
            return;
        }
        let lags = lag_many_at_classes(iv, &self.d.temps[sensor].1, &missing, self.rows);
        let mut cols = self.kept();
        for (t, g) in missing.iter().zip(lags) {
            if cols.len() < CACHED_COLUMNS {
                cols.insert((sensor, t.to_bits()), g);
            }
        }
    }

    /// `sensor`'s lags at the τ of `taus` a search is about to ask [`LagCache::on_rows`] for
    /// (see [`Search::minimise_ahead`]), made together ([`lag_many_at_classes`]: the same
    /// values as one at a time) where not kept already: a golden-section step's point and the
    /// two points the next step may take cost one pass over the samples instead of two.
    fn ahead(&self, sensor: usize, taus: &[f64]) {
        let Some(iv) = &self.fwd else {
            return;
        };
        let missing: Vec<f64> = {
            let cols = self.kept();
            let soon = self.soon.lock().unwrap_or_else(|e| e.into_inner());
            taus.iter()
                .copied()
                .filter(|&t| {
                    let key = (sensor, t.to_bits());
                    t > 0.0 && !cols.contains_key(&key) && !soon.contains_key(&key)
                })
                .collect()
        };
        // one filter alone gains nothing from the lanes
        if missing.len() < 2 {
            return;
        }
        let lags = lag_many_at_classes(iv, &self.d.temps[sensor].1, &missing, self.rows);
        let mut soon = self.soon.lock().unwrap_or_else(|e| e.into_inner());
        soon.retain(|k, _| k.0 != sensor || taus.iter().any(|t| t.to_bits() == k.1));
        for (t, g) in missing.iter().zip(lags) {
            soon.insert((sensor, t.to_bits()), g);
        }
    }

    /// [`zero_phase_twin`] on the fitted rows.
    fn twin_on_rows(&self, sensor: usize, tau_s: f64) -> Vec<f64> {
        zero_phase_twin(self, sensor, tau_s, self.rows)
    }
}

/// How much lag term `j` moves the prediction: |gain| × the spread of its lagged temperature.
fn importance(f: &contract::Fitted, j: usize) -> f64 {
    let c = &f.proposal.regs[j];
    let n = c.len().max(1) as f64;
    let m = c.iter().sum::<f64>() / n;
    f.coeffs[j].abs() * (c.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / n).sqrt()
}

/// The effect's headline term: the one that moves the prediction most.
fn main_term(f: &contract::Fitted) -> usize {
    let k = match &f.proposal.detail {
        Detail::Lags(terms) => terms.len(),
        _ => 0,
    };
    (0..k)
        .max_by(|&a, &b| importance(f, a).total_cmp(&importance(f, b)))
        .unwrap_or(0)
}

/// The parameter names of each lag term: (`tau_s_<sensor>`, `gain_um_per_c_<sensor>`) for a
/// sensor's first term, `tau2_s_…` / `gain2_um_per_c_…` for its second.
fn term_names(d: &Data, terms: &[LagTerm]) -> Vec<(String, String)> {
    terms
        .iter()
        .enumerate()
        .map(|(j, t)| {
            let name = sensor_name(d, t.sensor);
            if terms[..j].iter().any(|o| o.sensor == t.sensor) {
                (format!("tau2_s_{name}"), format!("gain2_um_per_c_{name}"))
            } else {
                (format!("tau_s_{name}"), format!("gain_um_per_c_{name}"))
            }
        })
        .collect()
}

fn sensor_name(d: &Data, sensor: usize) -> String {
    let n = &d.temps[sensor].0;
    n.strip_prefix("temp_").unwrap_or(n).to_string()
}

/// Searched range of τ for `sensor`, s: from the shortest lag the record resolves (two
/// samples, the sensor's report interval) to half the record.
fn tau_range(d: &Data, sensor: usize) -> (f64, f64) {
    (d.shortest_lag_s(sensor), 0.5 * d.duration_s())
}

/// Best τ for a term on `sensor` on top of `basis`, keeping clear of `taken` time constants of
/// the same sensor: over the sensor's whole range, or only around a grid point `near` found by
/// screening (between its grid neighbours); (θ with its range, rss).
fn best_tau(
    s: &Search,
    cache: &LagCache,
    basis: &Basis,
    sensor: usize,
    taken: &[f64],
    sigma: bool,
    near: Option<f64>,
) -> Option<(Theta, f64)> {
    let (lo, hi) = tau_range(s.d, sensor);
    if hi.is_nan() || lo.is_nan() || hi <= 4.0 * lo {
        return None;
    }
    let step = (hi / lo).powf(1.0 / (SCREEN_POINTS - 1) as f64);
    let (a, b, points) = match near {
        Some(t) => ((t / step).max(lo), (t * step).min(hi), 3),
        None => (lo, hi, SCREEN_POINTS),
    };
    // the grid's lags side by side, as the search will ask for them
    cache.prefill(sensor, &log_grid(a, b, points));
    let (mut theta, rss) = s.minimise_ahead(
        "tau_s",
        (a, b),
        points,
        sigma,
        |tau| {
            if clear(taken, tau) {
                basis.rss_with_gathered(vec![cache.on_rows(sensor, tau)])
            } else {
                basis.rss()
            }
        },
        |taus| {
            let wanted: Vec<f64> = taus.iter().copied().filter(|&t| clear(taken, t)).collect();
            cache.ahead(sensor, &wanted);
        },
    );
    theta.lo = lo;
    theta.hi = hi;
    (clear(taken, theta.value) && rss < basis.rss()).then_some((theta, rss))
}

impl contract::Candidate for Candidate {
    fn name(&self) -> &'static str {
        NAME
    }
    fn description(&self) -> &'static str {
        "the measured displacement follows the temperatures with a delay: the structure warms and cools more slowly than its sensors (first-order lags, a time constant per sensor)"
    }
    fn deploy(&self) -> &'static str {
        "in the blob: one lag filter per term (LagSpec{sensor, tau_s}) and terms with Factor::Lagged(k); the firmware runs the same causal LagFilter on the raw readings"
    }
    fn applies(&self, d: &Data, _ch: usize) -> bool {
        !d.temps.is_empty() && d.rows() >= 50
    }
    fn propose(&self, s: &Search) -> Result<Option<Proposal>, ExplainError> {
        let d = s.d;
        let mut basis = s.basis.clone();
        let cache = LagCache::new(d, &s.basis.rows);
        // every sensor's lag on a τ grid, kept orthogonal to the growing model as terms join
        // (one Gram–Schmidt step per new term), so screening a grid point costs one dot product
        // (each sensor's grid on a core of its own where one is idle, taken in sensor order)
        let sensors: Vec<usize> = (0..d.temps.len())
            .filter(|&sensor| {
                let (lo, hi) = tau_range(d, sensor);
                !(hi.is_nan() || lo.is_nan() || hi <= 4.0 * lo)
            })
            .collect();
        let screened = in_parallel(&sensors, |&sensor| {
            let (lo, hi) = tau_range(d, sensor);
            let grid = log_grid(lo, hi, SCREEN_POINTS);
            cache.prefill(sensor, &grid);
            grid.into_iter()
                .map(|tau| {
                    let g = cache.on_rows(sensor, tau);
                    let norm0 = g.iter().map(|v| v * v).sum::<f64>().sqrt();
                    Screened {
                        sensor,
                        tau,
                        perp: basis.project_out(g),
                        norm0,
                    }
                })
                .collect::<Vec<Screened>>()
        });
        let mut screen: Vec<Screened> = screened.into_iter().flatten().collect();
        let mut terms: Vec<LagTerm> = Vec::new();
        let mut cols: Vec<Vec<f64>> = Vec::new();
        let mut cv_cur = f64::NAN;
        while terms.len() < MAX_TERMS.min(2 * d.temps.len()) {
            // screen: the best grid point of each sensor that may still take a term
            let r = basis.residual();
            let mut per_sensor: Vec<(f64, usize)> = Vec::new();
            for (k, c) in screen.iter().enumerate() {
                let taken: Vec<f64> = terms
                    .iter()
                    .filter(|t| t.sensor == c.sensor)
                    .map(|t| t.tau.value)
                    .collect();
                if taken.len() >= 2 || !clear(&taken, c.tau) {
                    continue;
                }
                let gain = c.gain(r);
                match per_sensor
                    .iter_mut()
                    .find(|p| screen[p.1].sensor == c.sensor)
                {
                    Some(p) if gain > p.0 => *p = (gain, k),
                    Some(_) => {}
                    None => per_sensor.push((gain, k)),
                }
            }
            per_sensor.sort_by(|a, b| b.0.total_cmp(&a.0));
            // refine the most promising sensors' τ between grid points (side by side where a
            // core is idle; taken in the order of their screening gain, as one after the other)
            let picked: Vec<usize> = per_sensor
                .iter()
                .take(REFINE_SENSORS)
                .map(|&(_, k)| k)
                .collect();
            let refined = in_parallel(&picked, |&k| -> Option<(f64, LagTerm)> {
                let sensor = screen[k].sensor;
                let taken: Vec<f64> = terms
                    .iter()
                    .filter(|t| t.sensor == sensor)
                    .map(|t| t.tau.value)
                    .collect();
                let (tau, rss) = best_tau(
                    s,
                    &cache,
                    &basis,
                    sensor,
                    &taken,
                    false,
                    Some(screen[k].tau),
                )?;
                let n_eff = s.n_eff;
                if n_eff * (rss / basis.rss()).ln() + 2.0 * n_eff.ln() > -MIN_TERM_BIC {
                    return None;
                }
                // a lag must earn its place by its delay, not by smoothing sensor noise:
                // it must fit better than the best zero-phase smoothing of the same sensor
                // (its width searched too) — positive evidence, as a slow lag over a short
                // record is hard to tell from smoothing
                let (_, rss_twin) =
                    s.minimise("tau_s", (tau.value / 4.0, tau.value * 4.0), 5, false, |t| {
                        basis.rss_with_gathered(vec![cache.twin_on_rows(sensor, t)])
                    });
                if n_eff * (rss / rss_twin).ln() > -TWIN_BIC {
                    return None;
                }
                Some((rss, LagTerm { sensor, tau }))
            });
            let mut best: Option<(f64, LagTerm)> = None;
            for (rss, term) in refined.into_iter().flatten() {
                if best.as_ref().is_none_or(|b| rss < b.0) {
                    best = Some((rss, term));
                }
            }
            let Some((_, term)) = best else { break };
            let col = lag_column(d, term.sensor, term.tau.value);
            // beyond the first term, a term must also predict held-out data better
            if !terms.is_empty() {
                let mut all: Vec<&[f64]> = s.model.clone();
                all.extend(cols.iter().map(|c| c.as_slice()));
                if cv_cur.is_nan() {
                    cv_cur = cross_validate_score(&all, s.y, s.design, &s.basis.rows)?.rms_um;
                }
                all.push(&col);
                let cv_new = cross_validate_score(&all, s.y, s.design, &s.basis.rows)?.rms_um;
                if cv_new.is_nan() || cv_new >= cv_cur * (1.0 - MIN_TERM_CV_GAIN) {
                    break;
                }
                cv_cur = cv_new;
            }
            let dim = basis.dim();
            basis.add_column(&col);
            if basis.dim() > dim {
                let e = basis.last().to_vec();
                for c in screen.iter_mut() {
                    let k = dot(&e, &c.perp);
                    for (p, ei) in c.perp.iter_mut().zip(&e) {
                        *p -= k * ei;
                    }
                }
            }
            cols.push(col);
            terms.push(term);
        }
        // settle: refine each τ with the other terms fixed (coordinate descent; greedy
        // selection picks a τ that the later terms make suboptimal), then prune again, until
        // the set stops changing; a last sweep gives each τ its 1σ
        let mut last: Vec<(usize, f64)> = Vec::new();
        for _ in 0..REFINE_SWEEPS {
            prune(s, &mut terms, &mut cols);
            drop_implausible(s, &mut terms, &mut cols)?;
            if terms.is_empty() {
                return Ok(None);
            }
            refine(s, &cache, &mut terms, &mut cols, false);
            let now: Vec<(usize, f64)> = terms.iter().map(|t| (t.sensor, t.tau.value)).collect();
            let settled = now.len() == last.len()
                && now
                    .iter()
                    .zip(&last)
                    .all(|(a, b)| a.0 == b.0 && (a.1 / b.1 - 1.0).abs() < 0.02);
            last = now;
            if settled {
                break;
            }
        }
        refine(s, &cache, &mut terms, &mut cols, true);
        Ok(Some(Proposal {
            regs: cols.into_iter().map(std::sync::Arc::new).collect(),
            thetas: terms.iter().map(|t| t.tau.clone()).collect(),
            detail: Detail::Lags(terms),
            design: None,
            evidence_units: None,
        }))
    }
    fn params(&self, d: &Data, _ch: usize, f: &contract::Fitted) -> Vec<Estimate> {
        let Detail::Lags(terms) = &f.proposal.detail else {
            return Vec::new();
        };
        let mut out = vec![terms[main_term(f)].tau.estimate()];
        for (j, (t, (tau, gain))) in terms.iter().zip(term_names(d, terms)).enumerate() {
            out.push(Estimate::new(&tau, t.tau.value, t.tau.sigma_unless_bound()));
            out.push(Estimate::new(&gain, f.coeffs[j], f.se[j]));
        }
        out
    }
    /// A replicate's lag terms under the names of the full fit's, like with like: each full
    /// term takes the replicate's term of the same sensor and rank (its first or second τ);
    /// full terms whose sensor the replicate left without that term take, in order of how much
    /// they move the prediction, the replicate's terms left over in the same order (the lag
    /// moved to another sensor in that replicate: that is part of the term's uncertainty). The
    /// headline `tau_s` follows the full fit's main term, so a replicate whose largest term
    /// is another sensor's no longer puts that sensor's τ in the headline's spread (GX-H12A's
    /// `tau_s` read 521 ± 576 s, the bed's own τ 521 ± 53 s).
    fn replicate_params(
        &self,
        d: &Data,
        ch: usize,
        full: &contract::Fitted,
        rep: &contract::Fitted,
    ) -> Vec<Estimate> {
        let (Detail::Lags(ft), Detail::Lags(rt)) = (&full.proposal.detail, &rep.proposal.detail)
        else {
            return self.params(d, ch, rep);
        };
        let key = |terms: &[LagTerm], j: usize| {
            let rank = terms[..j]
                .iter()
                .filter(|o| o.sensor == terms[j].sensor)
                .count();
            (terms[j].sensor, rank)
        };
        let mut matched: Vec<Option<usize>> = (0..ft.len())
            .map(|j| (0..rt.len()).find(|&i| key(rt, i) == key(ft, j)))
            .collect();
        let by_importance = |f: &contract::Fitted, mut idx: Vec<usize>| {
            idx.sort_by(|&a, &b| importance(f, b).total_cmp(&importance(f, a)));
            idx
        };
        let full_left = by_importance(
            full,
            (0..ft.len()).filter(|&j| matched[j].is_none()).collect(),
        );
        let rep_left = by_importance(
            rep,
            (0..rt.len())
                .filter(|i| !matched.contains(&Some(*i)))
                .collect(),
        );
        for (&j, &i) in full_left.iter().zip(&rep_left) {
            matched[j] = Some(i);
        }
        let mut out = Vec::new();
        let main = main_term(full);
        if let Some(i) = matched[main] {
            out.push(Estimate::new(&ft[main].tau.name, rt[i].tau.value, f64::NAN));
        }
        for (j, (tau, gain)) in term_names(d, ft).into_iter().enumerate() {
            if let Some(i) = matched[j] {
                out.push(Estimate::new(&tau, rt[i].tau.value, f64::NAN));
                out.push(Estimate::new(&gain, rep.coeffs[i], f64::NAN));
            }
        }
        out
    }
    fn summary(&self, d: &Data, _ch: usize, f: &contract::Fitted) -> String {
        let Detail::Lags(terms) = &f.proposal.detail else {
            return String::new();
        };
        let parts: Vec<String> = terms
            .iter()
            .enumerate()
            .map(|(j, t)| {
                let second = terms[..j].iter().any(|o| o.sensor == t.sensor);
                let sign_note = match terms[..j].iter().find(|o| o.sensor == t.sensor) {
                    Some(_) if second => {
                        let first = terms.iter().position(|o| o.sensor == t.sensor).unwrap_or(j);
                        if f.coeffs[first].signum() != f.coeffs[j].signum() {
                            ", opposite in sign to its first"
                        } else {
                            ", same sign as its first"
                        }
                    }
                    _ => "",
                };
                let bound = t
                    .tau
                    .bound_note()
                    .or_else(|| held_apart_note(terms, j))
                    .map(|b| format!(" [{b}]"))
                    .unwrap_or_default();
                format!(
                    "{}{} τ = {} ({} µm/°C{}){}",
                    sensor_name(d, t.sensor),
                    if second { " again," } else { "" },
                    duration(t.tau.value),
                    sig3(f.coeffs[j]),
                    sign_note,
                    bound
                )
            })
            .collect();
        format!("lags: {}", parts.join("; "))
    }
    fn blob_terms(
        &self,
        ctx: &contract::BlobContext,
        f: &contract::Fitted,
    ) -> Option<contract::BlobTerms> {
        let Detail::Lags(terms) = &f.proposal.detail else {
            return None;
        };
        let usable: Vec<&LagTerm> = terms
            .iter()
            .filter(|t| t.sensor < ctx.temps as usize)
            .take(nanocal_model::MAX_LAGS)
            .collect();
        (!usable.is_empty()).then(|| contract::BlobTerms {
            lags: usable
                .iter()
                .map(|t| (t.sensor as u8, t.tau.value))
                .collect(),
            terms: (0..usable.len() as u8)
                .map(|k| contract::term(ctx.output, [0; 3], nanocal_model::Factor::Lagged(k), 0))
                .collect(),
            plays: Vec::new(),
            play: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::recording::Recording;
    use crate::explain::contract::{Candidate as _, Fitted};

    fn data() -> Data {
        let n = 200;
        let t: Vec<f64> = (0..n).map(|k| k as f64).collect();
        let cmd: Vec<f64> = (0..n).map(|k| 10.0 * (k / 20) as f64).collect();
        let meas: Vec<f64> = cmd.iter().map(|c| c + 0.001).collect();
        let air: Vec<f64> = (0..n)
            .map(|k| 20.0 + 0.1 * (k as f64 / 30.0).sin())
            .collect();
        let base: Vec<f64> = (0..n)
            .map(|k| 20.0 + 0.1 * (k as f64 / 50.0).cos())
            .collect();
        let rec = Recording::from_columns(vec![
            ("t".into(), t),
            ("cmd_x".into(), cmd),
            ("meas_x".into(), meas),
            ("temp_air".into(), air),
            ("temp_base".into(), base),
        ])
        .unwrap();
        Data::from_recording(&rec, None).unwrap()
    }

    fn term(sensor: usize, tau_s: f64) -> LagTerm {
        LagTerm {
            sensor,
            tau: Theta {
                name: "tau_s".into(),
                value: tau_s,
                sigma: 0.1 * tau_s,
                lo: 10.0,
                hi: 1e5,
            },
        }
    }

    fn proposal(terms: Vec<LagTerm>) -> Proposal {
        // every column has the same spread: a term's importance is its |gain|
        let col: Vec<f64> = (0..200).map(|k| (k % 2) as f64).collect();
        Proposal {
            regs: (0..terms.len())
                .map(|_| std::sync::Arc::new(col.clone()))
                .collect(),
            thetas: terms.iter().map(|t| t.tau.clone()).collect(),
            detail: Detail::Lags(terms),
            design: None,
            evidence_units: None,
        }
    }

    fn value(ps: &[Estimate], name: &str) -> Option<f64> {
        ps.iter().find(|p| p.name == name).map(|p| p.value)
    }

    /// A replicate whose largest term is another sensor's gives the headline `tau_s` the τ of
    /// the full fit's main sensor, and every sensor's τ its own; a sensor the replicate left
    /// without a term takes the term left over (the lag moved there).
    #[test]
    fn replicates_are_read_like_with_like_by_sensor() {
        let d = data();
        let sensor = |name: &str| d.temps.iter().position(|t| t.0 == name).unwrap();
        let (air, base) = (sensor("temp_air"), sensor("temp_base"));
        let full_p = proposal(vec![term(air, 500.0), term(base, 2000.0)]);
        let se = [0.1, 0.1];
        let full = Fitted {
            proposal: &full_p,
            coeffs: &[3.0, 1.0],
            se: &se,
            noise_sigma_um: 0.01,
        };
        let ps = Candidate.params(&d, 0, &full);
        assert_eq!(value(&ps, "tau_s"), Some(500.0));
        // the replicate found base first and with the larger gain
        let rep_p = proposal(vec![term(base, 1900.0), term(air, 520.0)]);
        let rep = Fitted {
            proposal: &rep_p,
            coeffs: &[4.0, 2.0],
            se: &se,
            noise_sigma_um: 0.01,
        };
        let r = Candidate.replicate_params(&d, 0, &full, &rep);
        assert_eq!(value(&r, "tau_s"), Some(520.0), "{r:?}");
        assert_eq!(value(&r, "tau_s_air"), Some(520.0), "{r:?}");
        assert_eq!(value(&r, "tau_s_base"), Some(1900.0), "{r:?}");
        assert_eq!(value(&r, "gain_um_per_c_air"), Some(2.0), "{r:?}");
        // its own reading would have put base's τ in the headline
        assert_eq!(value(&Candidate.params(&d, 0, &rep), "tau_s"), Some(1900.0));
        // a replicate without an air term: base is matched by sensor, air takes the leftover
        let rep_p = proposal(vec![term(base, 2100.0), term(base, 300.0)]);
        let rep = Fitted {
            proposal: &rep_p,
            coeffs: &[1.0, 5.0],
            se: &se,
            noise_sigma_um: 0.01,
        };
        let r = Candidate.replicate_params(&d, 0, &full, &rep);
        assert_eq!(value(&r, "tau_s_base"), Some(2100.0), "{r:?}");
        assert_eq!(value(&r, "tau_s_air"), Some(300.0), "{r:?}");
        assert_eq!(value(&r, "tau_s"), Some(300.0), "{r:?}");
        assert_eq!(value(&r, "tau2_s_base"), None, "{r:?}");
    }
}
