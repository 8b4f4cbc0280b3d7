//! The digital twin standing on the virtual bench: the stage behind the simulated controller,
//! the room its temperature sensors sit in, and what the interferometer reads — for commands the
//! firmware actually sends, which the plan does not know in advance.
//!
//! The twin ([`crate::twin::Twin`]) simulates a whole command trajectory at once (its effects
//! are written over whole series: thermal lags, drifts that switch on and off, creep). On the
//! bench the commands arrive one at a time, corrected by the firmware. So the stage's position
//! is computed in two parts, both by the twin's own code:
//!
//! - the **plan's trajectory**, simulated once (the plan's targets as commands, with every
//!   effect, the room, the positioning scatter of each move and the interferometer's noise);
//! - the **difference the actual command makes**: the twin simulated at that instant for the
//!   actual command and for the plan's, with no noise, and subtracted. Everything that depends
//!   on the command at that instant — geometry, the thermal change of the stroke, coupling,
//!   refraction — is thereby the twin's exactly; what depends on the history of commands (the
//!   direction of approach, each move's scatter, creep) follows the plan's moves. The firmware's
//!   corrections are a few µm on moves of tens to hundreds: they never reverse a move.
//!
//! Temperatures for the sensor chips are the twin's true spot temperatures (no reading noise: the
//! chips add their own), interpolated between samples; the barometer reads the room's pressure.

use crate::twin::{room, Columns, Dwell, Trajectory, Twin, AXIS_NAMES};

/// Plan time before the plan's first step that the bench also simulates (the stage rests at the
/// first pose: boot, configuration, upload and the sensors' first conversions happen here), s.
pub const PRE_ROLL_S: f64 = 120.0;

/// The twin on the bench.
pub struct TwinStage {
    axes: usize,
    /// Twin absolute time of plan time 0, s.
    start_abs_s: f64,
    period_s: f64,
    /// Plan time of the nominal run's first sample.
    first_s: f64,
    nominal: Columns,
    /// Nominal segments: (start, end, command) in plan time.
    segments: Vec<(f64, f64, Vec<f64>)>,
    /// Noise-free twin for the local differences.
    exact: Twin,
    resolution_um: f64,
    /// Commands the stage received: (plan time, command).
    commands: Vec<(f64, Vec<f64>)>,
    /// Cached difference per (command index, nominal segment index).
    delta: std::collections::HashMap<(usize, usize), Vec<f64>>,
    sensors: Vec<String>,
}

impl TwinStage {
    /// The twin `twin` playing `traj` (the plan's schedule as dwells, starting at plan time 0 at
    /// the twin's absolute time `start_abs_s`), sampled every `twin.cfg.sample_period_s`;
    /// `stream` separates the noise of runs.
    pub fn new(twin: &Twin, traj: &Trajectory, start_abs_s: f64, stream: u64) -> Self {
        let axes = twin.cfg.axes;
        let first = traj
            .dwells
            .first()
            .map(|d| d.cmd_um.clone())
            .unwrap_or(vec![0.0; axes]);
        let mut nominal_traj = Trajectory {
            dwells: vec![Dwell {
                cmd_um: first,
                dwell_s: PRE_ROLL_S,
            }],
        };
        nominal_traj.dwells.extend(traj.dwells.iter().cloned());
        // after the plan the stage rests where it ended (reports, a safe pose)
        let last = nominal_traj.dwells.last().map(|d| d.cmd_um.clone());
        if let Some(last) = last {
            nominal_traj.dwells.push(Dwell {
                cmd_um: last,
                dwell_s: 3600.0,
            });
        }
        let mut truth = twin.clone();
        for s in truth.cfg.sensors.iter_mut() {
            // the spots' true temperatures (the same random draws happen, multiplied by 0)
            s.noise_c = 0.0;
            s.resolution_c = 0.0;
        }
        truth.cfg.record_pressure = true;
        truth.cfg.pressure_noise_hpa = 0.0;
        let nominal = truth.simulate(&nominal_traj, start_abs_s - PRE_ROLL_S, stream);
        let mut segments = Vec::with_capacity(nominal_traj.dwells.len());
        let mut t = -PRE_ROLL_S;
        for d in &nominal_traj.dwells {
            segments.push((t, t + d.dwell_s, d.cmd_um.clone()));
            t += d.dwell_s;
        }
        let mut exact = twin.clone();
        exact.cfg.interferometer_noise_nm = 0.0;
        exact.cfg.interferometer_resolution_nm = 0.0;
        exact.cfg.positioning_sigma_nm = 0.0;
        exact.cfg.sample_period_s = twin.cfg.sample_period_s;
        let sensors = twin
            .cfg
            .sensors
            .iter()
            .filter(|s| s.recorded)
            .map(|s| s.name.clone())
            .collect();
        Self {
            axes,
            start_abs_s,
            period_s: twin.cfg.sample_period_s,
            first_s: -PRE_ROLL_S,
            nominal,
            segments,
            exact,
            resolution_um: twin.cfg.interferometer_resolution_nm * 1e-3,
            commands: Vec::new(),
            delta: Default::default(),
            sensors,
        }
    }

    /// The interferometer's sample period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Names of the sensed spots (the sensor chips, in chip-select order).
    pub fn sensors(&self) -> &[String] {
        &self.sensors
    }

    /// Plan time of the last sample the twin has, s.
    pub fn end_s(&self) -> f64 {
        self.first_s + (self.nominal.rows().saturating_sub(1)) as f64 * self.period_s
    }

