//! The plots a person looks at after a validation: error vs position (forward and backward),
//! drift vs temperature, accuracy per pose in the first test (paper 000 Fig. 11), error over
//! time, and every test's accuracy over time (Fig. 12) for each compensation.

pub mod html_report;
pub mod plot;

use std::path::{Path, PathBuf};

use crate::report::plot::{write_chart, Chart, PlotError, Series, Style};
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
    // 6. 2-DoF and more: each pose in x–y with its barycentre offset and repeatability circle
    if reports.iter().any(|r| {
        r.tests
            .iter()
            .any(|t| t.poses.iter().any(|p| p.target_um.len() >= 2))
    }) {
        files.extend(write_pose_figures(dir, reports)?);
    }
    Ok(files)
}

/// A 1-2-5 number at or below `v`.
fn nice_floor(v: f64) -> f64 {
    if !(v > 0.0 && v.is_finite()) {
        return 1.0;
    }
    let e = 10f64.powf(v.log10().floor());
    let m = v / e;
    let f = if m >= 5.0 {
        5.0
    } else if m >= 2.0 {
        2.0
    } else {
        1.0
    };
    f * e
}

/// ISO 9283 pose figures for a stage with two or more axes, one per compensation (first test,
/// first two axes): every pose at its commanded x–y, an arrow to its barycentre with the offset
/// (AP vector) scaled by a common factor, and around the barycentre the repeatability circle
/// of radius RP on the same scale. The factor (a 1-2-5 number, in the title and legend) is
/// chosen per compensation so that its largest offset + circle fills about half the pose
/// spacing — a compensated stage's nanometres and an uncompensated one's micrometres both show;
/// the plot range is padded to the canvas's aspect (≈ 1.8 : 1) so the circles stay round.
pub fn write_pose_figures(
    dir: &Path,
    reports: &[&ValidationReport],
) -> Result<Vec<PathBuf>, PlotError> {
    let firsts: Vec<(&ValidationReport, &crate::validate::iso9283::TestStats)> = reports
        .iter()
        .filter_map(|r| r.tests.first().map(|t| (*r, t)))
        .collect();
    let poses = || {
        firsts
            .iter()
            .flat_map(|(_, t)| t.poses.iter())
            .filter(|p| p.target_um.len() >= 2 && p.mean_error_um.len() >= 2)
    };
    // spacing of the poses and the largest offset + circle decide the scale
    let targets: Vec<(f64, f64)> = poses().map(|p| (p.target_um[0], p.target_um[1])).collect();
    let mut spacing = f64::INFINITY;
    for (i, a) in targets.iter().enumerate() {
        for b in &targets[i + 1..] {
            let d = ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
            if d > 1e-9 {
                spacing = spacing.min(d);
            }
        }
    }
    if !spacing.is_finite() {
        spacing = 1.0;
    }
    let (xs, ys): (Vec<f64>, Vec<f64>) = targets.iter().copied().unzip();
    let span = |v: &[f64]| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    };
    let ((xl, xh), (yl, yh)) = (span(&xs), span(&ys));
    let pad = 0.6 * spacing;
    let (mut x0, mut x1, mut y0, mut y1) = (xl - pad, xh + pad, yl - pad, yh + pad);
    // equal scale on both axes: the plot area is about 1.8 times wider than high
    let aspect = 1.8;
    let (w, h) = (x1 - x0, y1 - y0);
    if w < aspect * h {
        let grow = 0.5 * (aspect * h - w);
        x0 -= grow;
        x1 += grow;
    } else {
        let grow = 0.5 * (w / aspect - h);
        y0 -= grow;
        y1 += grow;
    }
    let mut files = Vec::new();
    for (r, t) in &firsts {
        // this compensation's scale: its largest offset + circle fills 45 % of the spacing
        let reach = t
            .poses
            .iter()
            .filter(|p| p.mean_error_um.len() >= 2)
            .map(|p| p.mean_error_um[0].hypot(p.mean_error_um[1]) + p.repeatability_um)
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        let scale = nice_floor(0.45 * spacing / reach.max(1e-12));
        let gap = (f64::NAN, f64::NAN);
        let mut arrows = Vec::new();
        let mut circles = Vec::new();
        let mut centres = Vec::new();
        for p in t.poses.iter().filter(|p| p.target_um.len() >= 2) {
            let (cx, cy) = (p.target_um[0], p.target_um[1]);
            centres.push((cx, cy));
            let (dx, dy) = (scale * p.mean_error_um[0], scale * p.mean_error_um[1]);
            let (tx, ty) = (cx + dx, cy + dy);
            arrows.extend([(cx, cy), (tx, ty), gap]);
            let len = dx.hypot(dy);
            if len > 0.0 {
                let head = 0.25 * len;
                let (ux, uy) = (dx / len, dy / len);
                for side in [1.0, -1.0] {
                    let (c, s) = (0.94f64, 0.34 * side); // ±20°
                    let (hx, hy) = (-(ux * c - uy * s), -(ux * s + uy * c));
                    arrows.extend([(tx, ty), (tx + head * hx, ty + head * hy), gap]);
                }
            }
            let rad = scale * p.repeatability_um;
            if rad.is_finite() && rad > 0.0 {
                for k in 0..=64 {
                    let a = k as f64 / 64.0 * std::f64::consts::TAU;
                    circles.push((tx + rad * a.cos(), ty + rad * a.sin()));
                }
                circles.push(gap);
            }
        }
        // corners that fix the range (lone points between gaps draw nothing)
        circles.extend([gap, (x0, y0), gap, (x1, y1), gap]);
        let name = r.compensation.name();
        let stem = format!("pose_xy_{}", name.replace(' ', "_"));
        files.extend(write_chart(
            &dir.join(stem),
            &Chart {
                title: format!(
                    "{name}: poses in x–y, first test (ISO 9283 pose figure; offsets and circles ×{scale})"
                ),
                x_label: "x (µm)".into(),
                y_label: "y (µm)".into(),
                series: vec![
                    Series {
                        name: "commanded pose".into(),
                        points: centres,
                        style: Style::Points,
                    },
                    Series {
                        name: format!("barycentre offset AP ×{scale}"),
                        points: arrows,
                        style: Style::Line,
                    },
                    Series {
                        name: format!("repeatability circle RP ×{scale}"),
                        points: circles,
                        style: Style::Line,
                    },
                ],
            },
        )?);
    }
    Ok(files)
}
