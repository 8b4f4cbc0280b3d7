//! Dense polynomials in up to three scaled positions, stored in a triangular layout and
//! evaluated by nested Horner's rule — the fast path's arithmetic.
//!
//! A block of `k` variables and total degree `D` holds one coefficient per monomial
//! `u^i v^j w^l` with `i + j + l ≤ D` (`C(D + k, k)` of them), in this order:
//!
//! ```text
//! for i in D..=0 { for j in (D − i)..=0 { for l in (D − i − j)..=0 { c[i][j][l] } } }
//! ```
//!
//! which is the order nested Horner reads them in, so evaluation is one pass over the block.

/// Number of coefficients of a block of `vars` variables (1..=3) and total degree `degree`.
pub(crate) const fn block_len(vars: usize, degree: usize) -> usize {
    match vars {
        1 => degree + 1,
        2 => (degree + 1) * (degree + 2) / 2,
        _ => (degree + 1) * (degree + 2) * (degree + 3) / 6,
    }
}

/// Position of monomial `powers` in a block of `vars` variables and total degree `degree`, or
/// `None` when it does not belong to the block. Blocks whose first power is higher come first:
/// `block_len(vars, degree − i − 1)` entries precede first power `i`; within them the other
/// variables form a block of degree `degree − i`.
pub(crate) fn position(vars: usize, degree: usize, powers: [u8; 3]) -> Option<usize> {
    let total: usize = powers.iter().map(|&p| p as usize).sum();
    if total > degree || powers[vars.min(3)..].iter().any(|&p| p != 0) {
        return None;
    }
    let (mut pos, mut d) = (0, degree);
    for v in (1..=vars).rev() {
        let i = powers[vars - v] as usize;
        if i < d {
            pos += block_len(v, d - i - 1);
        }
        d -= i;
    }
    Some(pos)
}

/// What nested Horner computes with: plain f32 on the fast path, a value with its gradient
/// for the inverse's Jacobian.
pub(crate) trait HornerNum: Copy {
    /// The number 0.
    const ZERO: Self;
    /// `self · x + c` for a coefficient `c`.
    fn mul_add_coeff(self, x: Self, c: f32) -> Self;
    /// `self · x + y`.
    fn mul_add(self, x: Self, y: Self) -> Self;
}

impl HornerNum for f32 {
    const ZERO: Self = 0.0;
    #[inline(always)]
    fn mul_add_coeff(self, x: Self, c: f32) -> Self {
        self * x + c
    }
    #[inline(always)]
    fn mul_add(self, x: Self, y: Self) -> Self {
        self * x + y
    }
}

/// A value and its gradient with respect to the first `N` scaled positions (forward-mode
/// differentiation); `N` is the model's number of axes, so no work goes to absent ones.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Dual<const N: usize> {
    pub value: f32,
    pub grad: [f32; N],
}

impl<const N: usize> Dual<N> {
    /// Variable `axis` at `value` (gradient: the unit vector of that axis; none beyond `N`).
    pub fn variable(axis: usize, value: f32) -> Self {
        let mut grad = [0.0; N];
        if let Some(g) = grad.get_mut(axis) {
            *g = 1.0;
        }
        Dual { value, grad }
    }
}

impl<const N: usize> HornerNum for Dual<N> {
    const ZERO: Self = Dual {
        value: 0.0,
        grad: [0.0; N],
    };
    #[inline(always)]
    fn mul_add_coeff(self, x: Self, c: f32) -> Self {
        let mut grad = [0.0; N];
        for a in 0..N {
            grad[a] = self.grad[a] * x.value + self.value * x.grad[a];
        }
        Dual {
            value: self.value * x.value + c,
            grad,
        }
    }
    #[inline(always)]
    fn mul_add(self, x: Self, y: Self) -> Self {
        let mut grad = [0.0; N];
        for a in 0..N {
            grad[a] = self.grad[a] * x.value + self.value * x.grad[a] + y.grad[a];
        }
        Dual {
            value: self.value * x.value + y.value,
            grad,
        }
    }
}

