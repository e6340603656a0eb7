//! Cage dynamics calibrated against a body's precise model: a Galerkin projection of the
//! precise model onto the space of motions its cage can make.
//!
//! The cage map `x(V) = sum_i phi_i V_i + sum_j psi_j t_j(V)` (Green coordinates, `t_j` the
//! stretched face normals) is linearised at the rest cage: `dx = J dV`, `J` the `3N x 3m`
//! Jacobian (the face terms' derivative taken by central differences of the face terms, which
//! cost `O(faces)` each). With the precise model's lumped masses `M`, stiffness `K` at its rest
//! (or settled) state and damping `C`, the cage's reduced matrices are `Mc = J^T M J`,
//! `Kc = J^T K J`, `Cc = J^T C J` (`3m x 3m`): the cage moves as the precise model would if
//! it could only take the shapes the cage gives. Because Green coordinates map a rotated cage
//! to the rotated points, `J` is rotation-equivariant and `Kc` annihilates rigid motions;
//! a free body steps in its cage's corotated frame (the best rigid fit of the cage to its
//! rest shape), so large rotations cost no spurious strain. Fixed precise nodes become stiff
//! penalty springs on their cage motion (`k_fix J_F^T J_F`), anchors come in with the
//! precise stiffness. A step is linearised implicit Euler with the dense `3m x 3m` system
//! factored once per step size.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{DMatrix, DVector, Matrix3, UnitQuaternion};

use super::green::GreenCoordinates;
use super::{Cage, CageError};
use crate::Vec3;

/// How a cage's vertices move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum CageDynamics {
    /// Reduced mass, stiffness and damping projected from the body's precise model (see
    /// [`ReducedModel`]); the cage's MSD parameters are not used.
    #[default]
    Calibrated,
    /// The paper's cage MSD: springs between cage vertices with the scene's cage MSD
    /// parameters (paper: stiffness 50, mass 20, damping 0.3 whatever the body).
    Paper,
}

/// Penalty stiffness of a fixed precise node component, as a multiple of the mean stiffness a
/// node component sees through the cage (`tr Kc / tr J^T J`).
const FIXED_PENALTY: f64 = 100.0;

/// A cage's mass, stiffness and damping on its `3m` vertex coordinates (row-major dense).
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedModel {
    dim: usize,
    triangles: Vec<[u32; 3]>,
    /// Per face, `d t_j / d V` for its three vertices (9 vectors).
    face_jacobians: Vec<Vec3>,
    mass: Vec<f64>,
    stiffness: Vec<f64>,
    damping: Vec<f64>,
    rest: Vec<Vec3>,
    corotate: bool,
}

/// What the projection needs of the precise model at its rest (or settled) state.
pub struct PreciseOperators<'a> {
    /// Lumped node masses.
    pub masses: &'a [f64],
    /// Fixed components per node.
    pub fixed: &'a [[bool; 3]],
    /// `out = K u` for a nodal vector `u` (elastic stiffness, anchors included, constraints
    /// not applied).
    pub stiffness: &'a mut dyn FnMut(&[Vec3], &mut [Vec3]),
    /// Rayleigh-style damping `C = alpha M + beta K + gamma I`: `(alpha, beta, gamma)`.
    pub damping: (f64, f64, f64),
    /// Whether the body is free (no fixed nodes, no anchors): it then steps corotated.
    pub free: bool,
}