    /// The stage received `cmd_um` at plan time `t_s` (commands arrive in time order).
    pub fn command(&mut self, t_s: f64, cmd_um: Vec<f64>) {
        assert_eq!(cmd_um.len(), self.axes);
        if self.commands.last().is_some_and(|(_, c)| *c == cmd_um) {
            return;
        }
        self.commands.push((t_s, cmd_um));
    }

    /// Commands the stage received so far.
    pub fn commands(&self) -> &[(f64, Vec<f64>)] {
        &self.commands
    }

    fn segment_at(&self, t_s: f64) -> usize {
        let i = self.segments.partition_point(|s| s.0 <= t_s);
        i.saturating_sub(1)
    }

    fn row_at(&self, t_s: f64) -> f64 {
        (t_s - self.first_s) / self.period_s
    }

    fn column(&self, name: &str) -> &[f64] {
        self.nominal.get(name).unwrap_or(&[])
    }

    /// Linear interpolation of a nominal column at plan time `t_s` (clamped to the run).
    fn interp(&self, name: &str, t_s: f64) -> f64 {
        let c = self.column(name);
        if c.is_empty() {
            return f64::NAN;
        }
        let x = self.row_at(t_s).clamp(0.0, (c.len() - 1) as f64);
        let i = x.floor() as usize;
        let f = x - i as f64;
        if i + 1 < c.len() {
            c[i] + f * (c[i + 1] - c[i])
        } else {
            c[i]
        }
    }

    /// The noise-free twin's reading at `t_s` for command `cmd_um`.
    fn exact_at(&self, t_s: f64, cmd_um: &[f64]) -> Vec<f64> {
        let traj = Trajectory {
            dwells: vec![Dwell {
                cmd_um: cmd_um.to_vec(),
                dwell_s: self.period_s,
            }],
        };
        let run = self.exact.simulate(&traj, self.start_abs_s + t_s, 0);
        (0..self.axes)
            .map(|a| {
                run.get(&format!("meas_{}", AXIS_NAMES[a]))
                    .map_or(f64::NAN, |c| c[0])
            })
            .collect()
    }

    /// What the interferometer reads at plan time `t_s` (a sample time: the first sample plus
    /// a whole number of periods), µm per axis.
    pub fn measure(&mut self, t_s: f64) -> Vec<f64> {
        let k = self.row_at(t_s).round().max(0.0) as usize;
        let seg = self.segment_at(t_s);
        let ci = self.commands.partition_point(|c| c.0 <= t_s);
        let nominal: Vec<f64> = (0..self.axes)
            .map(|a| {
                self.column(&format!("meas_{}", AXIS_NAMES[a]))
                    .get(k)
                    .copied()
                    .unwrap_or(f64::NAN)
            })
            .collect();
        let Some(cmd_index) = ci.checked_sub(1) else {
            return nominal; // nothing commanded yet: the stage rests where the plan starts it
        };
        let planned = self.segments[seg].2.clone();
        let actual = self.commands[cmd_index].1.clone();
        if actual == planned {
            return nominal;
        }
        let key = (cmd_index, seg);
        if !self.delta.contains_key(&key) {
            // evaluated where the command met this segment
            let at = self.commands[cmd_index].0.max(self.segments[seg].0);
            let a = self.exact_at(at, &actual);
            let p = self.exact_at(at, &planned);
            self.delta
                .insert(key, a.iter().zip(&p).map(|(x, y)| x - y).collect());
        }
        let d = &self.delta[&key];
        nominal
            .iter()
            .zip(d)
            .map(|(n, d)| room::quantize(n + d, self.resolution_um))
            .collect()
    }

    /// True temperature of sensed spot `sensor` at plan time `t_s`, °C.
    pub fn spot_c(&self, sensor: usize, t_s: f64) -> f64 {
        match self.sensors.get(sensor) {
            Some(name) => self.interp(&format!("temp_{name}"), t_s),
            None => f64::NAN,
        }
    }

    /// Barometric pressure at plan time `t_s`, hPa.
    pub fn pressure_hpa(&self, t_s: f64) -> f64 {
        self.interp("pressure", t_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::twin::examples::published_1dof_twin;

    #[test]
    fn the_plans_commands_give_the_twins_own_run_and_others_its_exact_difference() {
        let twin = published_1dof_twin(3);
        let traj = Trajectory::forward_backward(&[0.0, 240.0, 480.0], 22.0, 1, 0.0);
        let mut st = TwinStage::new(&twin, &traj, 8.0 * 3600.0, 1);
        let t = 30.0; // in the second dwell (240 µm)
        let plain = st.measure(t);
        // the plan's own command changes nothing
        st.command(22.0, vec![240.0]);
        assert_eq!(st.measure(t), plain);
        // 3 µm more: the stage goes 3 µm further, plus what the twin's geometry makes of it
        st.command(22.5, vec![243.0]);
        let moved = st.measure(t);
        let d = moved[0] - plain[0];
        assert!((d - 3.0).abs() < 0.01, "{d}");
        let exact = st.exact_at(22.5, &[243.0])[0] - st.exact_at(22.5, &[240.0])[0];
        assert!((d - exact).abs() < 0.0004, "{d} vs {exact}");
        // temperatures and pressure are the room's, whatever was commanded
        assert!(st.spot_c(0, t).is_finite() && st.pressure_hpa(t) > 900.0);
        assert!(st.spot_c(9, t).is_nan());
    }
}
