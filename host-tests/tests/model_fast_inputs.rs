//! Fast (real-time) aux inputs: evaluated per command by the fast path, never folded (paper 001
//! §VI: "variations due to external forces have imperatively to be compensated in real-time");
//! a missing one is never a silent zero.

use nanocal_model::{
    AuxKind, AuxSpec, EnvelopeFlags, Factor, FastInputs, HysteresisState, Input, Model,
    ModelBuilder, ModelError, SlowInputs, Term, MAX_AXES,
};
use proptest::prelude::*;

const F32_TOLERANCE_UM: f64 = 0.05e-3;

/// A stage of `axes` axes with a slow air-pressure input (aux 0) and a fast force input (aux 1,
/// ±2 N: paper 001 §III.B, "1-2 N is responsible of an accuracy loss of ~1 µm").
fn model(axes: usize, force_terms: &[(u8, [u8; 3], u8, f64)]) -> Result<Model, ModelError> {
    let mut b = ModelBuilder::new(axes, 1, 2)?
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Aux(0), 950.0, 1050.0)
        .trained_range(Input::Aux(1), -2.0, 2.0)
        .aux_spec(0, AuxSpec::slow(AuxKind::AirPressureHpa))
        .aux_spec(1, AuxSpec::fast(AuxKind::ForceN));
    for a in 0..axes {
        b = b.trained_range(Input::Axis(a as u8), 0.0, 100.0 * (a + 1) as f64);
    }
    for a in 0..axes {
        let mut unit = [0u8; 3];
        unit[a] = 1;
        b.add_raw_term(a as u8, unit, Factor::None, 0, 1.0)?;
        let mut square = [0u8; 3];
        square[a] = 2;
        b.add_term(term(a as u8, square, Factor::None, 0, 0.2))?;
        b.add_term(term(a as u8, [0; 3], Factor::Temp(0), 0, 0.3))?;
        b.add_term(term(a as u8, [0; 3], Factor::Aux(0), 0, -0.1))?;
    }
    for &(output, powers, direction, coeff) in force_terms {
        let mut p = powers;
        p[axes..].fill(0);
        b.add_term(term(
            output % axes as u8,
            p,
            Factor::Aux(1),
            direction % (axes as u8 + 1),
            coeff,
        ))?;
    }
    b.build()
}

fn term(output: u8, powers: [u8; 3], factor: Factor, direction: u8, coeff: f64) -> Term {
    Term {
        output,
        powers,
        factor,
        direction,
        coeff,
    }
}

fn slow(pressure_hpa: f64) -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[0] = 22.5;
    s.aux[0] = pressure_hpa;
    s
}

proptest! {
    #![proptest_config(ProptestConfig {
        // the same cases on every run (deterministic tests; a new case goes in by its seed)
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6e61_6e6f_6361_6c00),
        ..ProptestConfig::with_cases(3_000)
    })]

    #[test]
    fn fast_path_with_a_force_matches_the_f64_reference(
        axes in 1usize..=3,
        force_terms in proptest::collection::vec((0u8..3, [0u8..3, 0u8..3, 0u8..2], 0u8..4, -1.0f64..1.0), 1..6),
        frac in proptest::array::uniform3(0.0f64..=1.0),
        dir in proptest::array::uniform3(-1i8..=1),
        force_n in -2.0f32..=2.0,
        pressure_hpa in 950.0f64..=1050.0,
    ) {
        let model = model(axes, &force_terms).unwrap();
        let mut s = slow(pressure_hpa);
        let fold = model.fold(&s);
        let mut x = [0.0f32; MAX_AXES];
        for a in 0..axes {
            x[a] = (frac[a] * 100.0 * (a + 1) as f64) as f32;
        }
        let fast = FastInputs::NONE.with_aux(1, force_n);
        let c = fold.correct(&x, &dir, &fast, &mut HysteresisState::new());
        prop_assert_eq!(c.fast_outside_envelope, 0);
        // The reference reads every aux input, the fast one included, from the slow inputs.
        s.aux[1] = f64::from(force_n);
        let reference = model.eval_f64(&x.map(f64::from), &dir, &s);
        for (a, (&q32, &q64)) in c.q_um.iter().zip(&reference).take(axes).enumerate() {
            let err = (f64::from(q32) - q64).abs();
            prop_assert!(err <= F32_TOLERANCE_UM, "axis {a}: {q32} vs {q64} ({} nm)", err * 1e3);
        }
        let back = fold.inverse(&c.q_um, &dir, &fast, &HysteresisState::new()).unwrap();
        for a in 0..axes {
            prop_assert!((back[a] - x[a]).abs() <= 1e-4, "axis {a}: {x:?} -> {back:?}");
        }
    }
}

