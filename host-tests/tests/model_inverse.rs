//! The inverse map (position replies) and its failure modes; the adaptive KMZ offset; envelope flags.

use nanocal::papers::published::{coupled_2dof, published_1dof};
use nanocal_model::{
    Factor, FastInputs, HysteresisState, Input, InverseError, ModelBuilder, SlowInputs, Term,
    MAX_AXES,
};
use proptest::prelude::*;

fn slow_with_temps(temps: &[f64]) -> SlowInputs {
    let mut slow = SlowInputs::default();
    slow.temps_c[..temps.len()].copy_from_slice(temps);
    slow
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(5_000)
    })]

    #[test]
    fn inverse_undoes_correct_1dof(x_um in 0.0f32..=480.0, t in 21.0f64..=23.0, dir in -1i8..=1) {
        let fold = published_1dof().unwrap().fold(&slow_with_temps(&[t, t + 0.1, t - 0.2, t]));
        let q = fold.correct(&[x_um, 0.0, 0.0], &[dir, 0, 0], &FastInputs::NONE, &mut HysteresisState::new()).q_um;
        let back = fold.inverse(&q, &[dir, 0, 0], &FastInputs::NONE, &HysteresisState::new()).unwrap();
        prop_assert!((back[0] - x_um).abs() as f64 <= 0.1e-3, "{x_um} -> {} -> {}", q[0], back[0]);
    }

    #[test]
    fn inverse_undoes_correct_2dof(x_um in 0.0f32..=80.0, y_um in 0.0f32..=80.0) {
        let fold = coupled_2dof().unwrap().fold(&slow_with_temps(&[22.0, 22.5, 21.5, 23.0]));
        let q = fold.correct(&[x_um, y_um, 0.0], &[0; MAX_AXES], &FastInputs::NONE, &mut HysteresisState::new()).q_um;
        let back = fold.inverse(&q, &[0; MAX_AXES], &FastInputs::NONE, &HysteresisState::new()).unwrap();
        prop_assert!((back[0] - x_um).abs() <= 0.1e-3 && (back[1] - y_um).abs() <= 0.1e-3,
            "({x_um}, {y_um}) -> {q:?} -> {back:?}");
    }
}

#[test]
fn inverse_reports_a_non_monotone_model_instead_of_guessing() {
    // q = x − 1.5·u³·h: the slope vanishes at u² = 2/9·… so the map folds back; at the fold the
    // Jacobian is singular, beyond it Newton cannot settle.
    let mut b = ModelBuilder::new(1, 0, 0)
        .unwrap()
        .trained_range(Input::Axis(0), -1.0, 1.0);
    b.add_term(Term {
        output: 0,
        powers: [1, 0, 0],
        factor: Factor::None,
        direction: 0,
        coeff: 1.0,
    })
    .unwrap();
    b.add_term(Term {
        output: 0,
        powers: [3, 0, 0],
        factor: Factor::None,
        direction: 0,
        coeff: -1.0,
    })
    .unwrap();
    let fold = b.build().unwrap().fold(&SlowInputs::default());
    // The map peaks at q = 2/(3√3) ≈ 0.385: a larger command has no preimage.
    let err = fold
        .inverse(
            &[0.9, 0.0, 0.0],
            &[0; MAX_AXES],
            &FastInputs::NONE,
            &HysteresisState::new(),
        )
        .unwrap_err();
    assert!(
        matches!(err, InverseError::NotConverged | InverseError::Singular),
        "{err:?}"
    );
    assert_eq!(
        fold.inverse(
            &[f32::NAN, 0.0, 0.0],
            &[0; MAX_AXES],
            &FastInputs::NONE,
            &HysteresisState::new()
        ),
        Err(InverseError::NonFinite)
    );
}

