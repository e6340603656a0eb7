//! Corotational FEM with a constant, prefactored system
//! ([`super::FemModel::CorotationalPrefactored`]).
//!
//! Backward Euler for the corotated material is the minimisation over the end-of-step
//! positions `x` of the incremental potential
//!
//! ```text
//! Phi(x) = c/2 |x - y|_M^2 + E(x) + anchors,   c = (1 + h alpha) / h^2,
//! y = x_n + h v_n / (1 + h alpha) + h^2 M^-1 f_ext / (1 + h alpha),
//! ```
//!
//! with `E` the corotated energy `sum_e V (mu |eps|^2 + lambda / 2 tr(eps)^2)`,
//! `eps = sym(R^T F) - I` (the material of [`super::FemModel::Corotational`]). The
//! linearized corotational step re-assembles the rotated stiffness `R K R^T` and solves it by
//! conjugate gradients, whose iterations grow with the deformation. Here every iteration is
//! a Newton-like step `x += A^-1 (-grad Phi(x))` with a rotation-invariant matrix
//!
//! ```text
//! A = c M + Ka + (2 mu + 3 lambda) L,   L = sum_e V G_e^T G_e   (the same for the 3 axes).
//! ```
//!
//! Two facts make this work. The stretching part of the corotated energy,
//! `mu |F - R|^2`, has the Hessian `2 mu L` whatever the rotations (Kugelstadt, Koschier and
//! Bender, "Fast Corotated FEM using Operator Splitting", SCA 2018, build their method on
//! this); and `mu |eps|^2 + lambda / 2 tr(eps)^2 <= (mu + 3 lambda / 2) |grad u|^2`
//! (`|sym A| <= |A|`, `tr(A)^2 <= 3 |A|^2`), so `A` bounds the Hessian of `Phi` from above in
//! every element's frame (the rotations' own derivative only lowers it). A step with a
//! matrix that bounds the Hessian from above never increases `Phi` (majorization; the
//! quasi-Newton view of Liu, Bouaziz and Kavan, "Quasi-Newton Methods for Real-Time
//! Simulation of Hyperelastic Materials", 2017), so the method is stable for any stiffness
//! and step; its fixed point is the exact backward-Euler step, so a body at rest sits on
//! the exact static equilibrium. `A` is factorized once per axis pattern of fixed components
//! (scalar Cholesky on a third of the unknowns). A step costs the same whatever the
//! deformation: per iteration one element loop (the corotational model's, eight elements at
//! a time) and three scalar solves. Fewer iterations than convergence leave the step short of
//! backward Euler in stiff, slow modes (extra numerical damping, never energy gain); the
//! report's speed-against-error table measures what that costs.
//!
//! Stiffness-proportional damping is not modelled (`stiffness_damping` must be 0).

use super::{FemBody, FemError, packed};
use crate::Vec3;
use crate::linalg::{LinalgError, ScalarCholesky};

/// Correction angle (radians) below which a rotation is not refined further: far below the
/// linearized model's, since the forces depend on the rotations to first order and a body
/// at rest should sit on its exact equilibrium (refined one iteration a step).
const ROTATION_TOLERANCE_PREFACTORED: f64 = 1e-9;

/// The stiffness of the constant matrix is `(2 mu + KAPPA_LAMBDA lambda) L`.
const KAPPA_LAMBDA: f64 = 3.0;

/// The rigid part (translation and rotation about the centre of mass) of a velocity field.
struct RigidFit {
    centre: Vec3,
    linear: Vec3,
    angular: Vec3,
}

impl RigidFit {
    /// Least-squares fit with mass weights: the centre-of-mass velocity and the angular
    /// velocity `I^-1 L` (none when the inertia tensor is singular).
    fn of(x: &[Vec3], v: &[Vec3], mass: &[f64]) -> Self {
        let total: f64 = mass.iter().sum();
        let centre = x.iter().zip(mass).map(|(p, m)| p * *m).sum::<Vec3>() / total;
        let linear = v.iter().zip(mass).map(|(u, m)| u * *m).sum::<Vec3>() / total;
        let mut momentum = Vec3::zeros();
        let mut inertia = nalgebra::Matrix3::zeros();
        for ((p, u), &m) in x.iter().zip(v).zip(mass) {
            let r = p - centre;
            momentum += m * r.cross(&(u - linear));
            inertia += m * (nalgebra::Matrix3::identity() * r.norm_squared() - r * r.transpose());
        }
        let angular = inertia
            .try_inverse()
            .map(|i| i * momentum)
            .filter(|w| w.iter().all(|c| c.is_finite()))
            .unwrap_or_else(Vec3::zeros);
        RigidFit {
            centre,
            linear,
            angular,
        }
    }

