//! A model the size of paper 001's delta robot (78 parameters, 3 outputs, 10 temperatures, a
//! 1 cm³ workspace) folds into the fast path and keeps the host's f64 to 0.05 nm — with the
//! command formed as `x + δ` in f64, since an f32 command rounds by up to 0.24 nm at 5 mm.

use nanocal_model::reference::{delta_robot_78, ROBOT_HALF_STROKE_UM, ROBOT_TEMPS};
use nanocal_model::{Factor, FastInputs, HysteresisState, SlowInputs, FOLD_CAPACITY, MAX_AXES};
use proptest::prelude::*;

const F32_TOLERANCE_UM: f64 = 0.05e-3;

#[test]
fn the_robot_model_has_the_published_size_and_folds() {
    let model = delta_robot_78().unwrap();
    assert_eq!(model.axes(), 3);
    assert_eq!(model.temps(), ROBOT_TEMPS);
    assert_eq!(model.terms().len(), 78);
    let thermal = model
        .terms()
        .iter()
        .filter(|t| t.factor != Factor::None)
        .count();
    assert_eq!((78 - thermal, thermal), (45, 33));
    let fold = model.fold(&SlowInputs::default());
    assert_eq!(fold.fast_coefficients(), 3 * 35);
    assert!(fold.fast_coefficients() <= FOLD_CAPACITY);
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(5_000)
    })]

    #[test]
    fn the_robot_model_keeps_f64_to_0_05_nm(
        frac in proptest::array::uniform3(-1.0f64..=1.0),
        temps in proptest::array::uniform10(20.0f64..=24.0),
    ) {
        let model = delta_robot_78().unwrap();
        let mut s = SlowInputs::default();
        s.temps_c[..ROBOT_TEMPS].copy_from_slice(&temps);
        let fold = model.fold(&s);
        let x = frac.map(|f| (f * ROBOT_HALF_STROKE_UM) as f32);
        let x64 = x.map(f64::from);
        let c = fold.correct(&x, &[0; MAX_AXES], &FastInputs::NONE, &mut HysteresisState::new());
        let reference = model.eval_f64(&x64, &[0; MAX_AXES], &s);
        for a in 0..3 {
            let via_delta = x64[a] + f64::from(c.delta_um[a]);
            let err = (via_delta - reference[a]).abs();
            prop_assert!(err <= F32_TOLERANCE_UM, "axis {a}: {} nm", err * 1e3);
            // The f32 command itself is that, rounded: half an ulp of 5 mm is 0.24 nm.
            let ulp = f64::from(c.q_um[a].abs()) * f64::from(f32::EPSILON);
            prop_assert!((f64::from(c.q_um[a]) - reference[a]).abs() <= F32_TOLERANCE_UM + ulp);
        }
        // Inverse: an f32 position, and in f64 from the deviation at it.
        let q64 = reference;
        let q32 = q64.map(|q| q as f32);
        let back = fold.inverse(&q32, &[0; MAX_AXES], &FastInputs::NONE, &HysteresisState::new()).unwrap();
        let d = fold.deviation(&back, &[0; MAX_AXES], &FastInputs::NONE, &HysteresisState::new());
        for a in 0..3 {
            let ulp = f64::from(x[a].abs()) * f64::from(f32::EPSILON);
            prop_assert!((f64::from(back[a]) - x64[a]).abs() <= 4.0 * ulp + F32_TOLERANCE_UM);
            let x_from_q = q64[a] - f64::from(d[a]);
            prop_assert!((x_from_q - x64[a]).abs() <= F32_TOLERANCE_UM, "axis {a}: {} nm", (x_from_q - x64[a]).abs() * 1e3);
        }
    }
}
