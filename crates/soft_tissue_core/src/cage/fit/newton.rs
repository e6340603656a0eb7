//! Newton steps through the face terms: where [`SurfaceFit`]'s fixed point does not
//! converge.
//!
//! The fit minimises `|Phi V + Psi T(V) - P|^2 + rho |V - V0|^2` over the surface points,
//! with `T` the face terms and `V0` the fit's start (its warm start: the last fit); the small
//! weight `rho` ([`PRIOR`] of the mean diagonal of `Phi^T Phi`) holds the cage vertices the
//! surface hardly sees, which would otherwise drift. The residual's Jacobian is
//! `J = Phi + Psi D`, `D = dT/dV` (each face's term depends on its own three vertices: exact
//! derivatives from [`GreenCoordinates::face_term_jacobians`]), and `J^T J` is assembled from
//! the Gram matrices `Phi^T Phi`, `Phi^T Psi` and `Psi^T Psi` (no pass over the surface); the
//! gradient `J^T r` from the residual formed point by point (one pass: from the Gram matrices it
//! cancels to rounding near a minimum with a residual left, and the steps stall). A
//! step solves `(H + lambda diag(J^T J) + mu I + rho I) dV = -g` with `H` the Hessian (`J^T J`
//! plus the face terms' second derivatives weighted by `Psi^T r`,
//! [`GreenCoordinates::face_term_curvatures`]), or with `H = J^T J` (Gauss-Newton) where that
//! matrix is not positive definite, by a dense Cholesky factorization (`faer`) of size
//! `3 x cage vertices`. Levenberg-Marquardt damping: `lambda` falls after a step that lowers
//! the objective and grows after one that does not. Converged when a step with `lambda` at
//! most 1e-3, not shortened by the fold guard, moves no surface point's image (linearised, `J dV`) by more than the tolerance:
//! directions the surface hardly sees do not hold a fit back. At most [`STEPS`] steps.
//! Velocities are linear in the cage velocities: one solve of `(J^T J + mu I) U = J^T v` with
//! `J` at the fitted cage.
//!
//! The objective also carries the fold guard's penalty (`fit::fold`): a cage face squeezed
//! below a fifth of its rest area is pushed back, and a step toward a face the model does not
//! see yet is shortened, then halved while it raises the objective (up to [`HALVINGS`]
//! times) before the damping grows.
//!
//! Measured on the cylinder's 128-vertex fitted cage (114 vertices, 224 faces) held precise
//! under `poke-a` (corotational FEM, 500 steps, `soft-tissue report --fig5-only`): the fixed
//! point converged in none of the 500 fits; these steps without the guard converged in 61
//! (439 stopped at their cap of 12: the fit followed the tool's dent by turning cage faces
//! over, where the face terms jump); with the guard 494 converge within 40 steps and all
//! 500 within 69 ([`SurfaceFit::set_newton_steps`]; the last ones creep down a slow valley,
//! each step barely damped and lowering the objective by about 1e-5 of itself). About 6 ms a
//! step there (2-core EPYC VM).

use super::{FitReport, SurfaceFit};
use crate::Vec3;
use crate::cage::GreenCoordinates;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::{factor, solve};
use faer::{Conj, MatMut, MatRef, Par};
use nalgebra::{DMatrix, Matrix3};

/// Newton steps (each one solve) a fit takes at most unless told otherwise
/// ([`SurfaceFit::set_newton_steps`]).
pub(super) const STEPS: u32 = 12;

/// Halvings of a step that raises the objective before the damping grows.
const HALVINGS: u32 = 6;

/// Relative change of the objective taken for rounding.
const ROUNDING: f64 = 1e-12;

/// The weight holding the cage near the fit's start, relative to the mean diagonal of
/// `Phi^T Phi` (see [`SurfaceFit::newton_positions`]).
const PRIOR: f64 = 1e-6;

