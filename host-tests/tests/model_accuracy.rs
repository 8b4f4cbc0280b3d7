//! The firmware's f32 fast path against the host's f64 reference, and the raw-unit expansion
//! against the published formulas, everywhere in the training envelope.

use nanocal::papers::published::{
    coupled_2dof, coupled_2dof_raw, published_1dof, published_1dof_raw,
};
use nanocal_model::{FastInputs, HysteresisState, Model, SlowInputs, MAX_AXES};
use proptest::prelude::*;

const F32_TOLERANCE_UM: f64 = 0.05e-3;

fn slow_with_temps(temps: &[f64]) -> SlowInputs {
    let mut slow = SlowInputs::default();
    slow.temps_c[..temps.len()].copy_from_slice(temps);
    slow
}

/// |f32 fast path − f64 reference| at a target that is exactly representable in f32.
fn fast_path_error_um(model: &Model, x_um: [f64; MAX_AXES], slow: &SlowInputs) -> f64 {
    let x32 = x_um.map(|v| v as f32);
    let x64 = x32.map(|v| v as f64);
    let fold = model.fold(slow);
    let fast = fold.correct(
        &x32,
        &[0; MAX_AXES],
        &FastInputs::NONE,
        &mut HysteresisState::new(),
    );
    let reference = model.eval_f64(&x64, &[0; MAX_AXES], slow);
    (0..model.axes())
        .map(|a| (fast.q_um[a] as f64 - reference[a]).abs())
        .fold(0.0, f64::max)
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(20_000)
    })]

    #[test]
    fn published_1dof_f32_matches_f64_within_0_05_nm(
        x_um in 0.0f64..=480.0,
        temps in proptest::array::uniform4(21.0f64..=23.0),
    ) {
        let model = published_1dof().unwrap();
        let slow = slow_with_temps(&temps);
        let err = fast_path_error_um(&model, [x_um, 0.0, 0.0], &slow);
        prop_assert!(err <= F32_TOLERANCE_UM, "error {} nm at x = {x_um} µm, T = {temps:?}", err * 1e3);
    }

    #[test]
    fn coupled_2dof_f32_matches_f64_within_0_05_nm(
        x_um in 0.0f64..=80.0,
        y_um in 0.0f64..=80.0,
        temps in proptest::array::uniform4(20.0f64..=24.0),
    ) {
        let model = coupled_2dof().unwrap();
        let slow = slow_with_temps(&temps);
        let err = fast_path_error_um(&model, [x_um, y_um, 0.0], &slow);
        prop_assert!(err <= F32_TOLERANCE_UM, "error {} nm at ({x_um}, {y_um}) µm", err * 1e3);
    }

    #[test]
    fn published_1dof_expansion_matches_raw_formula(
        x_um in 0.0f64..=480.0,
        temps in proptest::array::uniform4(21.0f64..=23.0),
    ) {
        let model = published_1dof().unwrap();
        let slow = slow_with_temps(&temps);
        let q = model.eval_f64(&[x_um, 0.0, 0.0], &[0; MAX_AXES], &slow)[0];
        let raw = published_1dof_raw(x_um, &slow.temps_c);
        prop_assert!((q - raw).abs() <= 1e-9, "scaled {q} vs raw {raw}");
    }

    #[test]
    fn coupled_2dof_expansion_matches_raw_formula(
        x_um in 0.0f64..=80.0,
        y_um in 0.0f64..=80.0,
        temps in proptest::array::uniform4(20.0f64..=24.0),
    ) {
        let model = coupled_2dof().unwrap();
        let slow = slow_with_temps(&temps);
        let q = model.eval_f64(&[x_um, y_um, 0.0], &[0; MAX_AXES], &slow);
        let raw = coupled_2dof_raw([x_um, y_um], &slow.temps_c);
        for a in 0..2 {
            prop_assert!((q[a] - raw[a]).abs() <= 1e-9, "axis {a}: scaled {} vs raw {}", q[a], raw[a]);
        }
    }
}

#[test]
#[allow(clippy::approx_constant)] // −3.142 µm/°C is the published coefficient, not π
fn published_1dof_has_the_published_size_and_shape() {
    let model = published_1dof().unwrap();
    // a3, a2, a1 on the position, one term per temperature; λ is the offset.
    assert_eq!(model.terms().len(), 7);
    let fold = model.fold(&slow_with_temps(&[22.0; 4]));
    // The fold leaves a cubic in position: one dense block of four coefficients.
    assert_eq!(fold.fast_coefficients(), 4);
    // Spot value from the published formula, at the centre of the envelope.
    let q = model.eval_f64(
        &[240.0, 0.0, 0.0],
        &[0; MAX_AXES],
        &slow_with_temps(&[22.0; 4]),
    )[0];
    let expected = 2.454e-8 * 240f64.powi(3) - 2.167e-5 * 240f64.powi(2)
        + 1.005 * 240.0
        + (2.978 - 3.142 - 0.996 + 0.690) * 22.0
        + 10.413;
    assert!((q - expected).abs() < 1e-9, "{q} vs {expected}");
}
