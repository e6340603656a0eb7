//! Keeping a fitted cage unfolded: a penalty on cage faces whose area shrinks toward zero or
//! turns over.
//!
//! A face term of the Green coordinates is the deformed face's unit normal times a stretch
//! factor (`GreenCoordinates::face_terms`): where a deformed face passes through zero area
//! its normal flips, and the map from cage to surface jumps. Measured on the cylinder's
//! 128-vertex fitted cage under `poke-a` (Fig. 5, corotational FEM), the unconstrained
//! least-squares fit follows the tool's dent by folding cage faces: after step 61, 6-13
//! faces were below a fifth of their rest area and the worst one turned over (area ratio
//! -0.05 to -0.27), the objective's gradient there was 1e3-1e6 times that of the earlier
//! fits, and no Newton or Gauss-Newton step converged (439 of 500 fits stopped at their step
//! cap). A folded cage is also no cage for the cage level to run from. So the fit minimises
//! `|r|^2 + K sum_j a_j (delta - s_j)_+^3 / delta` over cages, with `s_j` the face's signed
//! area ratio `m_j . c'_j / |c_j|` (`c` the face's cross product, rest and deformed; `m_j` the
//! rest unit normal turned by the rigid rotation that best maps the rest cage onto the fit's
//! start, held for the fit), `a_j` the face's rest area, [`MARGIN`] for `delta` and
//! [`WEIGHT`] times the surface points for `K`: a face brought to zero area costs as much as
//! every surface point `sqrt(WEIGHT) delta sqrt(a_j)` (twice the face's size) off. Cubic in
//! the shortfall, so its Hessian is continuous where a face reaches the margin (a quadratic
//! penalty's jumps there: 82 fits of the 500 missed with it, 71 with the cubic one, before
//! the step limit, [`FoldGuard::step_limit`], that `fit::newton` uses); each `s_j` is quadratic in the
//! cage, so the penalty's Gauss-Newton part and exact second derivatives are written out here.

use crate::Vec3;
use crate::cage::GreenCoordinates;
use nalgebra::Matrix3;

/// The area ratio below which a face is pushed back.
pub(super) const MARGIN: f64 = 0.2;

/// The penalty's weight per surface point (see the module docs).
pub(super) const WEIGHT: f64 = 100.0;

/// Per face of a fit: the turned rest normal over the rest `|c|` (so `s_j = axis_j . c'_j`)
/// and the weight `K a_j`.
#[derive(Debug)]
pub(super) struct FoldGuard {
    axis: Vec<Vec3>,
    weight: Vec<f64>,
}

/// The derivatives of `m . (e1 x e2)` by the face's three vertices (`e1`, `e2` its edges
/// from the first): `e2 x m`, `m x e1` and minus their sum for the first.
fn ratio_gradient(m: &Vec3, e1: &Vec3, e2: &Vec3) -> [Vec3; 3] {
    let (g1, g2) = (e2.cross(m), m.cross(e1));
    [-(g1 + g2), g1, g2]
}

/// `u' x v'` of face `j` in `cage` and its edges from the first vertex.
fn cross(coords: &GreenCoordinates, cage: &[Vec3], j: usize) -> ([usize; 3], Vec3, Vec3, Vec3) {
    let v = coords.face_vertices(j).map(|v| v as usize);
    let (e1, e2) = (cage[v[1]] - cage[v[0]], cage[v[2]] - cage[v[0]]);
    (v, e1, e2, e1.cross(&e2))
}

impl FoldGuard {
    /// Room for `faces` faces.
    pub(super) fn new(faces: usize) -> Self {
        FoldGuard {
            axis: vec![Vec3::zeros(); faces],
            weight: vec![0.0; faces],
        }
    }

