//! Honest uncertainties for what the naming step estimates: a delete-a-block jackknife over
//! contiguous stretches of time (Quenouille–Tukey; Künsch, Ann. Stat. 17, 1989, for dependent
//! data), with the candidate's nonlinear parameters searched again on every reduced record.
//! The spread covers what a profile width misses when the residual is correlated in time or
//! the effect's form only approximates the data; the reported σ is the larger of the two.

/// Number of contiguous blocks left out one at a time.
pub const JACKKNIFE_BLOCKS: usize = 8;

/// The fitted rows without each of [`JACKKNIFE_BLOCKS`] contiguous blocks of time.
pub fn leave_one_block_out(rows: &[usize], t_s: &[f64]) -> Vec<Vec<usize>> {
    if rows.len() < 10 * JACKKNIFE_BLOCKS {
        return Vec::new();
    }
    let (t0, t1) = (t_s[rows[0]], t_s[rows[rows.len() - 1]]);
    let span = (t1 - t0).max(f64::MIN_POSITIVE);
    let block = |i: usize| {
        (((t_s[i] - t0) / span * JACKKNIFE_BLOCKS as f64) as usize).min(JACKKNIFE_BLOCKS - 1)
    };
    (0..JACKKNIFE_BLOCKS)
        .map(|b| rows.iter().copied().filter(|&i| block(i) != b).collect())
        .collect()
}

/// Jackknife standard deviation of an estimate from its leave-one-block-out values:
/// √((K − 1)/K · Σ (θₖ − θ̄)²); NaN with fewer than three values.
pub fn jackknife_sigma(values: &[f64]) -> f64 {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let k = v.len();
    if k < 3 {
        return f64::NAN;
    }
    let m = v.iter().sum::<f64>() / k as f64;
    ((k as f64 - 1.0) / k as f64 * v.iter().map(|x| (x - m).powi(2)).sum::<f64>()).sqrt()
}

/// The larger of a stated σ and the jackknife's (a NaN or zero stated σ gives way).
pub fn combine(stated: f64, jackknife: f64) -> f64 {
    match (stated.is_finite() && stated > 0.0, jackknife.is_finite()) {
        (true, true) => stated.max(jackknife),
        (true, false) => stated,
        (false, true) => jackknife,
        (false, false) => stated,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_jackknife_of_a_mean_is_its_standard_error() {
        // leave-one-out means of k values: the jackknife σ is the sample σ / √k
        let x = [1.0, 4.0, 2.0, 8.0, 5.0, 7.0];
        let k = x.len() as f64;
        let total: f64 = x.iter().sum();
        let loo: Vec<f64> = x.iter().map(|v| (total - v) / (k - 1.0)).collect();
        let mean = total / k;
        let sd = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0)).sqrt();
        assert!((jackknife_sigma(&loo) - sd / k.sqrt()).abs() < 1e-12);
        assert_eq!(combine(f64::NAN, 2.0), 2.0);
        assert_eq!(combine(3.0, 2.0), 3.0);
        assert_eq!(combine(0.0, f64::NAN), 0.0);
    }
}
