//! What explain works on: the response of each measured channel, the commands that drove it,
//! and the slow inputs (temperatures, auxiliary channels), taken from a recording — with what
//! real recordings bring found first: quantised readings, channels held between slower
//! reports, glitches (excluded from fitting and reported with their rows).

use crate::data::recording::Recording;

use super::error::ExplainError;
use super::robust;
use super::stats::centred_mean;
use super::units::TimeUnit;

/// One measured channel (a `meas_<axis>` column) and what drove it.
#[derive(Clone, Debug)]
pub struct Channel {
    /// Axis or channel name (`x`, `ch1`, …).
    pub name: String,
    /// The response to explain, µm: meas − cmd (positioning error), meas − simulation, or meas
    /// itself when the axis stands still and there is no simulation. NaN at outlier rows.
    pub y_um: Vec<f64>,
    /// The reference measurement, µm.
    pub meas_um: Vec<f64>,
    /// A noise-free estimate of the measured position, µm: the measurement minus the baseline
    /// residual once explain has fitted the baseline (the measurement itself before). Effects
    /// that depend on where the stage really is (periodic interferometer error) use it, so the
    /// response's own noise never leaks into a regressor.
    pub position_est_um: Vec<f64>,
    /// The command, µm, when the axis was commanded.
    pub cmd_um: Option<Vec<f64>>,
    /// Scaled command u ∈ [-1, 1] (centre and half range of the commanded travel).
    pub u: Option<Vec<f64>>,
    /// Half of the commanded range, µm (1 when not commanded).
    pub half_range_um: f64,
    /// Direction of the last move (+1/−1) when the axis was commanded and moved both ways.
    pub dir: Option<Vec<f64>>,
    /// Moves: (first sample at the new pose, step in µm).
    pub steps: Vec<(usize, f64)>,
    /// True when the command steps and holds poses (dwells of ≥ 3 samples between moves, or a
    /// log of one row per dwell: few poses, steps of ≥ 2 % of the stroke), as a step-and-settle
    /// procedure does; false for a continuous drive.
    pub has_dwells: bool,
    /// Quantisation step of the measurement, µm, when its readings sit on a grid.
    pub quant_step_um: Option<f64>,
    /// Rows where the measurement changed (false: a held reading repeated).
    pub changed: Vec<bool>,
    /// True when the measurement is held between slower updates (most rows repeat the last
    /// reading and it is not on a coarse grid).
    pub held: bool,
    /// Outlier rows (glitches): excluded from every fit, reported with their rows.
    pub outliers: Vec<usize>,
    /// Largest distance of an outlier from where the response was before it, µm.
    pub outlier_max_um: f64,
}

/// A recording prepared for explain.
#[derive(Clone, Debug)]
pub struct Data {
    /// Time since start, s.
    pub t_s: Vec<f64>,
    /// The measured channels.
    pub channels: Vec<Channel>,
    /// Temperature channels (full column name, °C) as explain's terms see them: the readings,
    /// or — when held-out prediction asks for it — denoised by a zero-phase mean of
    /// ±`smooth_half_window_s` (diagnostic only: it uses later readings). Static and lagged
    /// terms see the same, so only a delay can make a lag fit better.
    pub temps: Vec<(String, Vec<f64>)>,
    /// The temperature readings as recorded, glitches repaired: what a compensator reads.
    pub temps_raw: Vec<(String, Vec<f64>)>,
    /// Half width of the zero-phase mean applied to `temps` and the pressure, s (0: none).
    pub smooth_half_window_s: f64,
    /// Typical time between updates of each temperature channel, s (sample-and-hold logs
    /// update slower than the table's rows).
    pub temp_update_s: Vec<f64>,
    /// Glitches of temperatures and auxiliary channels repaired (column, rows), by
    /// interpolation between the readings around them.
    pub temp_repairs: Vec<(String, Vec<usize>)>,
    /// Median sample period, s.
    pub median_dt_s: f64,
    /// Auxiliary channels (column name, values).
    pub aux: Vec<(String, Vec<f64>)>,
    /// Barometric pressure in hPa, when an auxiliary channel is recognisably a pressure
    /// (denoised like the temperatures).
    pub pressure_hpa: Option<(String, Vec<f64>)>,
    /// The pressure as recorded, hPa.
    pub pressure_raw_hpa: Option<(String, Vec<f64>)>,
    /// True when the response is the difference to a given simulation.
    pub against_simulation: bool,
    /// The sample period when the samples are (nearly) evenly spaced, s.
    pub uniform_dt_s: Option<f64>,
    /// Data faults found before any physics (see [`super::faults`]).
    pub faults: Vec<super::faults::DataFault>,
    /// Columns of `unexplained_drift`'s cosine basis over `t_s`, computed once and shared by
    /// every naming round, channel and denoised copy (they depend on the time stamps alone).
    pub(crate) cosines: CosineCache,
}

