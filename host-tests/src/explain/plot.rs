//! Residual plots before/after as SVG (dependency-free; one polyline per series).

use std::fmt::Write as _;

/// An SVG of residual vs time, before (grey) and after (blue), in nm.
pub fn residual_svg(title: &str, t_s: &[f64], before_um: &[f64], after_um: &[f64]) -> String {
    let (w, h, m) = (900.0, 420.0, 60.0);
    let t0 = t_s.first().copied().unwrap_or(0.0);
    let t1 = t_s.last().copied().unwrap_or(1.0).max(t0 + 1e-9);
    let all = before_um.iter().chain(after_um).filter(|v| v.is_finite());
    let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
        (a.min(v * 1e3), b.max(v * 1e3))
    });
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        (lo - 1.0, lo + 1.0)
    };
    let x = |t: f64| m + (t - t0) / (t1 - t0) * (w - 2.0 * m);
    let y = |v: f64| h - m - (v - lo) / (hi - lo) * (h - 2.0 * m);
    let step = (t_s.len() / 3000).max(1);
    let line = |r: &[f64]| {
        let mut p = String::new();
        for i in (0..r.len()).step_by(step) {
            if r[i].is_finite() {
                let _ = write!(p, "{:.1},{:.1} ", x(t_s[i]), y(r[i] * 1e3));
            }
        }
        p
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(
        s,
        r#"<rect width="100%" height="100%" fill="white"/><text x="{m}" y="24" font-size="15">{title}</text>"#
    );
    let _ = writeln!(
        s,
        r#"<line x1="{m}" y1="{}" x2="{}" y2="{}" stroke="black"/><line x1="{m}" y1="{m}" x2="{m}" y2="{}" stroke="black"/>"#,
        h - m,
        w - m,
        h - m,
        h - m
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}">time {:.1}–{:.1} h</text>"#,
        w / 2.0 - 40.0,
        h - 20.0,
        t0 / 3600.0,
        t1 / 3600.0
    );
    let _ = writeln!(
        s,
        r#"<text x="8" y="{}">{:.0} nm</text><text x="8" y="{}">{:.0} nm</text>"#,
        y(hi) + 4.0,
        hi,
        y(lo) + 4.0,
        lo
    );
    let _ = writeln!(
        s,
        r##"<polyline fill="none" stroke="#aaaaaa" stroke-width="1" points="{}"/>"##,
        line(before_um)
    );
    let _ = writeln!(
        s,
        r##"<polyline fill="none" stroke="#1f5fbf" stroke-width="1" points="{}"/>"##,
        line(after_um)
    );
    let _ = writeln!(
        s,
        r##"<text x="{}" y="44" fill="#888888">before (held-out)</text><text x="{}" y="60" fill="#1f5fbf">after (held-out)</text>"##,
        w - 200.0,
        w - 200.0
    );
    s.push_str("</svg>\n");
    s
}