impl ReducedModel {
    /// Projects the precise model given by `ops` onto `cage` through `coords` (the Green
    /// coordinates of the precise nodes in that cage).
    pub fn project(
        cage: &Cage,
        coords: &GreenCoordinates,
        ops: PreciseOperators<'_>,
    ) -> Result<Self, CageError> {
        let n = coords.point_count();
        let nv = cage.vertices().len();
        let nf = cage.triangles().len();
        if ops.masses.len() != n || ops.fixed.len() != n {
            return Err(CageError::LengthMismatch {
                what: "precise masses / fixed flags (one per embedded point)",
                expected: n,
                found: ops.masses.len().min(ops.fixed.len()),
            });
        }
        let dim = 3 * nv;
        // Derivative of the face terms: face j's term depends on its own three vertices only;
        // `face_jacobians[9 j + 3 k + a]` is d t_j / d (vertex k of face j, axis a), by central
        // differences.
        let rest = cage.vertices().to_vec();
        let size = cage_size(&rest);
        let eps = 1e-6 * size;
        let mut face_jacobians = vec![Vec3::zeros(); 9 * nf];
        let (mut plus, mut minus) = (vec![Vec3::zeros(); nf], vec![Vec3::zeros(); nf]);
        let mut shifted = rest.clone();
        for c in 0..dim {
            let (v, a) = (c / 3, c % 3);
            shifted[v][a] = rest[v][a] + eps;
            coords.face_terms(&shifted, &mut plus);
            shifted[v][a] = rest[v][a] - eps;
            coords.face_terms(&shifted, &mut minus);
            shifted[v][a] = rest[v][a];
            for (j, t) in cage.triangles().iter().enumerate() {
                if let Some(k) = t.iter().position(|&w| w as usize == v) {
                    face_jacobians[9 * j + 3 * k + a] = (plus[j] - minus[j]) / (2.0 * eps);
                }
            }
        }
        // Columns of J: the motion of every node per unit motion of one cage coordinate.
        let mut cols: Vec<Vec<Vec3>> = vec![vec![Vec3::zeros(); n]; dim];
        // `p` indexes a row across every column.
        #[allow(clippy::needless_range_loop)]
        for p in 0..n {
            let (phi, psi) = (coords.phi(p), coords.psi(p));
            for (v, &w) in phi.iter().enumerate() {
                for a in 0..3 {
                    cols[3 * v + a][p][a] += w;
                }
            }
            for (j, t) in cage.triangles().iter().enumerate() {
                let w = psi[j];
                for (k, &v) in t.iter().enumerate() {
                    for a in 0..3 {
                        cols[3 * v as usize + a][p] += face_jacobians[9 * j + 3 * k + a] * w;
                    }
                }
            }
        }
        // K J, column by column.
        let mut kcols: Vec<Vec<Vec3>> = vec![vec![Vec3::zeros(); n]; dim];
        for (col, kcol) in cols.iter().zip(kcols.iter_mut()) {
            (ops.stiffness)(col, kcol);
        }
        let mut mass = vec![0.0; dim * dim];
        let mut stiffness = vec![0.0; dim * dim];
        let mut jtj = vec![0.0; dim * dim];
        let mut fixed_part = vec![0.0; dim * dim];
        let any_fixed = ops.fixed.iter().any(|f| f.iter().any(|&b| b));
        for r in 0..dim {
            for c in r..dim {
                let (a, b, kb) = (&cols[r], &cols[c], &kcols[c]);
                let (mut m, mut k, mut g, mut f) = (0.0, 0.0, 0.0, 0.0);
                for p in 0..n {
                    let d = a[p].dot(&b[p]);
                    m += ops.masses[p] * d;
                    g += d;
                    k += a[p].dot(&kb[p]);
                    if any_fixed {
                        for ax in 0..3 {
                            if ops.fixed[p][ax] {
                                f += a[p][ax] * b[p][ax];
                            }
                        }
                    }
                }
                for (mat, val) in [
                    (&mut mass, m),
                    (&mut stiffness, k),
                    (&mut jtj, g),
                    (&mut fixed_part, f),
                ] {
                    mat[r * dim + c] = val;
                    mat[c * dim + r] = val;
                }
            }
        }
        // Symmetrise K (a finite-difference K is symmetric only to rounding).
        for r in 0..dim {
            for c in r + 1..dim {
                let s = 0.5 * (stiffness[r * dim + c] + stiffness[c * dim + r]);
                stiffness[r * dim + c] = s;
                stiffness[c * dim + r] = s;
            }
        }
        // A stressed precise state (a settled MSD's compressed springs) can give the projected
        // stiffness negative directions, which would grow without bound: they are clamped to
        // zero (the symmetric eigen-decomposition of the small matrix).
        clamp_negative_eigenvalues(&mut stiffness, dim);
        // Cage directions that move no massive node (a mesh of a few nodes in a box cage)
        // would leave the mass singular; they get a mass of 1e-6 of the mean diagonal, which
        // no force excites (forces act through `J^T`) and the others do not notice.
        let floor = 1e-6 * (0..dim).map(|i| mass[i * dim + i]).sum::<f64>() / dim as f64;
        for i in 0..dim {
            mass[i * dim + i] += floor.max(f64::MIN_POSITIVE);
        }
        let (alpha, beta, gamma) = ops.damping;
        let damping: Vec<f64> = (0..dim * dim)
            .map(|i| alpha * mass[i] + beta * stiffness[i] + gamma * jtj[i])
            .collect();
        if any_fixed {
            let trace = |m: &[f64]| (0..dim).map(|i| m[i * dim + i]).sum::<f64>();
            let k_node = FIXED_PENALTY * trace(&stiffness) / trace(&jtj).max(f64::MIN_POSITIVE);
            for (k, f) in stiffness.iter_mut().zip(&fixed_part) {
                *k += k_node * f;
            }
        }
        let model = ReducedModel {
            dim,
            triangles: cage.triangles().to_vec(),
            face_jacobians,
            mass,
            stiffness,
            damping,
            rest,
            corotate: ops.free && !any_fixed,
        };
        if let Some(i) = model
            .mass
            .iter()
            .chain(&model.stiffness)
            .chain(&model.damping)
            .position(|v| !v.is_finite())
        {
            return Err(CageError::NonFinite {
                what: "reduced cage matrix entry",
                index: i,
            });
        }
        Ok(model)
    }