    /// No motion.
    fn none() -> Self {
        RigidFit {
            centre: Vec3::zeros(),
            linear: Vec3::zeros(),
            angular: Vec3::zeros(),
        }
    }

    fn velocity(&self, p: &Vec3) -> Vec3 {
        self.linear + self.angular.cross(&(p - self.centre))
    }
}

/// The prefactored model's constant system and its workspaces.
#[derive(Debug)]
pub(super) struct Prefactored {
    /// `L = sum_e V G_e^T G_e` in compressed rows (both triangles, diagonal included).
    row_ptr: Vec<u32>,
    cols: Vec<u32>,
    lap: Vec<f64>,
    /// One factor of `A` per distinct pattern of fixed components among the three axes, and
    /// which one each axis uses.
    pub(super) factors: Vec<ScalarCholesky>,
    pub(super) axis_factor: [usize; 3],
    /// Stored entries of the factors.
    factor_nnz: usize,
    /// Inertial target and current guess.
    y: Vec<Vec3>,
    guess: Vec<Vec3>,
    /// One axis of the right-hand side.
    axis: Vec<f64>,
    /// `c` the system was built with.
    inertia: f64,
}

impl Prefactored {
    /// Builds the Laplacian of the mesh and factorizes the step's system.
    pub(super) fn new(body: &FemBody) -> Result<Self, FemError> {
        let n = body.nodes.x.len();
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        for (t, tet) in body.tets.iter().enumerate() {
            let (g, v) = (&body.grads[t], body.volumes[t]);
            for a in 0..4 {
                for b in 0..4 {
                    rows[tet[a] as usize].push((tet[b], v * g[a].dot(&g[b])));
                }
            }
        }
        let mut row_ptr = Vec::with_capacity(n + 1);
        let (mut cols, mut lap) = (Vec::new(), Vec::new());
        row_ptr.push(0u32);
        for (i, row) in rows.iter_mut().enumerate() {
            // Unused nodes get an empty row with a diagonal.
            row.push((i as u32, 0.0));
            row.sort_by_key(|e| e.0);
            for &(j, v) in row.iter() {
                if cols.len() > row_ptr[i] as usize && cols.last() == Some(&j) {
                    *lap.last_mut().expect("an entry") += v;
                } else {
                    cols.push(j);
                    lap.push(v);
                }
            }
            row_ptr.push(cols.len() as u32);
        }
        let mut p = Prefactored {
            row_ptr,
            cols,
            lap,
            factors: Vec::new(),
            axis_factor: [0; 3],
            factor_nnz: 0,
            y: vec![Vec3::zeros(); n],
            guess: vec![Vec3::zeros(); n],
            axis: vec![0.0; n],
            inertia: 0.0,
        };
        p.factorize(body)?;
        Ok(p)
    }

    /// Stored entries of the factors.
    pub(super) fn factor_nnz(&self) -> usize {
        self.factor_nnz
    }

    /// Bytes of the Laplacian (values and indices) and of the factors' values and row
    /// indices.
    pub(super) fn bytes(&self) -> usize {
        self.lap.len() * 12 + self.row_ptr.len() * 4 + self.factor_nnz * 16
    }

    /// (Re)factorizes `A` for the body's current time step and damping.
    fn factorize(&mut self, body: &FemBody) -> Result<(), FemError> {
        let n = body.nodes.x.len();
        let h = body.config.system_dt();
        let c = (1.0 + h * body.config.mass_damping) / (h * h);
        let kappa = 2.0 * body.mu + KAPPA_LAMBDA * body.lambda;
        let nodes = &body.nodes;
        self.factors.clear();
        self.factor_nnz = 0;
        let mut patterns: Vec<Vec<bool>> = Vec::new();
        for axis in 0..3 {
            let fixed: Vec<bool> = nodes.fixed.iter().map(|f| f[axis]).collect();
            if let Some(k) = patterns.iter().position(|p| *p == fixed) {
                self.axis_factor[axis] = k;
                continue;
            }
            let (row_ptr, cols, lap) = (&self.row_ptr, &self.cols, &self.lap);
            let entries = (0..n).flat_map(|i| {
                let (s, e) = (row_ptr[i] as usize, row_ptr[i + 1] as usize);
                (s..e).map(move |k| {
                    let j = cols[k] as usize;
                    let mut v = kappa * lap[k];
                    if j == i {
                        v += c * nodes.mass[i] + nodes.anchor_k[i];
                    }
                    (i, j, v)
                })
            });
            let factor = ScalarCholesky::new(n, entries, &fixed).map_err(|e| match e {
                LinalgError::NotPositiveDefinite { dof } => LinalgError::NotPositiveDefinite {
                    dof: 3 * dof + axis,
                },
                e => e,
            })?;
            self.factor_nnz += factor.factor_nnz();
            self.axis_factor[axis] = self.factors.len();
            self.factors.push(factor);
            patterns.push(fixed);
        }
        self.inertia = c;
        Ok(())
    }
}

