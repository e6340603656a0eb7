//! Robust extraction of the rotation of a deformation gradient.
//!
//! Finds the rotation `R` in SO(3) maximizing `tr(R^T F)`: the rotation of the polar
//! decomposition `F = R S` when `det F > 0`, and for inverted elements (`det F < 0`) the
//! sign-corrected rotation `U diag(1, 1, -1) V^T` of the SVD (Irving et al. 2004), so the
//! element pushes itself back out. Iteration of Mueller et al., "A Robust Method to Extract
//! the Rotational Part of Deformations" (MIG 2016): a quaternion is rotated by
//! `omega = sum_i r_i x f_i / (|sum_i r_i . f_i| + eps)` until `omega` vanishes. It always
//! returns a unit quaternion, never divides by zero, keeps the previous rotation for flat or
//! zero `F`, and converges in one or two iterations when warm-started from the last step.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion};

use crate::Vec3;

/// The rotation of the rigid motion that best maps the points `rest` onto `moved`, paired by
/// index (Kabsch: the rotation of the polar decomposition of their cross-covariance about
/// their centroids, by [`extract_rotation`] from the identity).
pub fn best_rotation(rest: &[Vec3], moved: &[Vec3]) -> UnitQuaternion<f64> {
    let n = rest.len().max(1) as f64;
    let (c0, c1) = (
        rest.iter().sum::<Vec3>() / n,
        moved.iter().sum::<Vec3>() / n,
    );
    let mut h = Matrix3::zeros();
    for (x, x0) in moved.iter().zip(rest) {
        h += (x - c1) * (x0 - c0).transpose();
    }
    let mut q = UnitQuaternion::identity();
    let mut r = Matrix3::identity();
    extract_rotation(&h, &mut q, &mut r, 100, 1e-12);
    q
}

/// Updates `q` (and `r`, its rotation matrix, which the caller keeps with it) towards the
/// rotation of `f`, for at most `max_iterations` updates or until the correction angle is
/// below `tolerance` radians. Returns the updates made.
///
/// Small corrections (below 0.1 rad, the usual case when warm-started) use the first-order
/// quaternion update `q <- normalize((1, omega / 2) q)`, whose angle error is third order and
/// is removed by the next iteration or step; larger ones use the exact exponential map.
pub fn extract_rotation(
    f: &Matrix3<f64>,
    q: &mut UnitQuaternion<f64>,
    r: &mut Matrix3<f64>,
    max_iterations: u32,
    tolerance: f64,
) -> u32 {
    let f0: Vec3 = f.column(0).into();
    let f1: Vec3 = f.column(1).into();
    let f2: Vec3 = f.column(2).into();
    if !(f0
        .iter()
        .chain(f1.iter())
        .chain(f2.iter())
        .all(|v| v.is_finite()))
    {
        return 0;
    }
    for it in 0..max_iterations {
        let r0: Vec3 = r.column(0).into();
        let r1: Vec3 = r.column(1).into();
        let r2: Vec3 = r.column(2).into();
        let num = r0.cross(&f0) + r1.cross(&f1) + r2.cross(&f2);
        let den = (r0.dot(&f0) + r1.dot(&f1) + r2.dot(&f2)).abs() + 1e-9;
        let omega = num / den;
        let w2 = omega.norm_squared();
        if w2 < tolerance * tolerance {
            return it;
        }
        if w2 < 0.01 {
            let h = omega * 0.5;
            let dq = Quaternion::new(1.0, h.x, h.y, h.z);
            *q = UnitQuaternion::new_normalize(dq * q.into_inner());
        } else {
            *q = UnitQuaternion::from_scaled_axis(omega) * *q;
            q.renormalize();
        }
        *r = *q.to_rotation_matrix().matrix();
    }
    max_iterations
}

/// Whether `s` is symmetric (the iteration converged) and positive definite (its leading
/// minors are > 0).
fn stretch_is_positive_definite(s: &Matrix3<f64>) -> bool {
    if (s - s.transpose()).norm() > 1e-9 * s.norm() {
        return false;
    }
    let m = (s + s.transpose()) * 0.5;
    let a = m[(0, 0)];
    let b = m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)];
    a > 0.0 && b > 0.0 && m.determinant() > 0.0
}

