//! A fit from merged block compressions (`compress_parts` + `merge_parts`, what `nanocal
//! stepwise` uses for the full fit and its held-out refits, one pass over the data) equals
//! `stepwise` run on the same rows, NaN rows and constant columns included.
use nanocal::cli::stepwise::Blocks;
use nanocal::numerics::linalg::{compress_parts, merge_parts};
use nanocal::numerics::stepwise::{stepwise, stepwise_compressed, StepwiseOptions, StepwiseResult};

/// Deterministic design: 6 candidates (one constant, two correlated), y on three of them, a few
/// NaN rows.
fn design(n: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut s: u64 = 0x1234_5678_9ABC_DEF1;
    let mut u = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut x: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(n)).collect();
    let mut y = Vec::with_capacity(n);
    for i in 0..n {
        let a = 10.0 + 3.0 * u();
        let b = 20.0 + u();
        let c = 0.7 * a + 0.1 * u();
        let d = u();
        let e = 4.0; // constant
        let f = 100.0 + 10.0 * u();
        let mut v = [a, b, c, d, e, f];
        if i % 997 == 5 {
            v[3] = f64::NAN;
        }
        for (col, val) in x.iter_mut().zip(v) {
            col.push(val);
        }
        y.push(2.0 * a - 0.5 * d + 0.01 * f + 0.05 * u());
    }
    (x, y)
}

fn close(a: &StepwiseResult, b: &StepwiseResult) {
    assert_eq!(a.inmodel, b.inmodel);
    assert_eq!(a.history.len(), b.history.len());
    assert_eq!(a.rows_used, b.rows_used);
    for (p, q) in a.b.iter().zip(&b.b) {
        assert!((p - q).abs() <= 1e-9 * (1.0 + q.abs()), "b {p} vs {q}");
    }
    assert!((a.rmse - b.rmse).abs() <= 1e-9 * b.rmse, "rmse");
    assert!((a.intercept - b.intercept).abs() <= 1e-9 * (1.0 + b.intercept.abs()));
}

#[test]
fn merged_parts_fit_as_the_rows_they_hold() {
    let n = 20_000;
    let (x, y) = design(n);
    let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
    let opts = StepwiseOptions::default();
    let full = stepwise(&xr, &y, &opts).unwrap();
    assert_eq!(full.inmodel, vec![true, false, false, true, false, true]);
    let mut cols = xr.clone();
    cols.push(&y);
    let bounds = [0, 3_000, 9_000, 9_001, 15_500, n];
    let parts = compress_parts(&cols, true, 2, &bounds).unwrap();
    assert_eq!(parts.len(), bounds.len() - 1);
    let all: Vec<_> = parts.iter().collect();
    close(
        &stepwise_compressed(merge_parts(&all, n), &opts).unwrap(),
        &full,
    );
    // leave out each range: the same as stepwise on the rows outside it
    for leave in 0..parts.len() {
        let keep: Vec<_> = parts
            .iter()
            .enumerate()
            .filter(|(b, _)| *b != leave)
            .map(|(_, p)| p)
            .collect();
        let merged = stepwise_compressed(merge_parts(&keep, n), &opts).unwrap();
        let rows: Vec<usize> = (0..n)
            .filter(|&i| i < bounds[leave] || i >= bounds[leave + 1])
            .collect();
        let sub: Vec<Vec<f64>> = x
            .iter()
            .map(|c| rows.iter().map(|&i| c[i]).collect())
            .collect();
        let sub_y: Vec<f64> = rows.iter().map(|&i| y[i]).collect();
        let sr: Vec<&[f64]> = sub.iter().map(|c| c.as_slice()).collect();
        close(&merged, &stepwise(&sr, &sub_y, &opts).unwrap());
    }
}

#[test]
fn blocks_split_the_used_rows_in_time_order() {
    let n = 10_000;
    let (x, y) = design(n);
    let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
    let blocks = Blocks::compress(&xr, &y, 5, 2).unwrap();
    let nan_rows = (0..n).filter(|i| i % 997 == 5).count();
    assert_eq!(blocks.used.len(), n - nan_rows);
    let ranges = blocks.ranges.clone().unwrap().unwrap();
    assert_eq!(ranges.len(), 5);
    let opts = StepwiseOptions::default();
    for (b, &(start, end)) in ranges.iter().enumerate() {
        let rows: Vec<usize> = blocks.used[..start]
            .iter()
            .chain(&blocks.used[end..])
            .copied()
            .collect();
        let sub: Vec<Vec<f64>> = x
            .iter()
            .map(|c| rows.iter().map(|&i| c[i]).collect())
            .collect();
        let sub_y: Vec<f64> = rows.iter().map(|&i| y[i]).collect();
        let sr: Vec<&[f64]> = sub.iter().map(|c| c.as_slice()).collect();
        let merged = stepwise_compressed(blocks.merged(Some(b)), &opts).unwrap();
        close(&merged, &stepwise(&sr, &sub_y, &opts).unwrap());
    }
    // too few rows for the blocks: said, and the full fit still made
    let short: Vec<&[f64]> = xr.iter().map(|c| &c[..6]).collect();
    let few = Blocks::compress(&short, &y[..6], 5, 2).unwrap();
    assert!(matches!(few.ranges, Some(Err(_))));
    assert_eq!(few.merged(None).rows, 5); // row 5 holds a NaN
}
