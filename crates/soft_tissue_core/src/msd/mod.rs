//! Mass-spring-damper bodies (paper section III-C, eq. 6-7).
//!
//! Node `i` obeys `m_i a_i = -gamma v_i + sum_j g_ij + f_i` with Hooke springs
//! `g_ij = k (|x_j - x_i| - L_ij) (x_j - x_i) / |x_j - x_i|` (plus gravity and soft anchors).
//! Springs come from the tetrahedron edges, optionally with bending springs joining the two
//! opposite nodes of face-adjacent tetrahedra (they resist shear and volume loss).
//!
//! Integrators: classical RK4 (the paper), symplectic Euler, and linearised implicit Euler
//! (`(M + h gamma + h^2 K) dv = h (f - h K v)`, `K` the spring Jacobian with its compressive
//! transverse part clamped so it stays positive semi-definite), solved by CG preconditioned with
//! the rest-state Cholesky factorization. Explicit integrators have a stability limit, bounded
//! from the stiffness and masses when the body is built; a step longer than the limit is split
//! into equal substeps, or refused with [`MsdError::TimeStepTooLarge`], as configured. Nothing
//! allocates in a step; a step that would produce NaN is rolled back and reported.

// Index loops over parallel per-node arrays read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::boundary::{Boundary, BoundaryError};
use crate::linalg::{BlockSparse, CgStats, ImplicitSystem, LinalgError, NotConverged};
use crate::material::MsdParams;
use crate::mesh::TetMesh;
use crate::state::{self, NodalModel, Nodes};

mod contact;
mod explicit;
mod implicit;
mod material;
mod teleport;

pub use material::{SpringStiffness, fit_tet_springs, material_stiffnesses};

/// Time integrator of an MSD body.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum MsdIntegrator {
    /// Classical fourth-order Runge-Kutta (the paper). Explicit: has a stability limit.
    #[default]
    Rk4,
    /// Symplectic (semi-implicit) Euler: velocity first, then position. Explicit.
    SymplecticEuler,
    /// Linearised backward Euler with a sparse solve: stable for stiff springs and long steps.
    ImplicitEuler,
    /// Second-order backward differentiation (BDF2, constant step): the implicit Euler
    /// system with `2 dt / 3` solved from the state extrapolated from the last two, `x_n +
    /// (x_n - x_{n-1}) / 3`, `v_n + (v_n - v_{n-1}) / 3` (as `FemIntegrator::Bdf2`; see
    /// [`MsdBody::step`]). Stable like implicit Euler, far less numerical damping.
    ImplicitBdf2,
}

impl MsdIntegrator {
    /// Whether the integrator solves a linear system (implicit Euler, BDF2).
    pub fn is_implicit(self) -> bool {
        matches!(
            self,
            MsdIntegrator::ImplicitEuler | MsdIntegrator::ImplicitBdf2
        )
    }
}

/// Which springs a mesh gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum SpringSet {
    /// One spring per tetrahedron edge (the paper).
    #[default]
    Edges,
    /// Edges plus a spring between the opposite nodes of every pair of face-adjacent
    /// tetrahedra.
    EdgesAndBending,
}

/// What an explicit integrator does with a step longer than its stability limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ExplicitLimit {
    /// Split the step into equal substeps below the limit, at most this many.
    Substep {
        /// Largest number of substeps per step before refusing.
        max_substeps: u32,
    },
    /// Refuse the step with an error.
    Refuse,
}

impl Default for ExplicitLimit {
    fn default() -> Self {
        ExplicitLimit::Substep { max_substeps: 64 }
    }
}

