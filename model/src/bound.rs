//! The prediction bound a device evaluates: the half-width of the fit's prediction interval of
//! the correction at any (position, temperatures), cheaply, in f32.
//!
//! For a least-squares fit with intercept on regressors `x` (the model's own terms of one
//! output axis, evaluated on the scaled inputs), a new observation at `x₀` has the prediction
//! interval `ŷ(x₀) ± t_{1−α/2, dfe} · s · sqrt(1 + h(x₀))`, `h(x₀) = x₀ᵀ(XᵀX)⁻¹x₀` (Montgomery,
//! Peck & Vining, *Introduction to Linear Regression Analysis*, 5th ed., Eq. 3.52). With the
//! design's columns centred and scaled (`z = [1, (x − mean)/scale]`) and `Z = Q R`,
//! `h = ‖R⁻ᵀ z₀‖²`: one forward substitution through the triangular factor — for `P` regressors
//! `(P+1)(P+2)/2` multiply-adds, no matrix inverse, no square root but the last. The host
//! computes the same in f64 (`nanocal::numerics::uncertainty::PredictionBand`); the fit writes `R`, the
//! centring, `s` and the t quantile into the blob (format version 3) and the device reads them
//! here. An axis with more than [`MAX_BOUND_TERMS`] terms carries no bound (the device then
//! has no interval for it, and says so).

use crate::error::ModelError;

/// Most regressors (terms of one output axis, intercept not counted) a bound covers. The
/// published static model has 3 position terms and up to a dozen temperature terms per axis.
pub const MAX_BOUND_TERMS: usize = 16;
/// Entries of the packed upper-triangular factor for [`MAX_BOUND_TERMS`] regressors.
pub const MAX_BOUND_R_LEN: usize = packed_len(MAX_BOUND_TERMS);

/// Entries of the packed upper-triangular factor (intercept included) for `regressors`
/// regressors: `(P+1)(P+2)/2`.
pub const fn packed_len(regressors: usize) -> usize {
    (regressors + 1) * (regressors + 2) / 2
}

/// The prediction bound of one output axis (see the module doc), in f32 as the device uses it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisBound {
    regressors: u8,
    s_um: f32,
    t95: f32,
    mean: [f32; MAX_BOUND_TERMS],
    scale: [f32; MAX_BOUND_TERMS],
    /// Row-major packed upper triangle of `R` (size `P+1`): row `i` holds columns `i..=P`.
    r: [f32; MAX_BOUND_R_LEN],
}

impl AxisBound {
    /// A bound from the fit's residual standard deviation `s_um` (µm), the two-sided 95 %
    /// quantile of Student's t at the fit's residual degrees of freedom `t95`, the regressors'
    /// centring `mean` and `scale` (one per term, in the model's term order) and the packed
    /// triangular factor `r_packed` ([`packed_len`] entries). Every number must be finite, `s`,
    /// `t95` and the scales positive, and the diagonal of `R` non-zero
    /// ([`ModelError::InvalidBound`] otherwise).
    pub fn new(
        s_um: f32,
        t95: f32,
        mean: &[f32],
        scale: &[f32],
        r_packed: &[f32],
    ) -> Result<Self, ModelError> {
        let p = mean.len();
        let bad = ModelError::InvalidBound;
        if p > MAX_BOUND_TERMS || scale.len() != p || r_packed.len() != packed_len(p) {
            return Err(bad);
        }
        let scalars = [s_um, t95];
        let mut all = scalars.iter().chain(mean).chain(scale).chain(r_packed);
        if all.any(|v| !v.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        if s_um <= 0.0 || t95 <= 0.0 || scale.iter().any(|v| *v <= 0.0) {
            return Err(bad);
        }
        let mut b = AxisBound {
            regressors: p as u8,
            s_um,
            t95,
            mean: [0.0; MAX_BOUND_TERMS],
            scale: [1.0; MAX_BOUND_TERMS],
            r: [0.0; MAX_BOUND_R_LEN],
        };
        b.mean[..p].copy_from_slice(mean);
        b.scale[..p].copy_from_slice(scale);
        b.r[..r_packed.len()].copy_from_slice(r_packed);
        if (0..=p).any(|i| b.r_at(i, i) == 0.0) {
            return Err(bad);
        }
        Ok(b)
    }

    /// Regressors covered (the axis' terms).
    pub fn regressors(&self) -> usize {
        self.regressors as usize
    }

    /// Residual standard deviation of the fit `s`, µm.
    pub fn s_um(&self) -> f32 {
        self.s_um
    }

    /// Two-sided 95 % quantile of Student's t at the fit's residual degrees of freedom.
    pub fn t95(&self) -> f32 {
        self.t95
    }

    /// Centring of the regressors (one per term).
    pub fn mean(&self) -> &[f32] {
        &self.mean[..self.regressors()]
    }

    /// Scale of the regressors (one per term).
    pub fn scale(&self) -> &[f32] {
        &self.scale[..self.regressors()]
    }

    /// The packed upper-triangular factor, row-major ([`packed_len`] entries).
    pub fn r_packed(&self) -> &[f32] {
        &self.r[..packed_len(self.regressors())]
    }

    /// `R[i][j]`, `j ≥ i`.
    fn r_at(&self, i: usize, j: usize) -> f32 {
        let k = self.regressors() + 1;
        // rows 0..i hold k + (k−1) + … + (k−i+1) = i·k − i(i−1)/2 entries
        self.r[i * k - i * (i.saturating_sub(1)) / 2 + (j - i)]
    }

    /// The leverage `h(x₀) = x₀ᵀ(XᵀX)⁻¹x₀` of a point whose regressors (the axis' term values,
    /// in term order) are `x0`; extra entries are ignored, missing ones read as 0.
    pub fn leverage(&self, x0: &[f32]) -> f32 {
        let p = self.regressors();
        let mut z = [0.0f32; MAX_BOUND_TERMS + 1];
        for i in 0..=p {
            let v = if i == 0 {
                1.0
            } else {
                (x0.get(i - 1).copied().unwrap_or(0.0) - self.mean[i - 1]) / self.scale[i - 1]
            };
            let mut acc = v;
            for t in 0..i {
                acc -= self.r_at(t, i) * z[t];
            }
            z[i] = acc / self.r_at(i, i);
        }
        z[..=p].iter().map(|v| v * v).sum()
    }

    /// `k · s · sqrt(1 + h(x₀))`, µm: the half-width of the interval `k` standard errors of
    /// prediction wide (`k = t95` gives the 95 % prediction interval).
    pub fn half_width_um(&self, k: f32, x0: &[f32]) -> f32 {
        k * self.s_um * libm::sqrtf(1.0 + self.leverage(x0))
    }

    /// Half-width of the 95 % prediction interval at `x₀`, µm.
    pub fn pi95_half_width_um(&self, x0: &[f32]) -> f32 {
        self.half_width_um(self.t95, x0)
    }
}
