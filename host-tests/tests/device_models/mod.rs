//! Small blob-v2 models for the device-side tests (native proxy and QEMU firmware): one with a
//! play-operator bank, one with a fast force input.
#![allow(dead_code)]

use nanocal_model::{AuxKind, AuxSpec, Factor, Input, Model, ModelBuilder, SlowInputs};

/// The simulated amplifier's temperature (exact in MAX31856 LSBs).
pub const TEMP_C: f32 = 22.0;

/// Slow inputs at [`TEMP_C`].
pub fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[0] = f64::from(TEMP_C);
    s
}

/// A 0–480 µm axis with a temperature term and a bank of three play operators (thresholds 5,
/// 20, 60 µm, weights 0.02, 0.015, 0.01): a loop about 2 µm wide.
pub fn hysteresis_model() -> Model {
    let mut b = ModelBuilder::new(1, 1, 0)
        .unwrap()
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Axis(0), 0.0, 480.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(0, [2, 0, 0], Factor::None, 0, 2e-5).unwrap();
    b.add_raw_term(0, [0, 0, 0], Factor::Temp(0), 0, 0.3)
        .unwrap();
    b.play_bank(0, &[(5.0, 0.02), (20.0, 0.015), (60.0, 0.01)])
        .unwrap();
    b.build().unwrap()
}

/// A walk with reversals of every size (minor loops inside major ones); every target exact in
/// f32 and in the proxy's micros.
pub const WALK_UM: [f64; 20] = [
    240.0, 300.0, 250.0, 400.0, 120.0, 200.0, 180.0, 190.0, 175.0, 330.0, 240.0, 240.5, 239.75,
    10.0, 470.0, 240.0, 260.0, 240.0, 100.0, 240.0,
];

/// A 0–100 µm axis whose command depends on a force read per command (aux 0, fast, ±2 N):
/// 0.6 µm/N plus a position-dependent compliance 0.004 µm/(N·µm).
pub fn force_model() -> Model {
    let mut b = ModelBuilder::new(1, 1, 1)
        .unwrap()
        .trained_range(Input::Temp(0), 20.0, 24.0)
        .trained_range(Input::Axis(0), 0.0, 100.0)
        .trained_range(Input::Aux(0), -2.0, 2.0)
        .aux_spec(0, AuxSpec::fast(AuxKind::ForceN));
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).unwrap();
    b.add_raw_term(0, [0, 0, 0], Factor::Temp(0), 0, 0.3)
        .unwrap();
    b.add_raw_term(0, [0, 0, 0], Factor::Aux(0), 0, 0.6)
        .unwrap();
    b.add_raw_term(0, [1, 0, 0], Factor::Aux(0), 0, 0.004)
        .unwrap();
    b.build().unwrap()
}