/// Settings of an MSD body.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MsdConfig {
    /// Integrator. Default RK4.
    pub integrator: MsdIntegrator,
    /// Stiffness of every mesh spring, force / length (mesh constructor only).
    pub stiffness: f64,
    /// Total mass, lumped onto nodes by volume share (mesh constructor only).
    pub mass: f64,
    /// Per-node damping `gamma`, force * time / length.
    pub damping: f64,
    /// Springs made from a mesh. Default: edges.
    pub springs: SpringSet,
    /// Where the springs' stiffnesses come from (mesh constructor only): `stiffness` for
    /// every spring (the paper, the default), or fitted to a material's linear FEM stiffness.
    #[serde(default)]
    pub spring_stiffness: SpringStiffness,
    /// Volume stiffness `k_v` (force / length^2) of the optional per-tetrahedron volume term
    /// `E = k_v (V - V0)^2 / (2 V0)` on the signed volume (Teschner et al. 2004), mesh
    /// constructor only. Edge springs cannot tell a tetrahedron from its mirror image, so a
    /// body folded through itself stays folded; this term pushes inverted elements back.
    /// Default 0 (the paper's MSD).
    pub volume_stiffness: f64,
    /// Time step, time.
    pub dt: f64,
    /// Gravity, length / time^2. Default zero.
    pub gravity: Vec3,
    /// Policy above the explicit stability limit. Default: up to 64 substeps.
    pub explicit_limit: ExplicitLimit,
    /// Relative residual at which the implicit CG stops. Default 1e-6.
    pub cg_tolerance: f64,
    /// Iteration cap of the implicit CG. Default 50.
    pub cg_max_iterations: u32,
    /// What an implicit CG that reaches its cap above its tolerance does: `false` (the
    /// default) the step goes on with the last iterate and says so (its stats'
    /// `cg.converged` is false); `true` the step fails with [`MsdError::NotConverged`] and
    /// leaves the state unchanged.
    #[serde(default)]
    pub cg_must_converge: bool,
}

impl MsdConfig {
    /// The step length of the implicit Euler system the implicit integrators solve: `dt`, or
    /// `2 dt / 3` for BDF2.
    pub fn system_dt(&self) -> f64 {
        match self.integrator {
            MsdIntegrator::ImplicitBdf2 => 2.0 * self.dt / 3.0,
            _ => self.dt,
        }
    }

    /// RK4 with the paper's parameters and time step.
    pub fn paper(params: &MsdParams, dt: f64) -> Self {
        MsdConfig {
            integrator: MsdIntegrator::Rk4,
            stiffness: params.stiffness,
            mass: params.mass,
            damping: params.damping,
            springs: SpringSet::Edges,
            spring_stiffness: SpringStiffness::Constant,
            volume_stiffness: 0.0,
            dt,
            gravity: Vec3::zeros(),
            explicit_limit: ExplicitLimit::default(),
            cg_tolerance: 1e-6,
            cg_max_iterations: 50,
            cg_must_converge: false,
        }
    }

    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), MsdError> {
        let bad =
            |field: &'static str, message: String| Err(MsdError::InvalidConfig { field, message });
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !(self.stiffness.is_finite() && self.stiffness >= 0.0) {
            return bad(
                "stiffness",
                format!("must be >= 0, found {}", self.stiffness),
            );
        }
        if !pos(self.mass) {
            return bad("mass", format!("must be positive, found {}", self.mass));
        }
        if let Err((field, message)) = self.spring_stiffness.validate() {
            return bad(field, message);
        }
        if !(self.volume_stiffness.is_finite() && self.volume_stiffness >= 0.0) {
            return bad(
                "volume_stiffness",
                format!("must be >= 0, found {}", self.volume_stiffness),
            );
        }
        if !(self.damping.is_finite() && self.damping >= 0.0) {
            return bad("damping", format!("must be >= 0, found {}", self.damping));
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
        if let ExplicitLimit::Substep { max_substeps: 0 } = self.explicit_limit {
            return bad("explicit_limit", "max_substeps must be at least 1".into());
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
        Ok(())
    }
}

/// A spring between two nodes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spring {
    /// First node.
    pub a: u32,
    /// Second node.
    pub b: u32,
    /// Stiffness, force / length.
    pub stiffness: f64,
    /// Rest length.
    pub rest_length: f64,
}

