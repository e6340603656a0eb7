//! Tetrahedral finite elements with implicit (backward) Euler: linear and corotational.
//!
//! Equation of motion (paper eq. 1): `M a + D v + K u = f`, with lumped mass `M`, Rayleigh
//! damping `D = alpha M + beta K`, and `u = x - X`. One step of length `h` solves, linearised
//! at the start of the step,
//!
//! ```text
//! ((1 + h alpha) M + (h beta + h^2) K + h^2 Ka) dv = h (f_ext + M g + f_el(x) + f_a(x)
//!                                                     - alpha M v - (beta + h) K v - h Ka v)
//! v += dv,  x += h v
//! ```
//!
//! where `Ka` holds the soft anchors. Linear FEM (`f_el = -K u`, `K` constant) gives a constant
//! matrix: it is factorized once (sparse Cholesky with AMD ordering) and each step is one
//! solve, exactly backward Euler (the product with `K` the right-hand side needs is taken
//! from the system matrix itself, `h K y = (h / (h beta + h^2)) (A y - G y)` with `G` the
//! diagonal part, while the fixed nodes sit at rest). Corotational FEM (the default)
//! extracts a rotation per element (robust to inverted and flat elements, [`rotation`];
//! eight elements at a time in vector registers),
//! computes `f_el` with the rotated strain and assembles the warped stiffness `R K R^T` in
//! place through a scatter map; the system is solved by conjugate gradients warm-started from
//! the last step's `dv` and preconditioned by the rest-state factorization (the same matrix
//! as the linear model's). Nothing allocates in a step.
//!
//! BDF2 ([`FemIntegrator::Bdf2`], second order) reuses all of this: a BDF2 step is the same
//! backward Euler system with `h = 2 dt / 3`, solved from a state extrapolated from the last
//! two (see [`FemBody::step`]).
//!
//! Fixed components of nodes keep their position (they can be moved kinematically with
//! [`FemBody::positions_mut`]) and have zero velocity.

// Index loops over parallel per-node arrays read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

mod assembly;
mod config;
mod contact;
pub mod element;
mod packed;
mod prefactored;
pub mod rotation;
mod step;
mod teleport;

use assembly::*;
pub use config::{FemConfig, MassSpec};

use std::time::Instant;

use nalgebra::{Matrix3, UnitQuaternion};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::boundary::{Boundary, BoundaryError};
use crate::linalg::{BlockSparse, CgStats, ImplicitSystem, LinalgError, NotConverged};
use crate::material::FemParams;
use crate::mesh::TetMesh;
use crate::state::{self, NodalModel, Nodes};

/// The ten local node pairs `a <= b` of a tetrahedron.
const PAIRS: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// Flag in [`FemBody`]'s upper scatter map: store the block transposed.
const TRANSPOSED: u32 = 1 << 31;

/// At most this fraction (one in ...) of the elements has its warped stiffness updated in one
/// step (at least 64).
const ASSEMBLY_SHARE: usize = 4;

/// Elements per parallel part of the warped-stiffness update (fewer stale elements than two
/// parts: one thread).
const PARALLEL_ELEMENTS: usize = 128;

/// Default of [`FemConfig::rotation_tolerance`], radians.
pub const DEFAULT_ROTATION_TOLERANCE: f64 = 1e-10;

/// Which elastic model a FEM body uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum FemModel {
    /// Linear elasticity (paper): constant stiffness, exact backward Euler with a prefactored
    /// matrix. Wrong under large rotations (the body grows when it turns).
    Linear,
    /// Corotational: linear elasticity in each element's rotated frame; right under large
    /// rotations. The default precise method. Each step linearizes backward Euler at the
    /// start of the step and solves the warped system by preconditioned conjugate gradients:
    /// the reference corotational method, whose cost grows with the deformation.
    #[default]
    Corotational,
    /// The same corotated material, backward Euler solved by iterations with a constant,
    /// rotation-invariant, prefactored matrix that bounds the Hessian from above (see the
    /// `prefactored` module): stable for any stiffness and step, exact at rest, a fixed cost
    /// per step several times below [`FemModel::Corotational`]'s on large meshes; one
    /// iteration by default, more converge to the backward-Euler step. No
    /// stiffness-proportional damping.
    CorotationalPrefactored,
}