impl FemBody {
    /// One step of the prefactored model: the velocity change of the step into `dv` (the
    /// caller applies it as for the other models). Returns the worst rotation iterations and
    /// the times of the element loops and of the solves, microseconds.
    pub(super) fn prefactored_step(&mut self) -> Result<(u32, f64, f64), FemError> {
        let mut p = match self.prefactored.take() {
            Some(p) => p,
            None => Prefactored::new(self)?,
        };
        let result = self.prefactored_iterations(&mut p);
        self.prefactored = Some(p);
        result
    }

    fn prefactored_iterations(&mut self, p: &mut Prefactored) -> Result<(u32, f64, f64), FemError> {
        let h = self.config.system_dt();
        let damp = 1.0 + h * self.config.mass_damping;
        let c = damp / (h * h);
        if c != p.inertia {
            p.factorize(self)?;
        }
        let g = self.config.gravity;
        let n = self.nodes.x.len();
        // A held body (fixed components or anchors) has no free rigid motion to carry.
        let held = self.nodes.fixed.iter().any(|f| f.iter().any(|&a| a))
            || self.nodes.anchor_k.iter().any(|&k| k > 0.0);
        let rigid = if held {
            RigidFit::none()
        } else {
            RigidFit::of(&self.nodes.x, &self.nodes.v, &self.nodes.mass)
        };
        {
            let nodes = &self.nodes;
            for i in 0..n {
                let m = nodes.mass[i];
                let carried = nodes.x[i] + (h / damp) * nodes.v[i];
                let pulled = carried + (nodes.f_ext[i] / m + g) / c;
                // The first guess carries the body's rigid motion only (it costs no elastic
                // energy) and only for a free body; the deforming part of the velocity enters
                // through `y`. Carrying it all would turn, in a stiff body, a velocity into a
                // deformation one iteration cannot undo (energy growth).
                let carried = nodes.x[i] + (h / damp) * rigid.velocity(&nodes.x[i]);
                for a in 0..3 {
                    // Fixed components stay where they are (moved kinematically, if at all,
                    // before the step).
                    let fixed = nodes.fixed[i][a];
                    p.y[i][a] = if fixed { nodes.x[i][a] } else { pulled[a] };
                    p.guess[i][a] = if fixed { nodes.x[i][a] } else { carried[a] };
                }
            }
        }
        let (mut worst, mut loops_us, mut solve_us) = (0u32, 0.0, 0.0);
        for _ in 0..self.config.prefactored_iterations {
            let start = std::time::Instant::now();
            // Elastic forces at the guess (rotations refined from the held ones).
            self.rhs.fill(Vec3::zeros());
            let stats = self.packed.forces(
                &p.guess,
                packed::RotationState {
                    quats: &mut self.quats,
                    rots: &mut self.rots,
                    assembled: &self.quats_assembled,
                    stale: &mut self.stale,
                },
                self.lambda,
                self.mu,
                self.config.rotation_iterations,
                ROTATION_TOLERANCE_PREFACTORED,
                -1.0,
                &mut self.rhs,
            );
            worst = worst.max(stats.worst_iterations);
            loops_us += start.elapsed().as_secs_f64() * 1e6;
            let start = std::time::Instant::now();
            // -grad Phi = c M (y - x) + Ka (t - x) + f(x), one axis at a time.
            let nodes = &self.nodes;
            for a in 0..3 {
                for i in 0..n {
                    p.axis[i] = if nodes.fixed[i][a] {
                        0.0
                    } else {
                        c * nodes.mass[i] * (p.y[i][a] - p.guess[i][a])
                            + nodes.anchor_k[i] * (nodes.anchor_target[i][a] - p.guess[i][a])
                            + self.rhs[i][a]
                    };
                }
                let f = p.axis_factor[a];
                p.factors[f].solve_in_place(&mut p.axis)?;
                for i in 0..n {
                    if !nodes.fixed[i][a] {
                        p.guess[i][a] += p.axis[i];
                    }
                }
            }
            solve_us += start.elapsed().as_secs_f64() * 1e6;
        }
        for i in 0..n {
            self.dv[i] = (p.guess[i] - self.nodes.x[i]) / h - self.nodes.v[i];
        }
        Ok((worst, loops_us, solve_us))
    }
}
