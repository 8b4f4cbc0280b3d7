//! Plot helpers: one chart, written as PNG and SVG (via `plotters`).
//!
//! Text in PNGs is drawn with a TrueType font read at run time (no native font libraries at
//! build time): `$NANOCAL_FONT` if set, else DejaVu Sans or Liberation Sans from the usual
//! system folders (Debian: `apt-get install fonts-dejavu-core`).

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

/// Errors writing a plot.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The drawing backend failed (file, font).
    #[error("plot {path}: {message}")]
    Backend {
        /// The file being written.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Connected line.
    Line,
    /// Markers only.
    Points,
    /// Line with markers.
    LinePoints,
}

/// One named series of (x, y) points.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Points (non-finite ones are skipped).
    pub points: Vec<(f64, f64)>,
    /// How to draw it.
    pub style: Style,
}

/// A chart: title, axis labels, series.
#[derive(Debug, Clone)]
pub struct Chart {
    /// Title.
    pub title: String,
    /// x axis label (with unit).
    pub x_label: String,
    /// y axis label (with unit).
    pub y_label: String,
    /// The series.
    pub series: Vec<Series>,
}

/// Font files tried in order when `$NANOCAL_FONT` is not set.
const FONT_PATHS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
];

/// Registers the "sans-serif" font once; the error says what to install.
fn ensure_font() -> Result<(), String> {
    static FONT: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| {
        let candidates: Vec<PathBuf> = std::env::var_os("NANOCAL_FONT")
            .map(PathBuf::from)
            .into_iter()
            .chain(FONT_PATHS.iter().map(PathBuf::from))
            .collect();
        for path in &candidates {
            if let Ok(bytes) = std::fs::read(path) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
            }
        }
        Err(format!(
            "expected a TrueType font for PNG text, found none (tried $NANOCAL_FONT and {}); \
             install one, e.g. `apt-get install fonts-dejavu-core`, or set NANOCAL_FONT",
            FONT_PATHS.join(", ")
        ))
    })
    .clone()
}

const COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Lengths above 10 000 of a unit read better in the next unit up: nm → µm, µm → mm. Returns
/// the factor to multiply values by and the relabelled axis label.
fn scaled_unit(label: &str, max_abs: f64) -> (f64, String) {
    for (from, to) in [("(nm", "(µm"), ("(µm", "(mm")] {
        if label.contains(from) && max_abs > 10_000.0 {
            return (1e-3, label.replacen(from, to, 1));
        }
    }
    (1.0, label.to_string())
}

/// The range an axis shows: all finite values, unless a few outliers would squash the rest
/// (the full span over 4× the 0.2–99.8 % span): then the inner span, the outliers clipped at
/// the frame. Padded by 5 %.
fn axis_range(mut v: Vec<f64>) -> (f64, f64) {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return (0.0, 1.0);
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let (min, max) = (v[0], v[n - 1]);
    let (lo, hi) = (v[n / 500], v[(n - 1) - n / 500]);
    let (a, b) = if max - min > 4.0 * (hi - lo) && hi > lo {
        (lo, hi)
    } else {
        (min, max)
    };
    let span = if b > a { b - a } else { a.abs().max(1.0) };
    (a - 0.05 * span, b + 0.05 * span)
}

/// Tick label with as many decimals as the tick spacing needs (no "30000.0").
fn tick_label(v: f64, span: f64) -> String {
    let step = span / 8.0;
    let dec = if step > 0.0 && step.is_finite() {
        (-(step.log10().floor()) as i32).clamp(0, 6) as usize
    } else {
        0
    };
    let s = format!("{v:.dec$}");
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        "0".into()
    } else {
        s
    }
}