#[test]
fn kmz_reference_measurement_re_zeroes_the_model() {
    let mut model = published_1dof().unwrap();
    let slow = slow_with_temps(&[22.0; 4]);
    let x_ref = [240.0, 0.0, 0.0];
    let q_sent = model.eval_f64(&x_ref, &[0; MAX_AXES], &slow);
    // The stage drifted: sending q_sent, the interferometer reads 0.37 µm more than intended.
    let measured = [x_ref[0] + 0.37, 0.0, 0.0];
    model.set_kmz_from_reference(&q_sent, &measured, &[0; MAX_AXES], &slow);
    let q_after = model.eval_f64(&measured, &[0; MAX_AXES], &slow);
    assert!((q_after[0] - q_sent[0]).abs() < 1e-9);
    // The correction moved by the drift times the local slope dq/dx of the published cubic.
    let [a3, a2, a1] = nanocal::papers::published::one_dof::A;
    let slope = 3.0 * a3 * 240f64.powi(2) + 2.0 * a2 * 240.0 + a1;
    assert!(
        (model.kmz_offset_um(0) + 0.37 * slope).abs() < 1e-6,
        "{}",
        model.kmz_offset_um(0)
    );
    // And the fast path sees it after a new fold.
    let fast = model
        .fold(&slow)
        .correct(
            &[240.37, 0.0, 0.0],
            &[0; MAX_AXES],
            &FastInputs::NONE,
            &mut HysteresisState::new(),
        )
        .q_um[0] as f64;
    assert!((fast - q_sent[0]).abs() < 1e-4);
}

#[test]
fn envelope_flags_name_the_input_that_left_the_training_range() {
    let model = published_1dof().unwrap();
    let inside = slow_with_temps(&[22.0; 4]);
    assert!(model.check_envelope(&[100.0, 0.0, 0.0], &inside).is_empty());
    let flags = model.check_envelope(&[490.0, 0.0, 0.0], &inside);
    assert!(flags.contains(Input::Axis(0)) && !flags.contains(Input::Temp(0)));
    let warm = slow_with_temps(&[22.0, 23.4, 22.0, 22.0]);
    let flags = model.check_envelope(&[100.0, 0.0, 0.0], &warm);
    assert!(flags.contains(Input::Temp(1)) && !flags.contains(Input::Axis(0)));
    let fold = model.fold(&warm);
    assert_eq!(
        fold.slow_outside_envelope(),
        1 << Input::Temp(1).flat_index()
    );
    assert_eq!(
        fold.correct(
            &[490.0, 0.0, 0.0],
            &[0; MAX_AXES],
            &FastInputs::NONE,
            &mut HysteresisState::new()
        )
        .outside_envelope,
        1
    );
    assert_eq!(
        fold.correct(
            &[100.0, 0.0, 0.0],
            &[0; MAX_AXES],
            &FastInputs::NONE,
            &mut HysteresisState::new()
        )
        .outside_envelope,
        0
    );
}

#[test]
fn direction_and_lag_terms_reach_the_fast_path() {
    let mut b = ModelBuilder::new(1, 1, 1)
        .unwrap()
        .trained_range(Input::Axis(0), 0.0, 100.0)
        .trained_range(Input::Temp(0), 20.0, 22.0)
        .trained_range(Input::Aux(0), 1000.0, 1020.0);
    let lag = b.lag(0, 600.0).unwrap();
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    // Hysteresis: ±40 nm depending on the direction of approach.
    b.add_term(Term {
        output: 0,
        powers: [0; 3],
        factor: Factor::None,
        direction: 1,
        coeff: 0.04,
    })
    .unwrap();
    b.add_raw_term(0, [0; 3], Factor::Lagged(lag), 0, 2.0)
        .unwrap();
    b.add_raw_term(0, [1, 0, 0], Factor::Aux(0), 0, -2.7e-7)
        .unwrap();
    let model = b.build().unwrap();
    let mut slow = SlowInputs::default();
    slow.temps_c[0] = 21.0;
    slow.lagged_c[0] = 20.5;
    slow.aux[0] = 1013.25;
    let fold = model.fold(&slow);
    for dir in [-1i8, 0, 1] {
        let x = [50.0f32, 0.0, 0.0];
        let fast = fold
            .correct(
                &x,
                &[dir, 0, 0],
                &FastInputs::NONE,
                &mut HysteresisState::new(),
            )
            .q_um[0] as f64;
        let reference = model.eval_f64(&[50.0, 0.0, 0.0], &[dir, 0, 0], &slow)[0];
        assert!(
            (fast - reference).abs() < 1e-5,
            "dir {dir}: {fast} vs {reference}"
        );
        let expected = 50.0 + 0.04 * dir as f64 + 2.0 * 20.5 - 2.7e-7 * 50.0 * 1013.25;
        assert!(
            (reference - expected).abs() < 1e-9,
            "dir {dir}: {reference} vs {expected}"
        );
    }
}