impl FemModel {
    /// Whether the model follows element rotations (both corotational models).
    pub fn is_corotational(self) -> bool {
        matches!(
            self,
            FemModel::Corotational | FemModel::CorotationalPrefactored
        )
    }

    /// Short name: `linear`, `corotational`, `corotational-prefactored`.
    pub fn name(self) -> &'static str {
        match self {
            FemModel::Linear => "linear",
            FemModel::Corotational => "corotational",
            FemModel::CorotationalPrefactored => "corotational-prefactored",
        }
    }
}

/// Time integrator of a FEM body (every elastic model takes either).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum FemIntegrator {
    /// Backward (implicit) Euler, first order: strongly damps every mode it resolves poorly
    /// (the numerical damping of a mode of frequency `w` grows like `h w^2 / 2`). The default.
    #[default]
    BackwardEuler,
    /// Second-order backward differentiation (BDF2, constant step): `x_{n+1} = 4/3 x_n - 1/3
    /// x_{n-1} + 2/3 h v_{n+1}` and the same for `v`. A BDF2 step is exactly a backward Euler
    /// step of length `2h/3` taken from the extrapolated state `(x_n + (x_n - x_{n-1}) / 3,
    /// v_n + (v_n - v_{n-1}) / 3)`, so every model solves its usual system with `2h/3` in
    /// place of `h` (same cost per step; the matrices are built for `2h/3`). A-stable and
    /// L-stable like backward Euler (high frequencies are still damped out, only far less
    /// at the frequencies the step resolves), but not monotone: a sudden change (a contact,
    /// a kinematic jump) can overshoot by a fraction of it. See [`FemBody::step`] for how the
    /// history is kept across outside changes.
    Bdf2,
}

impl FemIntegrator {
    /// Short name: `backward-euler`, `bdf2`.
    pub fn name(self) -> &'static str {
        match self {
            FemIntegrator::BackwardEuler => "backward-euler",
            FemIntegrator::Bdf2 => "bdf2",
        }
    }
}

/// A FEM failure, naming what and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FemError {
    /// A configuration field is out of range.
    #[error("FEM config field `{field}` {message}")]
    InvalidConfig {
        /// The field.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The boundary conditions do not fit the mesh.
    #[error(transparent)]
    Boundary(#[from] BoundaryError),
    /// The mesh has an element the solver cannot use.
    #[error("tetrahedron {tet} is degenerate (zero volume) in the rest state")]
    DegenerateElement {
        /// The element.
        tet: usize,
    },
    /// A linear solve failed.
    #[error("FEM linear solve failed: {0}")]
    Linalg(#[from] LinalgError),
    /// A value given to the body, or produced by a step, is NaN or infinite. A step that
    /// produces one is rolled back: the state is the one before the step.
    #[error("{what} of node {node} is not finite")]
    NonFinite {
        /// `"external force"`, `"position"`, `"velocity"`.
        what: &'static str,
        /// The node.
        node: usize,
    },
    /// The step's CG reached its cap above its tolerance while
    /// [`FemConfig::cg_must_converge`] asks for convergence (the state is unchanged).
    #[error(transparent)]
    NotConverged(#[from] NotConverged),
    /// A static solve needs fixed nodes or anchors to remove rigid motions.
    #[error("static solve needs fixed nodes or anchors: the body is free to move rigidly")]
    Unconstrained,
    /// A static solve did not converge.
    #[error(
        "static solve did not converge in {iterations} iterations (last update {update:e} of the body size)"
    )]
    StaticNotConverged {
        /// Iterations done.
        iterations: u32,
        /// Last relative update.
        update: f64,
    },
}

/// What the last step did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct FemStepStats {
    /// The CG solve (corotational); zero iterations for the linear model's direct solve.
    pub cg: CgStats,
    /// Largest number of rotation-extraction iterations of any element.
    pub rotation_iterations: u32,
    /// Whether the warped stiffness was re-assembled this step (corotational).
    pub assembled: bool,
    /// Wall time of the element loop (rotations and elastic forces), microseconds.
    pub forces_us: f64,
    /// Wall time of the warped-stiffness assembly, microseconds (0 when not re-assembled).
    pub assembly_us: f64,
    /// Wall time of the linear solve (direct or CG) and its right-hand side, microseconds.
    pub solve_us: f64,
}