/// The cosines cos(πk(t − t₀)/T), k = 1, 2, …, over a recording's time, the first orders kept
/// as they are asked for. Clones share the cache: [`Data::with_smoothing`] keeps `t_s`.
#[derive(Clone, Default)]
pub(crate) struct CosineCache {
    cols: std::sync::Arc<std::sync::Mutex<KeptCosines>>,
}

/// Column k − 1 is order k; (t₀ bits, last t bits, rows) they were computed on.
type KeptCosines = (Vec<std::sync::Arc<Vec<f64>>>, (u64, u64, usize));

impl std::fmt::Debug for CosineCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self.cols.lock().map_or(0, |c| c.0.len());
        write!(f, "CosineCache({n} orders)")
    }
}

impl CosineCache {
    /// Orders 1..=`top` over `t_s`, computing those not yet kept with `column(t_s, order)`
    /// (side by side). `t_s` is checked against what the kept columns were computed on (its
    /// ends and length): a `Data` whose time was changed after preparation starts afresh.
    pub(crate) fn first(
        &self,
        t_s: &[f64],
        top: usize,
        column: impl Fn(&[f64], usize) -> Vec<f64> + Sync,
    ) -> Vec<std::sync::Arc<Vec<f64>>> {
        let key = (
            t_s.first().map_or(0, |t| t.to_bits()),
            t_s.last().map_or(0, |t| t.to_bits()),
            t_s.len(),
        );
        let mut kept = self.cols.lock().unwrap_or_else(|e| e.into_inner());
        if kept.1 != key {
            *kept = (Vec::new(), key);
        }
        if kept.0.len() < top {
            let missing: Vec<usize> = (kept.0.len() + 1..=top).collect();
            let new =
                super::parallel::in_parallel(&missing, |&j| std::sync::Arc::new(column(t_s, j)));
            kept.0.extend(new);
        }
        kept.0[..top].to_vec()
    }
}

/// Most rows a glitch may last to be told from a change of level.
fn max_glitch_run(n: usize) -> usize {
    (n / 50).clamp(3, 50)
}

/// Replace `rows` of `v` by linear interpolation between the readings around them.
fn interpolate_over(v: &mut [f64], rows: &[usize]) {
    let bad: std::collections::HashSet<usize> = rows.iter().copied().collect();
    let n = v.len();
    for &i in rows {
        let prev = (0..i).rev().find(|k| !bad.contains(k));
        let next = (i + 1..n).find(|k| !bad.contains(k));
        v[i] = match (prev, next) {
            (Some(a), Some(b)) => v[a] + (v[b] - v[a]) * (i - a) as f64 / (b - a) as f64,
            (Some(a), None) => v[a],
            (None, Some(b)) => v[b],
            (None, None) => v[i],
        };
    }
}

