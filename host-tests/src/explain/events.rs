//! Events: a residual that steps once and stays (a mount that slipped, a part re-seated, a
//! collision) is located sharply — its row, its size and how well both are known — and
//! reported as an event to check, never handed to a drift.
//!
//! The search runs on independent units (dwell means of a step-and-settle procedure, samples
//! otherwise, merged into at most [`MAX_SCAN_UNITS`] blocks): at every boundary and at several
//! scales, a line fitted on each side is extrapolated to the boundary and the two compared
//! (slow drift cancels, an abrupt change does not). The clearest boundary must be abrupt — in a
//! short window around it a line with a step explains far more than any smooth cubic — and
//! must not coincide with a step of any recorded input (then that input's response explains
//! it), before the row is pinned down on the samples.

use super::data::Data;
use super::locate::NoiseFloor;
use super::stats::median;

/// Most units the scan runs over (longer series are merged into blocks first).
pub const MAX_SCAN_UNITS: usize = 5000;
/// Scales of the scan, in units on each side of a boundary.
const SCALES: [usize; 4] = [4, 12, 36, 108];
/// A step's local evidence over a smooth cubic, in noise variances (Δχ²).
const MIN_ABRUPT_CHI2: f64 = 30.0;

/// A located step of the residual.
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    /// First row (0-based) at the new level.
    pub row: usize,
    /// Rows (0-based, inclusive) the step may have happened at: where the local misfit rises by
    /// less than one noise variance.
    pub row_range: (usize, usize),
    /// Time of the row, s since start.
    pub t_s: f64,
    /// Size of the step (after − before) from the local fit, µm.
    pub size_um: f64,
    /// Its 1σ from the local fit, µm.
    pub size_sigma_um: f64,
    /// The scan's z at the boundary.
    pub z: f64,
    /// The evidence of the whole record's fit with the step in it, in words.
    pub evidence: String,
}

/// Unit series of residual `r`: (first row, end row, mean) per unit with a finite mean.
fn unit_series(d: &Data, ch: usize, r: &[f64]) -> Vec<(usize, usize, f64)> {
    let c = &d.channels[ch];
    let n = d.rows();
    let mut bounds: Vec<usize> = vec![0];
    if c.has_dwells {
        bounds.extend(c.steps.iter().map(|s| s.0));
    } else {
        let block = n.div_ceil(MAX_SCAN_UNITS).max(1);
        bounds.extend((1..n.div_ceil(block)).map(|k| k * block));
    }
    bounds.push(n);
    bounds.dedup();
    let mut out = Vec::new();
    for w in bounds.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b <= a {
            continue;
        }
        let (s, k) = r[a..b]
            .iter()
            .filter(|v| v.is_finite())
            .fold((0.0, 0usize), |(s, k), v| (s + v, k + 1));
        if k > 0 {
            out.push((a, b, s / k as f64));
        }
    }
    // too many dwells for the scan: merge neighbours
    if out.len() > MAX_SCAN_UNITS {
        let g = out.len().div_ceil(MAX_SCAN_UNITS);
        out = out
            .chunks(g)
            .map(|c| {
                let m = c.iter().map(|u| u.2).sum::<f64>() / c.len() as f64;
                (c[0].0, c[c.len() - 1].1, m)
            })
            .collect();
    }
    out
}

/// Least-squares line through (k, y_k), k = 0..len, evaluated at `at`.
fn line_at(y: &[f64], at: f64) -> f64 {
    let n = y.len() as f64;
    let mx = (n - 1.0) / 2.0;
    let my = y.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (k, v) in y.iter().enumerate() {
        sxy += (k as f64 - mx) * (v - my);
        sxx += (k as f64 - mx).powi(2);
    }
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    my + slope * (at - mx)
}

/// Jump at boundary `j` of series `m`: a line through the `w` units after it minus a line
/// through the `w` units before it, both at the boundary.
fn jump(m: &[f64], j: usize, w: usize) -> f64 {
    line_at(&m[j..j + w], -0.5) - line_at(&m[j - w..j], w as f64 - 0.5)
}

/// The jump of input `x` (on the scan's units) at boundary `j` (scale `w`, the largest within two
/// units of it) when it is one the input rarely makes: beyond 3 robust standard deviations of
/// its jumps at all boundaries.
fn input_steps(x: &[f64], j: usize, w: usize) -> Option<f64> {
    let n = x.len();
    if j < w || j + w > n {
        return None;
    }
    let mut all: Vec<f64> = (w..=n - w)
        .step_by((n / 2000).max(1))
        .map(|k| jump(x, k, w))
        .collect();
    let med = median(&mut all.clone());
    let mut dev: Vec<f64> = all.iter_mut().map(|v| (*v - med).abs()).collect();
    let sd = 1.4826 * median(&mut dev);
    let here = (j.saturating_sub(2)..=(j + 2).min(n - w))
        .filter(|&k| k >= w)
        .map(|k| jump(x, k, w) - med)
        .fold(0.0f64, |a, v| if v.abs() > a.abs() { v } else { a });
    (sd > 0.0 && here.abs() > 3.0 * sd).then_some(here)
}