/// An MSD failure, naming what and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MsdError {
    /// A configuration field is out of range.
    #[error("MSD config field `{field}` {message}")]
    InvalidConfig {
        /// The field.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A spring is malformed.
    #[error("spring {spring}: {message}")]
    BadSpring {
        /// Index of the spring.
        spring: usize,
        /// What is wrong.
        message: String,
    },
    /// A node is malformed (mass not positive, position not finite).
    #[error("node {node}: {message}")]
    BadNode {
        /// The node.
        node: usize,
        /// What is wrong.
        message: String,
    },
    /// The boundary conditions do not fit.
    #[error(transparent)]
    Boundary(#[from] BoundaryError),
    /// The step of an explicit integrator is above its stability limit and the policy refuses
    /// it (or would need more substeps than allowed).
    #[error(
        "time step {dt} exceeds the {integrator:?} stability limit {limit:.3e} (would need {needed} substeps, {allowed} allowed); use a smaller dt, more substeps or the implicit integrator"
    )]
    TimeStepTooLarge {
        /// Integrator.
        integrator: MsdIntegrator,
        /// Requested step.
        dt: f64,
        /// Estimated limit.
        limit: f64,
        /// Substeps that would be needed.
        needed: u64,
        /// Substeps allowed by the policy (0 when refusing).
        allowed: u32,
    },
    /// A linear solve failed (implicit integrator).
    #[error("MSD linear solve failed: {0}")]
    Linalg(#[from] LinalgError),
    /// The step's CG reached its cap above its tolerance while
    /// [`MsdConfig::cg_must_converge`] asks for convergence (the state is unchanged).
    #[error(transparent)]
    NotConverged(#[from] NotConverged),
    /// A value given, or produced by a step, is NaN or infinite; a step that produces one is
    /// rolled back.
    #[error("{what} of node {node} is not finite")]
    NonFinite {
        /// `"external force"`, `"position"`, `"velocity"`.
        what: &'static str,
        /// The node.
        node: usize,
    },
}

/// What the last step did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MsdStepStats {
    /// Substeps taken (1 when none were needed).
    pub substeps: u32,
    /// Implicit integrator: the CG solve.
    pub cg: CgStats,
}

/// A mass-spring-damper body.
#[derive(Debug)]
pub struct MsdBody {
    config: MsdConfig,
    nodes: Nodes,
    springs: Vec<Spring>,
    /// Tetrahedra and rest volumes of the volume term (empty without it).
    tets: Vec<[u32; 4]>,
    rest_volumes: Vec<f64>,
    /// Bound on the largest angular frequency (rad / time) and damping rate (1 / time).
    omega_max: f64,
    damping_rate: f64,
    // Workspaces.
    kx: [Vec<Vec3>; 4],
    kv: [Vec<Vec3>; 4],
    xt: Vec<Vec3>,
    vt: Vec<Vec3>,
    backup_x: Vec<Vec3>,
    backup_v: Vec<Vec3>,
    implicit: Option<Implicit>,
    limit_row: Vec<f64>,
    stats: MsdStepStats,
    /// BDF2 history (see [`crate::state::Bdf2History`]).
    bdf2: crate::state::Bdf2History,
    /// Contact compliance columns and correction workspaces.
    contact: contact::MsdContact,
}

#[derive(Debug)]
struct Implicit {
    system: ImplicitSystem,
    /// Per spring: block indices (aa, bb, ab, ba).
    blocks: Vec<[u32; 4]>,
    /// Per tetrahedron of the volume term: block indices (a, b), row-major.
    tet_blocks: Vec<[u32; 16]>,
    rhs: Vec<Vec3>,
    dv: Vec<Vec3>,
}

impl NodalModel for MsdBody {
    fn nodes(&self) -> &Nodes {
        &self.nodes
    }

    fn nodes_mut(&mut self) -> &mut Nodes {
        &mut self.nodes
    }
}

