//! The plain statistics the parts of explain share (median, centred moving average): a leaf, so
//! that the data, its fault checks, the robust estimators and the fit need not import each
//! other for them.

/// Median (reorders the slice).
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    v.select_nth_unstable_by(m, f64::total_cmp);
    v[m]
}

/// Centred moving average over ±`half` samples (shrinking at the ends); NaN-free input assumed.
/// Zero-phase: it uses later samples, so it is for diagnosis only.
pub fn centred_mean(x: &[f64], half: usize) -> Vec<f64> {
    if half == 0 {
        return x.to_vec();
    }
    let n = x.len();
    let mut pre = vec![0.0; n + 1];
    for i in 0..n {
        pre[i + 1] = pre[i] + x[i];
    }
    (0..n)
        .map(|i| {
            let h = half.min(i).min(n - 1 - i);
            let (a, b) = (i - h, i + h + 1);
            (pre[b] - pre[a]) / (b - a) as f64
        })
        .collect()
}