    /// Adds to the cage vertex forces `out` the generalised force `J_p^T f` of a force `f` on
    /// the point with coordinates `phi`, `psi` (the face terms' part included).
    pub fn add_point_force(&self, phi: &[f64], psi: &[f64], f: Vec3, out: &mut [Vec3]) {
        for (o, w) in out.iter_mut().zip(phi) {
            *o += f * *w;
        }
        for (j, t) in self.triangles.iter().enumerate() {
            let w = psi[j];
            if w == 0.0 {
                continue;
            }
            for (k, &v) in t.iter().enumerate() {
                let g = &self.face_jacobians[9 * j + 3 * k..9 * j + 3 * k + 3];
                out[v as usize] += Vec3::new(g[0].dot(&f), g[1].dot(&f), g[2].dot(&f)) * w;
            }
        }
    }

    /// This model with other reduced mass, stiffness and damping matrices (row-major, `dim x
    /// dim`, symmetric), for a calibration computed elsewhere; its face-term derivatives,
    /// rest and frame are kept. A matrix of another size or with a non-finite entry is an
    /// error.
    pub fn with_matrices(
        &self,
        mass: Vec<f64>,
        stiffness: Vec<f64>,
        damping: Vec<f64>,
    ) -> Result<Self, CageError> {
        let d2 = self.dim * self.dim;
        for (what, m) in [
            ("reduced mass", &mass),
            ("reduced stiffness", &stiffness),
            ("reduced damping", &damping),
        ] {
            if m.len() != d2 {
                return Err(CageError::LengthMismatch {
                    what,
                    expected: d2,
                    found: m.len(),
                });
            }
            if let Some(index) = m.iter().position(|v| !v.is_finite()) {
                return Err(CageError::NonFinite { what, index });
            }
        }
        Ok(ReducedModel {
            mass,
            stiffness,
            damping,
            ..self.clone()
        })
    }

