//! Fitting a cage to a body's surface: the cage vertex positions (and velocities) whose Green
//! coordinates best reproduce given surface positions (and velocities), in the least-squares
//! sense. What a down-switch uses to hand a precise body over to its cage.
//!
//! The map is `P = Phi V + Psi T(V)` with `T` the face terms (unit normals times stretch
//! factors, nonlinear in the cage `V`). For fixed face terms the best cage solves the normal
//! equations `(Phi^T Phi + mu I) V = Phi^T P - (Phi^T Psi) T + mu V_prev` (factorized once; the
//! small Tikhonov term `mu` regularises the solve and vanishes at the fixed point); the face
//! terms are then refreshed from the new cage. `Phi^T P` is computed once per fit and
//! `Phi^T Psi` once per body, so an iteration costs `O(cage vertices x cage faces)`, not a pass
//! over the surface. The fixed-point iteration converges linearly (about 0.7 per iteration on
//! the organs with a box cage), roughly twice as fast with Anderson mixing over the last five
//! iterates (Walker and Ni 2011). Velocities: `v = Phi U + Psi dT/dV U`, linear in `U`,
//! solved the same way with the face-term rate from central differences.
//!
//! The fixed point's limit makes the residual orthogonal to `Phi` only (it is not the
//! least-squares minimum: on the 32-vertex fitted cylinder cage a random move of 1e-4 of the
//! size lowered its sum of squares by 0.09 %), and where the face terms weigh much (the
//! 128-vertex fitted cylinder cage in Fig. 5) it is not a contraction. When it does not
//! converge, damped Newton steps through the face terms take over (`fit::newton`): they
//! minimise `|Phi V + Psi T(V) - P|^2` itself (with a small pull toward the fit's start and
//! the fold guard's penalty, `fit::fold`), and once the fixed point has failed, later fits of
//! that body start with them. A fixed point that converged stands, folded or not: on the box
//! cages of three organs settled on a table (`tests/contact.rs`'s stack) two down-switch fits
//! converged with a face turned over (area ratios -0.11 and -0.31), and sending those to the
//! guarded Newton steps left them unconverged after 12 steps and the stomach's cage then
//! pressed 1.2e-2 of its size into the table.
//!
//! A fit touches the surface twice: `Phi^T P` and the residual. Nothing allocates after
//! [`SurfaceFit::new`] except the Newton fallback's workspace, made the first time a fit
//! needs it and kept (fits whose fixed point converges never pay for it).

// Index loops over small dense matrices read clearer than iterator chains here.
#![allow(clippy::needless_range_loop)]

use nalgebra::DMatrix;

use super::{CageError, GreenCoordinates};
use crate::Vec3;

mod fold;
mod newton;
#[cfg(test)]
mod testing;

/// Past iterates Anderson mixing combines.
const WINDOW: usize = 5;

/// How a fit ended.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FitReport {
    /// Fixed-point iterations (each one normal-equation solve).
    pub iterations: u32,
    /// Largest change in the last iteration: of a cage vertex (the fixed point), or of a
    /// surface point's image under the step (the Newton fallback).
    pub change: f64,
    /// Whether the change fell below the tolerance.
    pub converged: bool,
}

/// Anderson mixing of a fixed-point iteration `x <- g(x)` over vectors of points.
#[derive(Debug)]
struct Anderson {
    df: Vec<Vec<Vec3>>,
    dg: Vec<Vec<Vec3>>,
    f_prev: Vec<Vec3>,
    g_prev: Vec<Vec3>,
    f_norm_prev: f64,
    /// Columns in the window, the next to overwrite, and whether `*_prev` hold an iterate.
    len: usize,
    head: usize,
    primed: bool,
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

impl Anderson {
    fn new(d: usize) -> Self {
        Anderson {
            df: vec![vec![Vec3::zeros(); d]; WINDOW],
            dg: vec![vec![Vec3::zeros(); d]; WINDOW],
            f_prev: vec![Vec3::zeros(); d],
            g_prev: vec![Vec3::zeros(); d],
            f_norm_prev: f64::INFINITY,
            len: 0,
            head: 0,
            primed: false,
        }
    }

