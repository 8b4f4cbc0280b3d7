//! Locate: where a residual is structured — time spans, positions, direction, other axes,
//! temperature rate, auxiliary channels — against a noise floor estimated from the data.

use super::data::Data;
use super::fit::noise_floor;
use super::stats::median;

/// A place where the residual is larger than its noise allows.
#[derive(Clone, Debug, PartialEq)]
pub struct Finding {
    /// What the place is, in words (`time 3.0–5.5 h`, `position 450–480 µm backward`, …).
    pub place: String,
    /// Which dimension (`time`, `position`, `direction`, `temperature rate`, an aux name, …).
    pub dimension: String,
    /// RMS of the residual there, nm.
    pub rms_nm: f64,
    /// Mean of the residual there, nm.
    pub mean_nm: f64,
    /// Largest |bin mean| / its noise standard error.
    pub z: f64,
}

/// The noise a residual would have with nothing left to explain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseFloor {
    /// High-frequency (sample-to-sample) scatter, µm.
    pub sample_um: f64,
    /// Scatter of independent units (dwell means for commanded axes, samples otherwise), µm.
    pub unit_um: f64,
}

/// Segments between moves (dwells) of a commanded channel, or single samples.
fn units(d: &Data, ch: usize) -> Vec<(usize, usize)> {
    let c = &d.channels[ch];
    if c.steps.is_empty() {
        return (0..d.rows()).map(|i| (i, i + 1)).collect();
    }
    let mut b: Vec<usize> = vec![0];
    b.extend(c.steps.iter().map(|s| s.0));
    b.push(d.rows());
    b.windows(2)
        .filter(|w| w[1] > w[0])
        .map(|w| (w[0], w[1]))
        .collect()
}

/// Effective number of independent positioning events (dwells weighted by their length:
/// (Σ len)² / Σ len², so one long rest counts once, not as many rows) of a commanded channel,
/// or rows.
pub fn unit_count(d: &Data, ch: usize) -> usize {
    let us = units(d, ch);
    let s1: f64 = us.iter().map(|(a, b)| (b - a) as f64).sum();
    let s2: f64 = us.iter().map(|(a, b)| ((b - a) as f64).powi(2)).sum();
    if s2 > 0.0 {
        (s1 * s1 / s2).round() as usize
    } else {
        us.len()
    }
}

/// Estimate the noise floor of residual `r` on channel `ch`: the robust sample-to-sample
/// scatter (over the rows where a held measurement was updated), never below the
/// quantisation's step/√12 (the RMS of rounding to a grid).
pub fn noise(d: &Data, ch: usize, r: &[f64]) -> NoiseFloor {
    let c = &d.channels[ch];
    let changed = c.held.then_some(c.changed.as_slice());
    let quant = c.quant_step_um.map_or(0.0, |q| q / 12f64.sqrt());
    let sample_um = noise_floor(r, changed).max(quant);
    let us = units(d, ch);
    if us.len() == d.rows() {
        return NoiseFloor {
            sample_um,
            unit_um: sample_um,
        };
    }
    // dwell means: scatter of consecutive dwell means (robust), minus nothing: an upper bound of
    // the per-move positioning scatter plus averaged sample noise
    let means: Vec<f64> = us
        .iter()
        .map(|&(a, b)| unit_mean(r, a, b))
        .filter(|v| v.is_finite())
        .collect();
    let unit_um = if means.len() >= 4 {
        noise_floor(&means, None)
    } else {
        sample_um
    };
    NoiseFloor {
        sample_um,
        unit_um: unit_um.max(sample_um / 10.0),
    }
}

fn unit_mean(r: &[f64], a: usize, b: usize) -> f64 {
    let (s, c) = r[a..b]
        .iter()
        .filter(|x| x.is_finite())
        .fold((0.0, 0), |(s, c), x| (s + x, c + 1));
    if c == 0 {
        f64::NAN
    } else {
        s / c as f64
    }
}

/// Bins of a key over the rows: (label, row indices).
type Bins = Vec<(String, Vec<usize>)>;

fn quantile_bins(key: &[f64], k: usize, fmt: impl Fn(f64, f64) -> String) -> Bins {
    let mut idx: Vec<usize> = (0..key.len()).filter(|&i| key[i].is_finite()).collect();
    idx.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
    let n = idx.len();
    if n < k * 5 {
        return Vec::new();
    }
    let mut out: Bins = Vec::new();
    for b in 0..k {
        let s = &idx[b * n / k..(b + 1) * n / k];
        let label = fmt(key[s[0]], key[s[s.len() - 1]]);
        // quantiles of a channel that often sits at one value (rpm = 0) give equal labels: merge
        match out.last_mut() {
            Some(last) if last.0 == label => last.1.extend_from_slice(s),
            _ => out.push((label, s.to_vec())),
        }
    }
    out
}