    /// This model for its cage moved rigidly by `m` (a teleport): the rest moved, the mass,
    /// stiffness and damping matrices and the face terms' derivatives turned block by block
    /// (`R B R^T`), which is the projection of the moved precise model onto the moved cage.
    pub(crate) fn moved(&self, m: &nalgebra::Isometry3<f64>) -> Self {
        let mut out = self.clone();
        for p in &mut out.rest {
            *p = m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin();
        }
        if m.rotation.angle() != 0.0 {
            let r = *m.rotation.to_rotation_matrix().matrix();
            for mat in [&mut out.mass, &mut out.stiffness, &mut out.damping] {
                turn_blocks(mat, self.dim, &r);
            }
            // Per face and vertex, the three columns of `d t_j / d V_k`.
            for g in out.face_jacobians.chunks_exact_mut(3) {
                let j = r * Matrix3::from_columns(&[g[0], g[1], g[2]]) * r.transpose();
                for (a, c) in g.iter_mut().enumerate() {
                    *c = j.column(a).into_owned();
                }
            }
        }
        out
    }

    /// Number of reduced coordinates (`3 x cage vertices`).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The reduced mass matrix, row-major.
    pub fn mass(&self) -> &[f64] {
        &self.mass
    }

    /// The reduced stiffness matrix (fixed-node penalty included), row-major.
    pub fn stiffness(&self) -> &[f64] {
        &self.stiffness
    }

    /// The reduced damping matrix, row-major.
    pub fn damping(&self) -> &[f64] {
        &self.damping
    }

    /// Whether steps are taken in the cage's corotated frame (free bodies).
    pub fn corotates(&self) -> bool {
        self.corotate
    }
}

/// Turns every 3 x 3 block (a pair of cage vertices) of the row-major `dim x dim` matrix
/// `m`: `R B R^T`.
fn turn_blocks(m: &mut [f64], dim: usize, r: &Matrix3<f64>) {
    let n = dim / 3;
    for bi in 0..n {
        for bj in 0..n {
            let at = |i: usize, j: usize| (3 * bi + i) * dim + 3 * bj + j;
            let b = Matrix3::from_fn(|i, j| m[at(i, j)]);
            let t = r * b * r.transpose();
            for i in 0..3 {
                for j in 0..3 {
                    m[at(i, j)] = t[(i, j)];
                }
            }
        }
    }
}

/// Replaces the symmetric `dim x dim` matrix `k` (row-major) by its nearest positive
/// semi-definite one (negative eigenvalues set to zero).
fn clamp_negative_eigenvalues(k: &mut [f64], dim: usize) {
    let m = DMatrix::from_row_slice(dim, dim, k);
    let eig = m.symmetric_eigen();
    if eig.eigenvalues.iter().all(|&l| l >= 0.0) {
        return;
    }
    let clamped = eig.eigenvalues.map(|l| l.max(0.0));
    let q = &eig.eigenvectors;
    let r = q * DMatrix::from_diagonal(&clamped) * q.transpose();
    for i in 0..dim {
        for j in 0..dim {
            k[i * dim + j] = 0.5 * (r[(i, j)] + r[(j, i)]);
        }
    }
}

/// Largest extent of a vertex set's bounding box.
fn cage_size(v: &[Vec3]) -> f64 {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in v {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (hi - lo).max().max(f64::MIN_POSITIVE)
}

/// The process-wide cache of reduced models: identical bodies (same mesh state, cage,
/// material and supports, summed up by a key the builder computes) share one.
fn cache() -> &'static Mutex<HashMap<u64, Arc<ReducedModel>>> {
    static CACHE: OnceLock<Mutex<HashMap<u64, Arc<ReducedModel>>>> = OnceLock::new();
    CACHE.get_or_init(Default::default)
}

/// Most models the cache keeps; beyond it the cache starts over.
const CACHE_CAPACITY: usize = 64;

