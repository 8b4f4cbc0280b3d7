//! `periodic_nonlinearity`: the interferometer's error is periodic in position with the
//! fringe period λ/2 (316.4 nm for HeNe) and its harmonic λ/4 (polarisation mixing).

use serde::{Deserialize, Serialize};

use super::zeros;
use crate::twin::SimContext;

/// The effect's name.
pub const NAME: &str = "periodic_nonlinearity";

/// Fringe period of a HeNe interferometer, λ/2, nm.
pub const HENE_HALF_WAVELENGTH_NM: f64 = 316.4;

/// Twin parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Params {
    /// Axis index.
    pub axis: usize,
    /// Amplitude of the first harmonic (period λ/2), nm.
    pub amplitude_nm: f64,
    /// Phase of the first harmonic, rad.
    pub phase_rad: f64,
    /// Amplitude of the second harmonic (period λ/4), nm.
    pub second_harmonic_nm: f64,
}

impl Params {
    /// error = A sin(2πx/P + φ) + A₂ sin(4πx/P).
    pub fn produce(&self, ctx: &SimContext) -> Vec<Vec<f64>> {
        let mut out = zeros(ctx);
        let a = self.axis;
        for k in 0..ctx.t_s.len() {
            let ph = std::f64::consts::TAU * ctx.pos_um[a][k] * 1e3 / HENE_HALF_WAVELENGTH_NM;
            out[a][k] = (self.amplitude_nm * (ph + self.phase_rad).sin()
                + self.second_harmonic_nm * (2.0 * ph).sin())
                * 1e-3;
        }
        out
    }
}