/// Clip segment p→q to the rectangle (Liang–Barsky); None when it lies outside.
fn clip(p: (f64, f64), q: (f64, f64), x: (f64, f64), y: (f64, f64)) -> Option<[(f64, f64); 2]> {
    let (dx, dy) = (q.0 - p.0, q.1 - p.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (pp, qq) in [
        (-dx, p.0 - x.0),
        (dx, x.1 - p.0),
        (-dy, p.1 - y.0),
        (dy, y.1 - p.1),
    ] {
        if pp == 0.0 {
            if qq < 0.0 {
                return None;
            }
        } else {
            let r = qq / pp;
            if pp < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some([
        (p.0 + t0 * dx, p.1 + t0 * dy),
        (p.0 + t1 * dx, p.1 + t1 * dy),
    ])
}

/// Polylines of `pts` inside the frame: broken at non-finite points and where the line leaves.
fn clipped_paths(pts: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let mut paths: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    for w in pts.windows(2) {
        let ok = w.iter().all(|p| p.0.is_finite() && p.1.is_finite());
        match ok.then(|| clip(w[0], w[1], x, y)).flatten() {
            Some([a, b]) => {
                if cur.last() != Some(&a) {
                    if cur.len() > 1 {
                        paths.push(std::mem::take(&mut cur));
                    }
                    cur.clear();
                    cur.push(a);
                }
                cur.push(b);
            }
            None => {
                if cur.len() > 1 {
                    paths.push(std::mem::take(&mut cur));
                }
                cur.clear();
            }
        }
    }
    if cur.len() > 1 {
        paths.push(cur);
    }
    paths
}

/// Text shortened with "…" to fit `width` pixels in `font`.
fn fit_text<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    text: &str,
    font: &TextStyle,
    width: u32,
) -> String {
    let fits = |t: &str| {
        area.estimate_text_size(t, font)
            .map_or(true, |(w, _)| w <= width)
    };
    if fits(text) {
        return text.to_string();
    }
    let chars: Vec<char> = text.chars().collect();
    let mut n = chars.len();
    while n > 1 {
        n -= 1;
        let t: String = chars[..n].iter().collect::<String>() + "…";
        if fits(&t) {
            return t;
        }
    }
    "…".into()
}

/// Legend entries laid out in rows below the plot: returns (rows of (series index, x offset)).
fn legend_rows<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    names: &[String],
    font: &TextStyle,
    width: u32,
) -> Vec<Vec<(usize, u32, String)>> {
    let mut rows: Vec<Vec<(usize, u32, String)>> = vec![Vec::new()];
    let mut x = 0u32;
    for (i, name) in names.iter().enumerate() {
        let label = fit_text(area, name, font, width.saturating_sub(40));
        let w = area.estimate_text_size(&label, font).map_or(200, |s| s.0) + 40;
        if x > 0 && x + w > width {
            rows.push(Vec::new());
            x = 0;
        }
        if let Some(r) = rows.last_mut() {
            r.push((i, x, label));
        }
        x += w + 10;
    }
    rows
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (width, _) = root.dim_in_pixel();
    let xs: Vec<f64> = chart
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.0))
        .collect();
    let ys: Vec<f64> = chart
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .collect();
    let max_abs = |v: &[f64]| {
        v.iter()
            .filter(|x| x.is_finite())
            .fold(0.0f64, |m, x| m.max(x.abs()))
    };
    let (fx, x_label) = scaled_unit(&chart.x_label, max_abs(&xs));
    let (fy, y_label) = scaled_unit(&chart.y_label, max_abs(&ys));
    let (x0, x1) = axis_range(xs.iter().map(|x| x * fx).collect());
    let (y0, y1) = axis_range(ys.iter().map(|y| y * fy).collect());

    // legend below the plot, outside the data
    let legend_font: TextStyle = ("sans-serif", 14).into_font().into();
    let names: Vec<String> = chart.series.iter().map(|s| s.name.clone()).collect();
    let rows = legend_rows(&root, &names, &legend_font, width.saturating_sub(40));
    let legend_h = 10 + 20 * rows.len() as u32;
    let (plot_area, legend_area) = root.split_vertically(root.dim_in_pixel().1 - legend_h);

    let title_font: TextStyle = ("sans-serif", 20).into_font().into();
    let title = fit_text(
        &plot_area,
        &chart.title,
        &title_font,
        width.saturating_sub(30),
    );
    let mut ctx = ChartBuilder::on(&plot_area)
        .caption(&title, title_font)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| e.to_string())?;
    let x_fmt = |v: &f64| tick_label(*v, x1 - x0);
    let y_fmt = |v: &f64| tick_label(*v, y1 - y0);
    ctx.configure_mesh()
        .x_desc(&x_label)
        .y_desc(&y_label)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, s) in chart.series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let pts: Vec<(f64, f64)> = s.points.iter().map(|p| (p.0 * fx, p.1 * fy)).collect();
        if matches!(s.style, Style::Line | Style::LinePoints) {
            for path in clipped_paths(&pts, (x0, x1), (y0, y1)) {
                ctx.draw_series(std::iter::once(PathElement::new(
                    path,
                    color.stroke_width(2),
                )))
                .map_err(|e| e.to_string())?;
            }
        }
        if matches!(s.style, Style::Points | Style::LinePoints) {
            let inside = pts.into_iter().filter(|p| {
                p.0.is_finite()
                    && p.1.is_finite()
                    && p.0 >= x0
                    && p.0 <= x1
                    && p.1 >= y0
                    && p.1 <= y1
            });
            ctx.draw_series(inside.map(|p| Circle::new(p, 3, color.filled())))
                .map_err(|e| e.to_string())?;
        }
    }
    for (r, row) in rows.iter().enumerate() {
        let y = 8 + 20 * r as i32;
        for (i, x, label) in row {
            let color = COLORS[i % COLORS.len()];
            let x = 20 + *x as i32;
            match chart.series[*i].style {
                Style::Points => legend_area
                    .draw(&Circle::new((x + 12, y + 8), 4, color.filled()))
                    .map_err(|e| e.to_string())?,
                _ => legend_area
                    .draw(&PathElement::new(
                        vec![(x, y + 8), (x + 24, y + 8)],
                        color.stroke_width(2),
                    ))
                    .map_err(|e| e.to_string())?,
            }
            legend_area
                .draw(&Text::new(label.clone(), (x + 32, y), legend_font.clone()))
                .map_err(|e| e.to_string())?;
        }
    }
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}

