//! Per-dwell samples: the published procedure averages the last seconds of each dwell.
//!
//! A dwell is a maximal run of consecutive rows in which every `cmd_<axis>` column keeps its
//! value. For each dwell, every measured channel (`meas_*`, `temp_*`, auxiliary) is averaged
//! over the rows whose time lies within the last [`DwellOptions::average_last_s`] seconds of the
//! dwell (at least the last row). The direction of approach of each axis is the sign of the last
//! command change on that axis (+1 before the first move, as the digital twin does).

use crate::data::recording::{Recording, RecordingError};

/// Errors of [`dwell_average`] and [`step_average`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DwellError {
    /// A column the procedure needs is missing.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// No `cmd_<axis>` column: dwells cannot be found.
    #[error(
        "expected at least one `cmd_<axis>` column to find the dwells, found none (columns: {0})"
    )]
    NoCommand(String),
    /// Averaging window not positive.
    #[error("averaging window must be > 0 s, found {0}")]
    BadWindow(f64),
    /// A plan step has no rows in the recording.
    #[error("plan step {step} (from t = {t_s} s) has no rows in the recording")]
    EmptyStep {
        /// Index of the step.
        step: usize,
        /// Its start in recording time, s.
        t_s: f64,
    },
    /// A plan step's pose has a different number of axes than the recording.
    #[error("plan step {step} has {found} axes, the recording {expected}")]
    StepAxes {
        /// Index of the step.
        step: usize,
        /// Axes of the recording.
        expected: usize,
        /// Axes of the step.
        found: usize,
    },
}

/// Options of [`dwell_average`].
#[derive(Debug, Clone, Copy)]
pub struct DwellOptions {
    /// Average over the last this many seconds of each dwell.
    pub average_last_s: f64,
    /// Leave out dwells shorter than this (s), e.g. transit poses.
    pub min_dwell_s: f64,
}

impl Default for DwellOptions {
    fn default() -> Self {
        DwellOptions {
            average_last_s: 10.0,
            min_dwell_s: 0.0,
        }
    }
}

/// The per-dwell samples of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Dwells {
    /// Axis names (from the `cmd_` columns, in file order).
    pub axes: Vec<String>,
    /// Time of the last row of each dwell, s.
    pub t_end_s: Vec<f64>,
    /// Time of the first row of each dwell, s.
    pub t_start_s: Vec<f64>,
    /// Commanded position per axis, per dwell, µm.
    pub cmd_um: Vec<Vec<f64>>,
    /// Averaged measured position per axis, per dwell, µm (NaN if the axis has no `meas_`).
    pub meas_um: Vec<Vec<f64>>,
    /// Sample standard deviation of the measurement within the averaging window, µm.
    pub meas_sd_um: Vec<Vec<f64>>,
    /// Direction of approach per axis, per dwell (+1 forward, −1 backward).
    pub dir: Vec<Vec<i8>>,
    /// Averaged other channels (temperatures, aux): (column name, value per dwell).
    pub channels: Vec<(String, Vec<f64>)>,
    /// Rows averaged for each dwell.
    pub rows_averaged: Vec<usize>,
}

impl Dwells {
    /// Number of dwells.
    pub fn len(&self) -> usize {
        self.t_end_s.len()
    }
    /// Whether there are no dwells.
    pub fn is_empty(&self) -> bool {
        self.t_end_s.is_empty()
    }
    /// An averaged channel by column name.
    pub fn channel(&self, name: &str) -> Option<&[f64]> {
        self.channels
            .iter()
            .find(|c| c.0 == name)
            .map(|c| c.1.as_slice())
    }
    /// Keeps only the dwells for which `keep(i)` is true.
    pub fn filter(&self, keep: impl Fn(usize) -> bool) -> Dwells {
        let idx: Vec<usize> = (0..self.len()).filter(|&i| keep(i)).collect();
        let pick = |v: &Vec<f64>| idx.iter().map(|&i| v[i]).collect::<Vec<f64>>();
        Dwells {
            axes: self.axes.clone(),
            t_end_s: pick(&self.t_end_s),
            t_start_s: pick(&self.t_start_s),
            cmd_um: self.cmd_um.iter().map(pick).collect(),
            meas_um: self.meas_um.iter().map(pick).collect(),
            meas_sd_um: self.meas_sd_um.iter().map(pick).collect(),
            dir: self
                .dir
                .iter()
                .map(|d| idx.iter().map(|&i| d[i]).collect())
                .collect(),
            channels: self
                .channels
                .iter()
                .map(|(n, v)| (n.clone(), pick(v)))
                .collect(),
            rows_averaged: idx.iter().map(|&i| self.rows_averaged[i]).collect(),
        }
    }
    /// As a recording in the shared layout: `t` (end of dwell), `cmd_*`, `meas_*`, `dir_*`,
    /// and the averaged channels.
    pub fn to_recording(&self) -> Recording {
        let mut cols = vec![("t".to_string(), self.t_end_s.clone())];
        for (a, name) in self.axes.iter().enumerate() {
            cols.push((format!("cmd_{name}"), self.cmd_um[a].clone()));
            cols.push((format!("meas_{name}"), self.meas_um[a].clone()));
            cols.push((
                format!("dir_{name}"),
                self.dir[a].iter().map(|&d| d as f64).collect(),
            ));
        }
        cols.extend(self.channels.iter().cloned());
        Recording::from_columns(cols).expect("dwell columns have equal lengths and unique names")
    }
}

