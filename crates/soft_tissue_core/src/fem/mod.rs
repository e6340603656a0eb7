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

pub mod element;
mod packed;
mod prefactored;
pub mod rotation;

use std::time::Instant;

use nalgebra::{Matrix3, UnitQuaternion};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::boundary::{Boundary, BoundaryError};
use crate::linalg::{BlockSparse, CgStats, ImplicitSystem, LinalgError, NotConverged};
use crate::material::FemParams;
use crate::mesh::TetMesh;
use crate::state::{self, NodalBody, Nodes};

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

/// How the body's mass is given.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum MassSpec {
    /// Total mass (mass units), lumped onto nodes in proportion to their share of volume.
    Total(f64),
    /// Density (mass / length^3); node mass is density times a quarter of each adjacent
    /// tetrahedron's volume.
    Density(f64),
}

/// Settings of a FEM body. Units follow the scene (see [`crate::material`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FemConfig {
    /// Elastic model. Default: corotational.
    pub model: FemModel,
    /// Young's modulus, force / length^2.
    pub young_modulus: f64,
    /// Poisson ratio, in (-1, 0.5).
    pub poisson_ratio: f64,
    /// Mass of the body.
    pub mass: MassSpec,
    /// Rayleigh mass-proportional damping `alpha`, 1 / time (the paper's FEM "damping").
    pub mass_damping: f64,
    /// Rayleigh stiffness-proportional damping `beta`, time. Default 0.
    pub stiffness_damping: f64,
    /// Time step, time.
    pub dt: f64,
    /// Gravity, length / time^2. Default zero.
    pub gravity: Vec3,
    /// Relative residual at which the corotational CG stops. Default 1e-4.
    pub cg_tolerance: f64,
    /// Iteration cap of the corotational CG. Default 20.
    pub cg_max_iterations: u32,
    /// What a corotational CG that reaches its cap without meeting its tolerance does.
    /// `false` (the default, for real time): the step goes on with the last iterate (an
    /// inexact implicit step, still stable) and says so ([`FemStepStats::cg`]'s `converged`
    /// is false; the world counts it in `BodyDiagnostics::unconverged_solves`). `true`: the
    /// step fails with [`FemError::NotConverged`] and leaves the state unchanged.
    #[serde(default)]
    pub cg_must_converge: bool,
    /// Iteration cap of the per-element rotation extraction (warm-started). Default 1.
    pub rotation_iterations: u32,
    /// Corotational: an element's warped stiffness in the implicit system is updated when it
    /// has turned by more than this angle (radians) since its last update; forces always use
    /// the current rotations. 0 updates every element every step (the textbook method).
    /// Default 0.01: the implicit Jacobian lags the rotations by at most 0.6 degrees, well
    /// inside the error of dropping the derivative of `R` that every corotational method
    /// makes. At most a quarter of the elements are updated in one step (the ones turned
    /// longest ago first), so a step never pays a whole re-assembly; under fast rotation of
    /// the whole body the rest follow within a few steps.
    pub stiffness_update_angle: f64,
    /// Prefactored corotational model: iterations per step (each one element loop and three
    /// scalar solves). Default 1.
    #[serde(default = "default_prefactored_iterations")]
    pub prefactored_iterations: u32,
    /// Time integrator. Default backward Euler.
    #[serde(default)]
    pub integrator: FemIntegrator,
    /// Corotational (CG): a warm-started element rotation is refined (up to
    /// `rotation_iterations` updates a step) until its correction angle is below this many
    /// radians. The elastic forces, and so the state stepping settles in, are off the true
    /// corotational forces by about this angle times the stress: with 1e-4 a body at rest
    /// sat 1e-5 to 4e-5 (relative) away from [`FemBody::solve_static`]. Default 1e-10 (see
    /// [`DEFAULT_ROTATION_TOLERANCE`]): stepping converges to the static solution within
    /// 1e-8 (relative); a converged element takes no update, so the cost in motion is a
    /// few more element updates (docs/solvers.md quotes the measured change).
    #[serde(default = "default_rotation_tolerance")]
    pub rotation_tolerance: f64,
}

fn default_prefactored_iterations() -> u32 {
    1
}

fn default_rotation_tolerance() -> f64 {
    DEFAULT_ROTATION_TOLERANCE
}

impl FemConfig {
    /// Corotational FEM with the paper's material parameters (its damping taken as the
    /// mass-proportional Rayleigh coefficient) and time step.
    pub fn paper(params: &FemParams, dt: f64) -> Self {
        FemConfig {
            model: FemModel::Corotational,
            young_modulus: params.young_modulus,
            poisson_ratio: params.poisson_ratio,
            mass: MassSpec::Total(params.mass),
            mass_damping: params.damping,
            stiffness_damping: 0.0,
            dt,
            gravity: Vec3::zeros(),
            cg_tolerance: 1e-4,
            cg_max_iterations: 20,
            cg_must_converge: false,
            rotation_iterations: 1,
            stiffness_update_angle: 0.01,
            prefactored_iterations: default_prefactored_iterations(),
            integrator: FemIntegrator::BackwardEuler,
            rotation_tolerance: DEFAULT_ROTATION_TOLERANCE,
        }
    }