impl Data {
    /// Prepare a recording (and optionally a simulation of it, row by row).
    pub fn from_recording(rec: &Recording, sim: Option<&Recording>) -> Result<Self, ExplainError> {
        let n = rec.rows();
        if n < 20 {
            return Err(ExplainError::Input(format!(
                "expected at least 20 rows, found {n}"
            )));
        }
        // data faults first: time repaired, missing and frozen readings, clipped channels, a
        // glitching drive — reported, and the rows they spoil left out
        let inspection = super::faults::inspect(rec)?;
        let rec = &inspection.recording;
        let t_s = rec
            .time_s()
            .ok_or_else(|| {
                ExplainError::Input("expected a time column `t` (s), found none".into())
            })?
            .to_vec();
        if let Some(s) = sim {
            if s.rows() != n {
                return Err(ExplainError::Input(format!(
                    "simulation has {} rows, the recording {n}: expected the same rows",
                    s.rows()
                )));
            }
        }
        let mut channels = Vec::new();
        for axis in rec.axes() {
            let Some(meas) = rec.meas(&axis) else {
                continue;
            };
            let meas_um = meas.to_vec();
            let cmd_um = rec.cmd(&axis).map(|c| c.to_vec());
            let mut y_um: Vec<f64> = match (sim, &cmd_um) {
                (Some(s), _) => {
                    let sm = s.meas(&axis).ok_or_else(|| {
                        ExplainError::Input(format!(
                            "simulation: expected column `meas_{axis}`, found none"
                        ))
                    })?;
                    meas_um.iter().zip(sm).map(|(a, b)| a - b).collect()
                }
                (None, Some(c)) => meas_um.iter().zip(c).map(|(m, c)| m - c).collect(),
                (None, None) => meas_um.clone(),
            };
            let (mut u, mut half_range_um, mut dir, mut steps) = (None, 1.0, None, Vec::new());
            if let Some(c) = &cmd_um {
                let lo = c.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = c.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                if hi > lo {
                    let centre = 0.5 * (lo + hi);
                    half_range_um = 0.5 * (hi - lo);
                    u = Some(
                        c.iter()
                            .map(|v| (v - centre) / half_range_um)
                            .collect::<Vec<f64>>(),
                    );
                    let tol = 1e-9 * half_range_um.max(1.0);
                    let mut d = vec![0.0; n];
                    let mut cur = 0.0;
                    let (mut fwd, mut bwd) = (false, false);
                    for k in 0..n {
                        if k > 0 {
                            let dq = c[k] - c[k - 1];
                            if dq.abs() > tol {
                                cur = dq.signum();
                                steps.push((k, dq));
                                fwd |= dq > 0.0;
                                bwd |= dq < 0.0;
                            }
                        }
                        d[k] = cur;
                    }
                    // before the first move the direction is unknown: take the first move's
                    if let Some(first) = d.iter().copied().find(|&v| v != 0.0) {
                        for v in d.iter_mut() {
                            if *v == 0.0 {
                                *v = first;
                            } else {
                                break;
                            }
                        }
                    }
                    if fwd && bwd {
                        dir = Some(d);
                    }
                }
            }
            // step and hold: the command holds poses for several samples between moves, or
            // (a log of one row per dwell) jumps between few poses by sizeable steps; a
            // continuous drive moves by a little at every sample
            let has_dwells = steps.len() >= 3 && {
                let mut lens: Vec<f64> = std::iter::once(0)
                    .chain(steps.iter().map(|s| s.0))
                    .chain(std::iter::once(n))
                    .collect::<Vec<usize>>()
                    .windows(2)
                    .map(|w| (w[1] - w[0]) as f64)
                    .collect();
                let mut sizes: Vec<f64> = steps.iter().map(|s| s.1.abs()).collect();
                let poses = cmd_um.as_ref().map_or(0, |c| {
                    let mut v: Vec<i64> = c.iter().map(|x| (x * 1e6).round() as i64).collect();
                    v.sort_unstable();
                    v.dedup();
                    v.len()
                });
                super::stats::median(&mut lens) >= 3.0
                    || (3 * poses <= n
                        && super::stats::median(&mut sizes) >= 0.02 * 2.0 * half_range_um)
            };
            let quant_step_um = robust::quantisation_step(&meas_um);
            let changed = robust::changed(&meas_um);
            let repeats = changed.iter().filter(|c| !**c).count();
            let held = quant_step_um.is_none() && repeats * 2 > n;
            let moved: Option<Vec<bool>> = has_dwells.then(|| {
                let mut m = vec![false; n];
                for s in &steps {
                    m[s.0] = true;
                }
                m
            });
            let outliers =
                robust::glitch_rows(&y_um, quant_step_um, max_glitch_run(n), moved.as_deref());
            let mut outlier_max_um = 0.0f64;
            for &i in &outliers {
                let before = (0..i).rev().find(|k| !outliers.contains(k));
                if let Some(b) = before {
                    outlier_max_um = outlier_max_um.max((y_um[i] - y_um[b]).abs());
                }
            }
            for &i in &outliers {
                y_um[i] = f64::NAN;
            }
            let own = inspection
                .excluded_meas
                .iter()
                .find(|e| e.0 == format!("meas_{axis}"))
                .map(|e| e.1.as_slice());
            for (i, y) in y_um.iter_mut().enumerate() {
                if inspection.excluded_all[i] || own.is_some_and(|m| m[i]) {
                    *y = f64::NAN;
                }
            }
            let position_est_um = meas_um.clone();
            channels.push(Channel {
                name: axis,
                y_um,
                meas_um,
                position_est_um,
                cmd_um,
                u,
                half_range_um,
                dir,
                steps,
                has_dwells,
                quant_step_um,
                changed,
                held,
                outliers,
                outlier_max_um,
            });
        }
        if channels.is_empty() {
            return Err(ExplainError::Input(
                "expected at least one `meas_<axis>` column, found none".into(),
            ));
        }
        let mut temps: Vec<(String, Vec<f64>)> = rec
            .temp_columns()
            .iter()
            .map(|&c| (c.to_string(), rec.column(c).unwrap_or_default().to_vec()))
            .collect();
        let mut temp_repairs = Vec::new();
        // each sensor on its own, side by side (a million-row log: seconds of sorting); the
        // repairs taken in column order
        let glitches = super::parallel::in_parallel(&temps, |(_, v)| {
            let q = robust::quantisation_step(v);
            robust::glitch_rows(v, q, max_glitch_run(n), None)
        });
        for ((name, v), bad) in temps.iter_mut().zip(glitches) {
            if !bad.is_empty() {
                interpolate_over(v, &bad);
                temp_repairs.push((name.clone(), bad));
            }
        }
        let temp_update_s =
            super::parallel::in_parallel(&temps, |(_, v)| robust::update_interval_s(&t_s, v));
        let mut aux: Vec<(String, Vec<f64>)> = rec
            .aux_columns()
            .iter()
            .map(|&c| (c.to_string(), rec.column(c).unwrap_or_default().to_vec()))
            .collect();
        // glitches of an auxiliary channel (a drive voltage, a pressure) repaired the same way
        for (name, v) in aux.iter_mut() {
            let q = robust::quantisation_step(v);
            let bad = robust::glitch_rows(v, q, max_glitch_run(n), None);
            if !bad.is_empty() {
                interpolate_over(v, &bad);
                temp_repairs.push((name.clone(), bad));
            }
        }
        let pressure_hpa: Option<(String, Vec<f64>)> = aux.iter().find_map(|(name, v)| {
            let l = name.to_ascii_lowercase();
            if !(l.contains("press")
                || l.ends_with("_hpa")
                || l.ends_with("_pa")
                || l.ends_with("_mbar")
                || l == "p")
            {
                return None;
            }
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let scale = if l.ends_with("_pa") || mean > 20_000.0 {
                0.01
            } else {
                1.0
            };
            Some((
                name.clone(),
                v.iter().map(|x| x * scale).collect::<Vec<f64>>(),
            ))
        });
        let dts: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
        // the order statistic alone (the same element a full sort puts there)
        let mut sorted = dts.clone();
        let mid = sorted.len() / 2;
        let med = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
        let uniform_dt_s = (med > 0.0
            && dts.iter().all(|d| (d - med).abs() <= 1e-6 * med.max(1.0)))
        .then_some(med);
        Ok(Self {
            t_s,
            channels,
            temps: temps.clone(),
            temps_raw: temps,
            temp_update_s,
            temp_repairs,
            smooth_half_window_s: 0.0,
            median_dt_s: med,
            aux,
            pressure_hpa: pressure_hpa.clone(),
            pressure_raw_hpa: pressure_hpa,
            against_simulation: sim.is_some(),
            uniform_dt_s,
            faults: inspection.faults,
            cosines: CosineCache::default(),
        })
    }