/// RSS of least squares of `y` on the columns `x` (with an intercept).
fn rss_of(x: &[&[f64]], y: &[f64]) -> Option<(f64, Vec<f64>, Vec<f64>)> {
    let ls = crate::numerics::linalg::lstsq(x, y, true).ok()?;
    let se = ls.std_errors();
    Some((ls.rss, ls.coeffs, se))
}

/// The window [j − w, j + w) of units: how much a step at j explains beyond a smooth cubic
/// (the RSS drop, in noise variances), and what the step model leaves (in noise variances).
fn abrupt_chi2(m: &[f64], j: usize, w: usize, sigma: f64) -> Option<(f64, f64)> {
    let (a, b) = (j.saturating_sub(w), (j + w).min(m.len()));
    if j - a < 3 || b - j < 3 {
        return None;
    }
    let y = &m[a..b];
    let k: Vec<f64> = (a..b).map(|i| (i as f64 - j as f64) / w as f64).collect();
    let step: Vec<f64> = (a..b).map(|i| f64::from(u8::from(i >= j))).collect();
    let k2: Vec<f64> = k.iter().map(|v| v * v).collect();
    let k3: Vec<f64> = k.iter().map(|v| v * v * v).collect();
    let (rss_step, _, _) = rss_of(&[&k, &k2, &step], y)?;
    let (rss_smooth, _, _) = rss_of(&[&k, &k2, &k3], y)?;
    let s2 = sigma * sigma;
    Some(((rss_smooth - rss_step) / s2, rss_step / s2))
}