/// The columns of a recording that dwell averaging reads.
struct Columns<'a> {
    axes: Vec<String>,
    t: std::borrow::Cow<'a, [f64]>,
    cmd: Vec<&'a [f64]>,
    meas: Vec<Option<&'a [f64]>>,
    channel_names: Vec<String>,
    channel_cols: Vec<&'a [f64]>,
}

impl<'a> Columns<'a> {
    fn of(rec: &'a Recording) -> Result<Self, DwellError> {
        let axes: Vec<String> = rec
            .names()
            .iter()
            .filter_map(|n| n.strip_prefix("cmd_").map(str::to_string))
            .collect();
        if axes.is_empty() {
            return Err(DwellError::NoCommand(rec.names().join(", ")));
        }
        let t = match rec.time_s() {
            Some(t) => std::borrow::Cow::Borrowed(t),
            None => std::borrow::Cow::Owned((0..rec.rows()).map(|i| i as f64).collect()),
        };
        let cmd = axes.iter().map(|a| rec.cmd(a).expect("listed")).collect();
        let meas = axes.iter().map(|a| rec.meas(a)).collect();
        let channel_names: Vec<String> = rec
            .names()
            .iter()
            .filter(|n| {
                n.as_str() != "t"
                    && !n.starts_with("cmd_")
                    && !n.starts_with("meas_")
                    && !n.starts_with("dir_")
            })
            .cloned()
            .collect();
        let channel_cols = channel_names
            .iter()
            .map(|c| rec.column(c).expect("listed"))
            .collect();
        Ok(Columns {
            axes,
            t,
            cmd,
            meas,
            channel_names,
            channel_cols,
        })
    }

    fn empty_dwells(&self) -> Dwells {
        let k = self.axes.len();
        Dwells {
            axes: self.axes.clone(),
            t_end_s: Vec::new(),
            t_start_s: Vec::new(),
            cmd_um: vec![Vec::new(); k],
            meas_um: vec![Vec::new(); k],
            meas_sd_um: vec![Vec::new(); k],
            dir: vec![Vec::new(); k],
            channels: self
                .channel_names
                .iter()
                .map(|c| (c.clone(), Vec::new()))
                .collect(),
            rows_averaged: Vec::new(),
        }
    }

    /// Appends the dwell of rows `start..end` (non-empty), averaged over its last
    /// `average_last_s` seconds (at least the last row), approached in direction `dir`.
    fn push(&self, out: &mut Dwells, start: usize, end: usize, average_last_s: f64, dir: &[i8]) {
        let t = &self.t;
        let t_end = t[end - 1];
        let from = (start..end)
            .find(|&i| t[i] > t_end - average_last_s)
            .unwrap_or(end - 1);
        out.t_end_s.push(t_end);
        out.t_start_s.push(t[start]);
        out.rows_averaged.push(end - from);
        for (a, &d) in dir.iter().enumerate().take(self.axes.len()) {
            out.cmd_um[a].push(self.cmd[a][start]);
            out.dir[a].push(d);
            let (m, sd) = match self.meas[a] {
                Some(col) => mean_sd(&col[from..end]),
                None => (f64::NAN, f64::NAN),
            };
            out.meas_um[a].push(m);
            out.meas_sd_um[a].push(sd);
        }
        for (c, col) in self.channel_cols.iter().enumerate() {
            out.channels[c].1.push(mean_sd(&col[from..end]).0);
        }
    }
}

/// Averages the last seconds of each dwell of `rec` (see the module doc). Without a `t`
/// column the row index is the time (1 s per row).
pub fn dwell_average(rec: &Recording, opts: &DwellOptions) -> Result<Dwells, DwellError> {
    if opts.average_last_s.is_nan() || opts.average_last_s <= 0.0 {
        return Err(DwellError::BadWindow(opts.average_last_s));
    }
    let cols = Columns::of(rec)?;
    let n = rec.rows();
    let k = cols.axes.len();
    let mut out = cols.empty_dwells();
    let mut dir = vec![1i8; k];
    let mut last_cmd: Vec<f64> = vec![f64::NAN; k];
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && (0..k).all(|a| same(cols.cmd[a][end], cols.cmd[a][start])) {
            end += 1;
        }
        // rows start..end form one dwell
        for a in 0..k {
            let c = cols.cmd[a][start];
            if last_cmd[a].is_finite() && c != last_cmd[a] {
                dir[a] = if c > last_cmd[a] { 1 } else { -1 };
            }
            last_cmd[a] = c;
        }
        if cols.t[end - 1] - cols.t[start] >= opts.min_dwell_s {
            cols.push(&mut out, start, end, opts.average_last_s, &dir);
        }
        start = end;
    }
    Ok(out)
}