impl MsdBody {
    /// An MSD on the nodes and edges of a tetrahedral mesh, at rest in the mesh's shape.
    pub fn from_mesh(
        mesh: &TetMesh,
        config: MsdConfig,
        boundary: &Boundary,
    ) -> Result<Self, MsdError> {
        config.validate()?;
        let positions = mesh.positions().to_vec();
        let n = positions.len();
        let mut share = vec![0.0; n];
        for (tet, vol) in mesh.tets().iter().zip(mesh.tet_volumes()) {
            for &i in tet {
                share[i as usize] += vol.abs() / 4.0;
            }
        }
        let total: f64 = share.iter().sum();
        let min_share = share
            .iter()
            .copied()
            .filter(|&s| s > 0.0)
            .fold(f64::INFINITY, f64::min);
        let masses: Vec<f64> = share
            .iter()
            .map(|&s| config.mass * if s > 0.0 { s } else { min_share } / total)
            .collect();
        let mut pairs: Vec<[u32; 2]> = mesh.edges().to_vec();
        if config.springs == SpringSet::EdgesAndBending {
            let edges: std::collections::HashSet<[u32; 2]> = pairs.iter().copied().collect();
            let tets = mesh.tets();
            let mut extra = std::collections::BTreeSet::new();
            for (t, nb) in mesh.tet_neighbors().iter().enumerate() {
                for &u in nb {
                    let u = u as usize;
                    if u >= tets.len() || u < t {
                        continue;
                    }
                    let a = tets[t].iter().find(|i| !tets[u].contains(i));
                    let b = tets[u].iter().find(|i| !tets[t].contains(i));
                    if let (Some(&a), Some(&b)) = (a, b) {
                        let key = [a.min(b), a.max(b)];
                        if !edges.contains(&key) {
                            extra.insert(key);
                        }
                    }
                }
            }
            pairs.extend(extra);
        }
        let fitted = match config.spring_stiffness {
            SpringStiffness::Constant => vec![None; pairs.len()],
            SpringStiffness::Material {
                young_modulus,
                poisson_ratio,
            } => material_stiffnesses(
                &positions,
                mesh.tets(),
                &pairs,
                young_modulus,
                poisson_ratio,
            ),
        };
        let springs = pairs
            .iter()
            .zip(fitted)
            .map(|(&[a, b], k)| Spring {
                a,
                b,
                stiffness: k.unwrap_or(config.stiffness),
                rest_length: (positions[b as usize] - positions[a as usize]).norm(),
            })
            .collect();
        let (tets, rest_volumes) = if config.volume_stiffness > 0.0 {
            let tets: Vec<[u32; 4]> = mesh.tets().to_vec();
            let vols = tets
                .iter()
                .map(|t| signed_volume(&positions, t).abs())
                .collect();
            (tets, vols)
        } else {
            (Vec::new(), Vec::new())
        };
        MsdBody::build(
            positions,
            masses,
            springs,
            (tets, rest_volumes),
            config,
            boundary,
        )
    }

    /// An MSD from explicit nodes (positions are the initial state), masses and springs.
    /// `config.stiffness` and `config.mass` are not used.
    pub fn new(
        positions: Vec<Vec3>,
        masses: Vec<f64>,
        springs: Vec<Spring>,
        config: MsdConfig,
        boundary: &Boundary,
    ) -> Result<Self, MsdError> {
        MsdBody::build(
            positions,
            masses,
            springs,
            (Vec::new(), Vec::new()),
            config,
            boundary,
        )
    }

