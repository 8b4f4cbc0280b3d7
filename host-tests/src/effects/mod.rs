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

pub mod context;

use crate::explain::contract::Candidate;
pub use context::SimContext;

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
    let mut at = AtRows::<1>::new(rows);
    lag_run(t_s, x, tau_s, y0, |k, y| at.take(k, &[y]));
    let [out] = at.out;
    out
}

/// The outputs of `N` runs side by side at `rows` (ascending), taken as the runs hand each
/// sample's outputs over in order.
struct AtRows<'a, const N: usize> {
    rows: &'a [usize],
    next: usize,
    out: [Vec<f64>; N],
}

impl<'a, const N: usize> AtRows<'a, N> {
    fn new(rows: &'a [usize]) -> Self {
        Self {
            rows,
            next: 0,
            out: std::array::from_fn(|_| vec![0.0; rows.len()]),
        }
    }

    /// Sample `k`'s outputs `y`, one per run.
    #[inline]
    fn take(&mut self, k: usize, y: &[f64; N]) {
        // rows ascending: every row is met once, in order
        while self.next < self.rows.len() && self.rows[self.next] == k {
            for (out, &y) in self.out.iter_mut().zip(y) {
                out[self.next] = y;
            }
            self.next += 1;
        }
    }
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
    let mut at = AtRows::<1>::new(rows);
    lag_run_classes(iv, x, tau_s, y0, |k, y| at.take(k, &[y]));
    let [out] = at.out;
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

/// Lags run side by side by [`lag_many_at_classes`].
const LAG_LANES: usize = 4;

/// [`lag_series_at_classes`] (no start value) for several positive time constants at once:
/// one pass over the samples runs [`LAG_LANES`] filters side by side. Each filter's step
/// waits on its own last state (a multiply, a subtract and an add in a chain), so a filter
/// alone leaves the core mostly idle; independent filters fill it. Every filter does the same
/// arithmetic in the same order as alone, bit for bit. Entry j is `taus[j]`'s.
pub(crate) fn lag_many_at_classes(
    iv: &Intervals,
    x: &[f64],
    taus: &[f64],
    rows: &[usize],
) -> Vec<Vec<f64>> {
    debug_assert!(taus.iter().all(|&t| t > 0.0));
    let mut outs: Vec<Vec<f64>> = Vec::with_capacity(taus.len());
    if x.is_empty() {
        return taus.iter().map(|_| vec![0.0; rows.len()]).collect();
    }
    debug_assert_eq!(iv.class.len(), x.len());
    // per class: what `lag_run_classes` does with a positive τ (a restart after a non-finite
    // interval, a hold after one ≤ 0, else smoothing by the factor)
    const SMOOTH: u8 = 0;
    const RESTART: u8 = 1;
    const HOLD: u8 = 2;
    let kind: Vec<u8> = iv
        .dt_s
        .iter()
        .map(|&dt| {
            if !dt.is_finite() {
                RESTART
            } else if dt > 0.0 {
                SMOOTH
            } else {
                HOLD
            }
        })
        .collect();
    for chunk in taus.chunks(LAG_LANES) {
        // a short last chunk repeats its last τ in the spare lanes (their outputs dropped)
        let lane_tau: [f64; LAG_LANES] = std::array::from_fn(|j| chunk[j.min(chunk.len() - 1)]);
        let alpha: Vec<[f64; LAG_LANES]> = iv
            .dt_s
            .iter()
            .zip(&kind)
            .map(|(&dt, &k)| {
                std::array::from_fn(|j| {
                    if k == SMOOTH {
                        1.0 - libm::exp(-dt / lane_tau[j])
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        let mut at = AtRows::<LAG_LANES>::new(rows);
        let mut state = [x[0]; LAG_LANES];
        at.take(0, &state);
        for k in 1..x.len() {
            let c = iv.class[k] as usize;
            match kind[c] {
                SMOOTH => {
                    let a = &alpha[c];
                    let xk = x[k];
                    for j in 0..LAG_LANES {
                        state[j] += a[j] * (xk - state[j]);
                    }
                }
                RESTART => state = [x[k]; LAG_LANES],
                _ => {}
            }
            at.take(k, &state);
        }
        outs.extend(at.out.into_iter().take(chunk.len()));
    }
    outs
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
    vec![vec![0.0; ctx.t_s.len()]; ctx.axes]
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

    /// A 1 kHz clock far from zero whose intervals differ in their last bits, with a repeated
    /// (row 500), a backward (900) and a missing (1200) time stamp, and a reading, missing
    /// 10 rows before the end: `n` rows of time and temperature.
    fn irregular_log(n: usize) -> (Vec<f64>, Vec<f64>) {
        let mut t: Vec<f64> = (0..n)
            .map(|k| 1000.0 + k as f64 * 1e-3 + ((k * k) % 1009) as f64 * 1e-9)
            .collect();
        t[500] = t[499];
        t[900] = t[899] - 0.01;
        t[1200] = f64::NAN;
        let mut x: Vec<f64> = (0..n)
            .map(|k| 21.0 + (k as f64 * 1e-3).sin() + ((k * 31) % 7) as f64 * 1e-3)
            .collect();
        x[n - 10] = f64::NAN;
        (t, x)
    }

    #[test]
    fn lags_side_by_side_are_each_lag_alone_bit_for_bit() {
        // irregular 1 kHz clock with a repeated, a backward and a missing time stamp, a
        // missing reading; τ counts that fill the lanes, leave one short, and one alone
        let (t, x) = irregular_log(5_000);
        let iv = Intervals::of(&t).expect("fewer intervals than the classes hold");
        let rows: Vec<usize> = (0..t.len()).step_by(7).chain([4_999]).collect();
        for taus in [
            vec![2e-3, 0.7, 120.0, 1e6],
            vec![0.05, 3.0, 17.0, 250.0, 1e4, 0.3],
            vec![42.0],
        ] {
            let many = lag_many_at_classes(&iv, &x, &taus, &rows);
            assert_eq!(many.len(), taus.len());
            for (tau, got) in taus.iter().zip(&many) {
                let alone = lag_series_at_classes(&iv, &x, *tau, None, &rows);
                assert_eq!(got.len(), alone.len());
                for (r, (a, b)) in rows.iter().zip(got.iter().zip(&alone)) {
                    assert_eq!(a.to_bits(), b.to_bits(), "τ {tau}, row {r}");
                }
            }
        }
    }

    #[test]
    fn lag_series_is_the_model_filter_bit_for_bit() {
        // a 1 kHz clock far from zero (intervals differing in their last bits, more distinct
        // intervals than the table holds), irregular gaps, a repeated and a backward time
        // stamp, a missing one, and a missing reading
        let (mut t, x) = irregular_log(20_000);
        // (the jitter's rows, multiples of 97, miss the repeated, backward and missing stamps)
        for k in (0..t.len()).step_by(97) {
            t[k] += ((k * 7919) % 13) as f64 * 1.3e-4;
        }
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