/// A deformable body discretised by linear tetrahedra.
#[derive(Debug)]
pub struct FemBody {
    config: FemConfig,
    lambda: f64,
    mu: f64,
    tets: Vec<[u32; 4]>,
    grads: Vec<[Vec3; 4]>,
    volumes: Vec<f64>,
    /// Per element: for the pairs `a <= b` (in the order of [`PAIRS`]), the storage index of
    /// the upper-triangle block of the node pair, with [`TRANSPOSED`] set when the element's
    /// block `(a, b)` lands transposed (node of `a` after node of `b`).
    upper: Vec<[u32; 10]>,
    nodes: Nodes,
    quats: Vec<UnitQuaternion<f64>>,
    /// Rotation matrices of `quats`.
    rots: Vec<Matrix3<f64>>,
    /// Rotations the system matrix was last assembled with.
    quats_assembled: Vec<UnitQuaternion<f64>>,
    /// Whether the system matrix holds the warped stiffness of `quats_assembled` for the
    /// current time step and parameters.
    matrix_current: bool,
    /// Elements turned past the update angle in this step's element loop.
    stale: Vec<u32>,
    /// Where the next incremental update starts among the stale elements (round robin).
    assembly_cursor: usize,
    /// Rest elastic stiffness `K` (no anchors, no constraints).
    k_rest: BlockSparse,
    /// System matrix and the factorization of its rest value.
    system: ImplicitSystem,
    rhs: Vec<Vec3>,
    dv: Vec<Vec3>,
    tmp: Vec<Vec3>,
    backup_x: Vec<Vec3>,
    backup_v: Vec<Vec3>,
    stats: FemStepStats,
    static_system: Option<ImplicitSystem>,
    /// The elements packed eight at a time for the corotational element loop.
    packed: packed::PackedElements,
    /// The prefactored model's system, built when the model is first used.
    prefactored: Option<prefactored::Prefactored>,
    /// Per stale element, the change of its upper blocks, when they are computed in
    /// parallel (sized the first time).
    assembly_deltas: Vec<[[f64; 9]; 10]>,
    /// BDF2 history (see [`crate::state::Bdf2History`]).
    bdf2: crate::state::Bdf2History,
    /// Contact compliance columns and correction workspaces.
    contact: contact::FemContact,
    /// The body's best rigid rotation (warm start of [`FemBody::body_frame`]).
    frame: UnitQuaternion<f64>,
}

impl NodalModel for FemBody {
    fn nodes(&self) -> &Nodes {
        &self.nodes
    }

    fn nodes_mut(&mut self) -> &mut Nodes {
        &mut self.nodes
    }
}