/// The workspace, made the first time a fit falls back (see [`SurfaceFit::newton`]).
pub(super) struct Newton {
    /// `Psi^T Psi` over the surface points, cage faces x cage faces.
    psi_t_psi: DMatrix<f64>,
    /// Per face, `d t_j / d v` for its three vertices.
    jac: Vec<[Matrix3<f64>; 3]>,
    /// Per cage vertex, the faces it belongs to and its corner there: `corners[start[v]..
    /// start[v + 1]]`.
    start: Vec<u32>,
    corners: Vec<(u32, u8)>,
    /// Per face, scratch for one column block of `Psi^T Psi D`.
    e: Vec<Matrix3<f64>>,
    /// `J^T J` (row-major, `3 nv` square) and its damped factor.
    h: Vec<f64>,
    factor: Vec<f64>,
    /// `faer`'s scratch for the dense Cholesky factorization.
    stack: MemBuffer,
    /// The diagonal of `J^T J` (the damping's scale).
    diag: Vec<f64>,
    /// Per face, the weighted second derivatives of its term (Newton's part beyond
    /// Gauss-Newton).
    curvature: Vec<[f64; 81]>,
    /// Gradient `J^T r` (then the step), `3 nv`.
    grad: Vec<f64>,
    step: Vec<f64>,
    /// Per face: `Psi^T r`, and the face terms' change under a step.
    fw: Vec<Vec3>,
    fd: Vec<Vec3>,
    trial: Vec<Vec3>,
    /// The fit's start, which a small weight holds weakly determined vertices near.
    prior: Vec<Vec3>,
    /// That weight (0 for velocities).
    rho: f64,
}

impl Newton {
    fn new(coords: &GreenCoordinates, surface: &[u32]) -> Self {
        let (nv, nf) = (coords.vertex_count(), coords.face_count());
        let psi_s = DMatrix::from_fn(surface.len(), nf, |r, c| coords.psi(surface[r] as usize)[c]);
        let mut start = vec![0u32; nv + 1];
        for j in 0..nf {
            for v in coords.face_vertices(j) {
                start[v as usize + 1] += 1;
            }
        }
        for v in 0..nv {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut corners = vec![(0, 0); 3 * nf];
        for j in 0..nf {
            for (k, v) in coords.face_vertices(j).into_iter().enumerate() {
                let slot = &mut fill[v as usize];
                corners[*slot as usize] = (j as u32, k as u8);
                *slot += 1;
            }
        }
        let d = 3 * nv;
        Newton {
            psi_t_psi: psi_s.tr_mul(&psi_s),
            jac: vec![[Matrix3::zeros(); 3]; nf],
            start,
            corners,
            e: vec![Matrix3::zeros(); nf],
            h: vec![0.0; d * d],
            factor: vec![0.0; d * d],
            stack: MemBuffer::new(factor::cholesky_in_place_scratch::<f64>(
                d,
                Par::Seq,
                Default::default(),
            )),
            diag: vec![0.0; d],
            curvature: vec![[0.0; 81]; nf],
            grad: vec![0.0; d],
            step: vec![0.0; d],
            fw: vec![Vec3::zeros(); nf],
            fd: vec![Vec3::zeros(); nf],
            trial: vec![Vec3::zeros(); nv],
            prior: vec![Vec3::zeros(); nv],
            rho: 0.0,
        }
    }
}

/// `h[3r.., 3c..] += m` (row-major, `d` columns).
fn add_block(h: &mut [f64], d: usize, r: usize, c: usize, m: &Matrix3<f64>) {
    for a in 0..3 {
        let row = &mut h[(3 * r + a) * d + 3 * c..(3 * r + a) * d + 3 * c + 3];
        for (b, x) in row.iter_mut().enumerate() {
            *x += m[(a, b)];
        }
    }
}

/// The sum of squared distances between the surface points of `points` and the cage's exact
/// image of them (`terms`: scratch for the face terms).
fn sum_squares(
    phi_t: &DMatrix<f64>,
    surface: &[u32],
    coords: &GreenCoordinates,
    cage: &[Vec3],
    points: &[Vec3],
    terms: &mut [Vec3],
) -> f64 {
    coords.face_terms(cage, terms);
    let mut sum = 0.0;
    for (c, &i) in surface.iter().enumerate() {
        let i = i as usize;
        let mut acc = -points[i];
        for (w, v) in phi_t.column(c).iter().zip(cage) {
            acc += v * *w;
        }
        for (psi, t) in coords.psi(i).iter().zip(terms.iter()) {
            acc += t * *psi;
        }
        sum += acc.norm_squared();
    }
    sum
}

/// The larger, a NaN winning.
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

impl SurfaceFit {
    /// The workspace, made on first use.
    fn newton(&mut self, coords: &GreenCoordinates) -> &mut Newton {
        let surface = &self.surface;
        self.newton
            .get_or_insert_with(|| Box::new(Newton::new(coords, surface)))
    }

