//! Printing and JSON of what a fit knows about itself (shared by `fit` and `stepwise`): the
//! prediction interval, variance inflation, held-out accuracy ([`crate::numerics::uncertainty`]).

use crate::numerics::uncertainty::{collinearity_warnings, HeldOut, Vif};

fn num(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::json!(v)
    } else {
        serde_json::Value::Null
    }
}

/// `(smallest, median, largest)` of finite values (NaN when there are none).
pub fn spread(values: impl IntoIterator<Item = f64>) -> (f64, f64, f64) {
    let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    // the element a sort would put in the middle, in linear time (a sort of 200,000
    // half-widths cost more than computing them)
    let mid = v.len() / 2;
    let (below, &mut median, above) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let min = below.iter().copied().fold(median, f64::min);
    let max = above.iter().copied().fold(median, f64::max);
    (min, median, max)
}

/// The half-width spread as JSON.
pub fn spread_json(s: (f64, f64, f64)) -> serde_json::Value {
    serde_json::json!({"min": num(s.0), "median": num(s.1), "max": num(s.2)})
}

/// One line per column: `name VIF (most correlated with …, r)`, then the warnings.
pub fn vif_text(vifs: &[Vif], what: &str) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    if vifs.is_empty() {
        return s;
    }
    let _ = writeln!(
        s,
        "variance inflation of each {what} against the others (VIF > 10: collinear):"
    );
    for v in vifs {
        let partner = v.partner.as_ref().map_or(String::new(), |(n, r)| {
            format!("  (most correlated with {n}: r = {r:.3})")
        });
        let _ = writeln!(s, "  {:<20} VIF {:>10.2}{partner}", v.name, v.vif);
    }
    for w in collinearity_warnings(vifs, what) {
        let _ = writeln!(s, "{w}");
    }
    s
}

/// VIFs as JSON, with the warnings.
pub fn vif_json(vifs: &[Vif], what: &str) -> serde_json::Value {
    let cols: Vec<serde_json::Value> = vifs
        .iter()
        .map(|v| {
            serde_json::json!({"name": v.name, "vif": num(v.vif),
                "most_correlated_with": v.partner.as_ref().map(|p| p.0.clone()),
                "correlation": v.partner.as_ref().map(|p| num(p.1))})
        })
        .collect();
    serde_json::json!({"columns": cols, "threshold": crate::numerics::uncertainty::VIF_WARN,
        "warnings": collinearity_warnings(vifs, what)})
}

/// Held-out accuracy as JSON (in the response's unit).
pub fn held_out_json(h: &HeldOut) -> serde_json::Value {
    serde_json::json!({"blocks": h.blocks, "predictions": h.n, "rms": num(h.rms),
        "max_abs": num(h.max_abs), "block_rms": h.block_rms.iter().map(|&v| num(v)).collect::<Vec<_>>()})
}
