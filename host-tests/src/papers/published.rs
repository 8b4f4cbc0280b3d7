//! Reference models: the published 1-DoF piezo-stage model and a coupled 2-DoF model, built
//! from raw-unit coefficients, each with an independent raw-unit evaluation to check against.

use nanocal_model::{Factor, Input, Model, ModelBuilder, ModelError, MAX_AXES, MAX_TEMPS};

/// Published static 1-DoF model (0–480 µm, four temperature sensors at 21–23 °C):
/// `q = a3·x³ + a2·x² + a1·x + Σ b_i·T_i + λ`.
pub mod one_dof {
    /// Cubic, quadratic and linear coefficients a3, a2, a1.
    pub const A: [f64; 3] = [2.454e-8, -2.167e-5, 1.005];
    /// Thermal coefficients b1..b4, µm/°C.
    #[allow(clippy::approx_constant)] // −3.142 µm/°C is a measured coefficient, not π
    pub const B_UM_PER_C: [f64; 4] = [2.978, -3.142, -0.996, 0.690];
    /// Offset λ, µm.
    pub const LAMBDA_UM: f64 = 10.413;
    /// Training range of the position, µm.
    pub const X_RANGE_UM: (f64, f64) = (0.0, 480.0);
    /// Training range of the temperatures, °C.
    pub const T_RANGE_C: (f64, f64) = (21.0, 23.0);
    /// Travel of the stage, µm.
    pub const TRAVEL_UM: (f64, f64) = (-20.0, 520.0);
}

/// The published 1-DoF model as a shared-model [`Model`].
pub fn published_1dof() -> Result<Model, ModelError> {
    use one_dof::*;
    let mut b = ModelBuilder::new(1, 4, 0)?
        .id(0x0001_0001)
        .trained_range(Input::Axis(0), X_RANGE_UM.0, X_RANGE_UM.1)
        .travel_um(0, TRAVEL_UM.0, TRAVEL_UM.1);
    for t in 0..4 {
        b = b.trained_range(Input::Temp(t), T_RANGE_C.0, T_RANGE_C.1);
    }
    for (k, a) in A.iter().enumerate() {
        b.add_raw_term(0, [3 - k as u8, 0, 0], Factor::None, 0, *a)?;
    }
    for (t, coeff) in B_UM_PER_C.iter().enumerate() {
        b.add_raw_term(0, [0; MAX_AXES], Factor::Temp(t as u8), 0, *coeff)?;
    }
    b.offset_um(0, LAMBDA_UM).build()
}

/// The published 1-DoF model evaluated straight from its raw-unit formula.
pub fn published_1dof_raw(x_um: f64, temps_c: &[f64; MAX_TEMPS]) -> f64 {
    use one_dof::*;
    let poly = A[0] * x_um.powi(3) + A[1] * x_um.powi(2) + A[2] * x_um;
    let thermal: f64 = B_UM_PER_C.iter().zip(temps_c).map(|(b, t)| b * t).sum();
    poly + thermal + LAMBDA_UM
}

/// A raw-unit term of the 2-DoF reference: output, powers (x, y), temperature or none, coefficient.
type RawTerm = (u8, [u8; 2], Option<u8>, f64);

/// Raw terms of a coupled 2-DoF model on 0–80 µm: per output axis a quintic in its own axis, a
/// quintic in the other axis (coupling), mixed products, two temperatures, one position ×
/// temperature term and an offset — 20 terms per axis, 40 in all.
fn coupled_2dof_terms() -> [RawTerm; 38] {
    let mut terms = [(0u8, [0u8; 2], None, 0.0f64); 38];
    let mut n = 0;
    for out in 0..2u8 {
        let (own, other) = (out as usize, 1 - out as usize);
        let sign = if out == 0 { 1.0 } else { -1.0 };
        let own_poly = [1.0 + 2.1e-3 * sign, -1.7e-5, 2.3e-7, -1.1e-9, 2.0e-12];
        let cross_poly = [1.2e-3 * sign, 6.0e-6, -9.0e-8, 4.0e-10, -7.0e-13];
        for (k, c) in own_poly.iter().enumerate() {
            let mut p = [0u8; 2];
            p[own] = k as u8 + 1;
            terms[n] = (out, p, None, *c);
            n += 1;
        }
        for (k, c) in cross_poly.iter().enumerate() {
            let mut p = [0u8; 2];
            p[other] = k as u8 + 1;
            terms[n] = (out, p, None, *c);
            n += 1;
        }
        for (p, c) in [
            ([1, 1], 3.1e-6),
            ([2, 1], -2.2e-8),
            ([1, 2], 1.4e-8),
            ([2, 2], -9.0e-11),
        ] {
            terms[n] = (out, p, None, c * sign);
            n += 1;
        }
        for (t, c) in [(0u8, 2.4 * sign), (1, -1.9), (2, 0.8), (3, -0.35 * sign)] {
            terms[n] = (out, [0, 0], Some(t), c);
            n += 1;
        }
        let mut p = [0u8; 2];
        p[own] = 1;
        terms[n] = (out, p, Some(0), 1.1e-5);
        n += 1;
    }
    terms
}

/// Offsets λ of the 2-DoF reference, µm.
const COUPLED_2DOF_LAMBDA_UM: [f64; 2] = [-3.2, 4.7];

/// A coupled 2-DoF model on 0–80 µm per axis, four temperatures at 20–24 °C, 40 terms.
pub fn coupled_2dof() -> Result<Model, ModelError> {
    let mut b = ModelBuilder::new(2, 4, 0)?.id(0x0002_0001);
    for a in 0..2 {
        b = b
            .trained_range(Input::Axis(a as u8), 0.0, 80.0)
            .travel_um(a, -10.0, 100.0);
    }
    for t in 0..4 {
        b = b.trained_range(Input::Temp(t), 20.0, 24.0);
    }
    for (out, [px, py], temp, c) in coupled_2dof_terms() {
        b.add_raw_term(
            out,
            [px, py, 0],
            temp.map_or(Factor::None, Factor::Temp),
            0,
            c,
        )?;
    }
    for (a, lambda) in COUPLED_2DOF_LAMBDA_UM.iter().enumerate() {
        b = b.offset_um(a, *lambda);
    }
    b.build()
}

/// The coupled 2-DoF model evaluated straight from its raw-unit terms.
pub fn coupled_2dof_raw(x_um: [f64; 2], temps_c: &[f64; MAX_TEMPS]) -> [f64; 2] {
    let mut q = COUPLED_2DOF_LAMBDA_UM;
    for (out, [px, py], temp, c) in coupled_2dof_terms() {
        let factor = temp.map_or(1.0, |t| temps_c[t as usize]);
        q[out as usize] += c * x_um[0].powi(px as i32) * x_um[1].powi(py as i32) * factor;
    }
    q
}