    /// Orients the guard for a fit starting at `start`, with `surface_points` points fitted.
    pub(super) fn orient(
        &mut self,
        coords: &GreenCoordinates,
        start: &[Vec3],
        surface_points: usize,
    ) {
        let rest = coords.rest_cage_vertices();
        let nf = coords.face_count().min(self.axis.len());
        let rotation = crate::fem::rotation::best_rotation(rest, start);
        for j in 0..nf {
            let (_, _, _, c) = cross(coords, rest, j);
            let len = c.norm();
            if len > 0.0 {
                self.axis[j] = rotation * c / (len * len);
                self.weight[j] = WEIGHT * surface_points as f64 * 0.5 * len;
            } else {
                self.axis[j] = Vec3::zeros();
                self.weight[j] = 0.0;
            }
        }
    }

    /// The signed area ratio of face `j` of `cage`.
    pub(super) fn ratio(&self, coords: &GreenCoordinates, cage: &[Vec3], j: usize) -> f64 {
        self.axis[j].dot(&cross(coords, cage, j).3)
    }

    /// The penalty at `cage`.
    pub(super) fn penalty(&self, coords: &GreenCoordinates, cage: &[Vec3]) -> f64 {
        (0..self.weight.len())
            .filter(|&j| self.weight[j] > 0.0)
            .map(|j| {
                let short = (MARGIN - self.ratio(coords, cage, j)).max(0.0);
                self.weight[j] * short * short * short / MARGIN
            })
            .sum()
    }

    /// Adds half the penalty's gradient to `grad`, its Gauss-Newton part to `h` (row-major,
    /// `d` columns) and the rest of its Hessian to the faces' `curvature` blocks (as
    /// `GreenCoordinates::face_term_curvatures` orders them).
    pub(super) fn add(
        &self,
        coords: &GreenCoordinates,
        cage: &[Vec3],
        h: &mut [f64],
        grad: &mut [f64],
        curvature: &mut [[f64; 81]],
    ) {
        let d = grad.len();
        for j in 0..self.weight.len() {
            let (w, m) = (self.weight[j], self.axis[j]);
            let (v, e1, e2, c) = cross(coords, cage, j);
            let short = MARGIN - m.dot(&c);
            if w <= 0.0 || short <= 0.0 {
                continue;
            }
            let ds = ratio_gradient(&m, &e1, &e2);
            // P = w short^3 / MARGIN: half its gradient -1.5 w short^2 / MARGIN ds, half its
            // Hessian 3 w short / MARGIN ds ds^T - 1.5 w short^2 / MARGIN d2s.
            let (g, gg) = (1.5 * w * short * short / MARGIN, 3.0 * w * short / MARGIN);
            for (k, dk) in ds.iter().enumerate() {
                for a in 0..3 {
                    grad[3 * v[k] + a] -= g * dk[a];
                }
                for (l, dl) in ds.iter().enumerate() {
                    let block = dk * dl.transpose() * gg;
                    for a in 0..3 {
                        let row = &mut h[(3 * v[k] + a) * d + 3 * v[l]..][..3];
                        for b in 0..3 {
                            row[b] += block[(a, b)];
                        }
                    }
                }
            }
            // Half the penalty's second derivative beyond Gauss-Newton: -1.5 w short^2 / MARGIN d2s, with
            // d2s/dv1 dv2 = -[m]x (and its transpose), v0 through e1 = v1 - v0, e2 = v2 - v0.
            let s12 = -m.cross_matrix() * (-g);
            let mut full = [[Matrix3::zeros(); 3]; 3];
            // In (e1, e2) the second derivative is [[0, s12], [s12^T, 0]]; with
            // e1 = v1 - v0, e2 = v2 - v0 the v0 rows and columns take minus the sums.
            let e = [[Matrix3::zeros(), s12], [s12.transpose(), Matrix3::zeros()]];
            let t = |k: usize, i: usize| -> f64 {
                // d e_i / d v_k
                match (k, i) {
                    (0, _) => -1.0,
                    (1, 0) | (2, 1) => 1.0,
                    _ => 0.0,
                }
            };
            for k in 0..3 {
                for l in 0..3 {
                    for i in 0..2 {
                        for jj in 0..2 {
                            full[k][l] += e[i][jj] * (t(k, i) * t(l, jj));
                        }
                    }
                }
            }
            let o = &mut curvature[j];
            for k in 0..3 {
                for l in 0..3 {
                    for a in 0..3 {
                        for b in 0..3 {
                            o[(3 * k + a) * 9 + 3 * l + b] += full[k][l][(a, b)];
                        }
                    }
                }
            }
        }
    }

