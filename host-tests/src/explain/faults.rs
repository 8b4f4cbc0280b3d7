//! Data faults, found before any physics: time stamps that run backwards or jump, rows missing,
//! readings missing, channels that freeze (repeat one value exactly while they should move),
//! channels pinned at the end of their range, a drive with glitches, readings held between
//! slower updates. Each is reported with its channel and rows as a sensor or logger to check —
//! never as physics — and explain fits around it: time is repaired where the signals show the
//! clock (not the machine) jumped, unusable rows are left out of every fit, a sensor that is
//! unusable for most of the record is left out of the model.

use serde::Serialize;

use crate::data::recording::{ColumnRole, Recording};

use super::error::ExplainError;
use super::robust::{glitch_rows, quantisation_step, rows_in_words, update_interval_s};
use super::stats::median;
use super::units::duration;

/// What kind of data fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum FaultKind {
    /// Time stamps that go backwards or repeat.
    TimeBackwards,
    /// Time stamps that jump while every channel carries on as from one sample to the next: the
    /// logger's clock jumped, the machine did not stop.
    ClockJump,
    /// No rows for a stretch of time while the signals moved on: the logger stopped (a dropout).
    Gap,
    /// Readings missing (NaN or infinite values).
    Missing,
    /// A channel that repeats one value exactly, without noise, while it should move.
    Frozen,
    /// A channel pinned at the end of its range (clipped, an amplifier or ADC at its rail).
    Saturated,
    /// A command (drive) that jumps away and back while the measurement does not follow.
    DriveGlitch,
    /// A channel held between slower updates (logged faster than it is read).
    SampleAndHold,
}

impl FaultKind {
    /// True for what a person must check (a sensor, the logger); false for a property of the
    /// logging that explain handles (sample-and-hold).
    pub fn needs_check(self) -> bool {
        !matches!(self, Self::SampleAndHold)
    }
}

impl std::fmt::Display for FaultKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::TimeBackwards => "time runs backwards",
            Self::ClockJump => "clock jump",
            Self::Gap => "rows missing (logging gap)",
            Self::Missing => "readings missing",
            Self::Frozen => "frozen channel",
            Self::Saturated => "saturated channel",
            Self::DriveGlitch => "glitches in the drive",
            Self::SampleAndHold => "sample-and-hold",
        })
    }
}

/// A data fault: which channel, which rows, what was seen and what explain did about it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DataFault {
    /// What kind.
    pub kind: FaultKind,
    /// The column (`t` for the time stamps).
    pub column: String,
    /// Rows affected, as ranges `[first, end)` of 0-based data rows.
    pub rows: Vec<(usize, usize)>,
    /// What was seen, in words and numbers.
    pub detail: String,
    /// What explain did about it.
    pub handling: String,
}

impl DataFault {
    /// The rows as a person reads them (data rows counted from 1).
    pub fn rows_in_words(&self) -> String {
        let rows: Vec<usize> = self.rows.iter().flat_map(|&(a, b)| a..b).collect();
        if rows.is_empty() {
            "the whole record".into()
        } else {
            rows_in_words(&rows, 6)
        }
    }
}

/// A recording after inspection: repaired columns, the faults found, the rows no fit may use.
#[derive(Clone, Debug)]
pub struct Inspection {
    /// The recording with time repaired, missing readings and frozen stretches interpolated,
    /// glitches of the drive repaired, and columns left out that carry no usable information.
    pub recording: Recording,
    /// What was found.
    pub faults: Vec<DataFault>,
    /// Rows no channel may be fitted on (a temperature unusable there, time unknown).
    pub excluded_all: Vec<bool>,
    /// Rows excluded per measured column (`meas_<axis>` name).
    pub excluded_meas: Vec<(String, Vec<bool>)>,
}

/// Probability below which a run of exactly repeated readings is not chance (given how often
/// the channel changes around it): the run is frozen.
const FROZEN_LOG_P: f64 = -18.4; // ln(1e-8)
/// Shortest frozen run, rows.
const MIN_FROZEN_ROWS: usize = 10;
/// A channel unusable (frozen, saturated, missing) over more than this share of the rows is
/// left out of the model instead of leaving its rows out of every fit.
const MAX_EXCLUDED_SHARE: f64 = 0.8;
/// A time step this many typical steps long (and 3× the 99th percentile) is a jump.
const JUMP_STEPS: f64 = 10.0;
/// Evidence (log-likelihood ratio, summed over the signals that can tell) that a time jump is
/// the clock's, or a real gap.
const CLOCK_LLR: f64 = 6.0;

