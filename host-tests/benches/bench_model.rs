//! Benchmark of the shared model on the host: the f32 fast path's worst error against the f64
//! reference over a dense grid of the training envelope (along a walk with reversals for a
//! model with hysteresis, over force values for a model with a fast input), and native timings
//! of fold, correct and inverse. Run: `cargo bench --bench bench_model` in host-tests/.

use std::hint::black_box;
use std::time::Instant;

use nanocal::papers::published::{coupled_2dof, published_1dof};
use nanocal_model::reference::{delta_robot_78, ROBOT_HALF_STROKE_UM};
use nanocal_model::{
    AuxKind, AuxSpec, Factor, FastInputs, HysteresisState, Input, Model, ModelBuilder, SlowInputs,
    Term, MAX_AXES,
};

/// Temperature corners and centre over the sensors the model reads.
fn corners(t_range_c: (f64, f64)) -> Vec<SlowInputs> {
    let (t0, t1) = t_range_c;
    let patterns: [fn(usize, f64, f64) -> f64; 5] = [
        |_, a, _| a,
        |_, _, b| b,
        |k, a, b| if k % 2 == 0 { a } else { b },
        |k, a, b| if k % 2 == 0 { b } else { a },
        |_, a, b| 0.5 * (a + b),
    ];
    patterns
        .iter()
        .map(|p| {
            let mut s = SlowInputs::default();
            for (k, t) in s.temps_c.iter_mut().enumerate() {
                *t = p(k, t0, t1);
            }
            s
        })
        .collect()
}

/// One benchmark case: a model, the box of targets it was trained on, and the fast inputs and
/// target sequence to check it along.
struct Case {
    name: &'static str,
    model: Model,
    x_min_um: f64,
    x_max_um: f64,
    t_range_c: (f64, f64),
    /// Grid steps per axis (a walk's length for a model with hysteresis).
    steps: usize,
    /// Force values (N) to check a fast force input (aux `force_aux`) at.
    forces_n: &'static [f32],
    force_aux: usize,
}

/// Worst |f32 − f64| (nm): the f32 command `q` itself, and `x + δ` formed in f64.
fn worst_error_nm(c: &Case) -> (f64, f64) {
    let (mut worst_q, mut worst_delta): (f64, f64) = (0.0, 0.0);
    let axes = c.model.axes();
    let span = c.x_max_um - c.x_min_um;
    for mut s in corners(c.t_range_c) {
        let fold = c.model.fold(&s);
        for &force in if c.forces_n.is_empty() {
            &[f32::NAN][..]
        } else {
            c.forces_n
        } {
            let fast = FastInputs::NONE.with_aux(c.force_aux, force);
            s.aux[c.force_aux] = f64::from(force);
            let (mut state, mut reference) =
                (HysteresisState::new(), HysteresisState::<f64>::new());
            let mut check = |x: [f32; MAX_AXES]| {
                let out = fold.correct(&x, &[0; MAX_AXES], &fast, &mut state);
                let q64 = c.model.eval_f64_with_state(
                    &x.map(f64::from),
                    &[0; MAX_AXES],
                    &s,
                    &mut reference,
                );
                for a in 0..axes {
                    worst_q = worst_q.max((f64::from(out.q_um[a]) - q64[a]).abs() * 1e3);
                    let via_delta = f64::from(x[a]) + f64::from(out.delta_um[a]);
                    worst_delta = worst_delta.max((via_delta - q64[a]).abs() * 1e3);
                }
            };
            if c.model.has_hysteresis() {
                // A walk with reversals and minor loops: a large triangle with a small one on top.
                for i in 0..c.steps {
                    let tri = |period: usize| {
                        let p = (i % period) as f64 / period as f64;
                        if p < 0.5 {
                            2.0 * p
                        } else {
                            2.0 - 2.0 * p
                        }
                    };
                    let x = c.x_min_um + span * (0.8 * tri(2000) + 0.2 * tri(146));
                    check([x as f32, 0.0, 0.0]);
                }
            } else {
                let per_axis = |a: usize| if a < axes { c.steps } else { 0 };
                for i in 0..=per_axis(0) {
                    for j in 0..=per_axis(1) {
                        for k in 0..=per_axis(2) {
                            let at =
                                |n: usize| (c.x_min_um + span * n as f64 / c.steps as f64) as f32;
                            check([
                                at(i),
                                if axes > 1 { at(j) } else { 0.0 },
                                if axes > 2 { at(k) } else { 0.0 },
                            ]);
                        }
                    }
                }
            }
        }
    }
    (worst_q, worst_delta)
}

