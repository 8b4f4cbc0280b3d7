//! What real recordings bring that simulations rarely do: readings on a coarse grid
//! (quantisation), channels logged slower than the position (sample-and-hold), and glitches
//! (a mis-trigger, a homing error, a dropped reading) — found robustly, so that none of them is
//! mistaken for physics.

use super::stats::median;

/// The quantisation step of a series, if its values sit on a grid (ADC or encoder resolution,
/// a coarse sensor's printed decimals): the common step of the gaps between its distinct values,
/// when at least 95 % of those gaps are whole multiples of it and values repeat (fewer distinct
/// values than half the rows). None when the readings are effectively continuous.
pub fn quantisation_step(v: &[f64]) -> Option<f64> {
    let mut u: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    let n = u.len();
    if n < 20 {
        return None;
    }
    // unstable is the same order: values equal under total_cmp are the same bits
    u.sort_unstable_by(f64::total_cmp);
    let span = u[n - 1] - u[0];
    if span <= 0.0 {
        return None;
    }
    u.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * span);
    if u.len() < 3 || u.len() > n / 2 {
        return None;
    }
    let gaps: Vec<f64> = u.windows(2).map(|w| w[1] - w[0]).collect();
    // the order statistic alone (the same element a full sort puts there)
    let mut sorted = gaps.clone();
    let k = sorted.len() / 20;
    let q = *sorted.select_nth_unstable_by(k, f64::total_cmp).1;
    if q <= 0.0 {
        return None;
    }
    let on_grid = gaps
        .iter()
        .filter(|&&g| {
            let k = (g / q).round();
            k >= 1.0 && (g / q - k).abs() < 0.05 * k.sqrt()
        })
        .count();
    (on_grid as f64 >= 0.95 * gaps.len() as f64).then_some(q)
}

/// For each row, whether the reading differs from the previous one (the first row counts as
/// new). A channel logged slower than the table repeats its last value (sample-and-hold).
pub fn changed(v: &[f64]) -> Vec<bool> {
    (0..v.len()).map(|i| i == 0 || v[i] != v[i - 1]).collect()
}

/// Typical time between updates of a channel, s: the 10th percentile of the times between
/// changes of its value (a held channel changes at every report; a quantised slow one changes
/// rarely when it is quiet, but at every report while it moves). At least the median sample
/// interval.
pub fn update_interval_s(t_s: &[f64], v: &[f64]) -> f64 {
    let dt_med = {
        let mut d: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
        median(&mut d)
    };
    let times: Vec<f64> = (1..v.len())
        .filter(|&i| v[i] != v[i - 1])
        .map(|i| t_s[i])
        .collect();
    if times.len() < 10 {
        return dt_med;
    }
    let mut gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    // the order statistic alone (the same element a full sort puts there)
    let k = gaps.len() / 10;
    gaps.select_nth_unstable_by(k, f64::total_cmp).1.max(dt_med)
}

/// Rows of short excursions: the series jumps away from where it was by far more than its
/// sample-to-sample changes allow, stays away for at most `max_run` rows, and comes back to
/// where it was. A real change of level (a heater switching on, a move) does not come back, a
/// smooth feature does not jump: neither is flagged. `q` is the quantisation step, if any.
/// Rows where `moved` is true start a new pose of a step-and-hold procedure: a jump there is
/// the error at the new pose (one pose can be off by itself), so no excursion may start, end
/// or lie across one.
///
/// "Back" allows for the series moving on meanwhile: within half the jump threshold, or within
/// a tenth of the excursion's own size (a 4 mm glitch in a probe rising 30 µm per row).
/// An excursion to values the rest of the series never comes near (beyond its whole range by
/// more than the threshold: a homing error, a dropped-to-zero reading) may last longer, up to a
/// tenth of the record — no physics takes a reading there and back again.
pub fn glitch_rows(
    v: &[f64],
    q: Option<f64>,
    max_run: usize,
    moved: Option<&[bool]>,
) -> Vec<usize> {
    let n = v.len();
    if n < 8 {
        return Vec::new();
    }
    let d: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    // the scale of a change, from the rows where the value changed (a held or quantised
    // channel repeats its value; those repeats say nothing about how far it moves when it does)
    let moves: Vec<f64> = d
        .iter()
        .copied()
        .filter(|x| *x != 0.0 && x.is_finite())
        .collect();
    if moves.len() < 4 {
        return Vec::new();
    }
    let mut abs_d: Vec<f64> = moves.iter().map(|x| x.abs()).collect();
    // the order statistic alone (the same element a full sort puts there)
    let k90 = (abs_d.len() * 9) / 10;
    let p90 = *abs_d.select_nth_unstable_by(k90, f64::total_cmp).1;
    let mut dev: Vec<f64> = {
        let mut dd = moves.clone();
        let m = median(&mut dd);
        moves.iter().map(|x| (x - m).abs()).collect()
    };
    let sigma_d = 1.4826 * median(&mut dev);
    let thr = (12.0 * sigma_d).max(5.0 * p90).max(4.0 * q.unwrap_or(0.0));
    if thr.is_nan() || thr <= 0.0 {
        return Vec::new();
    }
    // first the short excursions; then, with those masked, the long ones far outside the rest
    let short = excursions(v, &d, thr, max_run, max_run, moved, None);
    let masked: Vec<f64> = {
        let mut m = v.to_vec();
        for &i in &short {
            m[i] = f64::NAN;
        }
        m
    };
    // built only when a run longer than `max_run` comes back (most series have none)
    let far = LazyFarRange {
        v: &masked,
        built: std::cell::OnceCell::new(),
    };
    let mut out = excursions(v, &d, thr, max_run, max_run.max(n / 10), moved, Some(&far));
    out.extend(short);
    out.sort_unstable();
    out.dedup();
    out
}

