//! Units a person reads: times in the unit that fits the record (seconds to days), lengths in
//! nm or µm.

/// A unit of time for reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeUnit {
    /// Symbol (`s`, `min`, `h`, `d`).
    pub symbol: &'static str,
    /// Seconds per unit.
    pub seconds: f64,
}

impl TimeUnit {
    /// The unit for a span of `span_s` seconds: s below 2 min, min below 2 h, h below 3 days,
    /// d beyond.
    pub fn for_span(span_s: f64) -> Self {
        let (symbol, seconds) = if span_s < 120.0 {
            ("s", 1.0)
        } else if span_s < 7200.0 {
            ("min", 60.0)
        } else if span_s < 3.0 * 86_400.0 {
            ("h", 3600.0)
        } else {
            ("d", 86_400.0)
        };
        Self { symbol, seconds }
    }

    /// `t_s` in this unit.
    pub fn of(&self, t_s: f64) -> f64 {
        t_s / self.seconds
    }
}

/// A number with about three significant digits.
pub fn sig3(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    let dec = (2 - mag).clamp(0, 6) as usize;
    format!("{v:.dec$}")
}

/// A duration in the unit that fits it (`42 s`, `4.2 min`, `3.1 h`, `2.5 d`).
pub fn duration(s: f64) -> String {
    let u = TimeUnit::for_span(s * 1.2);
    format!("{} {}", sig3(u.of(s)), u.symbol)
}

/// A length given in µm, in nm below 10 µm and in µm above (`850 nm`, `21.4 µm`).
pub fn length_um(v_um: f64) -> String {
    if v_um.abs() < 10.0 {
        format!("{} nm", sig3(v_um * 1e3))
    } else {
        format!("{} µm", sig3(v_um))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_fit_the_span() {
        assert_eq!(TimeUnit::for_span(40.0).symbol, "s");
        assert_eq!(TimeUnit::for_span(2800.0).symbol, "min");
        assert_eq!(TimeUnit::for_span(46.0 * 3600.0).symbol, "h");
        assert_eq!(TimeUnit::for_span(14.0 * 86_400.0).symbol, "d");
        assert_eq!(duration(240.0), "4.00 min");
        assert_eq!(duration(12.0), "12.0 s");
        assert_eq!(length_um(0.85), "850 nm");
        assert_eq!(length_um(21.37), "21.4 µm");
    }
}