impl FemBody {
    /// Builds a body at rest on `mesh` (positions are the rest state).
    pub fn new(mesh: &TetMesh, config: FemConfig, boundary: &Boundary) -> Result<Self, FemError> {
        config.validate()?;
        let n = mesh.positions().len();
        let (fixed, anchor_k) = boundary.resolve(n)?;
        let rest = mesh.positions().to_vec();
        let tets: Vec<[u32; 4]> = mesh.tets().to_vec();
        let mut grads = Vec::with_capacity(tets.len());
        let mut volumes = Vec::with_capacity(tets.len());
        for (t, tet) in tets.iter().enumerate() {
            let p = tet.map(|i| rest[i as usize]);
            let (b, vol) =
                element::shape_gradients(&p).ok_or(FemError::DegenerateElement { tet: t })?;
            if vol <= 0.0 {
                return Err(FemError::DegenerateElement { tet: t });
            }
            grads.push(b);
            volumes.push(vol);
        }
        let mut mass = vec![0.0; n];
        for (tet, vol) in tets.iter().zip(&volumes) {
            for &i in tet {
                mass[i as usize] += vol / 4.0;
            }
        }
        let total_volume: f64 = volumes.iter().sum();
        let scale = match config.mass {
            MassSpec::Total(m) => m / total_volume,
            MassSpec::Density(d) => d,
        };
        // Nodes outside every element get the smallest element-node mass, so M stays
        // positive definite (they then only follow gravity and external forces).
        let min_mass = mass
            .iter()
            .copied()
            .filter(|&m| m > 0.0)
            .fold(f64::INFINITY, f64::min);
        for m in &mut mass {
            *m = if *m > 0.0 {
                *m * scale
            } else {
                min_mass * scale
            };
        }
        let pairs = tets.iter().flat_map(|t| {
            let t = t.map(|i| i as usize);
            [
                [t[0], t[1]],
                [t[0], t[2]],
                [t[0], t[3]],
                [t[1], t[2]],
                [t[1], t[3]],
                [t[2], t[3]],
            ]
        });
        let mut k_rest = BlockSparse::from_pairs(n, pairs);
        let upper: Vec<[u32; 10]> = tets
            .iter()
            .map(|t| {
                PAIRS.map(|(a, b)| {
                    let (i, j) = (t[a] as usize, t[b] as usize);
                    if i <= j {
                        k_rest.block_index(i, j).expect("pattern") as u32
                    } else {
                        k_rest.block_index(j, i).expect("pattern") as u32 | TRANSPOSED
                    }
                })
            })
            .collect();
        let (lambda, mu) = element::lame(config.young_modulus, config.poisson_ratio);
        let identity = vec![UnitQuaternion::identity(); tets.len()];
        add_warped_upper(
            &mut k_rest,
            &upper,
            &grads,
            &volumes,
            |_| Matrix3::identity(),
            lambda,
            mu,
            1.0,
        );
        k_rest.mirror_upper();
        // The rest stiffness alone is singular for a free body: factorize the system matrix.
        let mut body_matrix = k_rest.clone();
        fill_rest_system(&mut body_matrix, &k_rest, &mass, &anchor_k, &config);
        let system = ImplicitSystem::new(body_matrix, fixed.clone())?;
        let packed = packed::PackedElements::new(&tets, &grads, &volumes, n);
        let tet_count = tets.len();
        let mut body = FemBody {
            packed,
            config,
            lambda,
            mu,
            tets,
            grads,
            volumes,
            upper,
            nodes: Nodes::new(rest, mass, fixed, anchor_k),
            rots: vec![Matrix3::identity(); identity.len()],
            quats_assembled: identity.clone(),
            stale: Vec::with_capacity(tet_count),
            assembly_cursor: 0,
            // The rest system is the warped system at the identity rotations.
            matrix_current: true,
            quats: identity,
            k_rest,
            system,
            rhs: vec![Vec3::zeros(); n],
            dv: vec![Vec3::zeros(); n],
            tmp: vec![Vec3::zeros(); n],
            backup_x: vec![Vec3::zeros(); n],
            backup_v: vec![Vec3::zeros(); n],
            stats: FemStepStats::default(),
            static_system: None,
            prefactored: None,
            assembly_deltas: Vec::new(),
            bdf2: Default::default(),
            contact: Default::default(),
            frame: UnitQuaternion::identity(),
        };
        if config.model == FemModel::CorotationalPrefactored {
            body.prefactored = Some(prefactored::Prefactored::new(&body)?);
        }
        Ok(body)
    }