    /// The face terms (into `terms`) and their derivatives at `cage`, and `J^T J` there.
    fn assemble(&mut self, coords: &GreenCoordinates, cage: &[Vec3]) {
        self.newton(coords);
        let Some(n) = self.newton.as_mut() else {
            return;
        };
        coords.face_term_jacobians(cage, &mut self.terms, &mut n.jac);
        let (nv, nf) = (cage.len(), self.terms.len());
        let d = 3 * nv;
        let (a, b) = (&self.phi_t_phi, &self.phi_t_psi);
        n.h.fill(0.0);
        // Phi^T Phi, per axis.
        for v in 0..nv {
            for w in 0..nv {
                let x = a[(v, w)];
                for c in 0..3 {
                    n.h[(3 * v + c) * d + 3 * w + c] += x;
                }
            }
        }
        // Phi^T Psi D and its transpose.
        for j in 0..nf {
            for (k, w) in coords.face_vertices(j).into_iter().enumerate() {
                let jk = n.jac[j][k];
                for (v, &bvj) in b.column(j).iter().enumerate() {
                    if bvj == 0.0 {
                        continue;
                    }
                    let m = jk * bvj;
                    add_block(&mut n.h, d, v, w as usize, &m);
                    add_block(&mut n.h, d, w as usize, v, &m.transpose());
                }
            }
        }
        // D^T Psi^T Psi D, one column block (cage vertex) at a time.
        for w in 0..nv {
            n.e.fill(Matrix3::zeros());
            for &(j2, k2) in &n.corners[n.start[w] as usize..n.start[w + 1] as usize] {
                let m = n.jac[j2 as usize][k2 as usize];
                for (e, &c) in n.e.iter_mut().zip(n.psi_t_psi.column(j2 as usize).iter()) {
                    *e += m * c;
                }
            }
            for j in 0..nf {
                for (k, v) in coords.face_vertices(j).into_iter().enumerate() {
                    let m = n.jac[j][k].tr_mul(&n.e[j]);
                    add_block(&mut n.h, d, v as usize, w, &m);
                }
            }
        }
    }

    /// `J^T r` at `cage` into the workspace's gradient ([`SurfaceFit::assemble`] first, for
    /// the face terms and their derivatives), `r` the residual against `values`, and `Psi^T
    /// r` into the workspace's face weights. One pass over the surface: `r` is formed per
    /// point, not from the Gram matrices, whose difference `A V + B T - Phi^T P` cancels to
    /// rounding long before a fit with a residual left converges.
    fn gradient(&mut self, coords: &GreenCoordinates, cage: &[Vec3], values: &[Vec3]) {
        let Some(n) = self.newton.as_mut() else {
            return;
        };
        n.grad.fill(0.0);
        n.fw.fill(Vec3::zeros());
        for (c, &i) in self.surface.iter().enumerate() {
            let i = i as usize;
            let phi = self.phi_t.column(c);
            let psi = coords.psi(i);
            let mut r = -values[i];
            for (x, w) in cage.iter().zip(phi.iter()) {
                r += x * *w;
            }
            for (t, w) in self.terms.iter().zip(psi) {
                r += t * *w;
            }
            for (v, w) in phi.iter().enumerate() {
                for a in 0..3 {
                    n.grad[3 * v + a] += w * r[a];
                }
            }
            for (f, w) in n.fw.iter_mut().zip(psi) {
                *f += r * *w;
            }
        }
        // Through the face terms' derivatives.
        for (j, (jf, w)) in n.jac.iter().zip(&n.fw).enumerate() {
            for (k, v) in coords.face_vertices(j).into_iter().enumerate() {
                let g = jf[k].tr_mul(w);
                let v = v as usize;
                for c in 0..3 {
                    n.grad[3 * v + c] += g[c];
                }
            }
        }
    }