/// Evaluates a block of `vars` variables and total degree `degree` whose coefficients are
/// `coeff(0), coeff(1), …` in layout order. (Half-open ranges: inclusive ones cost an extra
/// compare and branch per iteration on the Cortex-M4.)
#[inline(always)]
pub(crate) fn evaluate<T: HornerNum>(
    vars: usize,
    degree: usize,
    x: [T; 3],
    coeff: impl Fn(usize) -> f32,
) -> T {
    let d = degree;
    let mut pos = 0;
    match vars {
        1 => {
            let mut acc = T::ZERO;
            for _ in 0..d + 1 {
                acc = acc.mul_add_coeff(x[0], coeff(pos));
                pos += 1;
            }
            acc
        }
        2 => {
            let mut acc_i = T::ZERO;
            for i in (0..d + 1).rev() {
                let mut acc_j = T::ZERO;
                for _ in 0..d - i + 1 {
                    acc_j = acc_j.mul_add_coeff(x[1], coeff(pos));
                    pos += 1;
                }
                acc_i = acc_i.mul_add(x[0], acc_j);
            }
            acc_i
        }
        _ => {
            let mut acc_i = T::ZERO;
            for i in (0..d + 1).rev() {
                let mut acc_j = T::ZERO;
                for j in (0..d - i + 1).rev() {
                    let mut acc_l = T::ZERO;
                    for _ in 0..d - i - j + 1 {
                        acc_l = acc_l.mul_add_coeff(x[2], coeff(pos));
                        pos += 1;
                    }
                    acc_j = acc_j.mul_add(x[1], acc_l);
                }
                acc_i = acc_i.mul_add(x[0], acc_j);
            }
            acc_i
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::powi;

    /// The layout by definition: `f(position, powers)` for every monomial in order.
    fn for_each_monomial(vars: usize, degree: usize, mut f: impl FnMut(usize, [u8; 3])) {
        let d = degree;
        let (dj, dl) = (if vars >= 2 { d } else { 0 }, if vars >= 3 { d } else { 0 });
        let mut pos = 0;
        for i in (0..=d).rev() {
            for j in (0..=dj.min(d - i)).rev() {
                for l in (0..=dl.min(d - i - j)).rev() {
                    f(pos, [i as u8, j as u8, l as u8]);
                    pos += 1;
                }
            }
        }
    }

    /// Evaluates a block straight from its monomials, as a reference for Horner.
    fn by_monomials(vars: usize, degree: usize, x: [f64; 3], c: &[f64]) -> f64 {
        let mut sum = 0.0;
        for_each_monomial(vars, degree, |pos, p| {
            sum += c[pos] * powi(x[0], p[0]) * powi(x[1], p[1]) * powi(x[2], p[2]);
        });
        sum
    }

    #[test]
    fn layout_sizes_and_orders_agree_with_horner() {
        for vars in 1..=3 {
            for degree in 0..=6 {
                let mut count = 0;
                for_each_monomial(vars, degree, |pos, _| {
                    assert_eq!(pos, count);
                    count += 1;
                });
                assert_eq!(count, block_len(vars, degree));
                for_each_monomial(vars, degree, |pos, p| {
                    assert_eq!(
                        position(vars, degree, p),
                        Some(pos),
                        "vars {vars} degree {degree} {p:?}"
                    );
                });
                assert_eq!(position(vars, degree, [degree as u8 + 1, 0, 0]), None);
                let c: [f64; 84] = core::array::from_fn(|k| ((k * 37 % 11) as f64 - 5.0) / 7.0);
                let x = [0.3, -0.7, 0.55];
                let reference = by_monomials(vars, degree, x, &c);
                let horner = evaluate(vars, degree, x.map(|v| v as f32), |k| c[k] as f32) as f64;
                assert!(
                    (horner - reference).abs() < 1e-5,
                    "vars {vars} degree {degree}: {horner} vs {reference}"
                );
                let dual = evaluate(
                    vars,
                    degree,
                    core::array::from_fn(|a| Dual::<3>::variable(a, x[a] as f32)),
                    |k| c[k] as f32,
                );
                assert!((dual.value as f64 - reference).abs() < 1e-5);
                for a in 0..vars {
                    let h = 1e-6;
                    let mut xp = x;
                    xp[a] += h;
                    let numeric = (by_monomials(vars, degree, xp, &c) - reference) / h;
                    assert!(
                        (dual.grad[a] as f64 - numeric).abs() < 1e-3,
                        "d/dx{a}: {} vs {numeric}",
                        dual.grad[a]
                    );
                }
            }
        }
    }
}