    /// The step length of the backward-Euler system the integrator solves: `dt` for backward
    /// Euler, `2 dt / 3` for BDF2.
    pub fn system_dt(&self) -> f64 {
        match self.integrator {
            FemIntegrator::BackwardEuler => self.dt,
            FemIntegrator::Bdf2 => 2.0 * self.dt / 3.0,
        }
    }

    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), FemError> {
        let bad =
            |field: &'static str, message: String| Err(FemError::InvalidConfig { field, message });
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if !pos(self.young_modulus) {
            return bad(
                "young_modulus",
                format!("must be positive, found {}", self.young_modulus),
            );
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return bad(
                "poisson_ratio",
                format!("must be in (-1, 0.5), found {}", self.poisson_ratio),
            );
        }
        match self.mass {
            MassSpec::Total(m) if !pos(m) => {
                return bad("mass", format!("total mass must be positive, found {m}"));
            }
            MassSpec::Density(d) if !pos(d) => {
                return bad("mass", format!("density must be positive, found {d}"));
            }
            _ => {}
        }
        if !nonneg(self.mass_damping) {
            return bad(
                "mass_damping",
                format!("must be >= 0, found {}", self.mass_damping),
            );
        }
        if !nonneg(self.stiffness_damping) {
            return bad(
                "stiffness_damping",
                format!("must be >= 0, found {}", self.stiffness_damping),
            );
        }
        if !pos(self.dt) {
            return bad("dt", format!("must be positive, found {}", self.dt));
        }
        if !self.gravity.iter().all(|g| g.is_finite()) {
            return bad(
                "gravity",
                format!("must be finite, found {:?}", self.gravity),
            );
        }
        if !pos(self.cg_tolerance) {
            return bad(
                "cg_tolerance",
                format!("must be positive, found {}", self.cg_tolerance),
            );
        }
        if self.cg_max_iterations == 0 {
            return bad("cg_max_iterations", "must be at least 1".into());
        }
        if self.prefactored_iterations == 0 {
            return bad("prefactored_iterations", "must be at least 1".into());
        }
        if self.model == FemModel::CorotationalPrefactored && self.integrator == FemIntegrator::Bdf2
        {
            return bad(
                "integrator",
                "must be BackwardEuler for the corotational-prefactored model (its inexact \
                 iterations extrapolated by BDF2 grew energy fivefold in the Young x1000 hard \
                 case)"
                    .into(),
            );
        }
        if self.model == FemModel::CorotationalPrefactored && self.stiffness_damping != 0.0 {
            return bad(
                "stiffness_damping",
                format!(
                    "must be 0 for the corotational-prefactored model (it damps by mass only), found {}",
                    self.stiffness_damping
                ),
            );
        }
        if !pos(self.rotation_tolerance) {
            return bad(
                "rotation_tolerance",
                format!("must be positive, found {}", self.rotation_tolerance),
            );
        }
        if !nonneg(self.stiffness_update_angle) {
            return bad(
                "stiffness_update_angle",
                format!("must be >= 0, found {}", self.stiffness_update_angle),
            );
        }
        Ok(())
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
}

impl NodalBody for FemBody {
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

    /// Advances by one time step `config().dt`. On error the state is unchanged (the external
    /// force accumulator is kept for inspection).
    ///
    /// BDF2 ([`FemIntegrator::Bdf2`]) keeps the last step's differences `x_n - x_{n-1}` and
    /// `v_n - v_{n-1}` and takes a backward Euler step of `2 dt / 3` from `x_n + (x_n -
    /// x_{n-1}) / 3`, `v_n + (v_n - v_{n-1}) / 3` (fixed components stay where they are).
    /// Changes made to the state between steps (a contact's correction, a kinematic move)
    /// shift the whole history with them: `x_{n-1}` moves by the same amount as `x_n`, so the
    /// step continues from the corrected state and a correction is not extrapolated (no 4/3
    /// overshoot). The first step, and the first after a reset, a change of model, step or
    /// integrator, a rotation sync or [`FemBody::restart_history`], has no `x_{n-1}`: it takes
    /// `x_n - x_{n-1} = dt v_n`, `v_n - v_{n-1} = dt a_n` with `a_n` the acceleration of the
    /// current state under the step's forces (exact at rest; errors of order `dt^2`, so the
    /// method stays second order).
    pub fn step(&mut self) -> Result<FemStepStats, FemError> {
        self.check_inputs()?;
        self.backup_x.copy_from_slice(&self.nodes.x);
        self.backup_v.copy_from_slice(&self.nodes.v);
        let bdf2 = self.config.integrator == FemIntegrator::Bdf2;
        if bdf2 {
            self.extrapolate();
        }
        match self.step_from_current() {
            Ok(stats) => {
                if bdf2 {
                    self.bdf2
                        .record(&self.nodes, &self.backup_x, &self.backup_v);
                }
                self.nodes.f_ext.fill(Vec3::zeros());
                self.stats = stats;
                Ok(stats)
            }
            Err(e) => {
                self.nodes.x.copy_from_slice(&self.backup_x);
                self.nodes.v.copy_from_slice(&self.backup_v);
                self.dv.fill(Vec3::zeros());
                Err(e)
            }
        }
    }

    /// BDF2: moves the state to the extrapolated start of the step (see [`FemBody::step`]),
    /// starting the history first when there is none.
    fn extrapolate(&mut self) {
        if self.bdf2.needs_start(self.nodes.x.len()) {
            self.start_history();
        }
        self.bdf2.extrapolate(&mut self.nodes);
    }