/// Find the clearest abrupt step of residual `r` on channel `ch`, if any (the residual's
/// structure in position and direction is taken out first by the caller); `temp_gains` are the
/// baseline's static gains of the temperatures, µm/°C.
pub fn find_step(
    d: &Data,
    ch: usize,
    r: &[f64],
    floor: &NoiseFloor,
    temp_gains: &[f64],
) -> Option<Event> {
    let units = unit_series(d, ch, r);
    let m: Vec<f64> = units.iter().map(|u| u.2).collect();
    let nu = m.len();
    if nu < 24 {
        return None;
    }
    // the units' own scatter (first differences, robust): the scan's noise
    let sigma = {
        let mut dd: Vec<f64> = m.windows(2).map(|w| w[1] - w[0]).collect();
        let med = median(&mut dd.clone());
        let mut dev: Vec<f64> = dd.iter_mut().map(|x| (*x - med).abs()).collect();
        1.4826 * median(&mut dev) / std::f64::consts::SQRT_2
    }
    .max(floor.sample_um / (d.rows() as f64 / nu as f64).sqrt())
    .max(1e-12);
    let scales: Vec<usize> = SCALES.iter().copied().filter(|&w| 4 * w <= nu).collect();
    let z_min = (2.0 * ((nu * scales.len().max(1)) as f64).ln()).sqrt() + 3.5;
    // the temperatures on the same units: a step of the response that coincides with a step of
    // a temperature big enough (through its static gain) to make it is that temperature's doing
    // (the structure lags what the sensor saw at once), not a slip
    let inputs: Vec<(Vec<f64>, f64)> = d
        .temps
        .iter()
        .zip(temp_gains)
        .map(|((_, x), &g)| {
            (
                units
                    .iter()
                    .map(|u| x[u.0..u.1].iter().sum::<f64>() / (u.1 - u.0) as f64)
                    .collect(),
                g,
            )
        })
        .collect();
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for &w in &scales {
        // a line fitted to w units on each side, extrapolated to the boundary; for a line
        // through w equally spaced points the variance at the end is σ²(4w − 2)/(w(w + 1))
        let se = sigma * (2.0 * (4.0 * w as f64 - 2.0) / (w as f64 * (w as f64 + 1.0))).sqrt();
        for j in w..=nu - w {
            let z = jump(&m, j, w).abs() / se;
            if z > z_min {
                candidates.push((z, j, w));
            }
        }
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best: Option<(f64, usize, usize)> = None;
    let mut tried: Vec<usize> = Vec::new();
    for &(z, j, w) in candidates.iter() {
        if tried.len() >= 20 {
            break;
        }
        if tried.iter().any(|&t| t.abs_diff(j) <= w) {
            continue;
        }
        tried.push(j);
        // abrupt: in a short window around it (±8 or ±24 units) a line with a step explains far
        // more than any smooth cubic — at least as much as is left around it, which other
        // structure may make large
        let abrupt = SCALES[..2].iter().any(|&v| {
            abrupt_chi2(&m, j, 2 * v, sigma)
                .is_some_and(|(gain, rss_step)| gain >= MIN_ABRUPT_CHI2 && gain >= rss_step)
        });
        if !abrupt {
            continue;
        }
        let own = jump(&m, j, SCALES[0]);
        if inputs.iter().any(|(x, g)| {
            SCALES
                .iter()
                .filter(|&&v| v <= w)
                .any(|&v| input_steps(x, j, v).is_some_and(|s| (g * s).abs() >= 0.25 * own.abs()))
        }) {
            continue;
        }
        best = Some((z, j, w));
        break;
    }
    let (z, j, w) = best?;
    // pin the row down on the samples: a line with a step, moved over the rows of the units
    // around the boundary
    let lo_row = units[j.saturating_sub(1)].0;
    let hi_row = units[(j + 1).min(nu - 1)].1;
    let (win_a, win_b) = (
        units[j.saturating_sub(2 * w)].0,
        units[(j + 2 * w).min(nu) - 1].1,
    );
    let rows: Vec<usize> = (win_a..win_b).filter(|&i| r[i].is_finite()).collect();
    if rows.len() < 8 {
        return None;
    }
    let t0 = d.t_s[rows[0]];
    let span = (d.t_s[rows[rows.len() - 1]] - t0).max(1e-12);
    let tk: Vec<f64> = rows.iter().map(|&i| (d.t_s[i] - t0) / span).collect();
    let tk2: Vec<f64> = tk.iter().map(|v| v * v).collect();
    let y: Vec<f64> = rows.iter().map(|&i| r[i]).collect();
    let mut fits: Vec<(usize, f64, f64, f64)> = Vec::new();
    let stride = ((hi_row - lo_row) / 400).max(1);
    for k in (lo_row..=hi_row).step_by(stride) {
        let step: Vec<f64> = rows.iter().map(|&i| f64::from(u8::from(i >= k))).collect();
        if step.iter().all(|v| *v == step[0]) {
            continue;
        }
        if let Some((rss, c, se)) = rss_of(&[&tk, &tk2, &step], &y) {
            fits.push((k, rss, c[2], se[2]));
        }
    }
    let best_fit = fits.iter().min_by(|a, b| a.1.total_cmp(&b.1)).copied()?;
    let s2 = floor.sample_um.max(1e-12).powi(2);
    let near: Vec<usize> = fits
        .iter()
        .filter(|f| f.1 - best_fit.1 <= s2)
        .map(|f| f.0)
        .collect();
    let (rlo, rhi) = (
        near.iter().copied().min().unwrap_or(best_fit.0),
        near.iter().copied().max().unwrap_or(best_fit.0),
    );
    Some(Event {
        row: best_fit.0,
        row_range: (rlo, rhi),
        t_s: d.t_s[best_fit.0] - d.t_s[0],
        size_um: best_fit.2,
        size_sigma_um: best_fit.3,
        z,
        evidence: String::new(),
    })
}

/// The column of an event: 0 before its row, 1 from it on.
pub fn step_column(n: usize, row: usize) -> Vec<f64> {
    (0..n).map(|i| f64::from(u8::from(i >= row))).collect()
}

/// Residual `r` with what depends on the commanded state taken out — a mean per (pose,
/// direction) group for a step-and-settle procedure, a cubic in position per direction for a
/// continuous drive — so that hysteresis and geometry (which flip or change at every move) are
/// not mistaken for a step; a slip shifts every pose after it and survives.
pub fn without_pose_structure(d: &Data, ch: usize, r: &[f64]) -> Vec<f64> {
    let c = &d.channels[ch];
    let (Some(u), Some(cmd)) = (&c.u, &c.cmd_um) else {
        return r.to_vec();
    };
    let dir = c.dir.as_ref();
    let n = r.len();
    if c.has_dwells {
        let key = |i: usize| {
            (
                (cmd[i] * 1e6).round() as i64,
                dir.map_or(0, |dv| dv[i] as i64),
            )
        };
        let mut groups: std::collections::HashMap<(i64, i64), (f64, usize)> =
            std::collections::HashMap::new();
        for i in (0..n).filter(|&i| r[i].is_finite()) {
            let e = groups.entry(key(i)).or_insert((0.0, 0));
            e.0 += r[i];
            e.1 += 1;
        }
        if groups.len() <= 400 && groups.len() * 4 <= n {
            return (0..n)
                .map(|i| {
                    let (s, k) = groups[&key(i)];
                    r[i] - s / k.max(1) as f64
                })
                .collect();
        }
    }
    let mut cols: Vec<Vec<f64>> = (1..=3)
        .map(|p| u.iter().map(|x| x.powi(p)).collect())
        .collect();
    if let Some(dv) = dir {
        for p in 0..=2 {
            cols.push(u.iter().zip(dv).map(|(x, s)| s * x.powi(p)).collect());
        }
    }
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    match crate::numerics::linalg::lstsq(&refs, r, true) {
        Ok(ls) => (0..n)
            .map(|i| {
                if r[i].is_finite() {
                    r[i] - super::fit::predict(&ls, &refs, i)
                } else {
                    f64::NAN
                }
            })
            .collect(),
        Err(_) => r.to_vec(),
    }
}
