//! Element kernels of linear P1 tetrahedra, as pure functions.
//!
//! Notation: rest node positions `X_a`, current positions `x_a` (a = 0..3), shape-function
//! gradients `b_a = grad N_a` in the rest configuration, rest volume `V`. The deformation
//! gradient is `F = sum_a x_a b_a^T` (`F = I` at rest, since `sum_a X_a b_a^T = I` and
//! `sum_a b_a = 0`).
//!
//! Isotropic linear elasticity (paper eq. 2-5, Hooke's law with Lame parameters `lambda`,
//! `mu`): for a small strain `eps`, energy density `psi = mu eps:eps + lambda/2 tr(eps)^2`,
//! stress `sigma = 2 mu eps + lambda tr(eps) I`.
//! - Linear FEM: `eps = sym(F) - I`; nodal force `f_a = -V sigma b_a`; the element stiffness
//!   `K^e = V B^T C B` has the 3x3 blocks
//!   `K_ab = V (lambda b_a b_b^T + mu b_b b_a^T + mu (b_a . b_b) I)`.
//! - Corotational FEM: with `R` the rotation of `F` (polar decomposition, sign-corrected for
//!   inverted elements), `eps = sym(R^T F) - I` and `f_a = -V R sigma b_a`; this is the exact
//!   gradient of `V psi` with `R = R(F)`. The warped stiffness `R K^e R^T` has blocks `K_ab`
//!   with `b` replaced by `c = R b` in the outer products; it equals the exact Hessian at zero
//!   stress and drops the terms in the derivative of `R` elsewhere (the usual corotational
//!   approximation, which keeps the matrix symmetric positive semi-definite).

// Index loops over parallel per-node arrays read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use nalgebra::Matrix3;

use crate::Vec3;

/// Lame parameters `(lambda, mu)` from Young's modulus and Poisson ratio.
pub fn lame(young_modulus: f64, poisson_ratio: f64) -> (f64, f64) {
    let nu = poisson_ratio;
    let lambda = young_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mu = young_modulus / (2.0 * (1.0 + nu));
    (lambda, mu)
}

/// Shape-function gradients of a tetrahedron and its signed volume (positive when `x1 - x0`,
/// `x2 - x0`, `x3 - x0` are right-handed). `None` for a degenerate tetrahedron.
pub fn shape_gradients(x: &[Vec3; 4]) -> Option<([Vec3; 4], f64)> {
    let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let det = dm.determinant();
    let inv = dm.try_inverse()?;
    if !det.is_finite() || det == 0.0 {
        return None;
    }
    // Rows of Dm^-1 are the gradients of N1, N2, N3.
    let b1 = inv.row(0).transpose();
    let b2 = inv.row(1).transpose();
    let b3 = inv.row(2).transpose();
    Some(([-(b1 + b2 + b3), b1, b2, b3], det / 6.0))
}

/// Deformation gradient `F = sum_a x_a b_a^T`.
#[inline]
pub fn deformation_gradient(x: &[Vec3; 4], b: &[Vec3; 4]) -> Matrix3<f64> {
    x[0] * b[0].transpose()
        + x[1] * b[1].transpose()
        + x[2] * b[2].transpose()
        + x[3] * b[3].transpose()
}

/// Hooke's law: `sigma = 2 mu eps + lambda tr(eps) I` for a symmetric strain.
#[inline]
pub fn stress(eps: &Matrix3<f64>, lambda: f64, mu: f64) -> Matrix3<f64> {
    eps * (2.0 * mu) + Matrix3::identity() * (lambda * eps.trace())
}

/// Energy density `mu eps:eps + lambda/2 tr(eps)^2`.
#[inline]
pub fn energy_density(eps: &Matrix3<f64>, lambda: f64, mu: f64) -> f64 {
    let tr = eps.trace();
    mu * eps.component_mul(eps).sum() + 0.5 * lambda * tr * tr
}

/// Elastic forces on the four nodes and the element energy, for the rotation `r`
/// (`Matrix3::identity()` gives linear FEM). `f` is overwritten.
#[inline]
pub fn element_forces(
    x: &[Vec3; 4],
    b: &[Vec3; 4],
    volume: f64,
    lambda: f64,
    mu: f64,
    r: &Matrix3<f64>,
    f: &mut [Vec3; 4],
) -> f64 {
    let def = deformation_gradient(x, b);
    let s = r.transpose() * def;
    let eps = (s + s.transpose()) * 0.5 - Matrix3::identity();
    let sigma = stress(&eps, lambda, mu);
    let p = r * sigma * (-volume);
    for a in 0..4 {
        f[a] = p * b[a];
    }
    volume * energy_density(&eps, lambda, mu)
}

/// Stiffness block `K_ab` of the (warped) element stiffness, with `c_a = R b_a`:
/// `V (lambda c_a c_b^T + mu c_b c_a^T + mu (b_a . b_b) I)`.
#[inline]
pub fn stiffness_block(
    ca: &Vec3,
    cb: &Vec3,
    ba_dot_bb: f64,
    volume: f64,
    lambda: f64,
    mu: f64,
) -> Matrix3<f64> {
    (ca * cb.transpose()) * (volume * lambda)
        + (cb * ca.transpose()) * (volume * mu)
        + Matrix3::identity() * (volume * mu * ba_dot_bb)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> [Vec3; 4] {
        [Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()]
    }

    #[test]
    fn gradients_of_the_unit_tetrahedron() {
        let (b, v) = shape_gradients(&unit_tet()).unwrap();
        assert!((v - 1.0 / 6.0).abs() < 1e-15);
        assert_eq!(b[1], Vec3::x());
        assert_eq!(b[0], Vec3::new(-1.0, -1.0, -1.0));
        let f = deformation_gradient(&unit_tet(), &b);
        assert!((f - Matrix3::identity()).abs().max() < 1e-15);
    }

    #[test]
    fn degenerate_tetrahedron_has_no_gradients() {
        let flat = [
            Vec3::zeros(),
            Vec3::x(),
            Vec3::y(),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        assert!(shape_gradients(&flat).is_none());
    }

    #[test]
    fn lame_parameters_of_known_materials() {
        // E = 1, nu = 0.25: lambda = mu = 0.4.
        let (l, m) = lame(1.0, 0.25);
        assert!((l - 0.4).abs() < 1e-15 && (m - 0.4).abs() < 1e-15);
    }
}