    /// The settings.
    pub fn config(&self) -> &FemConfig {
        &self.config
    }

    /// The elastic model in use.
    pub fn model(&self) -> FemModel {
        self.config.model
    }

    /// Switches the elastic model at run time. Linear and corotational share the rest
    /// factorization (free); the prefactored model factorizes its own system the first time
    /// it is used. Fails (and keeps the model) when the configuration does not suit the new
    /// model (the prefactored model takes no stiffness damping) or its factorization fails.
    pub fn set_model(&mut self, model: FemModel) -> Result<(), FemError> {
        if model != self.config.model {
            let mut c = self.config;
            c.model = model;
            c.validate()?;
            if model == FemModel::CorotationalPrefactored && self.prefactored.is_none() {
                self.prefactored = Some(prefactored::Prefactored::new(self)?);
            }
            self.config.model = model;
            self.dv.fill(Vec3::zeros());
            self.bdf2.valid = false;
            // The linear model leaves the system matrix as it was: still the warped stiffness
            // of `quats_assembled`, updated element by element from the next step on.
            if model.is_corotational() {
                self.sync_rotations();
            }
        }
        Ok(())
    }

    /// Recomputes every element rotation from the current positions, to convergence. Call
    /// after setting positions far from the last step's (state transfer, teleporting); steps
    /// only refine the rotations incrementally. Same as [`FemBody::sync_rotations_from`] with
    /// no hint.
    pub fn sync_rotations(&mut self) {
        self.sync_rotations_from(UnitQuaternion::identity());
    }

    /// Recomputes every element rotation from the current positions, to convergence, starting
    /// from each element's held rotation turned by `hint`: when the body has turned as a whole
    /// by `hint` since the rotations were last updated (a state handed over from a cage that
    /// turned), every element starts next to its answer. The warped stiffness is updated by
    /// the next steps, element by element, as for any rotation.
    pub fn sync_rotations_from(&mut self, hint: UnitQuaternion<f64>) {
        if hint.angle() > 0.0 {
            for (q, r) in self.quats.iter_mut().zip(&mut self.rots) {
                *q = hint * *q;
                *r = *q.to_rotation_matrix().matrix();
            }
        }
        // Eight elements at a time, to a millionth of a radian (steps refine further, to
        // `rotation_tolerance`); large corrections and saddles get the scalar,
        // saddle-proof search.
        self.packed.sync(
            &self.nodes.x,
            packed::RotationState {
                quats: &mut self.quats,
                rots: &mut self.rots,
                assembled: &self.quats_assembled,
                stale: &mut self.stale,
            },
            50,
            1e-6,
        );
        // The last velocity change is no guess for a state from elsewhere, nor the last
        // step's history.
        self.dv.fill(Vec3::zeros());
        self.bdf2.valid = false;
    }

    /// Changes the time step: a numeric refactorization of the system (no allocation).
    pub fn set_dt(&mut self, dt: f64) -> Result<(), FemError> {
        let mut c = self.config;
        c.dt = dt;
        c.validate()?;
        self.config = c;
        self.bdf2.valid = false;
        self.refactor_rest()
    }

    /// The time integrator in use.
    pub fn integrator(&self) -> FemIntegrator {
        self.config.integrator
    }

    /// Changes the time integrator: a numeric refactorization of the system (BDF2 solves
    /// with `2 dt / 3`; no allocation but the BDF2 history, sized the first time). The next
    /// BDF2 step starts a new history. Fails, keeping the integrator, when the model does not
    /// take it (the prefactored model takes backward Euler only).
    pub fn set_integrator(&mut self, integrator: FemIntegrator) -> Result<(), FemError> {
        if integrator != self.config.integrator {
            let mut c = self.config;
            c.integrator = integrator;
            c.validate()?;
            let old = self.config.integrator;
            self.config.integrator = integrator;
            self.bdf2.valid = false;
            if let Err(e) = self.refactor_rest() {
                // Back to the integrator (and factorization) that worked.
                self.config.integrator = old;
                self.refactor_rest()?;
                return Err(e);
            }
        }
        Ok(())
    }

