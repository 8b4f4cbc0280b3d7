//! Deployable hysteresis: per-axis play-operator banks in the fast path (f32, stateful) against
//! the f64 reference with explicit state, over random walks with reversals and minor loops; the
//! inverse with the state frozen; a hand-computed example; the builder's and decoder's rules.

use nanocal_model::blob::{self, BlobError, MAX_BLOB_LEN};
use nanocal_model::{
    Factor, FastInputs, Fold, HysteresisState, Input, Model, ModelBuilder, ModelError, SlowInputs,
    Term, MAX_AXES,
};
use proptest::prelude::*;

const F32_TOLERANCE_UM: f64 = 0.05e-3;
/// The inverse stops once its step is at the f32 rounding of the residual (a few ulps).
const INVERSE_TOLERANCE_UM: f64 = 0.2e-3;

fn stroke_um(axis: usize) -> f64 {
    [480.0, 200.0, 100.0][axis]
}

/// A near-identity polynomial stage of `axes` axes with one bank per axis: `bank[a]` holds
/// (threshold fraction of the half stroke, weight) pairs; thresholds are sorted here.
fn model(
    axes: usize,
    poly: &[(u8, [u8; 3], f64)],
    banks: &[Vec<(f64, f64)>],
) -> Result<Model, ModelError> {
    let mut b = ModelBuilder::new(axes, 1, 0)?.trained_range(Input::Temp(0), 20.0, 24.0);
    for a in 0..axes {
        b = b.trained_range(Input::Axis(a as u8), 0.0, stroke_um(a));
    }
    for a in 0..axes {
        let mut unit = [0u8; 3];
        unit[a] = 1;
        b.add_raw_term(a as u8, unit, Factor::None, 0, 1.0)?;
        b.add_term(Term {
            output: a as u8,
            powers: [0; 3],
            factor: Factor::Temp(0),
            direction: 0,
            coeff: 0.3,
        })?;
    }
    for &(output, powers, coeff) in poly {
        let output = output % axes as u8;
        let mut p = powers;
        p[axes..].fill(0);
        b.add_term(Term {
            output,
            powers: p,
            factor: Factor::None,
            direction: 0,
            coeff,
        })?;
    }
    for (a, bank) in banks.iter().enumerate().take(axes) {
        let mut ops: Vec<(f64, f64)> = bank
            .iter()
            .map(|&(frac, w)| (frac * 0.5 * stroke_um(a), w))
            .collect();
        ops.sort_by(|p, q| p.0.total_cmp(&q.0));
        ops.dedup_by(|p, q| p.0 == q.0);
        b.play_bank(a as u8, &ops)?;
    }
    b.build()
}

fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[0] = 22.5;
    s
}

/// A walk of targets for every axis: each step adds an increment (reversing often, so the walk
/// makes minor loops of every size), clamped to the stroke, rounded to f32.
fn walk(axes: usize, steps: &[[f64; 3]]) -> Vec<[f32; MAX_AXES]> {
    let mut x = [0.5 * stroke_um(0), 0.5 * stroke_um(1), 0.5 * stroke_um(2)];
    steps
        .iter()
        .map(|inc| {
            let mut t = [0.0f32; MAX_AXES];
            for a in 0..axes {
                x[a] = (x[a] + inc[a] * stroke_um(a)).clamp(0.0, stroke_um(a));
                t[a] = x[a] as f32;
            }
            t
        })
        .collect()
}

fn bank_strategy() -> impl Strategy<Value = Vec<(f64, f64)>> {
    proptest::collection::vec((0.0f64..1.0, -0.05f64..0.03), 1..=16)
}