/// The cached model for `key`, or the one `build` makes (then cached). A failed build caches
/// nothing.
pub fn cached_model(
    key: u64,
    build: impl FnOnce() -> Result<ReducedModel, CageError>,
) -> Result<Arc<ReducedModel>, CageError> {
    if let Some(m) = cache().lock().ok().and_then(|c| c.get(&key).cloned()) {
        return Ok(m);
    }
    let model = Arc::new(build()?);
    if let Ok(mut c) = cache().lock() {
        if c.len() >= CACHE_CAPACITY {
            c.clear();
        }
        c.insert(key, model.clone());
    }
    Ok(model)
}

/// Builds a cache key from hashable parts (`f64`s hashed by their bits).
#[derive(Default)]
pub struct ModelKey(std::collections::hash_map::DefaultHasher);

impl ModelKey {
    /// Adds floats.
    pub fn floats(&mut self, v: impl IntoIterator<Item = f64>) -> &mut Self {
        for x in v {
            x.to_bits().hash(&mut self.0);
        }
        self
    }
    /// Adds anything hashable.
    pub fn add(&mut self, v: impl Hash) -> &mut Self {
        v.hash(&mut self.0);
        self
    }
    /// The key.
    pub fn finish(&self) -> u64 {
        self.0.finish()
    }
}

/// Steps a [`ReducedModel`] at a fixed step: `(Mc + h Cc + h^2 Kc)` factored once.
#[derive(Debug, Clone)]
pub struct ReducedStepper {
    model: Arc<ReducedModel>,
    dt: f64,
    chol: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    rhs: DVector<f64>,
    u: Vec<f64>,
    v: Vec<f64>,
    f: Vec<f64>,
    /// The displacement (in the step's frame) the springs hold at rest: zero for the model's
    /// rest shape, another equilibrium after [`ReducedStepper::rebase`].
    offset: Vec<f64>,
}