    /// Validates and builds, with the tetrahedra and rest volumes of the volume term (empty
    /// without it).
    fn build(
        positions: Vec<Vec3>,
        masses: Vec<f64>,
        springs: Vec<Spring>,
        (tets, rest_volumes): (Vec<[u32; 4]>, Vec<f64>),
        config: MsdConfig,
        boundary: &Boundary,
    ) -> Result<Self, MsdError> {
        config.validate()?;
        let n = positions.len();
        if masses.len() != n {
            return Err(MsdError::InvalidConfig {
                field: "masses",
                message: format!("has {} entries for {n} nodes", masses.len()),
            });
        }
        for (i, (p, &m)) in positions.iter().zip(&masses).enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(MsdError::BadNode {
                    node: i,
                    message: format!("position {p:?} is not finite"),
                });
            }
            if !(m.is_finite() && m > 0.0) {
                return Err(MsdError::BadNode {
                    node: i,
                    message: format!("mass {m} must be positive"),
                });
            }
        }
        for (s, sp) in springs.iter().enumerate() {
            let msg = if sp.a as usize >= n || sp.b as usize >= n {
                Some(format!(
                    "joins nodes {} and {}, but there are {n} nodes",
                    sp.a, sp.b
                ))
            } else if sp.a == sp.b {
                Some(format!("joins node {} to itself", sp.a))
            } else if !(sp.stiffness.is_finite() && sp.stiffness >= 0.0) {
                Some(format!("stiffness {} must be >= 0", sp.stiffness))
            } else if !(sp.rest_length.is_finite() && sp.rest_length >= 0.0) {
                Some(format!("rest length {} must be >= 0", sp.rest_length))
            } else {
                None
            };
            if let Some(message) = msg {
                return Err(MsdError::BadSpring { spring: s, message });
            }
        }
        let (fixed, anchor_k) = boundary.resolve(n)?;
        let zeros = vec![Vec3::zeros(); n];
        let mut body = MsdBody {
            config,
            nodes: Nodes::new(positions, masses, fixed, anchor_k),
            springs,
            tets,
            rest_volumes,
            omega_max: 0.0,
            damping_rate: 0.0,
            kx: [zeros.clone(), zeros.clone(), zeros.clone(), zeros.clone()],
            kv: [zeros.clone(), zeros.clone(), zeros.clone(), zeros.clone()],
            xt: zeros.clone(),
            vt: zeros.clone(),
            backup_x: zeros.clone(),
            backup_v: zeros,
            implicit: None,
            limit_row: Vec::with_capacity(n),
            stats: MsdStepStats::default(),
            bdf2: Default::default(),
            contact: Default::default(),
        };
        body.estimate_limits();
        if config.integrator.is_implicit() {
            body.build_implicit()?;
        }
        Ok(body)
    }

    /// The settings.
    pub fn config(&self) -> &MsdConfig {
        &self.config
    }

    /// Changes the integrator at run time (builds the implicit system on first use).
    /// Between implicit Euler and BDF2 the preconditioner is refactorized (they solve with
    /// `dt` and `2 dt / 3`); BDF2 starts a new history.
    pub fn set_integrator(&mut self, integrator: MsdIntegrator) -> Result<(), MsdError> {
        let old = self.config.integrator;
        if integrator == old {
            return Ok(());
        }
        self.config.integrator = integrator;
        self.bdf2.valid = false;
        let result = if !integrator.is_implicit() {
            Ok(())
        } else if self.implicit.is_none() {
            self.build_implicit()
        } else {
            self.refactor_implicit()
        };
        if result.is_err() {
            self.config.integrator = old;
            if old.is_implicit() && self.implicit.is_some() {
                self.refactor_implicit()?;
            }
        }
        result
    }

    /// Forgets the BDF2 history: the next step starts it again from the current state. Call
    /// after replacing the state with one that does not continue the last step.
    pub fn restart_history(&mut self) {
        self.bdf2.valid = false;
    }

    /// Changes the time step (refactorizes the implicit preconditioner if built).
    pub fn set_dt(&mut self, dt: f64) -> Result<(), MsdError> {
        let mut c = self.config;
        c.dt = dt;
        c.validate()?;
        self.config = c;
        self.bdf2.valid = false;
        self.refactor_implicit()
    }

    /// Changes the explicit-limit policy.
    pub fn set_explicit_limit(&mut self, policy: ExplicitLimit) -> Result<(), MsdError> {
        let mut c = self.config;
        c.explicit_limit = policy;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// Changes the implicit CG tolerance and iteration cap.
    pub fn set_cg(&mut self, tolerance: f64, max_iterations: u32) -> Result<(), MsdError> {
        let mut c = self.config;
        c.cg_tolerance = tolerance;
        c.cg_max_iterations = max_iterations;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// Sets [`MsdConfig::cg_must_converge`].
    pub fn set_cg_must_converge(&mut self, on: bool) {
        self.config.cg_must_converge = on;
    }

    /// Changes gravity.
    pub fn set_gravity(&mut self, gravity: Vec3) -> Result<(), MsdError> {
        let mut c = self.config;
        c.gravity = gravity;
        c.validate()?;
        self.config = c;
        Ok(())
    }

    /// The springs.
    pub fn springs(&self) -> &[Spring] {
        &self.springs
    }

    /// What the last step did.
    pub fn last_step(&self) -> MsdStepStats {
        self.stats
    }

    /// Energy stored in the springs and anchors.
    pub fn elastic_energy(&self) -> f64 {
        spring_energy(&self.springs, &self.nodes.x)
            + self
                .tets
                .iter()
                .zip(&self.rest_volumes)
                .map(|(t, v0)| {
                    let dv = signed_volume(&self.nodes.x, t) - v0;
                    0.5 * self.config.volume_stiffness * dv * dv / v0
                })
                .sum::<f64>()
            + self.nodes.anchor_energy()
    }

    /// Spring, volume-term and anchor forces at positions `x` (no damping, gravity or
    /// external force), written to `out`. For checks.
    pub fn spring_forces(&self, x: &[Vec3], out: &mut [Vec3]) {
        out.fill(Vec3::zeros());
        self.add_internal_forces(x, out);
        for i in 0..x.len() {
            out[i] -= self.nodes.anchor_k[i] * (x[i] - self.nodes.anchor_target[i]);
        }
    }

    /// The exact Jacobian `-d f / d x` of the spring and anchor forces (not the volume term) at `x`, as a dense
    /// `3n x 3n` matrix in row-major order. For checks on small bodies.
    pub fn stiffness_dense(&self, x: &[Vec3]) -> Vec<f64> {
        let n = x.len();
        let mut k = vec![0.0; 9 * n * n];
        let mut add = |i: usize, j: usize, m: &Matrix3<f64>, s: f64| {
            for r in 0..3 {
                for c in 0..3 {
                    k[(3 * i + r) * 3 * n + 3 * j + c] += s * m[(r, c)];
                }
            }
        };
        for sp in &self.springs {
            let (a, b) = (sp.a as usize, sp.b as usize);
            let d = x[b] - x[a];
            let l = d.norm();
            if l == 0.0 {
                continue;
            }
            let u = d / l;
            let uu = u * u.transpose();
            let m = (uu + (Matrix3::identity() - uu) * (1.0 - sp.rest_length / l)) * sp.stiffness;
            add(a, a, &m, 1.0);
            add(b, b, &m, 1.0);
            add(a, b, &m, -1.0);
            add(b, a, &m, -1.0);
        }
        for i in 0..n {
            add(i, i, &(Matrix3::identity() * self.nodes.anchor_k[i]), 1.0);
        }
        k
    }

    /// Makes the current shape the rest shape: rest positions, anchor targets and spring
    /// rest lengths are taken from the current positions (velocities are kept). Used when a
    /// body settles in a deformed equilibrium and should stay there.
    pub fn rebase_rest(&mut self) {
        self.nodes.rest.copy_from_slice(&self.nodes.x);
        self.nodes.anchor_target.copy_from_slice(&self.nodes.x);
        for s in &mut self.springs {
            s.rest_length = (self.nodes.x[s.b as usize] - self.nodes.x[s.a as usize]).norm();
        }
        if !self.tets.is_empty() {
            for (t, v0) in self.tets.iter().zip(self.rest_volumes.iter_mut()) {
                *v0 = signed_volume(&self.nodes.x, t);
            }
        }
        self.estimate_limits();
    }

    /// Puts the body back at rest in its rest shape.
    pub fn reset(&mut self) {
        self.nodes.reset();
        self.bdf2.valid = false;
        if let Some(imp) = &mut self.implicit {
            imp.dv.fill(Vec3::zeros());
        }
    }

    /// Adds spring and volume-term forces at `x` to `out`.
    fn add_internal_forces(&self, x: &[Vec3], out: &mut [Vec3]) {
        add_spring_forces(&self.springs, x, out);
        let kv = self.config.volume_stiffness;
        for (t, v0) in self.tets.iter().zip(&self.rest_volumes) {
            let g = volume_gradient(x, t);
            let p = -kv * (signed_volume(x, t) - v0) / v0;
            for a in 0..4 {
                out[t[a] as usize] += p * g[a];
            }
        }
    }

    /// `out = a(x, v)`: accelerations, zero on fixed components.
    fn accelerations(&self, x: &[Vec3], v: &[Vec3], out: &mut [Vec3]) {
        let g = self.config.gravity;
        let gamma = self.config.damping;
        for i in 0..x.len() {
            out[i] = self.nodes.f_ext[i] + self.nodes.mass[i] * g
                - gamma * v[i]
                - self.nodes.anchor_k[i] * (x[i] - self.nodes.anchor_target[i]);
        }
        self.add_internal_forces(x, out);
        for i in 0..x.len() {
            out[i] /= self.nodes.mass[i];
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    out[i][a] = 0.0;
                }
            }
        }
    }

    fn check_inputs(&self) -> Result<(), MsdError> {
        match self.nodes.first_non_finite_input() {
            Some((what, node)) => Err(MsdError::NonFinite { what, node }),
            None => Ok(()),
        }
    }

    /// Advances by one time step `config().dt`. On error the state is unchanged.
    ///
    /// BDF2 ([`MsdIntegrator::ImplicitBdf2`]) keeps the last step's differences `x_n -
    /// x_{n-1}`, `v_n - v_{n-1}`; changes made between steps (contact corrections,
    /// kinematic moves) shift the whole history with them, so they are not extrapolated.
    /// The first step, and the first after a reset, a change of integrator or step or
    /// [`MsdBody::restart_history`], takes `x_n - x_{n-1} = dt v_n`, `v_n - v_{n-1} = dt
    /// a_n` (`a_n` the current acceleration under the step's forces; errors of order
    /// `dt^2`, so the method stays second order).
    pub fn step(&mut self) -> Result<MsdStepStats, MsdError> {
        self.check_inputs()?;
        let explicit = !self.config.integrator.is_implicit();
        if explicit && !self.tets.is_empty() {
            self.estimate_limits_at(true);
        }
        let mut substeps = self.substeps_needed()?;
        self.backup_x.copy_from_slice(&self.nodes.x);
        self.backup_v.copy_from_slice(&self.nodes.v);
        let max_substeps = match self.config.explicit_limit {
            ExplicitLimit::Substep { max_substeps } => max_substeps,
            ExplicitLimit::Refuse => substeps,
        };
        loop {
            let h = self.config.dt / substeps as f64;
            let mut stats = MsdStepStats {
                substeps,
                cg: CgStats::default(),
            };
            let result = match self.config.integrator {
                MsdIntegrator::Rk4 => {
                    for _ in 0..substeps {
                        self.rk4(h);
                    }
                    Ok(())
                }
                MsdIntegrator::SymplecticEuler => {
                    for _ in 0..substeps {
                        self.symplectic(h);
                    }
                    Ok(())
                }
                MsdIntegrator::ImplicitEuler => self.implicit_step().map(|cg| stats.cg = cg),
                MsdIntegrator::ImplicitBdf2 => {
                    self.extrapolate();
                    self.implicit_step().map(|cg| stats.cg = cg)
                }
            };
            let bad = state::first_non_finite_state(&self.nodes.x, &self.nodes.v);
            if result.is_ok() && bad.is_none() {
                if self.config.integrator == MsdIntegrator::ImplicitBdf2 {
                    self.bdf2
                        .record(&self.nodes, &self.backup_x, &self.backup_v);
                }
                self.nodes.f_ext.fill(Vec3::zeros());
                self.stats = stats;
                return Ok(stats);
            }
            self.nodes.x.copy_from_slice(&self.backup_x);
            self.nodes.v.copy_from_slice(&self.backup_v);
            result?;
            // An explicit step blew up (a load far outside the linear range made the body
            // locally stiffer than its estimate): retry with twice the substeps while the
            // policy allows, then report.
            if explicit && substeps < max_substeps {
                substeps = (2 * substeps).min(max_substeps);
                continue;
            }
            let (what, node) = bad.expect("checked");
            return Err(MsdError::NonFinite { what, node });
        }
    }
}

