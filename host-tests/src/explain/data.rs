//! What explain works on: the response of each measured channel, the commands that drove it,
//! and the slow inputs (temperatures, auxiliary channels), taken from a recording.

use crate::recording::Recording;

use super::ExplainError;

/// One measured channel (a `meas_<axis>` column) and what drove it.
#[derive(Clone, Debug)]
pub struct Channel {
    /// Axis or channel name (`x`, `ch1`, …).
    pub name: String,
    /// The response to explain, µm: meas − cmd (positioning error), meas − simulation, or meas
    /// itself when the axis stands still and there is no simulation.
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
}

/// A recording prepared for explain.
#[derive(Clone, Debug)]
pub struct Data {
    /// Time since start, s.
    pub t_s: Vec<f64>,
    /// The measured channels.
    pub channels: Vec<Channel>,
    /// Temperature channels (full column name, °C), denoised without delay (centred moving
    /// average of ±`smooth_half_window_s`).
    pub temps: Vec<(String, Vec<f64>)>,
    /// The temperature readings as recorded.
    pub temps_raw: Vec<(String, Vec<f64>)>,
    /// Half width of the centred mean applied to `temps` and the pressure, s.
    pub smooth_half_window_s: f64,
    /// Median sample period, s.
    pub median_dt_s: f64,
    /// Auxiliary channels (column name, values).
    pub aux: Vec<(String, Vec<f64>)>,
    /// Barometric pressure in hPa, when an auxiliary channel is recognisably a pressure.
    pub pressure_hpa: Option<(String, Vec<f64>)>,
    /// True when the response is the difference to a given simulation.
    pub against_simulation: bool,
    /// The sample period when the samples are (nearly) evenly spaced, s.
    pub uniform_dt_s: Option<f64>,
}

/// Half width of the centred (delay-free) moving average applied to temperatures and pressure, s.
pub const SMOOTH_HALF_WINDOW_S: f64 = 60.0;

/// Centred moving average over ±`half` samples (shrinking at the ends); NaN-free input assumed.
pub fn centred_mean(x: &[f64], half: usize) -> Vec<f64> {
    if half == 0 {
        return x.to_vec();
    }
    let n = x.len();
    let mut pre = vec![0.0; n + 1];
    for i in 0..n {
        pre[i + 1] = pre[i] + x[i];
    }
    (0..n)
        .map(|i| {
            let h = half.min(i).min(n - 1 - i);
            let (a, b) = (i - h, i + h + 1);
            (pre[b] - pre[a]) / (b - a) as f64
        })
        .collect()
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
        let t_s = rec
            .time_s()
            .ok_or_else(|| {
                ExplainError::Input("expected a time column `t` (s), found none".into())
            })?
            .to_vec();
        for name in rec.names() {
            if let Some(i) = rec
                .column(name)
                .and_then(|c| c.iter().position(|v| !v.is_finite()))
            {
                return Err(ExplainError::Input(format!(
                    "column `{name}`, data row {}: expected a finite number, found {}",
                    i + 1,
                    rec.column(name).map_or(f64::NAN, |c| c[i])
                )));
            }
        }
        if let Some(i) = t_s.windows(2).position(|w| w[1] <= w[0]) {
            return Err(ExplainError::Input(format!(
                "column `t`, data row {}: expected time to increase, found {} after {}",
                i + 2,
                t_s[i + 1],
                t_s[i]
            )));
        }
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
            let y_um: Vec<f64> = match (sim, &cmd_um) {
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
            });
        }
        if channels.is_empty() {
            return Err(ExplainError::Input(
                "expected at least one `meas_<axis>` column, found none".into(),
            ));
        }
        let temps: Vec<(String, Vec<f64>)> = rec
            .temp_columns()
            .iter()
            .map(|&c| (c.to_string(), rec.column(c).unwrap_or_default().to_vec()))
            .collect();
        let aux: Vec<(String, Vec<f64>)> = rec
            .aux_columns()
            .iter()
            .map(|&c| (c.to_string(), rec.column(c).unwrap_or_default().to_vec()))
            .collect();
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
        let mut sorted = dts.clone();
        sorted.sort_by(f64::total_cmp);
        let med = sorted[sorted.len() / 2];
        let uniform_dt_s = (med > 0.0
            && dts.iter().all(|d| (d - med).abs() <= 1e-6 * med.max(1.0)))
        .then_some(med);
        // Sensor noise in a regressor would let any low-pass (a short "lag") look like physics:
        // denoise the slow inputs without delay (centred moving average) before anything is fitted.
        let half = if med > 0.0 {
            ((SMOOTH_HALF_WINDOW_S / med).round() as usize).min(n / 50)
        } else {
            0
        };
        let temps_raw = temps;
        let temps = temps_raw
            .iter()
            .map(|(c, v)| (c.clone(), centred_mean(v, half)))
            .collect();
        let pressure_hpa = pressure_hpa.map(|(c, v)| (c, centred_mean(&v, half)));
        Ok(Self {
            t_s,
            channels,
            temps,
            temps_raw,
            smooth_half_window_s: SMOOTH_HALF_WINDOW_S,
            median_dt_s: med,
            aux,
            pressure_hpa,
            against_simulation: sim.is_some(),
            uniform_dt_s,
        })
    }

    /// The same data with the temperatures denoised by a centred mean of ±`half_window_s`.
    pub fn with_smoothing(&self, half_window_s: f64) -> Data {
        let half = if self.median_dt_s > 0.0 {
            ((half_window_s / self.median_dt_s).round() as usize).min(self.rows() / 50)
        } else {
            0
        };
        let mut d = self.clone();
        d.temps = self
            .temps_raw
            .iter()
            .map(|(c, v)| (c.clone(), centred_mean(v, half)))
            .collect();
        d.smooth_half_window_s = half_window_s;
        d
    }

    /// Number of samples.
    pub fn rows(&self) -> usize {
        self.t_s.len()
    }

    /// Duration, s.
    pub fn duration_s(&self) -> f64 {
        self.t_s.last().copied().unwrap_or(0.0) - self.t_s.first().copied().unwrap_or(0.0)
    }
}