    fn reset(&mut self) {
        self.restart();
        self.primed = false;
        self.f_norm_prev = f64::INFINITY;
    }

    /// Empties the window (the columns are read from index 0 up, so the next one goes there).
    fn restart(&mut self) {
        self.len = 0;
        self.head = 0;
    }

    /// With `x` the current iterate and `g = g(x)`, writes the next iterate into `x`.
    fn step(&mut self, x: &mut [Vec3], g: &[Vec3]) {
        // f = g - x, kept in f_prev's place after the differences are taken.
        let mut f_norm = 0.0;
        if self.primed {
            let h = self.head;
            for i in 0..x.len() {
                let f = g[i] - x[i];
                self.df[h][i] = f - self.f_prev[i];
                self.dg[h][i] = g[i] - self.g_prev[i];
                self.f_prev[i] = f;
                self.g_prev[i] = g[i];
                f_norm += f.norm_squared();
            }
            self.head = (h + 1) % WINDOW;
            self.len = (self.len + 1).min(WINDOW);
        } else {
            for i in 0..x.len() {
                let f = g[i] - x[i];
                self.f_prev[i] = f;
                self.g_prev[i] = g[i];
                f_norm += f.norm_squared();
            }
            self.primed = true;
        }
        // Safeguard: when mixing stopped reducing the residual, start the window afresh.
        if f_norm > self.f_norm_prev {
            self.restart();
        }
        self.f_norm_prev = f_norm;
        x.copy_from_slice(g);
        let m = self.len;
        if m == 0 {
            return;
        }
        // gamma = argmin |f - dF gamma|: normal equations, lightly regularised.
        let mut a = [[0.0f64; WINDOW]; WINDOW];
        let mut b = [0.0f64; WINDOW];
        for i in 0..m {
            for j in 0..=i {
                let v = dot(&self.df[i], &self.df[j]);
                a[i][j] = v;
                a[j][i] = v;
            }
            b[i] = dot(&self.df[i], &self.f_prev);
        }
        let trace: f64 = (0..m).map(|i| a[i][i]).sum();
        if !(trace.is_finite() && trace > 0.0) {
            self.restart();
            return;
        }
        for (i, row) in a.iter_mut().enumerate().take(m) {
            row[i] += 1e-10 * trace / m as f64;
        }
        let Some(gamma) = solve_spd(&mut a, &mut b, m) else {
            self.restart();
            return;
        };
        for (k, gk) in gamma.iter().enumerate().take(m) {
            for (xi, d) in x.iter_mut().zip(&self.dg[k]) {
                *xi -= d * *gk;
            }
        }
    }
}

/// Solves the symmetric positive definite `m x m` system in place by Cholesky; `None` when it
/// is not positive definite.
fn solve_spd(
    a: &mut [[f64; WINDOW]; WINDOW],
    b: &mut [f64; WINDOW],
    m: usize,
) -> Option<[f64; WINDOW]> {
    for j in 0..m {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if d.is_nan() || d <= 0.0 {
            return None;
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..m {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    for i in 0..m {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i][k] * b[k];
        }
        b[i] = s / a[i][i];
    }
    for i in (0..m).rev() {
        let mut s = b[i];
        for k in i + 1..m {
            s -= a[k][i] * b[k];
        }
        b[i] = s / a[i][i];
    }
    Some(*b)
}

/// The least-squares fit of a cage to the surface points of a body (see the module docs).
pub struct SurfaceFit {
    surface: Vec<u32>,
    phi_t: DMatrix<f64>,
    /// `Phi^T Psi` over the surface points: cage vertices x cage faces.
    phi_t_psi: DMatrix<f64>,
    /// `Phi^T` times the values fitted (positions or velocities), cage vertices x 3.
    fixed_rhs: DMatrix<f64>,
    normal: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    mu: f64,
    terms: Vec<Vec3>,
    rate: Vec<Vec3>,
    moved: Vec<Vec3>,
    mapped: Vec<Vec3>,
    rhs: DMatrix<f64>,
    anderson: Anderson,
    /// `Phi^T Phi` over the surface points (without `mu`), for the Gauss-Newton fallback.
    phi_t_phi: DMatrix<f64>,
    /// The Gauss-Newton fallback's workspace, made when first needed.
    newton: Option<Box<newton::Newton>>,
    /// The penalty on folding cage faces (`fit::fold`), oriented at each fit's start.
    guard: fold::FoldGuard,
    /// Newton steps a fit takes at most.
    newton_steps: u32,
}

impl std::fmt::Debug for SurfaceFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SurfaceFit")
            .field("surface", &self.surface.len())
            .field("cage_vertices", &self.phi_t.nrows())
            .finish()
    }
}

