//! The plots a person looks at after a validation: error vs position (forward and backward),
//! drift vs temperature, accuracy per pose in the first test (paper 000 Fig. 11), error over
//! time, and every test's accuracy over time (Fig. 12) for each compensation.

use std::path::{Path, PathBuf};

use crate::plot::{write_chart, Chart, PlotError, Series, Style};
use crate::validate::ValidationReport;

fn nm(v: f64) -> f64 {
    v * 1e3
}

/// Signed error (1-D) or error distance (n-D) of a visit, nm.
fn err_nm(v: &crate::validate::Visit) -> f64 {
    if v.error_um.len() == 1 {
        nm(v.error_um[0])
    } else {
        nm(v.error_um.iter().map(|e| e * e).sum::<f64>().sqrt())
    }
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
        r.visits.iter().filter(|v| v.counted()).cloned().collect()
    };

    // 1. error vs position, forward and backward, per compensation
    let mut series = Vec::new();
    for r in reports {
        for (label, sign) in [("forward", 1i8), ("backward", -1i8)] {
            let pts = counted(r)
                .iter()
                .filter(|v| v.dir.first().is_some_and(|d| d.signum() == sign))
                .map(|v| (v.target_um[0], err_nm(v)))
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
            x_label: "target position (µm; first axis for n-D)".into(),
            y_label: "error (nm; distance for n-D)".into(),
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
                .map(|v| (v.mean_temp_c, err_nm(v)))
                .collect(),
            style: Style::Points,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("drift_vs_temperature"),
        &Chart {
            title: "Error vs mean sensor temperature".into(),
            x_label: "mean temperature (°C)".into(),
            y_label: "error (nm; distance for n-D)".into(),
            series,
        },
    )?);

    // 3. accuracy per pose in each compensation's first test (paper 000 Fig. 11)
    let mut series = Vec::new();
    for r in reports {
        let Some(first) = r.tests.first() else {
            continue;
        };
        for (label, sign) in [("forward", 1i8), ("backward", -1i8)] {
            series.push(Series {
                name: format!("{} {label}", r.compensation.name()),
                points: first
                    .poses
                    .iter()
                    .filter(|p| p.approach.first().is_some_and(|d| d.signum() == sign))
                    .map(|p| (p.target_um[0], nm(p.accuracy_um)))
                    .collect(),
                style: Style::LinePoints,
            });
        }
    }
    files.extend(write_chart(
        &dir.join("accuracy_per_pose"),
        &Chart {
            title: "ISO 9283 accuracy per pose, first test of each compensation".into(),
            x_label: "target position (µm; first axis for n-D)".into(),
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
                .map(|v| ((v.t_s - t0) / 3600.0, err_nm(v)))
                .collect(),
            style: Style::Points,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("error_over_time"),
        &Chart {
            title: "Error over time".into(),
            x_label: "time since start of validation (h)".into(),
            y_label: "error (nm; distance for n-D)".into(),
            series,
        },
    )?);

    // 5. every test's accuracy (max over its poses) over time (paper 000 Fig. 12)
    let series = reports
        .iter()
        .map(|r| Series {
            name: r.compensation.name().into(),
            points: r
                .tests
                .iter()
                .map(|t| {
                    (
                        (0.5 * (t.t_start_s + t.t_end_s) - t0) / 3600.0,
                        nm(t.accuracy_um),
                    )
                })
                .collect(),
            style: Style::LinePoints,
        })
        .collect();
    files.extend(write_chart(
        &dir.join("test_accuracy_over_time"),
        &Chart {
            title: "Accuracy of each test (max over its poses) over time".into(),
            x_label: "time since start of validation (h)".into(),
            y_label: "test accuracy (nm)".into(),
            series,
        },
    )?);
    Ok(files)
}