fn ranges(mask: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < mask.len() {
        if mask[i] {
            let a = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            out.push((a, i));
        } else {
            i += 1;
        }
    }
    out
}

/// Linear interpolation over the rows where `bad` is true, from the good readings around them
/// (held at the ends).
pub fn interpolate_mask(v: &mut [f64], bad: &[bool]) {
    let n = v.len();
    let mut i = 0;
    while i < n {
        if !bad[i] {
            i += 1;
            continue;
        }
        let a = i;
        while i < n && bad[i] {
            i += 1;
        }
        let before = a.checked_sub(1);
        let after = (i < n).then_some(i);
        for k in a..i {
            v[k] = match (before, after) {
                (Some(p), Some(q)) => v[p] + (v[q] - v[p]) * (k - p) as f64 / (q - p) as f64,
                (Some(p), None) => v[p],
                (None, Some(q)) => v[q],
                (None, None) => 0.0,
            };
        }
    }
}

fn robust_scale(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = median(v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    1.4826 * median(&mut dev)
}

/// The signals a time jump is judged by: every measured channel as the error (minus its
/// command), the temperatures and the auxiliary channels.
fn judging_signals(rec: &Recording) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    for name in rec.names() {
        let Some(v) = rec.column(name) else { continue };
        match ColumnRole::of(name) {
            ColumnRole::Meas(axis) => match rec.cmd(&axis) {
                Some(c) => out.push(v.iter().zip(c).map(|(m, c)| m - c).collect()),
                None => out.push(v.to_vec()),
            },
            ColumnRole::Temp(_) | ColumnRole::Aux(_) => out.push(v.to_vec()),
            _ => {}
        }
    }
    out
}

/// Log-likelihood ratio "a real gap of `m` rows" against "one sample to the next" for the
/// change across row `i` of every signal that can tell them apart (it moves far more over `m`
/// rows than from one row to the next). Positive: a gap.
fn gap_llr(signals: &[Vec<f64>], i: usize, m: usize) -> f64 {
    let mut llr = 0.0;
    for x in signals {
        let n = x.len();
        let m = m.clamp(2, n / 3);
        if n < 3 * m.max(4) {
            continue;
        }
        let mut d1: Vec<f64> = (1..n)
            .filter(|&k| k != i)
            .map(|k| x[k] - x[k - 1])
            .filter(|v| v.is_finite())
            .collect();
        let s1 = robust_scale(&mut d1).max(f64::MIN_POSITIVE);
        let dm: Vec<f64> = (m..n)
            .filter(|&k| k < i || k - m >= i)
            .map(|k| x[k] - x[k - m])
            .filter(|v| v.is_finite())
            .collect();
        if dm.len() < 10 {
            continue;
        }
        let sm = (dm.iter().map(|v| v * v).sum::<f64>() / dm.len() as f64).sqrt();
        if sm.partial_cmp(&(5.0 * s1)) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        let d = x[i] - x[i - 1];
        if !d.is_finite() {
            continue;
        }
        // Gaussian log densities of d under the two scales (the one-row one widened a little
        // so a heavy-tailed step cannot decide alone)
        let s1w = 1.5 * s1;
        let lg = -(sm.ln()) - 0.5 * (d / sm).powi(2);
        let lc = -(s1w.ln()) - 0.5 * (d / s1w).powi(2);
        llr += (lg - lc).clamp(-40.0, 40.0);
    }
    llr
}