    /// The face terms' second derivatives weighted by `Psi^T r` (after
    /// [`SurfaceFit::gradient`]), and `diag(J^T J)`: with `J^T J` the Hessian of half the
    /// squared residual (Newton's part beyond Gauss-Newton, which near a minimum with a
    /// residual left crawls).
    fn add_curvature(&mut self, coords: &GreenCoordinates, cage: &[Vec3]) {
        let Some(n) = self.newton.as_mut() else {
            return;
        };
        let d = n.grad.len();
        for i in 0..d {
            n.diag[i] = n.h[i * d + i];
        }
        coords.face_term_curvatures(cage, &n.fw, &mut n.curvature);
    }

    /// Solves `(J^T J [+ curvature] + lambda diag(J^T J) + (mu + rho) I) step = -grad`; false
    /// when the matrix is not positive definite.
    fn solve(&mut self, coords: &GreenCoordinates, lambda: f64, curvature: bool) -> bool {
        let mu = self.mu;
        let Some(n) = self.newton.as_mut() else {
            return false;
        };
        let d = n.grad.len();
        n.factor.copy_from_slice(&n.h);
        for i in 0..d {
            n.factor[i * d + i] += lambda * n.diag[i] + mu + n.rho;
        }
        if curvature {
            for (j, o) in n.curvature.iter().enumerate() {
                let v = coords.face_vertices(j).map(|v| v as usize);
                for r in 0..9 {
                    let row = 3 * v[r / 3] + r % 3;
                    for c in 0..9 {
                        n.factor[row * d + 3 * v[c / 3] + c % 3] += o[r * 9 + c];
                    }
                }
            }
        }
        // Symmetric, so its row-major storage is its column-major one.
        let a = MatMut::from_column_major_slice_mut(&mut n.factor, d, d);
        if factor::cholesky_in_place(
            a,
            Default::default(),
            Par::Seq,
            MemStack::new(&mut n.stack),
            Default::default(),
        )
        .is_err()
        {
            return false;
        }
        for (s, g) in n.step.iter_mut().zip(&n.grad) {
            *s = -g;
        }
        solve::solve_in_place_with_conj(
            MatRef::from_column_major_slice(&n.factor, d, d),
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut n.step, d, 1),
            Par::Seq,
            MemStack::new(&mut n.stack),
        );
        n.step.iter().all(|x| x.is_finite())
    }

    /// The largest motion of a surface point's image under the step, linearised (`J step`):
    /// directions the surface hardly sees do not hold a fit back.
    fn surface_change(&mut self, coords: &GreenCoordinates) -> f64 {
        let Some(n) = self.newton.as_mut() else {
            return f64::INFINITY;
        };
        let step = |v: usize| Vec3::new(n.step[3 * v], n.step[3 * v + 1], n.step[3 * v + 2]);
        for (j, (jf, d)) in n.jac.iter().zip(n.fd.iter_mut()).enumerate() {
            let [a, b, c] = coords.face_vertices(j).map(|v| v as usize);
            *d = jf[0] * step(a) + jf[1] * step(b) + jf[2] * step(c);
        }
        let mut worst: f64 = 0.0;
        for (c, &i) in self.surface.iter().enumerate() {
            let mut m = Vec3::zeros();
            for (v, w) in self.phi_t.column(c).iter().enumerate() {
                m += step(v) * *w;
            }
            for (d, w) in n.fd.iter().zip(coords.psi(i as usize)) {
                m += d * *w;
            }
            worst = nan_max(worst, m.norm());
        }
        worst
    }

