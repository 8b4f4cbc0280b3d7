//! Residual plots before/after (PNG and SVG through the host's [`crate::report::plot`]).

use std::path::{Path, PathBuf};

use super::data::Data;
use super::report::ChannelReport;
use crate::report::plot::{write_chart, Chart, PlotError, Series, Style};

fn series(name: &str, x: &[f64], r_um: &[f64], style: Style) -> Series {
    let step = (x.len() / 5000).max(1);
    let points = (0..x.len())
        .step_by(step)
        .map(|i| (x[i], r_um[i] * 1e3))
        .collect();
    Series {
        name: name.into(),
        points,
        style,
    }
}

/// Write the residual of channel `c` before and after (held-out) against time, and against
/// position when the axis was commanded, into `dir`; returns the files written.
pub fn write_residual_plots(
    dir: &Path,
    d: &Data,
    c: &ChannelReport,
) -> Result<Vec<PathBuf>, PlotError> {
    let ch = d
        .channels
        .iter()
        .position(|x| x.name == c.channel)
        .unwrap_or(0);
    let unit = d.time_unit();
    let time: Vec<f64> = d.t_s.iter().map(|t| unit.of(t - d.t_s[0])).collect();
    let baseline = c.baseline.split(" (").next().unwrap_or(&c.baseline);
    let before = format!(
        "before: {baseline} ({} RMS held-out)",
        super::units::length_um(c.baseline_rms_nm * 1e-3)
    );
    let after = format!(
        "after: + {} ({} RMS held-out)",
        names(c),
        super::units::length_um(c.final_rms_nm * 1e-3)
    );
    let mut files = write_chart(
        &dir.join(format!("residual_time_{}", c.channel)),
        &Chart {
            title: format!("{}: held-out residual before/after explain", c.channel),
            x_label: format!("time ({})", unit.symbol),
            y_label: "residual (nm)".into(),
            series: vec![
                series(&before, &time, &c.residual_before_um, Style::Line),
                series(&after, &time, &c.residual_after_um, Style::Line),
            ],
        },
    )?;
    if let Some(cmd) = &d.channels[ch].cmd_um {
        files.extend(write_chart(
            &dir.join(format!("residual_position_{}", c.channel)),
            &Chart {
                title: format!("{}: held-out residual vs position", c.channel),
                x_label: "commanded position (µm)".into(),
                y_label: "residual (nm)".into(),
                series: vec![
                    series(&before, cmd, &c.residual_before_um, Style::Points),
                    series(&after, cmd, &c.residual_after_um, Style::Points),
                ],
            },
        )?);
    }
    Ok(files)
}

fn names(c: &ChannelReport) -> String {
    if c.effects.is_empty() {
        "nothing".into()
    } else {
        c.effects
            .iter()
            .map(|e| e.name)
            .collect::<Vec<_>>()
            .join(" + ")
    }
}