fn add_spring_forces(springs: &[Spring], x: &[Vec3], out: &mut [Vec3]) {
    for s in springs {
        let (a, b) = (s.a as usize, s.b as usize);
        let d = x[b] - x[a];
        let l = d.norm();
        if l == 0.0 || l.is_nan() {
            // Coincident nodes: the direction is undefined; no force rather than NaN.
            continue;
        }
        let f = d * (s.stiffness * (l - s.rest_length) / l);
        out[a] += f;
        out[b] -= f;
    }
}

fn spring_energy(springs: &[Spring], x: &[Vec3]) -> f64 {
    springs
        .iter()
        .map(|s| {
            let l = (x[s.b as usize] - x[s.a as usize]).norm();
            0.5 * s.stiffness * (l - s.rest_length).powi(2)
        })
        .sum()
}

/// Signed volume of tetrahedron `t` at positions `x`.
fn signed_volume(x: &[Vec3], t: &[u32; 4]) -> f64 {
    let [a, b, c, d] = t.map(|i| x[i as usize]);
    (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
}

/// Gradient of the signed volume with respect to each node.
fn volume_gradient(x: &[Vec3], t: &[u32; 4]) -> [Vec3; 4] {
    let [a, b, c, d] = t.map(|i| x[i as usize]);
    let (e1, e2, e3) = (b - a, c - a, d - a);
    let g1 = e2.cross(&e3) / 6.0;
    let g2 = e3.cross(&e1) / 6.0;
    let g3 = e1.cross(&e2) / 6.0;
    [-(g1 + g2 + g3), g1, g2, g3]
}