impl ReducedStepper {
    /// A stepper of `model` at step `dt`. A singular system is an error.
    pub fn new(model: Arc<ReducedModel>, dt: f64) -> Result<Self, CageError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(CageError::InvalidArgument {
                field: "dt",
                message: format!("must be finite and > 0, found {dt}"),
            });
        }
        let d = model.dim;
        let a = DMatrix::from_fn(d, d, |r, c| {
            let i = r * d + c;
            model.mass[i] + dt * model.damping[i] + dt * dt * model.stiffness[i]
        });
        let chol = a.cholesky().ok_or_else(|| CageError::InvalidArgument {
            field: "calibrated cage",
            message: "the reduced system M + h C + h^2 K is not positive definite".into(),
        })?;
        Ok(ReducedStepper {
            dt,
            chol,
            rhs: DVector::zeros(d),
            u: vec![0.0; d],
            v: vec![0.0; d],
            f: vec![0.0; d],
            offset: vec![0.0; d],
            model,
        })
    }

    /// Moves the stepper with its cage rigidly by `m` (a teleport): the model moved (see
    /// [`ReducedModel::moved`]; a turned model's system factored again) and the equilibrium
    /// it holds turned with it. On error it is left as it was.
    pub(crate) fn move_by(&mut self, m: &nalgebra::Isometry3<f64>) -> Result<(), CageError> {
        let model = Arc::new(self.model.moved(m));
        if m.rotation.angle() == 0.0 {
            self.model = model;
            return Ok(());
        }
        let mut next = ReducedStepper::new(model, self.dt)?;
        for (to, from) in next
            .offset
            .chunks_exact_mut(3)
            .zip(self.offset.chunks_exact(3))
        {
            let u = m.rotation * Vec3::new(from[0], from[1], from[2]);
            to.copy_from_slice(u.as_slice());
        }
        *self = next;
        Ok(())
    }

    /// The model.
    pub fn model(&self) -> &Arc<ReducedModel> {
        &self.model
    }

    /// The step size.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The frame the step is taken in for cage positions `x`: the rotation of the cage's best
    /// rigid fit to its rest shape for a free body, the identity otherwise.
    pub fn frame(&self, x: &[Vec3]) -> Matrix3<f64> {
        if self.model.corotate {
            best_rotation(&self.model.rest, x)
        } else {
            Matrix3::identity()
        }
    }

    /// Makes the cage positions `x` the equilibrium the cage returns to (a body that came to
    /// rest on its supports keeps that shape at the cage level); `None` the model's rest
    /// shape again.
    pub fn rebase(&mut self, x: Option<&[Vec3]>) {
        let Some(x) = x else {
            self.offset.fill(0.0);
            return;
        };
        let rt = self.frame(x).transpose();
        for (i, xi) in x.iter().enumerate() {
            let u = rt * xi - self.model.rest[i];
            self.offset[3 * i..3 * i + 3].copy_from_slice(u.as_slice());
        }
    }

    /// `h^2 (M + h C + h^2 K)^-1 rhs` in place, reduced coordinates in the step's frame: the
    /// cage's displacement over a step under forces `rhs` held over it.
    pub fn compliance_solve(&self, rhs: &mut DVector<f64>) {
        self.chol.solve_mut(rhs);
        *rhs *= self.dt * self.dt;
    }

    /// One linearised implicit Euler step of the cage vertices `x`, `v` under the vertex
    /// forces `f` (cleared afterwards). On a non-finite result the state is unchanged and
    /// the error names the vertex.
    pub fn step(
        &mut self,
        x: &mut [Vec3],
        v: &mut [Vec3],
        f: &mut [Vec3],
    ) -> Result<(), CageError> {
        let m = &self.model;
        let d = m.dim;
        let h = self.dt;
        let rot = if m.corotate {
            best_rotation(&m.rest, x)
        } else {
            Matrix3::identity()
        };
        let rt = rot.transpose();
        for i in 0..d / 3 {
            let (xi, vi, fi) = (rt * x[i], rt * v[i], rt * f[i]);
            for a in 0..3 {
                self.u[3 * i + a] = xi[a] - m.rest[i][a] - self.offset[3 * i + a];
                self.v[3 * i + a] = vi[a];
                self.f[3 * i + a] = fi[a];
            }
        }
        // rhs = M v + h (f - K u)
        for r in 0..d {
            let (mr, kr) = (
                &m.mass[r * d..(r + 1) * d],
                &m.stiffness[r * d..(r + 1) * d],
            );
            let mut s = 0.0;
            let mut k = 0.0;
            for c in 0..d {
                s += mr[c] * self.v[c];
                k += kr[c] * self.u[c];
            }
            self.rhs[r] = s + h * (self.f[r] - k);
        }
        self.chol.solve_mut(&mut self.rhs);
        if let Some(i) = self.rhs.iter().position(|c| !c.is_finite()) {
            return Err(CageError::NonFinite {
                what: "cage vertex",
                index: i / 3,
            });
        }
        for i in 0..d / 3 {
            let w = rot * Vec3::new(self.rhs[3 * i], self.rhs[3 * i + 1], self.rhs[3 * i + 2]);
            v[i] = w;
            x[i] += w * h;
        }
        f.fill(Vec3::zeros());
        Ok(())
    }
}

/// Rotation of the best rigid fit of `rest` onto `x` (Kabsch).
fn best_rotation(rest: &[Vec3], x: &[Vec3]) -> Matrix3<f64> {
    let n = rest.len().max(1) as f64;
    let (c0, c1) = (rest.iter().sum::<Vec3>() / n, x.iter().sum::<Vec3>() / n);
    let mut hm = Matrix3::zeros();
    for (xi, x0) in x.iter().zip(rest) {
        hm += (xi - c1) * (x0 - c0).transpose();
    }
    let mut q = UnitQuaternion::identity();
    let mut r = Matrix3::identity();
    crate::fem::rotation::extract_rotation(&hm, &mut q, &mut r, 100, 1e-12);
    r
}