#[test]
fn a_force_is_multiplied_in_per_command_not_folded() {
    let model = model(1, &[(0, [0, 0, 0], 0, 0.5), (0, [1, 0, 0], 0, 0.1)]).unwrap();
    // The force's value in the slow inputs does not reach the fold …
    let mut s = slow(1000.0);
    let fold = model.fold(&s);
    s.aux[1] = 1.75;
    assert_eq!(model.fold(&s), fold);
    // … the pressure's does.
    assert_ne!(model.fold(&slow(1010.0)), fold);
    assert_eq!(fold.fast_aux_mask(), 0b10);
    // q = … + 0.5·F/2 + 0.1·u·F/2 per command: at x = 75 µm (u = 0.5), 1 N adds 0.275 µm.
    let x = [75.0f32, 0.0, 0.0];
    let mut state = HysteresisState::new();
    let at = |f: f32, state: &mut HysteresisState| {
        fold.correct(&x, &[0; 3], &FastInputs::NONE.with_aux(1, f), state)
            .q_um[0]
    };
    let (q0, q1) = (at(0.0, &mut state), at(1.0, &mut state));
    assert!(((q1 - q0) as f64 - 0.275).abs() < 1e-5, "{q0} → {q1}");
}

#[test]
fn a_missing_or_out_of_range_force_is_flagged_never_zero() {
    let model = model(2, &[(1, [0, 1, 0], 0, 0.4)]).unwrap();
    let fold = model.fold(&slow(1000.0));
    let mut state = HysteresisState::new();
    let x = [30.0f32, 120.0, 0.0];
    let missing = fold.correct(&x, &[0; 3], &FastInputs::NONE, &mut state);
    assert_eq!(missing.fast_outside_envelope, 0b10);
    assert!(missing.q_um[1].is_nan(), "{:?}", missing.q_um);
    let strong = fold.correct(&x, &[0; 3], &FastInputs::NONE.with_aux(1, 2.5), &mut state);
    assert_eq!(strong.fast_outside_envelope, 0b10);
    assert!(strong.q_um[1].is_finite());
    // The slow path never flags a fast input; the reference check does, as any input.
    let mut s = slow(1000.0);
    s.aux[1] = 2.5;
    assert_eq!(model.fold(&s).slow_outside_envelope(), 0);
    assert!(model
        .check_envelope(&[30.0, 120.0, 0.0], &s)
        .contains(Input::Aux(1)));
    // A model without fast inputs never reads them: NaN there changes nothing.
    let plain = model_without_force();
    let fold = plain.fold(&slow(1000.0));
    let c = fold.correct(&x, &[0; 3], &FastInputs::NONE, &mut state);
    assert_eq!(c.fast_outside_envelope, 0);
    assert!(c.q_um[..2].iter().all(|q| q.is_finite()));
}

fn model_without_force() -> Model {
    let mut b = ModelBuilder::new(2, 0, 1)
        .unwrap()
        .trained_range(Input::Axis(0), 0.0, 100.0)
        .trained_range(Input::Axis(1), 0.0, 200.0)
        .aux_spec(0, AuxSpec::fast(AuxKind::ForceN));
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(1, [0, 1, 0], Factor::None, 0, 1.0).unwrap();
    // Declared fast, but no term uses it: the fast path does not read it.
    let m = b.build().unwrap();
    assert!(m.is_fast(0));
    assert_eq!(m.fold(&SlowInputs::default()).fast_aux_mask(), 0);
    m
}

#[test]
fn envelope_flags_reach_every_input_of_a_full_model() {
    // 3 axes, 16 temperatures, 4 aux inputs: flat indices up to 22 need the u32 mask.
    let mut b = ModelBuilder::new(3, 16, 4).unwrap();
    for t in 0..16 {
        b = b.trained_range(Input::Temp(t), 20.0, 24.0);
    }
    for n in 0..4 {
        b = b.trained_range(Input::Aux(n), -1.0, 1.0);
    }
    for a in 0..3 {
        b = b.trained_range(Input::Axis(a), 0.0, 10.0);
    }
    let model = b.build().unwrap();
    let mut s = SlowInputs::default();
    s.temps_c[..16].fill(22.0);
    s.temps_c[15] = 30.0;
    s.aux[3] = 5.0;
    let flags = model.check_envelope(&[5.0, 5.0, 5.0], &s);
    assert!(flags.contains(Input::Temp(15)));
    assert!(flags.contains(Input::Aux(3)));
    assert_eq!(
        flags,
        EnvelopeFlags(1 << Input::Temp(15).flat_index() | 1 << Input::Aux(3).flat_index())
    );
    assert_eq!(Input::Aux(3).flat_index(), 22);
    assert_eq!(model.fold(&s).slow_outside_envelope(), flags.0);
}