    /// `|r|^2 + rho |V - prior|^2` at `cage`.
    fn objective(&mut self, coords: &GreenCoordinates, cage: &[Vec3], points: &[Vec3]) -> f64 {
        let squares = sum_squares(
            &self.phi_t,
            &self.surface,
            coords,
            cage,
            points,
            &mut self.terms,
        );
        let Some(n) = self.newton.as_ref() else {
            return squares;
        };
        let prior: f64 = cage
            .iter()
            .zip(&n.prior)
            .map(|(x, p)| (x - p).norm_squared())
            .sum();
        squares + n.rho * prior + self.guard.penalty(coords, cage)
    }

    /// Newton fit of the positions (see the module docs), from the better of the fit's
    /// start (in `moved`) and `cage`, where the fixed point ended after `iterations_before`
    /// iterations.
    pub(super) fn newton_positions(
        &mut self,
        coords: &GreenCoordinates,
        points: &[Vec3],
        cage: &mut [Vec3],
        tolerance: f64,
        iterations_before: u32,
    ) -> FitReport {
        self.newton(coords);
        let nv = cage.len();
        let rho = PRIOR * self.phi_t_phi.trace() / nv as f64;
        if let Some(n) = self.newton.as_mut() {
            n.prior.copy_from_slice(&self.moved);
            n.rho = rho;
        }
        self.guard.orient(coords, &self.moved, self.surface.len());
        let mut report = FitReport {
            iterations: iterations_before,
            change: f64::INFINITY,
            converged: false,
        };
        let start = std::mem::take(&mut self.moved);
        let f_start = self.objective(coords, &start, points);
        let mut f = self.objective(coords, cage, points);
        // The start where the fixed point ended worse (or not finite).
        if f.is_nan() || f > f_start {
            cage.copy_from_slice(&start);
            f = f_start;
        }
        self.moved = start;
        if !f.is_finite() {
            return report;
        }
        let mut lambda = 1e-6;
        let mut fresh = true;
        for _ in 0..self.newton_steps {
            if fresh {
                self.assemble(coords, cage);
                self.gradient(coords, cage, points);
                self.add_curvature(coords, cage);
                if let Some(n) = self.newton.as_mut() {
                    for (v, (x, p)) in cage.iter().zip(&n.prior).enumerate() {
                        for c in 0..3 {
                            n.grad[3 * v + c] += rho * (x[c] - p[c]);
                        }
                    }
                    self.guard
                        .add(coords, cage, &mut n.h, &mut n.grad, &mut n.curvature);
                    let d = n.grad.len();
                    for i in 0..d {
                        n.diag[i] = n.h[i * d + i];
                    }
                }
            }
            report.iterations += 1;
            // Newton where its matrix is positive definite, Gauss-Newton otherwise.
            if !self.solve(coords, lambda, true) && !self.solve(coords, lambda, false) {
                lambda *= 10.0;
                fresh = false;
                if lambda > 1e12 {
                    break;
                }
                continue;
            }
            // A step into a face the model does not see yet is shortened (`fit::fold`).
            let limit = match self.newton.as_mut() {
                Some(n) => {
                    let a = self.guard.step_limit(coords, cage, &n.step);
                    if a < 1.0 {
                        n.step.iter_mut().for_each(|x| *x *= a);
                    }
                    a
                }
                None => 1.0,
            };
            let change = self.surface_change(coords);
            let Some(n) = self.newton.as_mut() else {
                return report;
            };
            report.change = change;
            let mut trial = std::mem::take(&mut n.trial);
            // A step that raises the objective by no more than rounding is taken; one that
            // raises it more is halved up to [`HALVINGS`] times (an objective costs a pass
            // over the surface, a fresh damping a factorization).
            let (mut f_trial, mut taken, mut alpha) = (f, false, 1.0);
            for halving in 0..=HALVINGS {
                if halving > 0 {
                    alpha *= 0.5;
                }
                if let Some(n) = self.newton.as_ref() {
                    for (v, (t, x)) in trial.iter_mut().zip(cage.iter()).enumerate() {
                        *t = x + Vec3::new(n.step[3 * v], n.step[3 * v + 1], n.step[3 * v + 2])
                            * alpha;
                    }
                }
                f_trial = self.objective(coords, &trial, points);
                taken = f_trial <= f + ROUNDING * f;
                if taken {
                    break;
                }
            }
            let full = limit >= 1.0 && alpha >= 1.0;
            if taken {
                cage.copy_from_slice(&trial);
                f = f_trial;
            }
            if let Some(n) = self.newton.as_mut() {
                n.trial = trial;
            }
            // Converged: a barely damped step, not shortened, that the surface does not see.
            if change <= tolerance && lambda <= 1e-3 && limit >= 1.0 {
                report.converged = true;
                return report;
            }
            fresh = taken;
            lambda = if taken && full {
                (lambda * 0.25).max(1e-12)
            } else if taken {
                lambda
            } else {
                lambda * 10.0
            };
            if lambda > 1e12 {
                break;
            }
        }
        report
    }