fn time_ns<F: FnMut(usize)>(iterations: usize, mut f: F) -> f64 {
    let start = Instant::now();
    for i in 0..iterations {
        f(i);
    }
    start.elapsed().as_nanos() as f64 / iterations as f64
}

/// The published 1-DoF model with a bank of 16 play operators (thresholds 0–225 µm, weights
/// −0.010 … −0.025: a command that leads its target, as a piezo stack needs).
fn published_1dof_with_bank() -> anyhow::Result<Model> {
    let mut b = ModelBuilder::from_model(&published_1dof()?);
    let bank: Vec<(f64, f64)> = (0..16)
        .map(|k| (15.0 * k as f64, -0.01 - 0.001 * k as f64))
        .collect();
    b.play_bank(0, &bank)?;
    Ok(b.build()?)
}

/// The published 1-DoF model with a fast force input (±2 N) in two terms, F and x·F.
fn published_1dof_with_force() -> anyhow::Result<Model> {
    let mut b = ModelBuilder::from_model(&published_1dof()?);
    let force = b.add_aux(AuxSpec::fast(AuxKind::ForceN))?;
    let mut b = b.trained_range(Input::Aux(force), -2.0, 2.0);
    for (powers, coeff) in [([0, 0, 0], 0.6), ([1, 0, 0], 0.1)] {
        b.add_term(Term {
            output: 0,
            powers,
            factor: Factor::Aux(force),
            direction: 0,
            coeff,
        })?;
    }
    Ok(b.build()?)
}

fn main() -> anyhow::Result<()> {
    let case = |name, model, (x_min_um, x_max_um), t_range_c, steps| Case {
        name,
        model,
        x_min_um,
        x_max_um,
        t_range_c,
        steps,
        forces_n: &[],
        force_aux: 0,
    };
    let r = ROBOT_HALF_STROKE_UM;
    let cases = [
        case(
            "published 1-DoF (cubic + 4 T, 0–480 µm)",
            published_1dof()?,
            (0.0, 480.0),
            (21.0, 23.0),
            200_000,
        ),
        case(
            "coupled 2-DoF (40 terms, 0–80 µm)",
            coupled_2dof()?,
            (0.0, 80.0),
            (20.0, 24.0),
            400,
        ),
        case(
            "published 1-DoF + 16 play operators (walk of 200,000 targets)",
            published_1dof_with_bank()?,
            (0.0, 480.0),
            (21.0, 23.0),
            200_000,
        ),
        Case {
            forces_n: &[-2.0, -0.75, 0.0, 0.5, 2.0],
            ..case(
                "published 1-DoF + fast force (F, x·F; ±2 N)",
                published_1dof_with_force()?,
                (0.0, 480.0),
                (21.0, 23.0),
                20_000,
            )
        },
        case(
            "delta robot, 78 terms, 3 outputs, 10 T (±5 mm)",
            delta_robot_78()?,
            (-r, r),
            (20.0, 24.0),
            40,
        ),
    ];
    println!("| model | stored terms | fast coefficients | play operators | worst f32 q − f64 (nm) | worst x + δ − f64 (nm) | fold (µs) | correct (ns) | inverse (ns) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for c in &cases {
        let (worst_q, worst_delta) = worst_error_nm(c);
        let model = &c.model;
        let s = corners(c.t_range_c)[4];
        let fold = model.fold(&s);
        let fast = FastInputs::NONE.with_aux(c.force_aux, 0.5);
        let fold_ns = time_ns(20_000, |_| {
            black_box(model.fold(black_box(&s)));
        });
        let span = (c.x_max_um - c.x_min_um) as f32;
        let at = |i: usize| c.x_min_um as f32 + (i % 1000) as f32 * (span / 1000.0);
        let mut state = HysteresisState::new();
        let correct_ns = time_ns(2_000_000, |i| {
            let x = at(i);
            black_box(fold.correct(black_box(&[x, x, x]), &[0; MAX_AXES], &fast, &mut state));
        });
        let inverse_ns = time_ns(500_000, |i| {
            let q = at(i);
            black_box(
                fold.inverse(black_box(&[q, q, q]), &[0; MAX_AXES], &fast, &state)
                    .ok(),
            );
        });
        println!(
            "| {} | {} | {} | {} | {worst_q:.4} | {worst_delta:.4} | {:.2} | {correct_ns:.1} | {inverse_ns:.1} |",
            c.name,
            model.terms().len(),
            fold.fast_coefficients(),
            fold.play_operators(),
            fold_ns / 1e3
        );
    }
    Ok(())
}