fn value_bins(key: &[f64], max_bins: usize, fmt: impl Fn(f64) -> String) -> Option<Bins> {
    let mut vals: Vec<i64> = key.iter().map(|v| (v * 1e3).round() as i64).collect();
    vals.sort_unstable();
    vals.dedup();
    if vals.len() > max_bins || vals.len() < 2 {
        return None;
    }
    // one pass over the rows: each row's value found among the sorted distinct ones
    let mut rows: Vec<Vec<usize>> = vec![Vec::new(); vals.len()];
    for (i, v) in key.iter().enumerate() {
        if let Ok(b) = vals.binary_search(&((v * 1e3).round() as i64)) {
            rows[b].push(i);
        }
    }
    Some(
        vals.iter()
            .zip(rows)
            .map(|(&v, rows)| (fmt(v as f64 / 1e3), rows))
            .collect(),
    )
}

/// Rate of the mean temperature, °C/h, smoothed over ~10 minutes.
fn temperature_rate(d: &Data) -> Option<Vec<f64>> {
    if d.temps.is_empty() {
        return None;
    }
    let n = d.rows();
    let m = d.temps.len() as f64;
    let tm: Vec<f64> = (0..n)
        .map(|k| d.temps.iter().map(|(_, x)| x[k]).sum::<f64>() / m)
        .collect();
    let dt = d.duration_s() / n.max(2) as f64;
    let h = ((300.0 / dt.max(1e-9)).round() as usize).clamp(1, n / 4);
    Some(
        (0..n)
            .map(|k| {
                let (a, b) = (k.saturating_sub(h), (k + h).min(n - 1));
                if b > a {
                    (tm[b] - tm[a]) / (d.t_s[b] - d.t_s[a]) * 3600.0
                } else {
                    0.0
                }
            })
            .collect(),
    )
}

/// Find where residual `r` (µm) of channel `ch` is structured beyond the noise floor.
pub fn locate(d: &Data, ch: usize, r: &[f64], floor: NoiseFloor) -> Vec<Finding> {
    Places::of(d, ch).locate(r, floor)
}

/// A bin of one dimension: its label, its rows, and the effective number of independent
/// units among them (each unit weighted by its rows in the bin).
struct Bin {
    label: String,
    rows: Vec<usize>,
    n_units: f64,
}

/// The places [`locate`] looks at for one channel of one recording — every dimension's bins
/// with their rows and units. They depend on the recording alone, not on the residual, so a
/// channel's explain builds them once for its locate before naming and after (on a million
/// rows: a sort and two dozen passes over the rows each time).
pub struct Places {
    dims: Vec<(String, Vec<Bin>)>,
}

impl Places {
    /// The places of channel `ch` of `d`.
    pub fn of(d: &Data, ch: usize) -> Self {
        let c = &d.channels[ch];
        let us = units(d, ch);
        // unit index of each row, for counting independent units per bin
        let mut unit_of = vec![0usize; d.rows()];
        for (j, &(a, b)) in us.iter().enumerate() {
            for u in unit_of[a..b].iter_mut() {
                *u = j;
            }
        }
        let mut dims: Vec<(String, Bins)> = Vec::new();
        let unit = d.time_unit();
        let span = unit.of(d.duration_s());
        let t0 = d.t_s[0];
        let nb = (d.rows() / 200).clamp(4, 24);
        let time_key: Vec<f64> = d.t_s.iter().map(|t| unit.of(t - t0)).collect();
        let tb: Bins = (0..nb)
            .map(|b| {
                let (lo, hi) = (
                    span * b as f64 / nb as f64,
                    span * (b + 1) as f64 / nb as f64,
                );
                let rows = (0..d.rows())
                    .filter(|&i| time_key[i] >= lo && (time_key[i] < hi || b == nb - 1))
                    .collect();
                (format!("time {lo:.1}–{hi:.1} {}", unit.symbol), rows)
            })
            .collect();
        dims.push(("time".into(), tb));
        if let Some(cmd) = &c.cmd_um {
            let pb = value_bins(cmd, 40, |v| format!("position {v:.1} µm")).unwrap_or_else(|| {
                quantile_bins(cmd, 10, |a, b| format!("position {a:.1}–{b:.1} µm"))
            });
            dims.push(("position".into(), pb));
        }
        if let Some(dir) = &c.dir {
            let fwd = (0..d.rows()).filter(|&i| dir[i] > 0.0).collect();
            let bwd = (0..d.rows()).filter(|&i| dir[i] < 0.0).collect();
            dims.push((
                "direction".into(),
                vec![
                    ("forward approach".into(), fwd),
                    ("backward approach".into(), bwd),
                ],
            ));
        }
        for (b, other) in d.channels.iter().enumerate() {
            if b != ch {
                if let Some(cmd) = &other.cmd_um {
                    let name = other.name.clone();
                    let bins = value_bins(cmd, 40, |v| format!("{name} axis at {v:.1} µm"))
                        .unwrap_or_else(|| {
                            quantile_bins(cmd, 8, |a, z| format!("{name} axis at {a:.1}–{z:.1} µm"))
                        });
                    dims.push((format!("axis {}", other.name), bins));
                }
            }
        }
        if let Some(rate) = temperature_rate(d) {
            dims.push((
                "temperature rate".into(),
                quantile_bins(&rate, 5, |a, b| {
                    format!("temperature changing {a:+.3}…{b:+.3} °C/h")
                }),
            ));
        }
        for (name, x) in &d.aux {
            let n = name.clone();
            let bins = value_bins(x, 8, |v| format!("{n} = {v}")).unwrap_or_else(|| {
                quantile_bins(x, 5, |a, b| {
                    if a == b {
                        format!("{n} = {a}")
                    } else {
                        format!("{n} {a}…{b}")
                    }
                })
            });
            dims.push((name.clone(), bins));
        }

        // rows per unit within a bin (reset after each bin)
        let mut counts = vec![0u64; us.len().max(1)];
        let dims = dims
            .into_iter()
            .map(|(dim, bins)| {
                let bins = bins
                    .into_iter()
                    .map(|(label, rows)| {
                        // effective number of units in the bin, each weighted by its rows in the
                        // bin (sums of whole numbers far below 2⁵³: exact in any order)
                        for &i in &rows {
                            counts[unit_of[i]] += 1;
                        }
                        let (mut s1, mut s2) = (0.0f64, 0.0f64);
                        for &i in &rows {
                            let c = std::mem::take(&mut counts[unit_of[i]]);
                            if c > 0 {
                                s1 += c as f64;
                                s2 += (c * c) as f64;
                            }
                        }
                        let n_units = if s2 > 0.0 {
                            (s1 * s1 / s2).max(1.0)
                        } else {
                            1.0
                        };
                        Bin {
                            label,
                            rows,
                            n_units,
                        }
                    })
                    .collect();
                (dim, bins)
            })
            .collect();
        Places { dims }
    }