    /// Forgets the BDF2 history: the next step starts it again from the current state (as
    /// after a reset). Call after replacing the state with one that does not continue the
    /// last step (state transfer); small edits between steps (contact corrections,
    /// kinematic moves) need not.
    pub fn restart_history(&mut self) {
        self.bdf2.valid = false;
    }

    /// Changes gravity.
    pub fn set_gravity(&mut self, gravity: Vec3) -> Result<(), FemError> {
        let mut c = self.config;
        c.gravity = gravity;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// Changes the CG tolerance and iteration cap.
    pub fn set_cg(&mut self, tolerance: f64, max_iterations: u32) -> Result<(), FemError> {
        let mut c = self.config;
        c.cg_tolerance = tolerance;
        c.cg_max_iterations = max_iterations;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// Changes [`FemConfig::rotation_tolerance`].
    pub fn set_rotation_tolerance(&mut self, tolerance: f64) -> Result<(), FemError> {
        let mut c = self.config;
        c.rotation_tolerance = tolerance;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// Sets [`FemConfig::cg_must_converge`].
    pub fn set_cg_must_converge(&mut self, on: bool) {
        self.config.cg_must_converge = on;
    }

    fn refactor_rest(&mut self) -> Result<(), FemError> {
        // The rest system is the warped system at the identity rotations.
        self.quats_assembled.fill(UnitQuaternion::identity());
        self.matrix_current = true;
        fill_rest_system(
            &mut self.system.matrix,
            &self.k_rest,
            &self.nodes.mass,
            &self.nodes.anchor_k,
            &self.config,
        );
        self.system.refactor()?;
        Ok(())
    }

    /// Number of elements.
    pub fn tet_count(&self) -> usize {
        self.tets.len()
    }

    /// Stored entries of the Cholesky factor(s) the model in use solves with (the prefactored
    /// model's scalar factors, the others' block system).
    pub fn factor_nnz(&self) -> usize {
        match (&self.prefactored, self.config.model) {
            (Some(s), FemModel::CorotationalPrefactored) => s.factor_nnz(),
            _ => self.system.factor_nnz(),
        }
    }

    /// Bytes held by the model in use for its matrices and factors (values and indices):
    /// the block system matrix, the rest stiffness and the factor for linear and
    /// corotational; the Laplacian and scalar factors for the prefactored model (the body
    /// also keeps the rest system the others use).
    pub fn matrix_bytes(&self) -> usize {
        let blocks = self.system.matrix.stored_blocks() + self.k_rest.stored_blocks();
        let block_bytes = blocks * (72 + 4) + self.system.factor_nnz() * 16;
        match (&self.prefactored, self.config.model) {
            (Some(s), FemModel::CorotationalPrefactored) => s.bytes(),
            _ => block_bytes,
        }
    }

    /// What the last step did.
    pub fn last_step(&self) -> FemStepStats {
        self.stats
    }

    /// Elastic energy of the current state: strain energy of the model in use plus the energy
    /// of the anchor springs. Corotational rotations are refined from the last step's (warm
    /// start, no allocation), so this is cheap enough to call every step.
    pub fn elastic_energy(&self) -> f64 {
        let mut energy = 0.0;
        for (t, tet) in self.tets.iter().enumerate() {
            let p = tet.map(|i| self.nodes.x[i as usize]);
            let def = element::deformation_gradient(&p, &self.grads[t]);
            let s = match self.config.model {
                FemModel::Linear => def,
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    let (mut q, mut r) = (self.quats[t], self.rots[t]);
                    rotation::extract_rotation(&def, &mut q, &mut r, 50, 1e-12);
                    r.transpose() * def
                }
            };
            let eps = (s + s.transpose()) * 0.5 - Matrix3::identity();
            energy += self.volumes[t] * element::energy_density(&eps, self.lambda, self.mu);
        }
        energy + self.nodes.anchor_energy()
    }

    /// Puts the body back at rest in its rest shape.
    pub fn reset(&mut self) {
        self.nodes.reset();
        self.dv.fill(Vec3::zeros());
        self.bdf2.valid = false;
        self.quats.fill(UnitQuaternion::identity());
        self.rots.fill(Matrix3::identity());
        // Back to the system matrix the body was built with (the rest system, the warped
        // system at the identity rotations), so a run after a reset repeats the first.
        fill_rest_system(
            &mut self.system.matrix,
            &self.k_rest,
            &self.nodes.mass,
            &self.nodes.anchor_k,
            &self.config,
        );
        self.quats_assembled.fill(UnitQuaternion::identity());
        self.matrix_current = true;
        self.assembly_cursor = 0;
        // The body frame's warm start and the preconditioner turned by it: a run after a
        // reset starts from the identity as the first did (bit for bit).
        self.frame = UnitQuaternion::identity();
        self.system.set_preconditioner_frame(None);
    }

    /// Elastic plus anchor forces at positions `x` for `model` (rotations extracted to
    /// convergence from a cold start), written to `out`; returns the energy. Allocation-free
    /// but not for steps: used for checks and static solves.
    pub fn forces_and_energy(&self, x: &[Vec3], model: FemModel, out: &mut [Vec3]) -> f64 {
        out.fill(Vec3::zeros());
        let mut energy = 0.0;
        let mut fe = [Vec3::zeros(); 4];
        for (t, tet) in self.tets.iter().enumerate() {
            let p = tet.map(|i| x[i as usize]);
            let r = match model {
                FemModel::Linear => Matrix3::identity(),
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    rotation::rotation_of(&element::deformation_gradient(&p, &self.grads[t]))
                }
            };
            energy += element::element_forces(
                &p,
                &self.grads[t],
                self.volumes[t],
                self.lambda,
                self.mu,
                &r,
                &mut fe,
            );
            for a in 0..4 {
                out[tet[a] as usize] += fe[a];
            }
        }
        for i in 0..x.len() {
            let k = self.nodes.anchor_k[i];
            if k > 0.0 {
                let d = x[i] - self.nodes.anchor_target[i];
                out[i] -= k * d;
                energy += 0.5 * k * d.norm_squared();
            }
        }
        energy
    }

    /// The stiffness matrix of `model` at positions `x` (warped `R K R^T` for corotational,
    /// with converged rotations), anchors included, constraints not applied. For checks.
    pub fn stiffness_at(&self, x: &[Vec3], model: FemModel) -> BlockSparse {
        let rots: Vec<Matrix3<f64>> = (0..self.tets.len())
            .map(|t| match model {
                FemModel::Linear => Matrix3::identity(),
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    let p = self.tets[t].map(|i| x[i as usize]);
                    rotation::rotation_of(&element::deformation_gradient(&p, &self.grads[t]))
                }
            })
            .collect();
        let mut k = self.k_rest.clone();
        k.set_upper_zero();
        add_warped_upper(
            &mut k,
            &self.upper,
            &self.grads,
            &self.volumes,
            |t| rots[t],
            self.lambda,
            self.mu,
            1.0,
        );
        k.mirror_upper();
        for i in 0..x.len() {
            let d = k.diag_index(i);
            k.blocks_mut()[d] += Matrix3::identity() * self.nodes.anchor_k[i];
        }
        k
    }

    fn check_inputs(&self) -> Result<(), FemError> {
        match self.nodes.first_non_finite_input() {
            Some((what, node)) => Err(FemError::NonFinite { what, node }),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests;