    /// The same data with the temperatures and the pressure denoised by a zero-phase mean of
    /// ±`half_window_s` (diagnostic: every term explain fits sees them).
    pub fn with_smoothing(&self, half_window_s: f64) -> Data {
        let half = self.smoothing_half_rows(half_window_s);
        let mut d = self.clone();
        d.temps = self.smoothed_temps(half_window_s);
        d.pressure_hpa = self
            .pressure_raw_hpa
            .as_ref()
            .map(|(c, v)| (c.clone(), centred_mean(v, half)));
        d.smooth_half_window_s = if half == 0 { 0.0 } else { half_window_s };
        d
    }

    /// Half width in rows of the zero-phase mean of ±`half_window_s` (0: none).
    fn smoothing_half_rows(&self, half_window_s: f64) -> usize {
        if self.median_dt_s > 0.0 {
            ((half_window_s / self.median_dt_s).round() as usize).min(self.rows() / 50)
        } else {
            0
        }
    }

    /// The temperatures [`Data::with_smoothing`] gives `temps` for ±`half_window_s`, alone.
    pub fn smoothed_temps(&self, half_window_s: f64) -> Vec<(String, Vec<f64>)> {
        let half = self.smoothing_half_rows(half_window_s);
        self.temps_raw
            .iter()
            .map(|(c, v)| (c.clone(), centred_mean(v, half)))
            .collect()
    }

    /// Number of samples.
    pub fn rows(&self) -> usize {
        self.t_s.len()
    }

    /// Duration, s.
    pub fn duration_s(&self) -> f64 {
        self.t_s.last().copied().unwrap_or(0.0) - self.t_s.first().copied().unwrap_or(0.0)
    }

    /// The unit of time that fits this record.
    pub fn time_unit(&self) -> TimeUnit {
        TimeUnit::for_span(self.duration_s())
    }

    /// The shortest time constant the record can resolve for temperature `i`, s: two sample
    /// intervals, and no less than the interval at which the sensor is reported or the
    /// width of the diagnostic denoising.
    pub fn shortest_lag_s(&self, i: usize) -> f64 {
        (2.0 * self.median_dt_s)
            .max(self.temp_update_s.get(i).copied().unwrap_or(0.0))
            .max(self.smooth_half_window_s)
    }
}