impl SurfaceFit {
    /// The fit of `coords`' cage to the embedded points `surface` (indices into the points
    /// the coordinates were computed for). Fails when the normal matrix is singular.
    pub fn new(coords: &GreenCoordinates, surface: &[u32]) -> Result<Self, CageError> {
        let nv = coords.vertex_count();
        let nf = coords.face_count();
        if let Some(&bad) = surface
            .iter()
            .find(|&&i| i as usize >= coords.point_count())
        {
            return Err(CageError::InvalidArgument {
                field: "surface",
                message: format!(
                    "point {bad} is past the {} embedded points",
                    coords.point_count()
                ),
            });
        }
        let phi_t = DMatrix::from_fn(nv, surface.len(), |r, c| coords.phi(surface[c] as usize)[r]);
        let phi_t_phi = &phi_t * phi_t.transpose();
        let mut normal = phi_t_phi.clone();
        let mu = 1e-8 * normal.trace() / nv as f64;
        for i in 0..nv {
            normal[(i, i)] += mu;
        }
        let mut phi_t_psi = DMatrix::zeros(nv, nf);
        for (c, &i) in surface.iter().enumerate() {
            let psi = coords.psi(i as usize);
            for r in 0..nv {
                let w = phi_t[(r, c)];
                for (j, p) in psi.iter().enumerate() {
                    phi_t_psi[(r, j)] += w * p;
                }
            }
        }
        let normal = normal
            .cholesky()
            .ok_or_else(|| CageError::InvalidArgument {
                field: "surface",
                message: "the surface points do not determine the cage (singular fit)".into(),
            })?;
        Ok(SurfaceFit {
            surface: surface.to_vec(),
            phi_t,
            phi_t_psi,
            fixed_rhs: DMatrix::zeros(nv, 3),
            normal,
            mu,
            terms: vec![Vec3::zeros(); nf],
            rate: vec![Vec3::zeros(); nf],
            moved: vec![Vec3::zeros(); nv],
            mapped: vec![Vec3::zeros(); nv],
            rhs: DMatrix::zeros(nv, 3),
            anderson: Anderson::new(nv),
            phi_t_phi,
            newton: None,
            guard: fold::FoldGuard::new(nf),
            newton_steps: newton::STEPS,
        })
    }

    /// How many Newton steps a fit whose fixed point does not converge takes at most (12
    /// unless set; each is a dense factorization of size 3 x cage vertices, about 6 ms on
    /// the 114-vertex fitted cylinder cage). Fits warm-start from the last one, so a fit
    /// stopped at the cap goes on from there the next time.
    pub fn set_newton_steps(&mut self, steps: u32) {
        self.newton_steps = steps;
    }

    /// The surface points fitted (indices into the embedded points).
    pub fn surface(&self) -> &[u32] {
        &self.surface
    }

    /// `fixed_rhs = Phi^T values` over the surface points (one pass over the surface).
    fn project_values(&mut self, values: &[Vec3]) {
        let nv = self.phi_t.nrows();
        self.fixed_rhs.fill(0.0);
        for (c, &i) in self.surface.iter().enumerate() {
            let t = values[i as usize];
            let col = self.phi_t.column(c);
            for r in 0..nv {
                let w = col[r];
                self.fixed_rhs[(r, 0)] += w * t.x;
                self.fixed_rhs[(r, 1)] += w * t.y;
                self.fixed_rhs[(r, 2)] += w * t.z;
            }
        }
    }