fn check_inverse(
    fold: &Fold,
    state: &HysteresisState,
    x: &[f32; MAX_AXES],
    q: &[f32; MAX_AXES],
    axes: usize,
) -> Result<(), TestCaseError> {
    let none = FastInputs::NONE;
    let dir = [0; MAX_AXES];
    let cold = fold.inverse(q, &dir, &none, state);
    let warm = fold.inverse_from(q, &dir, &none, state, x);
    for back in [cold, warm] {
        let back =
            back.map_err(|e| TestCaseError::fail(format!("inverse of {q:?} failed: {e}")))?;
        for a in 0..axes {
            let err = (back[a] as f64 - x[a] as f64).abs();
            prop_assert!(
                err <= INVERSE_TOLERANCE_UM,
                "axis {a}: {x:?} -> {q:?} -> {back:?}"
            );
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(400)
    })]

    #[test]
    fn fast_path_matches_f64_reference_along_random_walks(
        axes in 1usize..=3,
        poly in proptest::collection::vec((0u8..3, [0u8..4, 0u8..4, 0u8..3], -0.5f64..0.5), 0..8),
        banks in proptest::collection::vec(bank_strategy(), 3),
        steps in proptest::collection::vec(proptest::array::uniform3(-0.3f64..0.3), 20..300),
    ) {
        let model = match model(axes, &poly, &banks) {
            Ok(m) => m,
            // Random weights can flatten a branch: that, and only that, may be refused.
            Err(ModelError::BankNotMonotone { .. }) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(format!("model refused: {e}"))),
        };
        let s = slow();
        let fold = model.fold(&s);
        let (mut state, mut reference) = (HysteresisState::new(), HysteresisState::<f64>::new());
        // the device's way: evaluate from the state as it stands, step it when the command goes
        let mut sent = HysteresisState::new();
        for x in walk(axes, &steps) {
            let trial = fold.evaluate(&x, &[0; MAX_AXES], &FastInputs::NONE, &sent);
            fold.step(&x, &mut sent);
            let fast = fold.correct(&x, &[0; MAX_AXES], &FastInputs::NONE, &mut state);
            prop_assert_eq!(trial, fast, "evaluate at {:?}", x);
            prop_assert_eq!(sent, state, "step at {:?}", x);
            let q64 = model.eval_f64_with_state(&x.map(f64::from), &[0; MAX_AXES], &s, &mut reference);
            for (a, (&q32, &q64)) in fast.q_um.iter().zip(&q64).take(axes).enumerate() {
                let err = (q32 as f64 - q64).abs();
                prop_assert!(err <= F32_TOLERANCE_UM, "axis {a} at {x:?}: f32 {q32} vs f64 {q64} ({} nm)", err * 1e3);
            }
            check_inverse(&fold, &state, &x, &fast.q_um, axes)?;
        }
    }
}