/// Rows this close before a step's start belong to the step (steps start at sums of
/// non-integer durations; rows come on whole sample periods), s. The campaign records its rows
/// by the same edge (`campaign::run`).
pub const STEP_EDGE_S: f64 = 1e-9;

/// One dwell per step of a plan ([`crate::data::plan::Step`]): the rows whose time lies in
/// `[t_start_s, t_end_s)` of the step, shifted by `t_offset_s` (the recording time of the plan's
/// start), averaged over the step's last `average_last_s`, with the step's direction of
/// approach. Steps are kept even when they repeat the previous pose (a turning point is two
/// steps, as the plan counts it); a step without rows is an error.
pub fn step_average(
    rec: &Recording,
    steps: &[crate::data::plan::Step],
    t_offset_s: f64,
) -> Result<Dwells, DwellError> {
    let cols = Columns::of(rec)?;
    let mut out = cols.empty_dwells();
    let t = &cols.t;
    let mut start = 0usize;
    for (i, s) in steps.iter().enumerate() {
        if s.average_last_s.is_nan() || s.average_last_s <= 0.0 {
            return Err(DwellError::BadWindow(s.average_last_s));
        }
        if s.approach.len() != cols.axes.len() {
            return Err(DwellError::StepAxes {
                step: i,
                expected: cols.axes.len(),
                found: s.approach.len(),
            });
        }
        let (t0, t1) = (s.t_start_s + t_offset_s, s.t_end_s() + t_offset_s);
        start += t[start..].partition_point(|&v| v < t0 - STEP_EDGE_S);
        let end = start + t[start..].partition_point(|&v| v < t1 - STEP_EDGE_S);
        if end == start {
            return Err(DwellError::EmptyStep { step: i, t_s: t0 });
        }
        cols.push(&mut out, start, end, s.average_last_s, &s.approach);
        start = end;
    }
    Ok(out)
}

fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

/// Mean and sample standard deviation of the finite values (NaN if none / fewer than two).
fn mean_sd(v: &[f64]) -> (f64, f64) {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = f.iter().sum::<f64>() / f.len() as f64;
    let sd = if f.len() > 1 {
        (f.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (f.len() - 1) as f64).sqrt()
    } else {
        f64::NAN
    };
    (m, sd)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_last_seconds_and_tracks_direction() {
        // 1 Hz, dwells of 5 s at 0, 30, 60, 30; meas settles (creep-like) in each dwell
        let poses = [0.0, 30.0, 60.0, 30.0];
        let mut t = Vec::new();
        let mut cmd = Vec::new();
        let mut meas = Vec::new();
        let mut temp = Vec::new();
        for (d, &p) in poses.iter().enumerate() {
            for s in 0..5 {
                t.push((d * 5 + s) as f64);
                cmd.push(p);
                meas.push(p + if s < 3 { 1.0 } else { 0.1 * s as f64 });
                temp.push(20.0 + d as f64);
            }
        }
        let rec = Recording::from_columns(vec![
            ("t".into(), t),
            ("cmd_x".into(), cmd),
            ("meas_x".into(), meas),
            ("temp_a".into(), temp),
        ])
        .unwrap();
        let d = dwell_average(
            &rec,
            &DwellOptions {
                average_last_s: 2.0,
                min_dwell_s: 0.0,
            },
        )
        .unwrap();
        assert_eq!(d.len(), 4);
        assert_eq!(d.cmd_um[0], poses.to_vec());
        assert_eq!(d.dir[0], vec![1, 1, 1, -1]);
        assert_eq!(d.rows_averaged, vec![2; 4]);
        // last 2 s: s = 3, 4 → offsets 0.3, 0.4
        assert!((d.meas_um[0][1] - 30.35).abs() < 1e-12);
        assert_eq!(d.channel("temp_a").unwrap(), &[20.0, 21.0, 22.0, 23.0]);
        let back = d.to_recording();
        assert_eq!(back.column("dir_x").unwrap(), &[1.0, 1.0, 1.0, -1.0]);
    }

    #[test]
    fn needs_a_command_column() {
        let rec = Recording::from_columns(vec![("meas_x".into(), vec![1.0])]).unwrap();
        assert!(matches!(
            dwell_average(&rec, &DwellOptions::default()),
            Err(DwellError::NoCommand(_))
        ));
    }
}