/// Writes `chart` to `<stem>.png` and `<stem>.svg` (960 × 600); returns both paths.
pub fn write_chart(stem: &Path, chart: &Chart) -> Result<Vec<PathBuf>, PlotError> {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    ensure_font().map_err(|message| PlotError::Backend {
        path: png.clone(),
        message,
    })?;
    draw(
        BitMapBackend::new(&png, (960, 600)).into_drawing_area(),
        chart,
    )
    .map_err(|message| PlotError::Backend {
        path: png.clone(),
        message,
    })?;
    draw(SVGBackend::new(&svg, (960, 600)).into_drawing_area(), chart).map_err(|message| {
        PlotError::Backend {
            path: svg.clone(),
            message,
        }
    })?;
    Ok(vec![png, svg])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_clipped_at_the_frame_and_broken_at_gaps() {
        let pts = [
            (0.0, 0.0),
            (2.0, 2.0),
            (3.0, f64::NAN),
            (4.0, 0.5),
            (5.0, 0.5),
        ];
        let paths = clipped_paths(&pts, (0.0, 10.0), (0.0, 1.0));
        assert_eq!(paths.len(), 2);
        assert_eq!(paths[0], vec![(0.0, 0.0), (1.0, 1.0)]);
        assert_eq!(paths[1], vec![(4.0, 0.5), (5.0, 0.5)]);
    }

    #[test]
    fn large_values_move_to_the_next_unit_and_ticks_have_no_spurious_decimals() {
        assert_eq!(
            scaled_unit("residual (nm)", 30_000.0),
            (1e-3, "residual (µm)".into())
        );
        assert_eq!(
            scaled_unit("residual (nm)", 3_000.0),
            (1.0, "residual (nm)".into())
        );
        assert_eq!(tick_label(30_000.0, 60_000.0), "30000");
        assert_eq!(tick_label(0.3, 1.0), "0.3");
        assert_eq!(tick_label(-0.0001, 1.0), "0");
    }

    #[test]
    fn a_few_outliers_do_not_squash_the_axis() {
        let mut v: Vec<f64> = (0..1000).map(|i| (i as f64 * 0.1).sin()).collect();
        v.push(4300.0);
        let (lo, hi) = axis_range(v);
        assert!(hi < 2.0 && lo > -2.0, "{lo} {hi}");
    }
}