    /// Where residual `r` (µm) of the channel is structured beyond the noise floor.
    pub fn locate(&self, r: &[f64], floor: NoiseFloor) -> Vec<Finding> {
        let sigma = floor.unit_um.max(1e-12);
        let mut out = Vec::new();
        for (dim, bins) in &self.dims {
            let mut flagged: Vec<(String, f64, f64, f64)> = Vec::new();
            for Bin {
                label,
                rows,
                n_units,
            } in bins
            {
                let n_units = *n_units;
                let vals: Vec<f64> = rows
                    .iter()
                    .map(|&i| r[i])
                    .filter(|v| v.is_finite())
                    .collect();
                if vals.len() < 3 {
                    continue;
                }
                let mean = vals.iter().sum::<f64>() / vals.len() as f64;
                let z = mean.abs() / (sigma / n_units.sqrt());
                // structured: statistically clear AND at least the size of the noise floor
                if z > 5.0 && mean.abs() > sigma.max(floor.sample_um) {
                    let rms = (vals.iter().map(|v| v * v).sum::<f64>() / vals.len() as f64).sqrt();
                    flagged.push((label.clone(), rms, mean, z));
                }
            }
            if flagged.is_empty() {
                continue;
            }
            // merge consecutive time spans into one place
            if dim == "time" && flagged.len() > 1 {
                let lo = flagged[0].0.clone();
                let hi = flagged[flagged.len() - 1].0.clone();
                let rms =
                    (flagged.iter().map(|f| f.1 * f.1).sum::<f64>() / flagged.len() as f64).sqrt();
                let mut means: Vec<f64> = flagged.iter().map(|f| f.2).collect();
                let zmax = flagged.iter().map(|f| f.3).fold(0.0, f64::max);
                let place = if flagged.len() == bins.len() {
                    "in every time span of the recording".to_string()
                } else {
                    format!(
                        "{} time spans between {} and {}",
                        flagged.len(),
                        lo.split(' ')
                            .nth(1)
                            .unwrap_or("")
                            .split('–')
                            .next()
                            .unwrap_or(""),
                        hi.split('–').nth(1).unwrap_or("")
                    )
                };
                out.push(Finding {
                    place,
                    dimension: dim.clone(),
                    rms_nm: rms * 1e3,
                    mean_nm: median(&mut means) * 1e3,
                    z: zmax,
                });
            } else {
                for (label, rms, mean, z) in flagged.into_iter().take(4) {
                    out.push(Finding {
                        place: label,
                        dimension: dim.clone(),
                        rms_nm: rms * 1e3,
                        mean_nm: mean * 1e3,
                        z,
                    });
                }
            }
        }
        out
    }
}