    /// The largest fraction (at most 1) of the step `step` (3 per cage vertex) after which
    /// no guarded face, linearised, has fallen more than a tenth of the margin below it, if
    /// it was above (the fit's quadratic model does not see such a face yet), or lost more
    /// than half its area ratio, if it was below (fraction to the boundary, as interior-point
    /// methods keep their iterates inside).
    pub(super) fn step_limit(&self, coords: &GreenCoordinates, cage: &[Vec3], step: &[f64]) -> f64 {
        let at = |v: usize| Vec3::new(step[3 * v], step[3 * v + 1], step[3 * v + 2]);
        let mut alpha: f64 = 1.0;
        for j in 0..self.weight.len() {
            if self.weight[j] <= 0.0 {
                continue;
            }
            let m = self.axis[j];
            let (v, e1, e2, c) = cross(coords, cage, j);
            let s = m.dot(&c);
            let ds: f64 = ratio_gradient(&m, &e1, &e2)
                .iter()
                .zip(v)
                .map(|(g, v)| g.dot(&at(v)))
                .sum();
            // A face the model sees (below the margin) may lose half its ratio; one it does
            // not see stops a tenth of the margin inside it.
            let floor = if s > MARGIN { 0.9 * MARGIN } else { 0.5 * s };
            if s > 0.0 && s + ds < floor {
                alpha = alpha.min((s - floor) / -ds);
            }
        }
        alpha
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{add_face_blocks, assert_derivatives, liver_cage};
    use super::*;
    use nalgebra::UnitQuaternion;

    /// Half the penalty's gradient and Hessian against central differences of the penalty,
    /// on a cage squashed and turned so that some faces are below the margin and some turned
    /// over; and a cage moved rigidly costs nothing.
    #[test]
    fn the_penalty_derivatives_match_finite_differences() {
        let (_, cage, coords) = liver_cage();
        let turn = UnitQuaternion::from_euler_angles(0.3, -0.2, 0.5);
        let turned: Vec<Vec3> = cage.vertices().iter().map(|v| turn * v).collect();
        let mut guard = FoldGuard::new(coords.face_count());
        guard.orient(&coords, &turned, 10);
        assert_eq!(guard.penalty(&coords, &turned), 0.0);
        // Squashed along one axis (areas of faces across it shrink), a wobble turning some
        // faces over, then turned.
        let x: Vec<Vec3> = cage
            .vertices()
            .iter()
            .enumerate()
            .map(|(i, v)| turn * Vec3::new(0.1 * v.x, v.y, v.z + 0.3 * (7.0 * i as f64).sin()))
            .collect();
        let ratios: Vec<f64> = (0..coords.face_count())
            .map(|j| guard.ratio(&coords, &x, j))
            .collect();
        let below = ratios.iter().filter(|&&r| r < MARGIN).count();
        let over = ratios.iter().filter(|&&r| r < 0.0).count();
        assert!(
            below > 10 && over > 0,
            "{below} below the margin, {over} over"
        );
        let (d, nf) = (3 * x.len(), coords.face_count());
        let half = |y: &[Vec3]| {
            let (mut h, mut g, mut c) = (vec![0.0; d * d], vec![0.0; d], vec![[0.0; 81]; nf]);
            guard.add(&coords, y, &mut h, &mut g, &mut c);
            add_face_blocks(&coords, &c, &mut h);
            (0.5 * guard.penalty(&coords, y), g, h)
        };
        let (_, grad, h) = half(&x);
        assert_derivatives(&x, &grad, &h, |y| {
            let (f, g, _) = half(y);
            (f, g)
        });
    }
}
