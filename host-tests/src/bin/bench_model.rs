//! Benchmark of the shared model on the host: the f32 fast path's worst error against the f64
//! reference over a dense grid of the training envelope, and native timings of fold, correct
//! and inverse. Run: `cargo run --release --bin bench_model` in host-tests/.

use std::hint::black_box;
use std::time::Instant;

use nanocal::published::{coupled_2dof, published_1dof};
use nanocal_model::{Model, SlowInputs, MAX_AXES};

fn slow(temps: [f64; 4]) -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[..4].copy_from_slice(&temps);
    s
}

/// Worst |f32 − f64| (nm) over a grid of positions × temperature corners and centre.
fn worst_error_nm(model: &Model, x_max_um: f64, t_range_c: (f64, f64), steps: usize) -> f64 {
    let (t0, t1) = t_range_c;
    let corners = [
        [t0; 4],
        [t1; 4],
        [t0, t1, t0, t1],
        [t1, t0, t1, t0],
        [0.5 * (t0 + t1); 4],
    ];
    let mut worst: f64 = 0.0;
    for temps in corners {
        let s = slow(temps);
        let fold = model.fold(&s);
        let grid_y = if model.axes() > 1 { steps } else { 0 };
        for i in 0..=steps {
            for j in 0..=grid_y {
                let x = [
                    (x_max_um * i as f64 / steps as f64) as f32,
                    (x_max_um * j as f64 / steps as f64) as f32,
                    0.0,
                ];
                let fast = fold.correct(&x, &[0; MAX_AXES]).q_um;
                let reference = model.eval_f64(&x.map(f64::from), &[0; MAX_AXES], &s);
                for a in 0..model.axes() {
                    worst = worst.max((fast[a] as f64 - reference[a]).abs() * 1e3);
                }
            }
        }
    }
    worst
}

fn time_ns<F: FnMut(usize)>(iterations: usize, mut f: F) -> f64 {
    let start = Instant::now();
    for i in 0..iterations {
        f(i);
    }
    start.elapsed().as_nanos() as f64 / iterations as f64
}

fn main() -> anyhow::Result<()> {
    let cases = [
        (
            "published 1-DoF (cubic + 4 T, 0–480 µm)",
            published_1dof()?,
            480.0,
            (21.0, 23.0),
            200_000,
        ),
        (
            "coupled 2-DoF (40 terms, 0–80 µm)",
            coupled_2dof()?,
            80.0,
            (20.0, 24.0),
            400,
        ),
    ];
    println!("| model | stored terms | fast coefficients | worst f32−f64 (nm) | fold (µs) | correct (ns) | inverse (ns) |");
    println!("|---|---|---|---|---|---|---|");
    for (name, model, x_max, t_range, steps) in cases {
        let worst = worst_error_nm(&model, x_max, t_range, steps);
        let s = slow([22.0; 4]);
        let fold = model.fold(&s);
        let fold_ns = time_ns(20_000, |_| {
            black_box(model.fold(black_box(&s)));
        });
        let correct_ns = time_ns(2_000_000, |i| {
            let x = (i % 1000) as f32 * (x_max as f32 / 1000.0);
            black_box(fold.correct(black_box(&[x, x, 0.0]), &[0; MAX_AXES]));
        });
        let inverse_ns = time_ns(500_000, |i| {
            let q = (i % 1000) as f32 * (x_max as f32 / 1000.0);
            black_box(fold.inverse(black_box(&[q, q, 0.0]), &[0; MAX_AXES]).ok());
        });
        println!(
            "| {name} | {} | {} | {worst:.4} | {:.2} | {correct_ns:.1} | {inverse_ns:.1} |",
            model.terms().len(),
            fold.fast_coefficients(),
            fold_ns / 1e3
        );
    }
    Ok(())
}