/// Repair the time stamps: missing ones interpolated; single bad stamps put back between their
/// neighbours; a clock that steps back, or jumps ahead while every signal carries on as from one
/// sample to the next, continued at the usual interval. A jump across which the signals moved as
/// much as the elapsed time says is a real gap: kept, and reported.
fn repair_time(
    t: &mut [f64],
    signals: &[Vec<f64>],
    faults: &mut Vec<DataFault>,
    excluded: &mut [bool],
) -> Result<(), ExplainError> {
    let n = t.len();
    let bad: Vec<bool> = t.iter().map(|v| !v.is_finite()).collect();
    let nbad = bad.iter().filter(|b| **b).count();
    if nbad * 2 > n {
        return Err(ExplainError::Input(format!(
            "column `t`: expected time stamps, found {nbad} of {n} rows without one"
        )));
    }
    if nbad > 0 {
        interpolate_mask(t, &bad);
        for (e, b) in excluded.iter_mut().zip(&bad) {
            *e |= *b;
        }
        faults.push(DataFault {
            kind: FaultKind::Missing,
            column: "t".into(),
            rows: ranges(&bad),
            detail: format!("{nbad} row(s) without a time stamp"),
            handling: "time interpolated from the rows around; the rows left out of every fit"
                .into(),
        });
    }
    let mut dts: Vec<f64> = t
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    if dts.len() < 10 {
        return Err(ExplainError::Input(
            "column `t`: expected time to increase from row to row, found it mostly standing still or going back".into(),
        ));
    }
    let med = median(&mut dts.clone());
    // the order statistic alone (the same element a full sort puts there)
    let k99 = (dts.len() * 99) / 100;
    let p99 = *dts.select_nth_unstable_by(k99, f64::total_cmp).1;
    let jump = (JUMP_STEPS * med).max(3.0 * p99);
    let mut backwards: Vec<(usize, f64)> = Vec::new();
    let mut glitches: Vec<usize> = Vec::new();
    let mut clock: Vec<(usize, f64)> = Vec::new();
    let mut gaps: Vec<(usize, f64, f64)> = Vec::new();
    let mut i = 1;
    while i < n {
        let dt = t[i] - t[i - 1];
        if dt > 0.0 && dt <= jump {
            i += 1;
            continue;
        }
        // one bad stamp: its neighbours are in order with each other
        if i + 1 < n {
            let span = t[i + 1] - t[i - 1];
            if span > 0.0 && span <= 2.0 * jump && (t[i] <= t[i - 1] || t[i] >= t[i + 1]) {
                t[i] = 0.5 * (t[i - 1] + t[i + 1]);
                glitches.push(i);
                i += 1;
                continue;
            }
        }
        if dt <= 0.0 {
            let shift = med - dt;
            for v in t[i..].iter_mut() {
                *v += shift;
            }
            backwards.push((i, dt));
        } else {
            let m = (dt / med).round() as usize;
            let llr = gap_llr(signals, i, m);
            if llr < -CLOCK_LLR {
                let shift = med - dt;
                for v in t[i..].iter_mut() {
                    *v += shift;
                }
                clock.push((i, dt));
            } else {
                gaps.push((i, dt, llr));
            }
        }
        i += 1;
    }
    if !glitches.is_empty() {
        faults.push(DataFault {
            kind: FaultKind::TimeBackwards,
            column: "t".into(),
            rows: glitches.iter().map(|&i| (i, i + 1)).collect(),
            detail: format!(
                "{} single time stamp(s) out of order with their neighbours",
                glitches.len()
            ),
            handling: "each put back half-way between its neighbours".into(),
        });
    }
    for (i, dt) in backwards {
        faults.push(DataFault {
            kind: FaultKind::TimeBackwards,
            column: "t".into(),
            rows: vec![(i, i + 1)],
            detail: format!(
                "time steps back by {} at data row {} (a clock reset?)",
                duration(-dt),
                i + 1
            ),
            handling: format!(
                "the time stamps from there on continued at the usual interval ({})",
                duration(med)
            ),
        });
    }
    for (i, dt) in clock {
        faults.push(DataFault {
            kind: FaultKind::ClockJump,
            column: "t".into(),
            rows: vec![(i, i + 1)],
            detail: format!(
                "time jumps ahead by {} at data row {} while every channel carries on as from one sample to the next: the clock jumped, the machine did not stop",
                duration(dt),
                i + 1
            ),
            handling: format!(
                "the time stamps from there on continued at the usual interval ({})",
                duration(med)
            ),
        });
    }
    for (i, dt, llr) in gaps {
        faults.push(DataFault {
            kind: FaultKind::Gap,
            column: "t".into(),
            rows: vec![(i, i + 1)],
            detail: format!(
                "no rows for {} before data row {}{}",
                duration(dt),
                i + 1,
                if llr > CLOCK_LLR {
                    " (the signals moved on as much as that time allows: the logger stopped, the machine did not)"
                } else {
                    " (the signals cannot tell a logging gap from a clock jump)"
                }
            ),
            handling: "time kept as logged".into(),
        });
    }
    Ok(())
}

