//! What real recordings bring that simulations rarely do: readings on a coarse grid
//! (quantisation), channels logged slower than the position (sample-and-hold), and glitches
//! (a mis-trigger, a homing error, a dropped reading) — found robustly, so that none of them is
//! mistaken for physics.

use super::fit::median;

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
    u.sort_by(f64::total_cmp);
    let span = u[n - 1] - u[0];
    if span <= 0.0 {
        return None;
    }
    u.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * span);
    if u.len() < 3 || u.len() > n / 2 {
        return None;
    }
    let gaps: Vec<f64> = u.windows(2).map(|w| w[1] - w[0]).collect();
    let mut sorted = gaps.clone();
    sorted.sort_by(f64::total_cmp);
    let q = sorted[sorted.len() / 20];
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
    gaps.sort_by(f64::total_cmp);
    gaps[gaps.len() / 10].max(dt_med)
}

/// Rows of short excursions: the series jumps away from where it was by far more than its
/// sample-to-sample changes allow, stays away for at most `max_run` rows, and comes back to
/// where it was. A real change of level (a heater switching on, a move) does not come back, a
/// smooth feature does not jump: neither is flagged. `q` is the quantisation step, if any.
/// Rows where `moved` is true start a new pose of a step-and-hold procedure: a jump there is
/// the error at the new pose (one pose can be off by itself), so no excursion may start, end
/// or lie across one.
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
    abs_d.sort_by(f64::total_cmp);
    let p90 = abs_d[(abs_d.len() * 9) / 10];
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
    let mut out = Vec::new();
    let mut i = 1;
    while i < n {
        if d[i - 1].abs() <= thr {
            i += 1;
            continue;
        }
        let at_move = |k: usize| moved.is_some_and(|m| m[k]);
        if at_move(i) {
            i += 1;
            continue;
        }
        let before = v[i - 1];
        // look for the return: the first row back within thr/2 of the level before
        let end = (i + max_run).min(n - 1);
        let found = (i + 1..=end)
            .take_while(|&j| !at_move(j))
            .find(|&j| (v[j] - before).abs() <= 0.5 * thr);
        match found {
            Some(j)
                if (i..j).all(|k| {
                    (v[k] - before).abs() > 0.5 * thr && (v[k] - v[j]).abs() > 0.5 * thr
                }) =>
            {
                out.extend(i..j);
                i = j + 1;
            }
            _ => i += 1,
        }
    }
    out
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
    }

    #[test]
    fn held_channels_update_at_their_report_interval() {
        let t: Vec<f64> = (0..400).map(|i| 2.0 * i as f64).collect();
        // reported every 20 s (10 rows), the value moving
        let v: Vec<f64> = (0..400).map(|i| (i / 10) as f64 * 0.1).collect();
        assert!((update_interval_s(&t, &v) - 20.0).abs() < 1e-9);
    }
}