/// The excursion scan of [`glitch_rows`]: runs up to `max_run` rows, or up to `long_run` rows
/// when they lie beyond the range `far` of everything else.
fn excursions(
    v: &[f64],
    d: &[f64],
    thr: f64,
    max_run: usize,
    long_run: usize,
    moved: Option<&[bool]>,
    far: Option<&LazyFarRange>,
) -> Vec<usize> {
    let n = v.len();
    let at_move = |k: usize| moved.is_some_and(|m| m[k]);
    let mut out = Vec::new();
    let mut i = 1;
    while i < n {
        if d[i - 1].abs() <= thr || at_move(i) {
            i += 1;
            continue;
        }
        let before = v[i - 1];
        let back_within = (0.5 * thr).max(0.1 * (v[i] - before).abs());
        // look for the return: the first row back near the level before
        let end = (i + long_run).min(n - 1);
        let found = (i + 1..=end)
            .take_while(|&j| !at_move(j))
            .find(|&j| (v[j] - before).abs() <= back_within);
        match found {
            Some(j)
                if (i..j).all(|k| {
                    (v[k] - before).abs() > back_within && (v[k] - v[j]).abs() > back_within
                }) && (j - i <= max_run || far.is_some_and(|f| f.outside(i, j, thr))) =>
            {
                out.extend(i..j);
                i = j + 1;
            }
            _ => i += 1,
        }
    }
    out
}

/// A [`FarRange`] of `v`, built on first use.
struct LazyFarRange<'a> {
    v: &'a [f64],
    built: std::cell::OnceCell<FarRange<'a>>,
}

impl LazyFarRange<'_> {
    /// See [`FarRange::outside`].
    fn outside(&self, a: usize, b: usize, margin: f64) -> bool {
        self.built
            .get_or_init(|| FarRange::new(self.v))
            .outside(a, b, margin)
    }
}

/// Prefix and suffix extremes of a series: whether a run of rows lies beyond the range of all
/// the other rows.
struct FarRange<'a> {
    v: &'a [f64],
    pre_min: Vec<f64>,
    pre_max: Vec<f64>,
    suf_min: Vec<f64>,
    suf_max: Vec<f64>,
}

impl<'a> FarRange<'a> {
    fn new(v: &'a [f64]) -> Self {
        let n = v.len();
        let (mut pre_min, mut pre_max) =
            (vec![f64::INFINITY; n + 1], vec![f64::NEG_INFINITY; n + 1]);
        for i in 0..n {
            pre_min[i + 1] = pre_min[i].min(v[i]);
            pre_max[i + 1] = pre_max[i].max(v[i]);
        }
        let (mut suf_min, mut suf_max) =
            (vec![f64::INFINITY; n + 1], vec![f64::NEG_INFINITY; n + 1]);
        for i in (0..n).rev() {
            suf_min[i] = suf_min[i + 1].min(v[i]);
            suf_max[i] = suf_max[i + 1].max(v[i]);
        }
        FarRange {
            v,
            pre_min,
            pre_max,
            suf_min,
            suf_max,
        }
    }

    /// Whether every row of `a..b` lies more than `margin` beyond the range of the rows
    /// outside `a..b`, all on the same side.
    fn outside(&self, a: usize, b: usize, margin: f64) -> bool {
        let lo = self.pre_min[a].min(self.suf_min[b]);
        let hi = self.pre_max[a].max(self.suf_max[b]);
        let run = &self.v[a..b];
        run.iter().all(|&x| x > hi + margin) || run.iter().all(|&x| x < lo - margin)
    }
}