/// Runs of exactly repeated values of at least `min_rows` rows: (first, end).
fn repeat_runs(x: &[f64], min_rows: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut a = 0;
    for i in 1..=x.len() {
        if i == x.len() || x[i] != x[a] {
            if i - a >= min_rows {
                out.push((a, i));
            }
            a = i;
        }
    }
    out
}

/// Share of rows in `[a, b)` where `x` changed from the row before.
fn change_rate(x: &[f64], a: usize, b: usize) -> Option<f64> {
    let a = a.max(1);
    (b > a + 10).then(|| (a..b).filter(|&k| x[k] != x[k - 1]).count() as f64 / (b - a) as f64)
}

/// Whether the other channels say `x` should have moved over `[a, b)`: `x` fitted on up to
/// eight of them that go with it best (least squares, outside the run, near it), its prediction
/// over the run spans more than 3 of its own steps (quantisation or scatter). None when no other
/// channel predicts it.
fn peers_say_moved(x: &[f64], a: usize, b: usize, peers: &[&[f64]]) -> Option<bool> {
    let n = x.len();
    let l = b - a;
    let w = (3 * l).max(200);
    let rows: Vec<usize> = (a.saturating_sub(w)..a).chain(b..(b + w).min(n)).collect();
    if rows.len() < 20 || peers.is_empty() {
        return None;
    }
    let xs: Vec<f64> = rows.iter().map(|&i| x[i]).collect();
    let mx = xs.iter().sum::<f64>() / xs.len() as f64;
    let mut scored: Vec<(f64, &[f64])> = peers
        .iter()
        .filter_map(|p| {
            let ps: Vec<f64> = rows.iter().map(|&i| p[i]).collect();
            let mp = ps.iter().sum::<f64>() / ps.len() as f64;
            let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
            for (u, v) in xs.iter().zip(&ps) {
                sxy += (u - mx) * (v - mp);
                sxx += (u - mx) * (u - mx);
                syy += (v - mp) * (v - mp);
            }
            let r = sxy / (sxx * syy).sqrt();
            r.is_finite().then_some((r.abs(), *p))
        })
        .collect();
    scored.sort_by(|p, q| q.0.total_cmp(&p.0));
    scored.truncate(8);
    if scored.first().is_none_or(|s| s.0 < 0.5) {
        return None;
    }
    let cols: Vec<Vec<f64>> = scored
        .iter()
        .map(|(_, p)| rows.iter().map(|&i| p[i]).collect())
        .collect();
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let ls = crate::numerics::linalg::lstsq(&refs, &xs, true).ok()?;
    let predict = |i: usize| {
        ls.intercept
            + scored
                .iter()
                .zip(&ls.coeffs)
                .map(|((_, p), c)| c * p[i])
                .sum::<f64>()
    };
    let pred: Vec<f64> = (a..b).map(predict).collect();
    let span = pred.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - pred.iter().cloned().fold(f64::INFINITY, f64::min);
    let fit_sd = (ls.rss / ls.dof.max(1) as f64).sqrt();
    let step = quantisation_step(x).unwrap_or(0.0);
    Some(span > 3.0 * step.max(fit_sd))
}

/// Frozen stretches of column `x`: runs of one exactly repeated value so long that the way the
/// channel changes around them makes them no chance (probability below 1e-8), unless the other
/// channels say the quantity stood still too.
fn frozen_runs(x: &[f64], peers: &[&[f64]]) -> Vec<(usize, usize, f64)> {
    let n = x.len();
    let q = quantisation_step(x).unwrap_or(0.0);
    let mut out = Vec::new();
    for (a, b) in repeat_runs(x, MIN_FROZEN_ROWS) {
        let l = b - a;
        if l == n {
            continue;
        }
        let w = l.max(50);
        let before = change_rate(x, a.saturating_sub(w), a);
        let after = change_rate(x, b, (b + w).min(n));
        let p = match (before, after) {
            (Some(p), Some(q)) => p.max(q),
            (Some(p), None) | (None, Some(p)) => p,
            (None, None) => continue,
        };
        if p <= 0.0 {
            continue;
        }
        let log_p = if p >= 1.0 {
            f64::NEG_INFINITY
        } else {
            l as f64 * (1.0 - p).ln()
        };
        // noise alone would have changed it (the channel changes at most rows, by noise larger
        // than its grid); otherwise the other channels must say the quantity moved (a coarse
        // sensor may sit still on a quiet stretch for as long as the quantity does)
        // (white noise has second differences √3 × its first; a smooth signal far smaller)
        let noisy = {
            let around = |lo: usize, hi: usize, order: usize| -> Vec<f64> {
                (lo.max(2)..hi)
                    .map(|k| {
                        if order == 2 {
                            x[k] - 2.0 * x[k - 1] + x[k - 2]
                        } else {
                            x[k] - x[k - 1]
                        }
                    })
                    .collect()
            };
            let both = |order: usize| {
                let mut v = around(a.saturating_sub(w), a, order);
                v.extend(around(b + 2, (b + w).min(n), order));
                v
            };
            let sd2 = robust_scale(&mut both(2)) / 6f64.sqrt();
            let sd1 = robust_scale(&mut both(1)) / std::f64::consts::SQRT_2;
            sd2 > 0.0 && sd2 >= q && sd2 >= 0.5 * sd1
        };
        let frozen = if p >= 0.5 && noisy {
            log_p < FROZEN_LOG_P
        } else {
            log_p < FROZEN_LOG_P && peers_say_moved(x, a, b, peers) == Some(true)
        };
        if frozen {
            out.push((a, b, x[a]));
        }
    }
    out
}