    /// A history for a state without one: `dt v_n` and `dt a_n`, `a_n` the acceleration of
    /// the current state under the step's external forces, gravity, damping, elastic and
    /// anchor forces (rotations extracted afresh; stiffness damping with the rest stiffness
    /// for the linear model, the assembled warped one for the corotational model).
    fn start_history(&mut self) {
        let h = self.config.dt;
        let model = self.config.model;
        let mut f = self.bdf2.take_buffer();
        self.forces_and_energy(&self.nodes.x, model, &mut f);
        let (alpha, beta) = (self.config.mass_damping, self.config.stiffness_damping);
        if beta > 0.0 {
            match model {
                FemModel::Linear => self.k_rest.mul_add(-beta, &self.nodes.v, &mut f),
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    // K v = (A v - G v) / c with the system matrix A = G + c K.
                    let hs = self.config.system_dt();
                    let c = beta * hs + hs * hs;
                    self.system.matrix.mul(&self.nodes.v, &mut self.tmp);
                    for i in 0..f.len() {
                        let diag = (1.0 + hs * alpha) * self.nodes.mass[i]
                            + hs * hs * self.nodes.anchor_k[i];
                        f[i] -= beta * (self.tmp[i] - diag * self.nodes.v[i]) / c;
                    }
                }
            }
        }
        let g = self.config.gravity;
        for i in 0..f.len() {
            let m = self.nodes.mass[i];
            f[i] = (f[i] + self.nodes.f_ext[i]) / m + g - alpha * self.nodes.v[i];
        }
        self.bdf2.start(&self.nodes, f, h);
    }

    /// One backward Euler step of `config().system_dt()` from the current state; on error
    /// the caller restores the state.
    fn step_from_current(&mut self) -> Result<FemStepStats, FemError> {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let mut stats = FemStepStats::default();
        match self.config.model {
            FemModel::Linear => {
                self.fill_common_rhs();
                let start = Instant::now();
                let with_product = !self.fixed_at_rest();
                self.linear_dv(with_product)?;
                stats.solve_us = start.elapsed().as_secs_f64() * 1e6;
            }
            FemModel::Corotational => {
                self.fill_common_rhs();
                (
                    stats.rotation_iterations,
                    stats.assembled,
                    stats.forces_us,
                    stats.assembly_us,
                ) = self.corotational_forces_and_matrix();
                let start = Instant::now();
                // -(beta + h) K_R v  =  -(A v - (1 + h alpha) M v - h^2 Ka v) / h
                self.system.matrix.mul(&self.nodes.v, &mut self.tmp);
                for i in 0..self.nodes.x.len() {
                    let diag =
                        (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
                    let krv = (self.tmp[i] - diag * self.nodes.v[i]) / h;
                    self.rhs[i] = h * (self.rhs[i] - krv);
                }
                stats.cg = self.system.solve_cg(
                    &self.rhs,
                    &mut self.dv,
                    self.config.cg_tolerance,
                    self.config.cg_max_iterations,
                )?;
                if self.config.cg_must_converge
                    && let Err(e) = stats.cg.require_converged(self.config.cg_tolerance)
                {
                    self.dv.fill(Vec3::zeros());
                    return Err(e.into());
                }
                stats.solve_us = start.elapsed().as_secs_f64() * 1e6;
            }
            FemModel::CorotationalPrefactored => {
                let (worst, loops_us, solve_us) = self.prefactored_step()?;
                stats.rotation_iterations = worst;
                stats.forces_us = loops_us;
                stats.solve_us = solve_us;
            }
        }
        for i in 0..self.nodes.x.len() {
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.v[i][a] += self.dv[i][a];
                    self.nodes.x[i][a] += h * self.nodes.v[i][a];
                }
            }
        }
        if let Some((what, node)) = state::first_non_finite_state(&self.nodes.x, &self.nodes.v) {
            return Err(FemError::NonFinite { what, node });
        }
        Ok(stats)
    }

    /// Forces that do not depend on the model: external, gravity, mass damping, anchors
    /// (with their implicit term), into `rhs`.
    fn fill_common_rhs(&mut self) {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let g = self.config.gravity;
        for i in 0..self.nodes.x.len() {
            let m = self.nodes.mass[i];
            let k = self.nodes.anchor_k[i];
            self.rhs[i] = self.nodes.f_ext[i] + m * g
                - alpha * m * self.nodes.v[i]
                - k * (self.nodes.x[i] - self.nodes.anchor_target[i] + h * self.nodes.v[i]);
        }
    }

    /// Linear model: `dv` from the forces in `rhs`, either with a product with `K` or
    /// without one (exact only when the fixed components sit at rest).
    fn linear_dv(&mut self, with_product: bool) -> Result<(), FemError> {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let beta = self.config.stiffness_damping;
        if !with_product {
            // The system matrix is A = G + c K with G = (1 + h alpha) M + h^2 Ka diagonal
            // and c = h beta + h^2, so h K y = (h / c) (A y - G y) for y = u + (beta + h) v:
            // dv = A^-1 (h r + (h / c) G y) - (h / c) y, one solve and no product with K.
            // Exact on the free unknowns when the fixed components sit at rest (y = 0
            // there); otherwise the branch below multiplies by K.
            let c = beta * h + h * h;
            let hc = h / c;
            for i in 0..self.nodes.x.len() {
                let y = self.nodes.x[i] - self.nodes.rest[i] + (beta + h) * self.nodes.v[i];
                let diag = (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
                self.tmp[i] = y;
                self.rhs[i] = h * self.rhs[i] + (hc * diag) * y;
            }
            self.system.solve_direct(&self.rhs, &mut self.dv)?;
            for (d, y) in self.dv.iter_mut().zip(&self.tmp) {
                *d -= hc * y;
            }
        } else {
            // -K (u + (beta + h) v)
            for i in 0..self.nodes.x.len() {
                self.tmp[i] = self.nodes.x[i] - self.nodes.rest[i] + (beta + h) * self.nodes.v[i];
            }
            self.k_rest.mul_add(-1.0, &self.tmp, &mut self.rhs);
            for r in &mut self.rhs {
                *r *= h;
            }
            self.system.solve_direct(&self.rhs, &mut self.dv)?;
        }
        Ok(())
    }

    /// Whether every fixed component sits at its rest coordinate (not moved kinematically).
    fn fixed_at_rest(&self) -> bool {
        self.nodes
            .fixed
            .iter()
            .zip(self.nodes.x.iter().zip(&self.nodes.rest))
            .all(|(f, (x, r))| (0..3).all(|a| !f[a] || x[a] == r[a]))
    }

    /// Corotational: updates rotations, adds elastic forces to `rhs`, and assembles the
    /// system matrix `(1 + h alpha) M + (h beta + h^2) R K R^T + h^2 Ka`. Returns the worst
    /// rotation iterations, whether it assembled, and the times of the two, microseconds.
    fn corotational_forces_and_matrix(&mut self) -> (u32, bool, f64, f64) {
        let start = Instant::now();
        let cos_half = (0.5 * self.config.stiffness_update_angle).cos();
        let loop_stats = self.packed.forces(
            &self.nodes.x,
            packed::RotationState {
                quats: &mut self.quats,
                rots: &mut self.rots,
                assembled: &self.quats_assembled,
                stale: &mut self.stale,
            },
            self.lambda,
            self.mu,
            self.config.rotation_iterations,
            self.config.rotation_tolerance,
            cos_half,
            &mut self.rhs,
        );
        let worst = loop_stats.worst_iterations;
        let forces_us = start.elapsed().as_secs_f64() * 1e6;
        let start = Instant::now();
        let assembled = if !self.matrix_current || self.config.stiffness_update_angle == 0.0 {
            self.assemble_warped_system();
            true
        } else if loop_stats.stale {
            self.update_stale_elements();
            true
        } else {
            false
        };
        (
            worst,
            assembled,
            forces_us,
            start.elapsed().as_secs_f64() * 1e6,
        )
    }

    /// Updates the warped stiffness of the stale elements of this step's element loop (at
    /// most [`ASSEMBLY_SHARE`] of all elements, continuing round robin from where the last
    /// update stopped): each element's contribution with its assembled rotation is taken out
    /// and the one with its current rotation put in.
    fn update_stale_elements(&mut self) {
        let n = self.stale.len();
        if n == 0 {
            return;
        }
        let budget = (self.tets.len() / ASSEMBLY_SHARE).max(64).min(n);
        let start = self
            .stale
            .partition_point(|&t| (t as usize) < self.assembly_cursor);
        let h = self.config.system_dt();
        let c = self.config.stiffness_damping * h + h * h;
        let (lambda, mu) = (self.lambda, self.mu);
        let element = |k: usize| self.stale[(start + k) % n] as usize;
        // An element's change `c (K(R) - K(R_assembled))` of its ten upper blocks; in a pool
        // the changes are computed side by side (the costly part), then added in element
        // order either way, so the matrix does not depend on the thread count.
        let delta = |t: usize| {
            let old = *self.quats_assembled[t].to_rotation_matrix().matrix();
            let (g, v) = (&self.grads[t], self.volumes[t]);
            element_upper_change(g, v, &old, &self.rots[t], lambda, mu, c)
        };
        let parallel = crate::parallel::in_pool() && budget >= 2 * PARALLEL_ELEMENTS;
        if parallel {
            if self.assembly_deltas.len() < budget {
                self.assembly_deltas.resize(budget, [[0.0; 9]; 10]);
            }
            self.assembly_deltas[..budget]
                .par_iter_mut()
                .with_min_len(PARALLEL_ELEMENTS / 4)
                .enumerate()
                .for_each(|(k, d)| *d = delta(element(k)));
        }
        let mut last = 0;
        for k in 0..budget {
            let t = element(k);
            let d = if parallel {
                self.assembly_deltas[k]
            } else {
                delta(t)
            };
            scatter_upper(self.system.matrix.blocks_mut(), &self.upper[t], &d);
            for &target in &self.upper[t] {
                self.system
                    .matrix
                    .mirror_block((target & !TRANSPOSED) as usize);
            }
            last = t;
        }
        for k in 0..budget {
            let t = element(k);
            self.quats_assembled[t] = self.quats[t];
        }
        self.assembly_cursor = last + 1;
    }

    /// `(1 + h alpha) M + (h beta + h^2) R K R^T + h^2 Ka` with the current rotations, in the
    /// upper triangle through the scatter map, then mirrored.
    fn assemble_warped_system(&mut self) {
        let h = self.config.system_dt();
        let c = self.config.stiffness_damping * h + h * h;
        self.system.matrix.set_upper_zero();
        let rots = &self.rots;
        add_warped_upper(
            &mut self.system.matrix,
            &self.upper,
            &self.grads,
            &self.volumes,
            |t| rots[t],
            self.lambda,
            self.mu,
            c,
        );
        self.system.matrix.mirror_upper();
        let alpha = self.config.mass_damping;
        for i in 0..self.nodes.x.len() {
            let d = self.system.matrix.diag_index(i);
            let diag = (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
            self.system.matrix.blocks_mut()[d] += Matrix3::from_diagonal_element(diag);
        }
        self.quats_assembled.copy_from_slice(&self.quats);
        self.matrix_current = true;
    }

    /// Solves for static equilibrium under gravity, external forces (kept, not cleared) and
    /// anchors, in place of the current positions; velocities are zeroed. Linear: one solve.
    /// Corotational: Newton-like iterations with the warped stiffness until the largest
    /// update is below `tolerance` times the rest bounding-box diagonal. Builds (once) a
    /// factorization of the stiffness; not meant for every frame.
    pub fn solve_static(&mut self, tolerance: f64, max_iterations: u32) -> Result<u32, FemError> {
        let boundary_ok = self.nodes.fixed.iter().any(|f| f.iter().any(|&a| a))
            || self.nodes.anchor_k.iter().any(|&k| k > 0.0);
        if !boundary_ok {
            return Err(FemError::Unconstrained);
        }
        self.check_inputs()?;
        if self.static_system.is_none() {
            let mut k = self.k_rest.clone();
            for i in 0..self.nodes.x.len() {
                let d = k.diag_index(i);
                k.blocks_mut()[d] += Matrix3::identity() * self.nodes.anchor_k[i];
            }
            self.static_system = Some(ImplicitSystem::new(k, self.nodes.fixed.clone())?);
        }
        let size = {
            let (lo, hi) = self.nodes.rest.iter().fold(
                (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
                |(lo, hi), p| (lo.inf(p), hi.sup(p)),
            );
            (hi - lo).norm()
        };
        let model = self.config.model;
        let g = self.config.gravity;
        let mut f = vec![Vec3::zeros(); self.nodes.x.len()];
        let mut dx = vec![Vec3::zeros(); self.nodes.x.len()];
        let mut update = f64::INFINITY;
        let mut rots = vec![Matrix3::identity(); self.tets.len()];
        for it in 0..max_iterations.max(1) {
            self.forces_and_energy(&self.nodes.x.clone(), model, &mut f);
            for i in 0..f.len() {
                f[i] += self.nodes.f_ext[i] + self.nodes.mass[i] * g;
            }
            let sys = self.static_system.as_mut().expect("built above");
            dx.fill(Vec3::zeros());
            match model {
                FemModel::Linear => sys.solve_direct(&f, &mut dx)?,
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    for (t, r) in rots.iter_mut().enumerate() {
                        let p = self.tets[t].map(|i| self.nodes.x[i as usize]);
                        *r = rotation::rotation_of(&element::deformation_gradient(
                            &p,
                            &self.grads[t],
                        ));
                    }
                    sys.matrix.set_upper_zero();
                    add_warped_upper(
                        &mut sys.matrix,
                        &self.upper,
                        &self.grads,
                        &self.volumes,
                        |t| rots[t],
                        self.lambda,
                        self.mu,
                        1.0,
                    );
                    sys.matrix.mirror_upper();
                    for i in 0..self.nodes.x.len() {
                        let d = sys.matrix.diag_index(i);
                        sys.matrix.blocks_mut()[d] += Matrix3::identity() * self.nodes.anchor_k[i];
                    }
                    sys.solve_cg(&f, &mut dx, 1e-12, 500)?;
                }
            }
            for i in 0..self.nodes.x.len() {
                self.nodes.x[i] += dx[i];
            }
            update = dx.iter().map(|d| d.norm()).fold(0.0, state::nan_max) / size;
            if !update.is_finite() {
                self.nodes.x.copy_from_slice(&self.nodes.rest);
                return Err(FemError::NonFinite {
                    what: "position",
                    node: 0,
                });
            }
            if model == FemModel::Linear || update <= tolerance {
                self.nodes.v.fill(Vec3::zeros());
                return Ok(it + 1);
            }
        }
        Err(FemError::StaticNotConverged {
            iterations: max_iterations,
            update,
        })
    }
}

/// `(1 + h alpha) M + (h beta + h^2) K + h^2 Ka` at rest, into `out` (same pattern as `k`).
fn fill_rest_system(
    out: &mut BlockSparse,
    k: &BlockSparse,
    mass: &[f64],
    anchor_k: &[f64],
    config: &FemConfig,
) {
    let h = config.system_dt();
    let c = config.stiffness_damping * h + h * h;
    out.copy_values_from(k);
    for b in out.blocks_mut() {
        *b *= c;
    }
    for i in 0..mass.len() {
        let d = out.diag_index(i);
        out.blocks_mut()[d] +=
            Matrix3::identity() * ((1.0 + h * config.mass_damping) * mass[i] + h * h * anchor_k[i]);
    }
}

/// Adds `scale * R K^e R^T` of every element into the upper triangle of `k` (diagonal
/// included) through the upper scatter map; call [`BlockSparse::mirror_upper`] after. Blocks
/// `K_ab = V (lambda c_a c_b^T + mu c_b c_a^T + mu (b_a . b_b) I)` with `c = R b`, written out
/// by hand (this is the hot loop of a corotational step); checked against
/// [`element::stiffness_block`] by a unit test.
#[allow(clippy::too_many_arguments)]
fn add_warped_upper(
    k: &mut BlockSparse,
    upper: &[[u32; 10]],
    grads: &[[Vec3; 4]],
    volumes: &[f64],
    rotation: impl Fn(usize) -> Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) {
    let blocks = k.blocks_mut();
    for t in 0..grads.len() {
        let r = rotation(t);
        add_element_upper(
            blocks, &upper[t], &grads[t], volumes[t], &r, lambda, mu, scale,
        );
    }
}

/// `scale (K(new) - K(old))` for the ten upper blocks `(a, b)`, `a <= b` in the order of
/// [`PAIRS`], of one element's warped stiffness `R K_e R^T` (see [`add_element_upper`]; the
/// rotation-free `mu (b_a . b_b) I` part cancels), each column-major (entry `(i, j)` at
/// `3 j + i`), oriented as the element's node pair (not yet transposed for storage).
fn element_upper_change(
    b: &[Vec3; 4],
    volume: f64,
    old: &Matrix3<f64>,
    new: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) -> [[f64; 9]; 10] {
    let co = [old * b[0], old * b[1], old * b[2], old * b[3]];
    let cn = [new * b[0], new * b[1], new * b[2], new * b[3]];
    let (vl, vm) = (volume * scale * lambda, volume * scale * mu);
    std::array::from_fn(|p| {
        let (a, bb) = PAIRS[p];
        let mut k = [0.0; 9];
        for j in 0..3 {
            for i in 0..3 {
                let outer = cn[a][i] * cn[bb][j] - co[a][i] * co[bb][j];
                let transposed = cn[bb][i] * cn[a][j] - co[bb][i] * co[a][j];
                k[3 * j + i] = vl * outer + vm * transposed;
            }
        }
        k
    })
}

/// Adds element block changes (as [`element_upper_change`] gives them) into the
/// upper-triangle storage through the element's scatter map.
fn scatter_upper(blocks: &mut [Matrix3<f64>], upper: &[u32; 10], element: &[[f64; 9]; 10]) {
    for (&target, e) in upper.iter().zip(element) {
        let k = blocks[(target & !TRANSPOSED) as usize].as_mut_slice();
        if target & TRANSPOSED == 0 {
            for (dst, src) in k.iter_mut().zip(e) {
                *dst += src;
            }
        } else {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * i + j] += e[3 * j + i];
                }
            }
        }
    }
}