    /// `(Phi^T Phi + mu I)^-1 (fixed_rhs - Phi^T Psi face + mu prior)` into `mapped`.
    fn normal_solve(&mut self, face: &[Vec3], prior: &[Vec3], mu: f64) {
        let nv = prior.len();
        self.rhs.copy_from(&self.fixed_rhs);
        for r in 0..nv {
            let mut acc = prior[r] * mu;
            for (j, t) in face.iter().enumerate() {
                acc -= t * self.phi_t_psi[(r, j)];
            }
            self.rhs[(r, 0)] += acc.x;
            self.rhs[(r, 1)] += acc.y;
            self.rhs[(r, 2)] += acc.z;
        }
        self.normal.solve_mut(&mut self.rhs);
        for (r, m) in self.mapped.iter_mut().enumerate() {
            *m = Vec3::new(self.rhs[(r, 0)], self.rhs[(r, 1)], self.rhs[(r, 2)]);
        }
    }

    /// Fits the cage positions `cage` (the starting guess in, the fit out) to the points
    /// `points` (every embedded point's position; only the surface ones are read), iterating
    /// until no cage vertex moves by more than `tolerance` or `max_iterations` iterations.
    pub fn positions(
        &mut self,
        coords: &GreenCoordinates,
        points: &[Vec3],
        cage: &mut [Vec3],
        tolerance: f64,
        max_iterations: u32,
    ) -> FitReport {
        self.anderson.reset();
        self.project_values(points);
        // The start, kept for the fallback (`moved` is the velocity fit's scratch).
        self.moved.copy_from_slice(cage);
        // Once the fixed point has failed, fits go to Newton at once.
        if self.newton.is_some() {
            return self.newton_positions(coords, points, cage, tolerance, 0);
        }
        let mut report = FitReport::default();
        for it in 0..max_iterations {
            coords.face_terms(cage, &mut self.terms);
            let terms = std::mem::take(&mut self.terms);
            self.normal_solve(&terms, cage, self.mu);
            self.terms = terms;
            let change = cage
                .iter()
                .zip(&self.mapped)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            let mapped = std::mem::take(&mut self.mapped);
            self.anderson.step(cage, &mapped);
            self.mapped = mapped;
            report = FitReport {
                iterations: it + 1,
                change,
                converged: change <= tolerance,
            };
            if report.converged || !change.is_finite() {
                break;
            }
        }
        if report.converged {
            return report;
        }
        self.newton_positions(coords, points, cage, tolerance, report.iterations)
    }

    /// Fits cage vertex velocities `velocities` (starting guess in, fit out) whose map,
    /// linearised at the cage `cage`, best reproduces the points' velocities `point_velocities`
    /// (every embedded point; only the surface ones are read). `h` is the central-difference
    /// step along the velocities (a thousandth of the time step is right).
    #[allow(clippy::too_many_arguments)]
    pub fn velocities(
        &mut self,
        coords: &GreenCoordinates,
        cage: &[Vec3],
        point_velocities: &[Vec3],
        velocities: &mut [Vec3],
        h: f64,
        tolerance: f64,
        max_iterations: u32,
    ) -> FitReport {
        self.anderson.reset();
        self.project_values(point_velocities);
        let mut report = FitReport::default();
        for it in 0..max_iterations {
            // Rate of the face terms along the velocities.
            for ((m, x), u) in self.moved.iter_mut().zip(cage).zip(velocities.iter()) {
                *m = x + u * h;
            }
            coords.face_terms(&self.moved, &mut self.rate);
            for ((m, x), u) in self.moved.iter_mut().zip(cage).zip(velocities.iter()) {
                *m = x - u * h;
            }
            coords.face_terms(&self.moved, &mut self.terms);
            for (r, t) in self.rate.iter_mut().zip(&self.terms) {
                *r = (*r - t) / (2.0 * h);
            }
            // No pull toward the previous iterate: the velocities fit from scratch.
            let rate = std::mem::take(&mut self.rate);
            let moved = std::mem::take(&mut self.moved);
            self.normal_solve(&rate, &moved, 0.0);
            self.rate = rate;
            self.moved = moved;
            let (mut change, mut size): (f64, f64) = (0.0, 0.0);
            for (a, b) in velocities.iter().zip(&self.mapped) {
                change = change.max((a - b).norm());
                size = size.max(b.norm());
            }
            let mapped = std::mem::take(&mut self.mapped);
            self.anderson.step(velocities, &mapped);
            self.mapped = mapped;
            report = FitReport {
                iterations: it + 1,
                change,
                converged: change <= tolerance.max(1e-12 * size),
            };
            if report.converged || !change.is_finite() {
                break;
            }
        }
        if report.converged {
            return report;
        }
        self.newton_velocities(
            coords,
            cage,
            point_velocities,
            velocities,
            report.iterations,
        )
    }