/// Rows pinned at the top or bottom of the column's range: the extreme value repeated far more
/// often than any value inside the range (at least 4 rows, 5× the 99th percentile of how often
/// an inner value repeats).
fn saturated_rows(x: &[f64]) -> Vec<(bool, f64, Vec<usize>)> {
    let n = x.len();
    let mut v: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
    if v.len() < 50 {
        return Vec::new();
    }
    // unstable is the same order: values equal under total_cmp are the same bits
    v.sort_unstable_by(f64::total_cmp);
    let (lo, hi) = (v[0], v[v.len() - 1]);
    if hi <= lo {
        return Vec::new();
    }
    let mut counts: Vec<usize> = Vec::new();
    let mut k = 0;
    while k < v.len() {
        let mut j = k;
        while j < v.len() && v[j] == v[k] {
            j += 1;
        }
        counts.push(j - k);
        k = j;
    }
    if counts.len() < 5 {
        return Vec::new();
    }
    let mut inner: Vec<usize> = counts[1..counts.len() - 1].to_vec();
    inner.sort_unstable();
    let p99 = inner[(inner.len() * 99) / 100].max(1);
    let mut out = Vec::new();
    for (top, value, count) in [(true, hi, counts[counts.len() - 1]), (false, lo, counts[0])] {
        if count >= 4 && count >= 5 * p99 && count * 2 < n {
            let rows: Vec<usize> = (0..n).filter(|&i| x[i] == value).collect();
            out.push((top, value, rows));
        }
    }
    out
}