/// Rows as a person reads them: data rows counted from 1 (the header is not a data row),
/// consecutive rows as ranges, at most `max` items.
pub fn rows_in_words(rows: &[usize], max: usize) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut k = 0;
    while k < rows.len() {
        let start = rows[k];
        let mut end = start;
        while k + 1 < rows.len() && rows[k + 1] == end + 1 {
            k += 1;
            end = rows[k];
        }
        parts.push(if end > start {
            format!("{}–{}", start + 1, end + 1)
        } else {
            format!("{}", start + 1)
        });
        k += 1;
    }
    let more = parts.len().saturating_sub(max);
    parts.truncate(max);
    let mut s = parts.join(", ");
    if more > 0 {
        s.push_str(&format!(" and {more} more"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_coarse_grid_is_found_with_its_step_and_continuous_readings_are_not() {
        let v: Vec<f64> = (0..500)
            .map(|i| 3.75 + 1.25 * ((i as f64 * 0.05).sin() * 8.0).round())
            .collect();
        let q = quantisation_step(&v).unwrap();
        assert!((q - 1.25).abs() < 1e-9, "{q}");
        let c: Vec<f64> = (0..500).map(|i| (i as f64 * 0.0137).sin() * 7.3).collect();
        assert_eq!(quantisation_step(&c), None);
    }

    #[test]
    fn excursions_are_flagged_and_level_changes_are_not() {
        let mut v: Vec<f64> = (0..300).map(|i| (i as f64 * 0.03).sin()).collect();
        for x in v.iter_mut().skip(200) {
            *x += 5.0; // a real step: stays
        }
        for x in v.iter_mut().skip(50).take(11) {
            *x += 4300.0; // a homing error: eleven readings far off, then back
        }
        v[120] -= 40.0; // a single mis-trigger
        let g = glitch_rows(&v, None, 20, None);
        let want: Vec<usize> = (50..61).chain([120]).collect();
        assert_eq!(g, want);
        assert_eq!(rows_in_words(&g, 5), "51–61, 121");
        // a regulated heater held between reports: ±1 °C swings at every report are its
        // normal changes, not glitches
        let held: Vec<f64> = (0..400)
            .map(|i| 220.0 + [0.9, -0.1, 0.0, 0.8, -0.6][(i / 10) % 5])
            .collect();
        assert!(glitch_rows(&held, Some(0.1), 20, None).is_empty());
        // a step-and-hold stage whose error at one pose is off: the pose, not a glitch
        let mut staircase = vec![0.0; 300];
        let mut moved = vec![false; 300];
        for k in (0..300).step_by(20) {
            moved[k] = true;
        }
        for x in staircase.iter_mut().skip(100).take(20) {
            *x = 50.0;
        }
        for (i, x) in staircase.iter_mut().enumerate() {
            *x += 0.5 * ((i * 7919) % 11) as f64 / 11.0;
        }
        assert!(!glitch_rows(&staircase, None, 30, None).is_empty());
        assert!(glitch_rows(&staircase, None, 30, Some(&moved)).is_empty());
        // a probe rising fast: a 4.3 mm mis-trigger while it moves 30 µm a row, and eleven
        // readings 4.3 mm off where only five may pass as a glitch by length alone
        let mut rising: Vec<f64> = (0..300)
            .map(|i| 15.0 * i as f64 + 8.0 * ((i * 37) % 5) as f64)
            .collect();
        rising[40] += 4300.0;
        for x in rising.iter_mut().skip(120).take(11) {
            *x += 4300.0 + 15.0 * 300.0;
        }
        let want: Vec<usize> = [40].into_iter().chain(120..131).collect();
        assert_eq!(glitch_rows(&rising, None, 5, None), want);
        // a level that goes away for twenty rows and comes back inside the series' own range
        // is a change of level, not a glitch, when only five rows may be a glitch
        let mut level = vec![0.0; 300];
        for (i, x) in level.iter_mut().enumerate() {
            *x = if i < 100 {
                0.0
            } else if i < 200 {
                10.0 * (i - 100) as f64 / 100.0
            } else {
                10.0
            };
            *x += 0.01 * ((i * 7919) % 11) as f64;
        }
        for x in level.iter_mut().skip(50).take(20) {
            *x += 8.0;
        }
        assert!(glitch_rows(&level, None, 5, None).is_empty());
    }

    #[test]
    fn held_channels_update_at_their_report_interval() {
        let t: Vec<f64> = (0..400).map(|i| 2.0 * i as f64).collect();
        // reported every 20 s (10 rows), the value moving
        let v: Vec<f64> = (0..400).map(|i| (i / 10) as f64 * 0.1).collect();
        assert!((update_interval_s(&t, &v) - 20.0).abs() < 1e-9);
    }
}