    /// The velocity fit as one least-squares solve with `J` at `cage`.
    pub(super) fn newton_velocities(
        &mut self,
        coords: &GreenCoordinates,
        cage: &[Vec3],
        point_velocities: &[Vec3],
        velocities: &mut [Vec3],
        iterations_before: u32,
    ) -> FitReport {
        self.newton(coords);
        self.assemble(coords, cage);
        if let Some(n) = self.newton.as_mut() {
            n.rho = 0.0;
            let d = n.grad.len();
            for i in 0..d {
                n.diag[i] = n.h[i * d + i];
            }
        }
        // At zero cage velocities (and zero face terms) the gradient is `-J^T v`.
        self.terms.fill(Vec3::zeros());
        let mut zero = std::mem::take(&mut self.mapped);
        zero.fill(Vec3::zeros());
        self.gradient(coords, &zero, point_velocities);
        self.mapped = zero;
        let solved = self.solve(coords, 0.0, false);
        let mut change: f64 = 0.0;
        if let Some(n) = self.newton.as_ref() {
            for (v, u) in velocities.iter_mut().enumerate() {
                let s = Vec3::new(n.step[3 * v], n.step[3 * v + 1], n.step[3 * v + 2]);
                change = change.max((s - *u).norm());
                *u = s;
            }
        }
        FitReport {
            iterations: iterations_before + 1,
            change,
            converged: solved && change.is_finite(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{add_face_blocks, assert_derivatives, liver_cage};
    use super::*;

    /// The gradient against central differences of the sum of squares, and the Hessian
    /// (`J^T J` plus the curvature) against central differences of the gradient.
    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        let (mesh, cage, coords) = liver_cage();
        let surface: Vec<u32> = (0..mesh.positions().len() as u32).step_by(3).collect();
        let mut fit = SurfaceFit::new(&coords, &surface).unwrap();
        // Target points: the rest points bent, so the residual is not zero.
        let points: Vec<Vec3> = mesh
            .positions()
            .iter()
            .map(|p| p + Vec3::new(0.1 * p.y * p.y, 0.05 * p.x, -0.02 * p.z * p.x))
            .collect();
        let x: Vec<Vec3> = cage
            .vertices()
            .iter()
            .enumerate()
            .map(|(i, v)| v + Vec3::new(0.01 * (i as f64).sin(), 0.02, -0.01 * (i as f64).cos()))
            .collect();
        fit.newton(&coords);
        fit.assemble(&coords, &x);
        fit.gradient(&coords, &x, &points);
        fit.add_curvature(&coords, &x);
        let n = fit.newton.as_ref().unwrap();
        let (grad, mut h) = (n.grad.clone(), n.h.clone());
        add_face_blocks(&coords, &n.curvature, &mut h);
        // `mu` and `rho` are added when solving.
        assert_derivatives(&x, &grad, &h, |y| {
            let f = 0.5
                * sum_squares(
                    &fit.phi_t,
                    &fit.surface,
                    &coords,
                    y,
                    &points,
                    &mut fit.terms,
                );
            fit.assemble(&coords, y);
            fit.gradient(&coords, y, &points);
            (f, fit.newton.as_ref().unwrap().grad.clone())
        });
    }
}