/// q = x − 0.1·F₀[x] − 0.05·F₁₀[x] (thresholds 0 and 10 µm), worked by hand along 0, 30, 20,
/// 25, 40, 25 µm: F₀ is the identity; F₁₀ starts at 0, follows 10 µm behind going up to 30
/// (20), holds through the reversal (20 at 20 and 25), follows again to 40 (30) and holds coming
/// back to 25 (30).
#[test]
fn a_bank_of_two_operators_matches_the_hand_computed_walk() {
    let mut b = ModelBuilder::new(1, 0, 0)
        .unwrap()
        .trained_range(Input::Axis(0), -100.0, 100.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.play_bank(0, &[(0.0, -0.1), (10.0, -0.05)]).unwrap();
    let model = b.build().unwrap();
    let fold = model.fold(&SlowInputs::default());
    let walk = [0.0, 30.0, 20.0, 25.0, 40.0, 25.0];
    let by_hand = [0.0, 26.0, 17.0, 21.5, 34.5, 21.0];
    let (mut state, mut reference) = (HysteresisState::new(), HysteresisState::<f64>::new());
    let none = FastInputs::NONE;
    for (&x, &want) in walk.iter().zip(&by_hand) {
        let q = fold
            .correct(&[x as f32, 0.0, 0.0], &[0; 3], &none, &mut state)
            .q_um[0];
        let q64 = model.eval_f64_with_state(
            &[x, 0.0, 0.0],
            &[0; 3],
            &SlowInputs::default(),
            &mut reference,
        )[0];
        assert!((q64 - want).abs() < 1e-12, "x = {x}: f64 {q64} vs {want}");
        assert!(
            (f64::from(q) - want).abs() < 1e-5,
            "x = {x}: f32 {q} vs {want}"
        );
    }
    // Negative weights put the rising branch above the falling one: 21.5 up vs 21.0 down at 25.
    assert!(by_hand[3] > by_hand[5]);
    // A reply to the last command maps back to its target with the state frozen.
    let back = fold
        .inverse(&[21.0, 0.0, 0.0], &[0; 3], &none, &state)
        .unwrap();
    assert!((back[0] - 25.0).abs() < 1e-4, "{back:?}");
    // A reply 0.5 µm higher: both operators held at 25 → 25.5 (F₀ follows), so
    // 0.5 = Δx·(1 − 0.1) and Δx = 0.5/0.9.
    let back = fold
        .inverse(&[21.5, 0.0, 0.0], &[0; 3], &none, &state)
        .unwrap();
    assert!(
        (f64::from(back[0]) - (25.0 + 0.5 / 0.9)).abs() < 1e-4,
        "{back:?}"
    );
    // The stateless reference is the first command after a reset: every operator at x.
    let fresh = model.eval_f64(&[25.0, 0.0, 0.0], &[0; 3], &SlowInputs::default())[0];
    assert!((fresh - (25.0 - 2.5 - 1.25)).abs() < 1e-12, "{fresh}");
    state.reset();
    assert!(!state.is_primed());
    let q = fold
        .correct(&[25.0, 0.0, 0.0], &[0; 3], &none, &mut state)
        .q_um[0];
    assert!((f64::from(q) - fresh).abs() < 1e-5, "{q} vs {fresh}");
    assert!(state.is_primed());
}

#[test]
fn rate_independent_coarse_and_fine_walks_agree_at_their_common_points() {
    let model = model(1, &[], &[vec![(0.1, -0.02), (0.3, -0.03), (0.6, -0.04)]]).unwrap();
    let fold = model.fold(&slow());
    let none = FastInputs::NONE;
    let (mut coarse, mut fine) = (HysteresisState::new(), HysteresisState::new());
    let turns = [240.0f32, 400.0, 100.0, 300.0, 250.0];
    let mut last = turns[0];
    fold.correct(&[last, 0.0, 0.0], &[0; 3], &none, &mut fine);
    for &t in &turns {
        for k in 1..=50 {
            let x = last + (t - last) * k as f32 / 50.0;
            fold.correct(&[x, 0.0, 0.0], &[0; 3], &none, &mut fine);
        }
        last = t;
        let a = fold
            .correct(&[t, 0.0, 0.0], &[0; 3], &none, &mut coarse)
            .q_um[0];
        let b = fold.correct(&[t, 0.0, 0.0], &[0; 3], &none, &mut fine).q_um[0];
        assert!((a - b).abs() < 2e-5, "at {t}: {a} vs {b}");
    }
}

#[test]
fn the_builder_refuses_banks_that_are_out_of_order_or_ill_posed() {
    let base = || {
        let mut b = ModelBuilder::new(2, 0, 0)
            .unwrap()
            .trained_range(Input::Axis(0), 0.0, 100.0)
            .trained_range(Input::Axis(1), 0.0, 100.0);
        b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
        b.add_raw_term(1, [0, 1, 0], Factor::None, 0, 1.0).unwrap();
        b
    };
    let mut b = base();
    b.play(0, 5.0).unwrap();
    assert_eq!(b.play(0, 5.0), Err(ModelError::InvalidPlay { operator: 1 }));
    assert_eq!(b.play(0, 2.0), Err(ModelError::InvalidPlay { operator: 1 }));
    assert_eq!(
        b.play(0, -1.0),
        Err(ModelError::InvalidPlay { operator: 1 })
    );
    assert_eq!(
        b.play(0, f64::NAN),
        Err(ModelError::InvalidPlay { operator: 1 })
    );
    assert_eq!(b.play(2, 1.0), Err(ModelError::InvalidPlay { operator: 1 }));
    b.play(1, 1.0).unwrap();
    // Axis 0 after axis 1: the banks must go in axis order.
    assert_eq!(b.play(0, 9.0), Err(ModelError::InvalidPlay { operator: 2 }));
    // A play term must be alone on its own axis' output.
    let term = |output, powers, direction| Term {
        output,
        powers,
        factor: Factor::Play(0),
        direction,
        coeff: -1.0,
    };
    assert_eq!(
        b.add_term(term(1, [0; 3], 0)),
        Err(ModelError::InvalidPlayTerm { term: 2 })
    );
    assert_eq!(
        b.add_term(term(0, [1, 0, 0], 0)),
        Err(ModelError::InvalidPlayTerm { term: 2 })
    );
    assert_eq!(
        b.add_term(term(0, [0; 3], 1)),
        Err(ModelError::InvalidPlayTerm { term: 2 })
    );
    // Powers whose sum is 256 (fuzz: blob, crash-0748455b): the degree saturates instead of
    // wrapping to 0 (a panic with overflow checks on; without them, a degree that looked like 0).
    assert_eq!(
        b.add_term(term(0, [200, 56, 0], 0)),
        Err(ModelError::InvalidPlayTerm { term: 2 })
    );
    let mut wide = term(0, [200, 56, 0], 0);
    wide.factor = Factor::None;
    assert_eq!(b.add_term(wide), Err(ModelError::DegreeTooHigh { term: 2 }));
    // Weights summing to −1 would flatten the branch once both operators follow.
    let mut b = base();
    b.play_bank(0, &[(1.0, -0.6), (5.0, -0.4)]).unwrap();
    assert_eq!(b.build(), Err(ModelError::BankNotMonotone { axis: 0 }));
    // The same weights the other way round are fine: the partial sums stay above the minimum.
    let mut b = base();
    b.play_bank(0, &[(1.0, -0.4), (5.0, 0.3), (9.0, -0.6)])
        .unwrap();
    assert!(b.build().is_ok());
}

/// Blob v2 carries the banks; the decoder applies the same rules as the builder.
#[test]
fn blobs_with_banks_round_trip_and_bad_banks_are_refused() {
    let m = model(
        2,
        &[(0, [2, 0, 0], 0.2)],
        &[vec![(0.0, -0.01), (0.5, -0.02)], vec![(0.2, 0.01)]],
    )
    .unwrap();
    let mut buf = vec![0u8; MAX_BLOB_LEN];
    let n = blob::encode(&m, &mut buf).unwrap();
    buf.truncate(n);
    assert_eq!(blob::decode(&buf).unwrap(), m);
    let reseal = |mut b: Vec<u8>| {
        let body = b.len() - 4;
        let crc = blob::crc32(&b[..body]);
        b[body..].copy_from_slice(&crc.to_le_bytes());
        b
    };
    // Play operators follow the inputs, travel, offsets and lags (none here); no aux inputs.
    let ops = blob::HEADER_LEN + 12 + 32 * (2 + 1) + 32 * 2;
    let threshold = |k: usize| ops + 16 * k + 8;
    let mut bad = buf.clone();
    bad[threshold(1)..threshold(1) + 8].copy_from_slice(&(-1.0f64).to_le_bytes());
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::InvalidPlay {
            operator: 1
        }))
    );
    let mut bad = buf.clone();
    bad[threshold(1)..threshold(1) + 8].copy_from_slice(&0.0f64.to_le_bytes());
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::InvalidPlay {
            operator: 1
        }))
    );
    let mut bad = buf.clone();
    bad[ops + 16 * 2] = 0; // operator 2 (axis 1) moved to axis 0 after a larger threshold
    assert!(matches!(
        blob::decode(&reseal(bad)),
        Err(BlobError::InvalidModel(ModelError::InvalidPlay { .. }))
    ));
    let mut bad = buf.clone();
    bad[ops + 1] = 1; // a reserved byte of operator 0
    assert_eq!(
        blob::decode(&reseal(bad)),
        Err(BlobError::ReservedNotZero { offset: ops + 1 })
    );
}