/// Inspect a recording for data faults and repair what can be repaired.
pub fn inspect(rec: &Recording) -> Result<Inspection, ExplainError> {
    let n = rec.rows();
    let mut faults = Vec::new();
    let mut excluded_all = vec![false; n];
    let mut t = rec
        .time_s()
        .ok_or_else(|| ExplainError::Input("expected a time column `t` (s), found none".into()))?
        .to_vec();
    let signals = judging_signals(rec);
    repair_time(&mut t, &signals, &mut faults, &mut excluded_all)?;

    let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
    let mut excluded_meas: Vec<(String, Vec<bool>)> = Vec::new();
    let mut drop: Vec<String> = Vec::new();
    // missing readings: interpolated; the rows left out (of every fit for a temperature or a
    // command, of the channel's own for a measurement)
    for name in rec.names() {
        if name == "t" {
            continue;
        }
        let mut v = rec.column(name).unwrap_or_default().to_vec();
        let bad: Vec<bool> = v.iter().map(|x| !x.is_finite()).collect();
        let nbad = bad.iter().filter(|b| **b).count();
        if nbad > 0 {
            let role = ColumnRole::of(name);
            if nbad as f64 > MAX_EXCLUDED_SHARE * n as f64 {
                drop.push(name.clone());
                faults.push(DataFault {
                    kind: FaultKind::Missing,
                    column: name.clone(),
                    rows: ranges(&bad),
                    detail: format!("{nbad} of {n} readings missing"),
                    handling: "the column is left out".into(),
                });
                continue;
            }
            interpolate_mask(&mut v, &bad);
            let handling = match role {
                ColumnRole::Meas(_) => {
                    excluded_meas.push((name.clone(), bad.clone()));
                    "the rows left out of this channel's fit"
                }
                _ => {
                    for (e, b) in excluded_all.iter_mut().zip(&bad) {
                        *e |= *b;
                    }
                    "interpolated from the readings around; the rows left out of every fit"
                }
            };
            faults.push(DataFault {
                kind: FaultKind::Missing,
                column: name.clone(),
                rows: ranges(&bad),
                detail: format!("{nbad} reading(s) missing (NaN or infinite)"),
                handling: handling.into(),
            });
        }
        columns.push((name.clone(), v));
    }

    // frozen and saturated channels (a command holds its value on purpose: not judged)
    let judged: Vec<usize> = (0..columns.len())
        .filter(|&j| !matches!(ColumnRole::of(&columns[j].0), ColumnRole::Cmd(_)))
        .collect();
    let mut unusable: Vec<(usize, Vec<bool>)> = Vec::new();
    // each column judged on its own, side by side (a million-row log: seconds of sorting);
    // the faults taken in column order
    let found = super::parallel::in_parallel(&judged, |&j| {
        let x = &columns[j].1;
        let peers: Vec<&[f64]> = (0..columns.len())
            .filter(|&k| k != j)
            .map(|k| columns[k].1.as_slice())
            .collect();
        (frozen_runs(x, &peers), saturated_rows(x))
    });
    for (&j, (frozen, saturated)) in judged.iter().zip(found) {
        let name = &columns[j].0;
        let mut mask = vec![false; n];
        for (a, b, value) in frozen {
            for m in mask[a..b].iter_mut() {
                *m = true;
            }
            faults.push(DataFault {
                kind: FaultKind::Frozen,
                column: name.clone(),
                rows: vec![(a, b)],
                detail: format!(
                    "exactly {value} for {} rows ({}) without any noise, while it changes around that stretch{}",
                    b - a,
                    duration(t[b - 1] - t[a]),
                    if b == n { " — it stopped updating" } else { "" }
                ),
                handling: String::new(),
            });
        }
        for (top, value, rows) in saturated {
            for &i in &rows {
                mask[i] = true;
            }
            let r: Vec<bool> = {
                let mut m = vec![false; n];
                for &i in &rows {
                    m[i] = true;
                }
                m
            };
            faults.push(DataFault {
                kind: FaultKind::Saturated,
                column: name.clone(),
                rows: ranges(&r),
                detail: format!(
                    "{} rows pinned at the {} of its range ({value}), far more often than any value inside it: clipped",
                    rows.len(),
                    if top { "top" } else { "bottom" }
                ),
                handling: String::new(),
            });
        }
        if mask.iter().any(|m| *m) {
            unusable.push((j, mask));
        }
    }
    for (j, mask) in unusable {
        let name = columns[j].0.clone();
        let count = mask.iter().filter(|m| **m).count();
        let role = ColumnRole::of(&name);
        let handling = if count as f64 > MAX_EXCLUDED_SHARE * n as f64
            && !matches!(role, ColumnRole::Meas(_))
        {
            drop.push(name.clone());
            "the channel is left out of the model (unusable for most of the record)".to_string()
        } else {
            match role {
                ColumnRole::Meas(_) => {
                    match excluded_meas.iter_mut().find(|e| e.0 == name) {
                        Some(e) => {
                            for (a, b) in e.1.iter_mut().zip(&mask) {
                                *a |= *b;
                            }
                        }
                        None => excluded_meas.push((name.clone(), mask.clone())),
                    }
                    "those rows left out of this channel's fit".to_string()
                }
                _ => {
                    interpolate_mask(&mut columns[j].1, &mask);
                    for (e, b) in excluded_all.iter_mut().zip(&mask) {
                        *e |= *b;
                    }
                    "those rows left out of every fit (the readings there interpolated)".to_string()
                }
            }
        };
        for f in faults
            .iter_mut()
            .filter(|f| f.column == name && f.handling.is_empty())
        {
            f.handling = handling.clone();
        }
    }

    // a drive that jumps away and back while the measurement does not follow: a glitch of the
    // command, repaired before position terms and play operators see it
    let names: Vec<String> = columns.iter().map(|c| c.0.clone()).collect();
    for name in &names {
        let ColumnRole::Cmd(axis) = ColumnRole::of(name) else {
            continue;
        };
        let Some(mi) = names.iter().position(|m| m == &format!("meas_{axis}")) else {
            continue;
        };
        let ci = names.iter().position(|c| c == name).unwrap_or(0);
        let meas = columns[mi].1.clone();
        let cmd = &columns[ci].1;
        let max_run = (n / 50).clamp(3, 50);
        let cand = glitch_rows(cmd, None, max_run, None);
        let rows: Vec<usize> = cand
            .into_iter()
            .filter(|&i| {
                let before = (0..i).rev().find(|k| !excluded_all[*k]).unwrap_or(0);
                let dc = (cmd[i] - cmd[before]).abs();
                let dm = (meas[i] - meas[before]).abs();
                dm < 0.3 * dc
            })
            .collect();
        if rows.is_empty() {
            continue;
        }
        let mut mask = vec![false; n];
        for &i in &rows {
            mask[i] = true;
        }
        interpolate_mask(&mut columns[ci].1, &mask);
        match excluded_meas.iter_mut().find(|e| e.0 == names[mi]) {
            Some(e) => {
                for (a, b) in e.1.iter_mut().zip(&mask) {
                    *a |= *b;
                }
            }
            None => excluded_meas.push((names[mi].clone(), mask.clone())),
        }
        faults.push(DataFault {
            kind: FaultKind::DriveGlitch,
            column: name.clone(),
            rows: ranges(&mask),
            detail: format!(
                "{} row(s) where the command jumps away and back while `{}` does not follow",
                rows.len(),
                names[mi]
            ),
            handling: "the command interpolated there (position terms and play operators see the repaired drive); the rows left out of the channel's fit".into(),
        });
    }

    // readings held between slower updates: a property of the logging, handled
    for (name, x) in &columns {
        if matches!(ColumnRole::of(name), ColumnRole::Cmd(_)) || drop.contains(name) {
            continue;
        }
        let upd = update_interval_s(&t, x);
        let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        let dt = median(&mut d);
        let changes = (1..n).filter(|&k| x[k] != x[k - 1]).count();
        // held: updated at a regular slower interval, not a quiet quantised reading
        if upd >= 3.0 * dt && changes * 3 > n / (upd / dt).round().max(1.0) as usize {
            faults.push(DataFault {
                kind: FaultKind::SampleAndHold,
                column: name.clone(),
                rows: Vec::new(),
                detail: format!(
                    "updated about every {} ({:.0} rows), held in between",
                    duration(upd),
                    upd / dt
                ),
                handling:
                    "its scatter and the shortest time constant searched are taken over its updates"
                        .into(),
            });
        }
    }

    let kept: Vec<(String, Vec<f64>)> = std::iter::once(("t".to_string(), t))
        .chain(columns.into_iter().filter(|c| !drop.contains(&c.0)))
        .collect();
    let recording = Recording::from_columns(kept).map_err(ExplainError::Recording)?;
    excluded_meas.retain(|e| !drop.contains(&e.0));
    Ok(Inspection {
        recording,
        faults,
        excluded_all,
        excluded_meas,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(cols: Vec<(&str, Vec<f64>)>) -> Recording {
        Recording::from_columns(cols.into_iter().map(|(n, v)| (n.to_string(), v)).collect())
            .unwrap()
    }

    fn noise(i: usize) -> f64 {
        (((i * 7919) % 1009) as f64 / 1009.0 - 0.5) * 0.01
    }

    #[test]
    fn a_clock_jump_is_repaired_and_a_real_gap_is_kept() {
        let n = 2000;
        let room: Vec<f64> = (0..n)
            .map(|i| 20.0 + 0.5 * (i as f64 / 300.0).sin())
            .collect();
        let temp: Vec<f64> = (0..n).map(|i| room[i] + noise(i)).collect();
        let meas: Vec<f64> = (0..n).map(|i| 2.0 * room[i] + noise(i + 7)).collect();
        // the clock jumps an hour ahead at row 1200; the signals carry on
        let t: Vec<f64> = (0..n)
            .map(|i| i as f64 + if i >= 1200 { 3600.0 } else { 0.0 })
            .collect();
        let r = rec(vec![
            ("t", t),
            ("meas_x", meas.clone()),
            ("temp_a", temp.clone()),
        ]);
        let ins = inspect(&r).unwrap();
        let f = ins
            .faults
            .iter()
            .find(|f| f.kind == FaultKind::ClockJump)
            .unwrap_or_else(|| panic!("{:?}", ins.faults));
        assert_eq!(f.rows, vec![(1200, 1201)]);
        let t2 = ins.recording.time_s().unwrap();
        assert!((t2[1200] - t2[1199] - 1.0).abs() < 1e-9);
        // the same time stamps over a real gap: the room moved on by 600 rows' worth
        let t: Vec<f64> = (0..n)
            .map(|i| i as f64 + if i >= 1200 { 600.0 } else { 0.0 })
            .collect();
        let shifted = |v: &[f64]| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    if i >= 1200 {
                        v[(i + 600).min(n - 1)]
                    } else {
                        v[i]
                    }
                })
                .collect()
        };
        let r = rec(vec![
            ("t", t),
            ("meas_x", shifted(&meas)),
            ("temp_a", shifted(&temp)),
        ]);
        let ins = inspect(&r).unwrap();
        assert!(
            ins.faults.iter().any(|f| f.kind == FaultKind::Gap),
            "{:?}",
            ins.faults
        );
        assert!(ins.faults.iter().all(|f| f.kind != FaultKind::ClockJump));
    }

    #[test]
    fn time_that_steps_back_is_continued() {
        let mut t: Vec<f64> = (0..500).map(|i| i as f64).collect();
        for v in t[300..].iter_mut() {
            *v -= 250.0;
        }
        t[100] = 5.0; // one stamp out of order
        let meas: Vec<f64> = (0..500).map(noise).collect();
        let ins = inspect(&rec(vec![("t", t), ("meas_x", meas)])).unwrap();
        let t2 = ins.recording.time_s().unwrap();
        assert!(t2.windows(2).all(|w| w[1] > w[0]));
        let kinds: Vec<(FaultKind, Vec<(usize, usize)>)> = ins
            .faults
            .iter()
            .map(|f| (f.kind, f.rows.clone()))
            .collect();
        assert!(kinds.contains(&(FaultKind::TimeBackwards, vec![(100, 101)])));
        assert!(kinds.contains(&(FaultKind::TimeBackwards, vec![(300, 301)])));
    }

    #[test]
    fn a_frozen_sensor_is_found_and_a_quiet_quantised_one_is_not() {
        let n = 3000;
        let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let room: Vec<f64> = (0..n)
            .map(|i| 20.0 + 0.3 * (i as f64 / 400.0).sin())
            .collect();
        let a: Vec<f64> = (0..n).map(|i| room[i] + noise(i)).collect();
        let mut b: Vec<f64> = (0..n).map(|i| 1.0 + room[i] + noise(i + 3)).collect();
        for v in b[1800..].iter_mut() {
            *v = 21.153;
        }
        // a coarse sensor on a quiet stretch: constant for 800 rows while the others are too
        let quiet: Vec<f64> = (0..n)
            .map(|i| {
                let x = if (1000..1800).contains(&i) {
                    20.0
                } else {
                    20.0 + 0.3 * (i as f64 / 50.0).sin()
                };
                (x / 0.1).round() * 0.1
            })
            .collect();
        let meas: Vec<f64> = (0..n).map(|i| 2.0 * room[i] + noise(i + 5)).collect();
        let ins = inspect(&rec(vec![
            ("t", t),
            ("meas_x", meas),
            ("temp_a", a),
            ("temp_b", b),
            ("temp_q", quiet),
        ]))
        .unwrap();
        let frozen: Vec<&DataFault> = ins
            .faults
            .iter()
            .filter(|f| f.kind == FaultKind::Frozen)
            .collect();
        assert_eq!(frozen.len(), 1, "{:?}", ins.faults);
        assert_eq!(frozen[0].column, "temp_b");
        assert_eq!(frozen[0].rows, vec![(1800, n)]);
        assert!(ins.excluded_all[1800] && !ins.excluded_all[1799]);
    }

    #[test]
    fn clipped_readings_are_found() {
        let n = 1000;
        let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let meas: Vec<f64> = (0..n)
            .map(|i| (5.0 * (i as f64 / 80.0).sin() + noise(i)).min(4.2))
            .collect();
        let ins = inspect(&rec(vec![("t", t), ("meas_x", meas)])).unwrap();
        let f = ins
            .faults
            .iter()
            .find(|f| f.kind == FaultKind::Saturated)
            .unwrap_or_else(|| panic!("{:?}", ins.faults));
        let rows: usize = f.rows.iter().map(|(a, b)| b - a).sum();
        assert!(rows > 50);
        assert!(f.detail.contains("top"));
    }
}