    /// Largest distance between a surface point of `points` and the cage's exact (`f64`)
    /// image of it.
    pub fn residual(&mut self, coords: &GreenCoordinates, cage: &[Vec3], points: &[Vec3]) -> f64 {
        coords.face_terms(cage, &mut self.terms);
        let mut worst: f64 = 0.0;
        for (c, &i) in self.surface.iter().enumerate() {
            let i = i as usize;
            let mut acc = Vec3::zeros();
            for (w, v) in self.phi_t.column(c).iter().zip(cage) {
                acc += v * *w;
            }
            for (psi, t) in coords.psi(i).iter().zip(&self.terms) {
                acc += t * *psi;
            }
            let d = (acc - points[i]).norm();
            // A NaN distance wins, so a broken fit is never taken for a perfect one.
            if d.is_nan() || d > worst {
                worst = d;
            }
        }
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anderson_mixing_recovers_when_its_residual_grows() {
        // x = A x + b with A = [[0, 2], [-0.1, 0]] per coordinate pair: a contraction in the
        // long run (spectral radius 0.45) whose residual grows on some iterations, so the
        // window restarts; the mixing must still converge, from the newest columns.
        let b = [Vec3::new(1.0, -2.0, 0.5), Vec3::new(0.3, 0.7, -1.1)];
        let g = |x: &[Vec3]| [x[1] * 2.0 + b[0], x[0] * -0.1 + b[1]];
        let mut x = vec![Vec3::new(50.0, -40.0, 30.0), Vec3::new(-20.0, 10.0, 5.0)];
        let mut aa = Anderson::new(2);
        let mut converged = false;
        for _ in 0..60 {
            let gx = g(&x);
            if x.iter().zip(&gx).all(|(p, q)| (p - q).norm() < 1e-12) {
                converged = true;
                break;
            }
            aa.step(&mut x, &gx);
        }
        assert!(converged, "{x:?}");
        // The fixed point: x0 = 2 x1 + b0, x1 = -0.1 x0 + b1.
        let x0 = (b[0] + b[1] * 2.0) / 1.2;
        assert!((x[0] - x0).norm() < 1e-10);
    }

    #[test]
    fn anderson_mixing_solves_a_linear_fixed_point_fast() {
        // x = A x + b with a contraction of rate 0.9: plain iteration needs about 300
        // iterations for 1e-14, Anderson mixing a few times the dimension.
        let d = 4;
        let a = [0.9, -0.5, 0.3, 0.7];
        let b: Vec<Vec3> = (0..d).map(|i| Vec3::new(1.0, i as f64, -2.0)).collect();
        let g = |x: &[Vec3], out: &mut Vec<Vec3>| {
            out.clear();
            out.extend(x.iter().zip(&b).zip(a).map(|((x, b), a)| x * a + b));
        };
        let mut x = vec![Vec3::zeros(); d];
        let mut gx = Vec::new();
        let mut aa = Anderson::new(d);
        let mut iterations = 0;
        for it in 0..100 {
            g(&x, &mut gx);
            let change = x
                .iter()
                .zip(&gx)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
            if change < 1e-13 {
                iterations = it;
                break;
            }
            aa.step(&mut x, &gx);
        }
        assert!(iterations > 0 && iterations < 20, "{iterations}");
        for (i, xi) in x.iter().enumerate() {
            let exact = b[i] / (1.0 - a[i]);
            assert!((xi - exact).norm() < 1e-11, "{xi:?} vs {exact:?}");
        }
    }
}