/// Adds `scale` times the warped stiffness `R K_e R^T` of one element (shape gradients `b`,
/// volume, rotation `r`) into the upper-triangle blocks its scatter map names.
#[allow(clippy::too_many_arguments)]
#[inline]
fn add_element_upper(
    blocks: &mut [Matrix3<f64>],
    upper: &[u32; 10],
    b: &[Vec3; 4],
    volume: f64,
    r: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) {
    let cr = [r * b[0], r * b[1], r * b[2], r * b[3]];
    let (vl, vm) = (volume * scale * lambda, volume * scale * mu);
    for (&(a, bb), &target) in PAIRS.iter().zip(upper) {
        let ca = [cr[a].x, cr[a].y, cr[a].z];
        let cb = [cr[bb].x, cr[bb].y, cr[bb].z];
        let d = vm * b[a].dot(&b[bb]);
        let k = blocks[(target & !TRANSPOSED) as usize].as_mut_slice();
        // Column-major storage: entry (i, j) at 3 j + i. Transposed: (j, i).
        if target & TRANSPOSED == 0 {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * j + i] += vl * ca[i] * cb[j] + vm * cb[i] * ca[j];
                }
                k[4 * j] += d;
            }
        } else {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * i + j] += vl * ca[i] * cb[j] + vm * cb[i] * ca[j];
                }
                k[4 * j] += d;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate::block;
    use nalgebra::Rotation3;

    /// The hand-written upper-triangle assembly (used by steps, `stiffness_at` and the static
    /// solve) equals a plain assembly of [`element::stiffness_block`] over all 16 blocks.
    #[test]
    fn fast_assembly_matches_the_element_kernel() {
        let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [3, 2, 2]).unwrap();
        let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
        c.stiffness_damping = 0.003;
        let mut boundary = Boundary::fixed_nodes([0, 1]);
        boundary.anchors.push((5, 40.0));
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        let rot = Rotation3::from_euler_angles(0.5, -0.3, 1.1);
        for (i, x) in body.positions_mut().iter_mut().enumerate() {
            *x = rot * (*x * (1.0 + 0.01 * (i % 5) as f64));
        }
        body.sync_rotations();
        // Converged rotations (the hand-over sync stops at 1e-6 rad).
        for t in 0..body.tets.len() {
            let p = body.tets[t].map(|i| body.nodes.x[i as usize]);
            let f = element::deformation_gradient(&p, &body.grads[t]);
            rotation::extract_rotation(&f, &mut body.quats[t], &mut body.rots[t], 100, 1e-15);
        }
        // Reference: K_R plus anchors, from the element kernel.
        let mut reference = body.k_rest.clone();
        reference.set_zero();
        for (t, tet) in body.tets.iter().enumerate() {
            let b = &body.grads[t];
            let r = body.rots[t];
            for a in 0..4 {
                for bb in 0..4 {
                    let blk = element::stiffness_block(
                        &(r * b[a]),
                        &(r * b[bb]),
                        b[a].dot(&b[bb]),
                        body.volumes[t],
                        body.lambda,
                        body.mu,
                    );
                    let k = reference
                        .block_index(tet[a] as usize, tet[bb] as usize)
                        .unwrap();
                    reference.blocks_mut()[k] += blk;
                }
            }
        }
        for i in 0..body.node_count() {
            let d = reference.diag_index(i);
            reference.blocks_mut()[d] += Matrix3::identity() * body.nodes.anchor_k[i];
        }
        let size = reference
            .blocks()
            .iter()
            .map(|b| b.abs().max())
            .fold(0.0, f64::max);
        let at = body.stiffness_at(body.positions(), FemModel::Corotational);
        let worst = at
            .blocks()
            .iter()
            .zip(reference.blocks())
            .map(|(a, b)| (a - b).abs().max())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-12 * size,
            "stiffness_at differs by {worst} (scale {size})"
        );
        // The step's system matrix: (1 + h alpha) M + c K_R + h^2 Ka, updated element by
        // element from the rest system, at most a quarter of the elements (at least 64) a
        // step: every element has turned here, so it takes two element loops.
        for round in 0..2 {
            body.rhs.fill(Vec3::zeros());
            body.corotational_forces_and_matrix();
            let pending = body
                .quats
                .iter()
                .zip(&body.quats_assembled)
                .filter(|(q, a)| q.angle_to(a) > 1e-12)
                .count();
            let expected = [body.tets.len() - 64, 0][round];
            assert_eq!(pending, expected, "round {round}");
        }
        let h = c.dt;
        let scale = c.stiffness_damping * h + h * h;
        let mut worst: f64 = 0.0;
        for i in 0..body.node_count() {
            let (cols, range) = reference.row(i);
            for (&j, k) in cols.iter().zip(range) {
                let mut expected = reference.blocks()[k] * scale;
                if j as usize == i {
                    expected += Matrix3::identity()
                        * ((1.0 + h * c.mass_damping) * body.nodes.mass[i]
                            + (h * h - scale) * body.nodes.anchor_k[i]);
                }
                worst = worst.max((body.system.matrix.blocks()[k] - expected).abs().max());
            }
        }
        assert!(worst < 1e-12 * size, "system matrix differs by {worst}");
        assert!(body.system.matrix.asymmetry() < 1e-15 * size);
    }

    /// The element loop, its force sums and the warped-stiffness update give the same bits
    /// on one thread and in pools of two and three (they split into parts only in a pool):
    /// rotations, forces, stale lists and the system matrix, on a turned, deformed block of
    /// 3000 elements whose every element is stale.
    #[test]
    fn element_loop_and_assembly_are_the_same_on_any_thread_count() {
        let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [10, 10, 5]).unwrap();
        let run = |threads: usize| {
            let c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
            let mut body = FemBody::new(&mesh, c, &Boundary::fixed_nodes([0])).unwrap();
            let rot = Rotation3::from_euler_angles(0.4, -0.2, 0.9);
            for (i, x) in body.nodes.x.iter_mut().enumerate() {
                let s = i as f64;
                *x = rot * (*x + 0.02 * Vec3::new(s.sin(), (1.3 * s).cos(), (0.4 * s).sin()));
            }
            let pool = crate::parallel::Threads::new(threads).unwrap();
            let mut stale = 0;
            pool.run(|| {
                for _ in 0..3 {
                    body.rhs.fill(Vec3::zeros());
                    body.corotational_forces_and_matrix();
                    stale = stale.max(body.stale.len());
                }
            });
            (body, stale)
        };
        let (one, stale) = run(1);
        assert!(stale >= 2 * PARALLEL_ELEMENTS, "{stale} stale elements");
        for threads in [2, 3] {
            let (other, _) = run(threads);
            assert_eq!(one.rhs, other.rhs, "{threads} threads: forces");
            assert_eq!(one.quats, other.quats, "{threads} threads: rotations");
            assert_eq!(one.stale, other.stale, "{threads} threads: stale list");
            assert_eq!(
                one.system.matrix.blocks(),
                other.system.matrix.blocks(),
                "{threads} threads: system matrix"
            );
        }
    }

    /// The linear step without a product with `K` (used when the fixed components sit at rest)
    /// gives the `dv` of the step with the product, on a body with fixed nodes, an anchor,
    /// stiffness damping, a deformed state, velocities and external forces.
    #[test]
    fn linear_step_without_the_stiffness_product_is_the_same_step() {
        let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [4, 2, 2]).unwrap();
        for beta in [0.0, 0.004] {
            let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
            c.model = FemModel::Linear;
            c.stiffness_damping = beta;
            c.mass_damping = 0.3;
            c.gravity = Vec3::new(0.0, -9.81, 0.0);
            let mut boundary = Boundary::fixed_nodes([0, 1, 2]);
            boundary.anchors.push((7, 40.0));
            let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
            for (i, (x, v)) in body
                .nodes
                .x
                .iter_mut()
                .zip(body.nodes.v.iter_mut())
                .enumerate()
            {
                if i > 2 {
                    let s = i as f64;
                    *x += Vec3::new(0.01 * s.sin(), 0.02 * s.cos(), -0.015 * (0.7 * s).sin());
                    *v = Vec3::new(0.3 * (1.3 * s).cos(), -0.2 * s.sin(), 0.1);
                }
            }
            body.nodes.f_ext[9] = Vec3::new(3.0, -1.0, 2.0);
            assert!(body.fixed_at_rest());
            body.fill_common_rhs();
            body.linear_dv(true).unwrap();
            let with = body.dv.clone();
            body.fill_common_rhs();
            body.linear_dv(false).unwrap();
            let scale = with.iter().map(|d| d.norm()).fold(0.0, f64::max);
            assert!(scale > 1e-3, "the state moves");
            for (i, (a, b)) in with.iter().zip(&body.dv).enumerate() {
                assert!(
                    (a - b).norm() <= 1e-10 * scale,
                    "beta {beta}, node {i}: {a:?} vs {b:?}"
                );
            }
        }
    }

    /// The packed (eight-lane) element loop gives the rotations, iteration counts and forces
    /// of the scalar element code ([`rotation::extract_rotation`], `-V R sigma b`): on a mesh
    /// whose element count is not a multiple of eight, for a small deformation (first-order
    /// updates), a half-turn-scale rotation (the large-correction fallback) and one inverted
    /// element, with one and with three rotation iterations. Both round differently (the
    /// vector code orders the quaternion arithmetic its own way); the iteration amplifies that
    /// for an element a half turn from its start (5e-10 measured, elsewhere 1e-13), so the
    /// bound is 1e-9, far below the 1e-4 rad stopping tolerance the test uses.
    #[test]
    fn packed_element_loop_matches_the_scalar_element_code() {
        let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [3, 2, 1]).unwrap();
        assert_ne!(mesh.tets().len() % packed::LANES, 0);
        for (angle, iterations) in [(0.02, 1), (0.02, 3), (1.3, 1), (1.3, 3)] {
            let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
            c.rotation_iterations = iterations;
            // A coarse stopping tolerance, so both codes stop on the same iteration (at the
            // default, rounding near the threshold could stop them one update apart).
            c.rotation_tolerance = 1e-4;
            let mut body = FemBody::new(&mesh, c, &Boundary::fixed_nodes([0])).unwrap();
            let rot = Rotation3::from_euler_angles(angle, -0.5 * angle, 0.7 * angle);
            for (i, x) in body.nodes.x.iter_mut().enumerate() {
                let s = i as f64;
                *x = rot * (*x + 0.03 * Vec3::new(s.sin(), (1.7 * s).cos(), (0.3 * s).sin()));
            }
            // Invert one element by pushing a corner through its opposite face.
            let t0 = body.tets[3];
            let (p0, p1, p2, p3) = (
                body.nodes.x[t0[0] as usize],
                body.nodes.x[t0[1] as usize],
                body.nodes.x[t0[2] as usize],
                body.nodes.x[t0[3] as usize],
            );
            body.nodes.x[t0[0] as usize] = p0 + 1.6 * ((p1 + p2 + p3) / 3.0 - p0);
            let (quats0, rots0) = (body.quats.clone(), body.rots.clone());
            body.rhs.fill(Vec3::zeros());
            let (worst, ..) = body.corotational_forces_and_matrix();
            // Scalar reference.
            let mut expected = vec![Vec3::zeros(); body.node_count()];
            let mut expected_worst = 0;
            for (t, tet) in body.tets.iter().enumerate() {
                let p = tet.map(|i| body.nodes.x[i as usize]);
                let f = element::deformation_gradient(&p, &body.grads[t]);
                let (mut q, mut r) = (quats0[t], rots0[t]);
                let it = rotation::extract_rotation(
                    &f,
                    &mut q,
                    &mut r,
                    iterations,
                    c.rotation_tolerance,
                );
                expected_worst = expected_worst.max(it);
                assert!(
                    (q.coords - body.quats[t].coords).abs().max() < 1e-9,
                    "angle {angle}, element {t}: {q:?} vs {:?}",
                    body.quats[t]
                );

                assert!((r - body.rots[t]).abs().max() < 1e-9);
                let s = r.transpose() * f;
                let eps = (s + s.transpose()) * 0.5 - Matrix3::identity();
                let pm = r * element::stress(&eps, body.lambda, body.mu) * (-body.volumes[t]);
                for a in 0..4 {
                    expected[tet[a] as usize] += pm * body.grads[t][a];
                }
            }
            assert_eq!(worst, expected_worst, "angle {angle}");
            let scale = expected.iter().map(|f| f.norm()).fold(0.0, f64::max);
            assert!(scale > 0.0);
            for (i, (a, b)) in body.rhs.iter().zip(&expected).enumerate() {
                assert!(
                    (a - b).norm() <= 1e-9 * scale,
                    "angle {angle}, node {i}: {a:?} vs {b:?}"
                );
            }
        }
    }
}
