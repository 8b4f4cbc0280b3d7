//! The plots a person looks at after a validation: error vs position (forward and backward),
//! drift vs temperature, accuracy per pose and error over time for each compensation.

use std::path::{Path, PathBuf};

use crate::plot::{write_chart, Chart, PlotError, Series, Style};
use crate::validate::ValidationReport;

fn nm(v: f64) -> f64 {
    v * 1e3
}

/// Writes the report plots for `reports` (e.g. no model, static, adaptive) into `dir`
/// (created if needed); returns the files written.
pub fn write_report(dir: &Path, reports: &[&ValidationReport]) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Backend {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut files = Vec::new();
    let counted = |r: &ValidationReport| -> Vec<crate::validate::Visit> {
        r.visits
            .iter()
            .filter(|v| !v.kmz_reference)
            .cloned()
            .collect()
    };

    // 1. error vs position, forward and backward, per compensation
    let mut series = Vec::new();
    for r in reports {
        for (label, sign) in [("forward", 1i8), ("backward", -1i8)] {
            let pts = counted(r)
                .iter()
                .filter(|v| v.dir.first().is_some_and(|d| d.signum() == sign))
                .map(|v| (v.target_um[0], nm(v.error_um[0])))
                .collect();
            series.push(Series {
                name: format!("{} {label}", r.compensation.name()),
                points: pts,
                style: Style::Points,
            });
        }
    }
    files.extend(write_chart(
        &dir.join("error_vs_position"),
        &Chart {
            title: "Positioning error vs target (validation visits)".into(),
            x_label: "target position (µm)".into(),
            y_label: "error (nm)".into(),
            series,
        },
    )?);

    // 2. drift vs temperature (mean of the temp_* sensors), per compensation
    let series = reports
        .iter()
        .map(|r| Series {
            name: r.compensation.name().into(),
            points: counted(r)
                .iter()
                .map(|v| (v.mean_temp_c, nm(v.error_um[0])))
                .collect(),
            style: Style::Points,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("drift_vs_temperature"),
        &Chart {
            title: "Error vs mean sensor temperature".into(),
            x_label: "mean temperature (°C)".into(),
            y_label: "error (nm)".into(),
            series,
        },
    )?);

    // 3. accuracy per pose
    let series = reports
        .iter()
        .map(|r| Series {
            name: r.compensation.name().into(),
            points: r
                .poses
                .iter()
                .map(|p| (p.target_um[0], nm(p.accuracy_um)))
                .collect(),
            style: Style::LinePoints,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("accuracy_per_pose"),
        &Chart {
            title: "ISO 9283 accuracy per pose".into(),
            x_label: "target position (µm)".into(),
            y_label: "accuracy (nm)".into(),
            series,
        },
    )?);

    // 4. error over time
    let t0 = reports
        .iter()
        .flat_map(|r| r.visits.first())
        .map(|v| v.t_s)
        .fold(f64::INFINITY, f64::min);
    let series = reports
        .iter()
        .map(|r| Series {
            name: r.compensation.name().into(),
            points: counted(r)
                .iter()
                .map(|v| ((v.t_s - t0) / 3600.0, nm(v.error_um[0])))
                .collect(),
            style: Style::Points,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("error_over_time"),
        &Chart {
            title: "Error over time".into(),
            x_label: "time since start of validation (h)".into(),
            y_label: "error (nm)".into(),
            series,
        },
    )?);
    Ok(files)
}
