//! Reference models of the sizes the papers publish, shared by the firmware's benchmark image
//! and the host's tests and benchmarks so that both measure the same thing. Their shapes follow
//! the papers; their coefficients are made up (deterministic, of realistic magnitude), not fitted.

use crate::builder::ModelBuilder;
use crate::error::ModelError;
use crate::input::Input;
use crate::limits::MAX_AXES;
use crate::model::Model;
use crate::term::{Factor, Term};

/// Half the workspace of the delta robot along each axis, µm (paper 001: "~1 cm³").
pub const ROBOT_HALF_STROKE_UM: f64 = 5000.0;
/// Temperature sensors of the delta robot: 7 on the structure, 3 in the air near the
/// interferometer beams (paper 001 §IV.B).
pub const ROBOT_TEMPS: usize = 10;

/// A model the size of paper 001's delta robot (§VII: "78 parameters (45 geometric and 33
/// thermal)"): 3 outputs (motor coordinates), each with 15 geometric terms — the 3 linear
/// and 6 quadratic monomials of the three axes, 5 cubic (own³, own·next², own·prev², x·y·z,
/// own²·next) and own⁴ — and 11 thermal terms — the 10 temperatures and own axis × its
/// structure sensor. Workspace ±5 mm, temperatures 20–24 °C. Its fold has three dense
/// degree-4 blocks (105 coefficients).
pub fn delta_robot_78() -> Result<Model, ModelError> {
    let mut b = ModelBuilder::new(MAX_AXES, ROBOT_TEMPS, 0)?.id(0x0001_0078);
    for a in 0..MAX_AXES {
        b = b
            .trained_range(
                Input::Axis(a as u8),
                -ROBOT_HALF_STROKE_UM,
                ROBOT_HALF_STROKE_UM,
            )
            .travel_um(a, -1.1 * ROBOT_HALF_STROKE_UM, 1.1 * ROBOT_HALF_STROKE_UM)
            .offset_um(a, 0.2 * (a as f64 + 1.0));
    }
    for t in 0..ROBOT_TEMPS as u8 {
        b = b.trained_range(Input::Temp(t), 20.0, 24.0);
    }
    // A small linear congruential sequence: coefficients of either sign, fixed run to run.
    let mut seed = 0x2545_F491u32;
    let mut coeff = |scale_um: f64| {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        scale_um * ((seed >> 8) as f64 / (1u32 << 24) as f64 * 2.0 - 1.0)
    };
    for o in 0..MAX_AXES {
        // q = x, which the own-axis linear term below (a scale error) joins.
        let mut unit = [0u8; MAX_AXES];
        unit[o] = 1;
        b.add_raw_term(o as u8, unit, Factor::None, 0, 1.0)?;
        // linear and quadratic terms larger than cubic ones, the quartic smallest
        const SCALES: [f64; 15] = [
            0.5, 0.5, 0.5, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1, 0.1, 0.1, 0.05,
        ];
        for (powers, scale) in delta_robot_78_geometric(o).into_iter().zip(SCALES) {
            b.add_term(term(o, powers, Factor::None, coeff(scale)))?;
        }
        for t in 0..ROBOT_TEMPS as u8 {
            b.add_term(term(o, [0; MAX_AXES], Factor::Temp(t), coeff(0.4)))?;
        }
        let (powers, factor) = delta_robot_78_interaction(o);
        b.add_term(term(o, powers, factor, coeff(0.05)))?;
    }
    b.build()
}

/// The 15 geometric monomials of motor `o` in [`delta_robot_78`] (powers of the three motor
/// coordinates): the 3 linear and 6 quadratic ones, 5 cubic (own³, own·next², own·prev², x·y·z,
/// own²·next) and own⁴. Paper 001 gives only the count (45 geometric parameters for three
/// motors); these shapes are this project's choice.
pub fn delta_robot_78_geometric(o: usize) -> [[u8; MAX_AXES]; 15] {
    let (own, next, prev) = (o % MAX_AXES, (o + 1) % MAX_AXES, (o + 2) % MAX_AXES);
    let mono = |pairs: &[(usize, u8)]| {
        let mut p = [0u8; MAX_AXES];
        for &(a, k) in pairs {
            p[a] += k;
        }
        p
    };
    [
        mono(&[(0, 1)]),
        mono(&[(1, 1)]),
        mono(&[(2, 1)]),
        mono(&[(0, 2)]),
        mono(&[(1, 2)]),
        mono(&[(2, 2)]),
        mono(&[(0, 1), (1, 1)]),
        mono(&[(0, 1), (2, 1)]),
        mono(&[(1, 1), (2, 1)]),
        mono(&[(own, 3)]),
        mono(&[(own, 1), (next, 2)]),
        mono(&[(own, 1), (prev, 2)]),
        mono(&[(0, 1), (1, 1), (2, 1)]),
        mono(&[(own, 2), (next, 1)]),
        mono(&[(own, 4)]),
    ]
}

/// The 11th thermal term of motor `o` in [`delta_robot_78`] (beside the 10 temperatures): the
/// motor's own coordinate times its structure sensor, temperature `o` — (powers, factor).
/// Paper 001 gives only the count (33 thermal parameters for three motors).
pub fn delta_robot_78_interaction(o: usize) -> ([u8; MAX_AXES], Factor) {
    let mut p = [0u8; MAX_AXES];
    p[o % MAX_AXES] = 1;
    (p, Factor::Temp((o % MAX_AXES) as u8))
}

fn term(output: usize, powers: [u8; MAX_AXES], factor: Factor, coeff: f64) -> Term {
    Term {
        output: output as u8,
        powers,
        factor,
        direction: 0,
        coeff,
    }
}