/// The rotation of `f` from a cold start, iterated to convergence (for tests and one-off
/// evaluations; steps use the warm-started [`extract_rotation`]).
pub fn rotation_of(f: &Matrix3<f64>) -> Matrix3<f64> {
    let mut q = UnitQuaternion::identity();
    let mut r = Matrix3::identity();
    extract_rotation(f, &mut q, &mut r, 200, 1e-15);
    // Where `R^T F` is positive definite, `R` is the rotation of the polar decomposition,
    // the best there is (the usual case: a mildly deformed element).
    if stretch_is_positive_definite(&(q.to_rotation_matrix().matrix().transpose() * f)) {
        return *q.to_rotation_matrix().matrix();
    }
    // A cold start may sit on a saddle (a half turn away); a second start from the found
    // rotation composed with each half turn picks the best.
    let mut best = q;
    let mut best_score = (q.to_rotation_matrix().matrix().transpose() * f).trace();
    for axis in [Vec3::x_axis(), Vec3::y_axis(), Vec3::z_axis()] {
        let mut q2 = UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI) * q;
        let mut r2 = *q2.to_rotation_matrix().matrix();
        extract_rotation(f, &mut q2, &mut r2, 200, 1e-15);
        let score = (q2.to_rotation_matrix().matrix().transpose() * f).trace();
        if score > best_score + 1e-12 {
            best = q2;
            best_score = score;
        }
    }
    *best.to_rotation_matrix().matrix()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn is_rotation(r: &Matrix3<f64>) -> bool {
        (r.transpose() * r - Matrix3::identity()).abs().max() < 1e-12
            && (r.determinant() - 1.0).abs() < 1e-12
    }

    /// Reference: SVD with the sign correction of Irving et al.
    fn svd_rotation(f: &Matrix3<f64>) -> Matrix3<f64> {
        let svd = f.svd(true, true);
        let (mut u, v_t) = (svd.u.unwrap(), svd.v_t.unwrap());
        let mut s = svd.singular_values;
        // nalgebra sorts singular values in decreasing order.
        if (u * v_t).determinant() < 0.0 {
            let k = (0..3).min_by(|&a, &b| s[a].total_cmp(&s[b])).unwrap();
            u.column_mut(k).neg_mut();
            s[k] = -s[k];
        }
        u * v_t
    }

    #[test]
    fn matches_polar_and_signed_svd() {
        let rot = Rotation3::from_euler_angles(0.7, -1.2, 2.5);
        let stretch = Matrix3::new(1.3, 0.2, 0.0, 0.2, 0.8, 0.1, 0.0, 0.1, 1.1);
        let cases = [
            *rot.matrix() * stretch,
            // inverted: a reflection through one axis
            *rot.matrix() * Matrix3::from_diagonal(&Vec3::new(1.2, 0.9, -0.3)),
            *rot.matrix() * Matrix3::from_diagonal(&Vec3::new(-0.5, 1.0, 1.4)),
        ];
        for f in cases {
            let r = rotation_of(&f);
            assert!(is_rotation(&r), "{r}");
            let reference = svd_rotation(&f);
            assert!((r - reference).abs().max() < 1e-9, "{r} vs {reference}");
        }
    }

    #[test]
    fn survives_flat_and_zero_gradients() {
        let rot = Rotation3::from_euler_angles(0.3, 0.2, -0.4);
        for f in [
            *rot.matrix() * Matrix3::from_diagonal(&Vec3::new(1.0, 1.0, 0.0)),
            *rot.matrix() * Matrix3::from_diagonal(&Vec3::new(1.0, 0.0, 0.0)),
            Matrix3::zeros(),
            Matrix3::from_element(f64::NAN),
        ] {
            let mut q = UnitQuaternion::identity();
            let mut m = Matrix3::identity();
            extract_rotation(&f, &mut q, &mut m, 50, 1e-12);
            let r = *q.to_rotation_matrix().matrix();
            assert!(is_rotation(&r), "{f} gave {r}");
        }
        // A flat element keeps the rotation of its plane.
        let f = *rot.matrix() * Matrix3::from_diagonal(&Vec3::new(1.0, 1.0, 0.0));
        assert!((rotation_of(&f) - rot.matrix()).abs().max() < 1e-9);
    }
}
