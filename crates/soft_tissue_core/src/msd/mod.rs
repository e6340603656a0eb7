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
use crate::state::{self, NodalBody, Nodes};

mod material;
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

impl NodalBody for MsdBody {
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
        };
        body.estimate_limits();
        if config.integrator.is_implicit() {
            body.build_implicit()?;
        }
        Ok(body)
    }

    /// Bounds the largest frequency at the rest state, or at the current one when `current`
    /// (the volume term stiffens as elements stretch, springs do not under tension).
    fn estimate_limits_at(&mut self, current: bool) {
        // Gershgorin bound on the eigenvalues of M^-1/2 K M^-1/2 (spring blocks have norm <= k
        // at rest and under tension), plus anchors.
        let n = self.nodes.x.len();
        let mut row = std::mem::take(&mut self.limit_row);
        row.clear();
        row.resize(n, 0.0);
        let x = if current {
            &self.nodes.x
        } else {
            &self.nodes.rest
        };
        for s in &self.springs {
            let (a, b) = (s.a as usize, s.b as usize);
            // Tangent stiffness norm: k along the spring, k |1 - L/l| across it (above k
            // only when compressed below half its length).
            let l = (x[b] - x[a]).norm();
            let factor = if current && l > 0.0 {
                (1.0 - s.rest_length / l).abs().max(1.0)
            } else {
                1.0
            };
            let k = s.stiffness * factor;
            let cross = k / (self.nodes.mass[a] * self.nodes.mass[b]).sqrt();
            row[a] += k / self.nodes.mass[a] + cross;
            row[b] += k / self.nodes.mass[b] + cross;
        }
        let kv = self.config.volume_stiffness;
        for (t, v0) in self.tets.iter().zip(&self.rest_volumes) {
            let g = volume_gradient(x, t);
            let norms = g.map(|v| v.norm());
            let sum: f64 = norms.iter().sum();
            // Second-derivative part: |k_v (V - V0) / V0| times the norm of the blocks of the
            // Hessian of V (skew matrices of edge vectors / 6), bounded by the longest edge.
            let p = t.map(|i| x[i as usize]);
            let mut longest: f64 = 0.0;
            for a in 0..4 {
                for b in a + 1..4 {
                    longest = longest.max((p[a] - p[b]).norm());
                }
            }
            let pressure = (kv * (signed_volume(x, t) - v0) / v0).abs();
            for a in 0..4 {
                let i = t[a] as usize;
                row[i] += (kv / v0 * norms[a] * sum + pressure * 3.0 * longest / 6.0)
                    / self.nodes.mass[i];
            }
        }
        let mut w2: f64 = 0.0;
        let mut rate: f64 = 0.0;
        for i in 0..n {
            w2 = w2.max(row[i] + self.nodes.anchor_k[i] / self.nodes.mass[i]);
            rate = rate.max(self.config.damping / self.nodes.mass[i]);
        }
        self.omega_max = w2.sqrt();
        self.damping_rate = rate;
        self.limit_row = row;
    }

    /// At build time: the Gershgorin bound, tightened by the largest eigenvalue of the
    /// mass-scaled spring graph Laplacian `M^-1/2 (sum_s k_s (e_a - e_b)(e_a - e_b)^T) M^-1/2`.
    /// Every spring's tangent block is at most `k I` under tension, so this bounds the
    /// frequencies of every stretched state, not only the rest one. The power method gives it
    /// from below; 80 iterations and a 5 % margin.
    fn estimate_limits(&mut self) {
        self.estimate_limits_at(false);
        if !self.tets.is_empty() {
            return;
        }
        let n = self.nodes.x.len();
        let free: Vec<bool> = self
            .nodes
            .fixed
            .iter()
            .map(|f| !f.iter().all(|&a| a))
            .collect();
        let inv_sqrt_m: Vec<f64> = self.nodes.mass.iter().map(|m| 1.0 / m.sqrt()).collect();
        // Deterministic start with components along every node.
        let mut u: Vec<f64> = (0..n)
            .map(|i| {
                if free[i] {
                    1.0 + ((i * 7919) % 13) as f64 / 13.0
                } else {
                    0.0
                }
            })
            .collect();
        let mut w = vec![0.0; n];
        let mut lambda = 0.0;
        for _ in 0..80 {
            let norm = u.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm == 0.0 {
                return;
            }
            u.iter_mut().for_each(|v| *v /= norm);
            w.fill(0.0);
            for s in &self.springs {
                let (a, b) = (s.a as usize, s.b as usize);
                let d = s.stiffness * (u[a] * inv_sqrt_m[a] - u[b] * inv_sqrt_m[b]);
                w[a] += d * inv_sqrt_m[a];
                w[b] -= d * inv_sqrt_m[b];
            }
            for i in 0..n {
                w[i] = if free[i] {
                    w[i] + self.nodes.anchor_k[i] / self.nodes.mass[i] * u[i]
                } else {
                    0.0
                };
            }
            lambda = u.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            std::mem::swap(&mut u, &mut w);
        }
        let power = (1.05 * lambda).max(0.0).sqrt();
        self.omega_max = self.omega_max.min(power);
    }

    /// Estimated largest stable step of the configured explicit integrator (infinite for the
    /// implicit one). RK4 is stable for `|lambda h| < 2.78` on the negative real axis and
    /// `< 2.83` on the imaginary axis; symplectic Euler for `omega h < 2`. The bound uses
    /// `omega_max + gamma / m_min` with a margin (2.5 and 1.9).
    pub fn stable_dt(&self) -> f64 {
        let rho = self.omega_max + self.damping_rate;
        if rho == 0.0 {
            return f64::INFINITY;
        }
        match self.config.integrator {
            MsdIntegrator::Rk4 => 2.5 / rho,
            MsdIntegrator::SymplecticEuler => 1.9 / rho,
            MsdIntegrator::ImplicitEuler | MsdIntegrator::ImplicitBdf2 => f64::INFINITY,
        }
    }

    fn build_implicit(&mut self) -> Result<(), MsdError> {
        let n = self.nodes.x.len();
        let matrix =
            BlockSparse::from_pairs(n, self.springs.iter().map(|s| [s.a as usize, s.b as usize]));
        let blocks = self
            .springs
            .iter()
            .map(|s| {
                let (a, b) = (s.a as usize, s.b as usize);
                [
                    matrix.diag_index(a),
                    matrix.diag_index(b),
                    matrix.block_index(a, b).expect("pattern"),
                    matrix.block_index(b, a).expect("pattern"),
                ]
                .map(|k| k as u32)
            })
            .collect();
        let tet_blocks = self
            .tets
            .iter()
            .map(|t| {
                let mut s = [0u32; 16];
                for a in 0..4 {
                    for b in 0..4 {
                        s[4 * a + b] = matrix
                            .block_index(t[a] as usize, t[b] as usize)
                            .expect("tetrahedron edges are springs")
                            as u32;
                    }
                }
                s
            })
            .collect();
        let system = ImplicitSystem::new(identity_like(matrix), self.nodes.fixed.clone())?;
        let mut imp = Implicit {
            system,
            blocks,
            tet_blocks,
            rhs: vec![Vec3::zeros(); n],
            dv: vec![Vec3::zeros(); n],
        };
        // Rest-state matrix as the preconditioner.
        self.assemble_implicit(&mut imp, true);
        imp.system.refactor()?;
        self.implicit = Some(imp);
        Ok(())
    }

    /// `M + h gamma I + h^2 (K + Ka)` into the implicit system (at rest positions if `rest`).
    fn assemble_implicit(&self, imp: &mut Implicit, rest: bool) {
        let h = self.config.system_dt();
        let x = if rest {
            &self.nodes.rest
        } else {
            &self.nodes.x
        };
        let m = &mut imp.system.matrix;
        m.set_zero();
        let blocks = m.blocks_mut();
        for (s, idx) in self.springs.iter().zip(&imp.blocks) {
            let k = spring_jacobian(s, &x[s.a as usize], &x[s.b as usize]) * (h * h);
            blocks[idx[0] as usize] += k;
            blocks[idx[1] as usize] += k;
            blocks[idx[2] as usize] -= k;
            blocks[idx[3] as usize] -= k;
        }
        // Volume term, Gauss-Newton part k_v / V0 g g^T (positive semi-definite).
        let kv = self.config.volume_stiffness;
        for ((t, v0), idx) in self
            .tets
            .iter()
            .zip(&self.rest_volumes)
            .zip(&imp.tet_blocks)
        {
            let g = volume_gradient(x, t);
            let c = h * h * kv / v0;
            for a in 0..4 {
                for b in 0..4 {
                    blocks[idx[4 * a + b] as usize] += (g[a] * g[b].transpose()) * c;
                }
            }
        }
        for i in 0..self.nodes.x.len() {
            let d = m.diag_index(i);
            let diag =
                self.nodes.mass[i] + h * self.config.damping + h * h * self.nodes.anchor_k[i];
            m.blocks_mut()[d] += Matrix3::identity() * diag;
        }
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

    /// The rest-state preconditioner for the current system step, refactorized.
    fn refactor_implicit(&mut self) -> Result<(), MsdError> {
        if let Some(mut imp) = self.implicit.take() {
            self.assemble_implicit(&mut imp, true);
            let r = imp.system.refactor();
            self.implicit = Some(imp);
            r?;
        }
        Ok(())
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

    /// Number of substeps the next step will take, or the error if the policy refuses it.
    pub fn substeps_needed(&self) -> Result<u32, MsdError> {
        let limit = self.stable_dt();
        let dt = self.config.dt;
        if dt <= limit {
            return Ok(1);
        }
        let needed = (dt / limit).ceil() as u64;
        let allowed = match self.config.explicit_limit {
            ExplicitLimit::Substep { max_substeps } => max_substeps,
            ExplicitLimit::Refuse => 0,
        };
        if needed > allowed as u64 {
            return Err(MsdError::TimeStepTooLarge {
                integrator: self.config.integrator,
                dt,
                limit,
                needed,
                allowed,
            });
        }
        Ok(needed as u32)
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

    fn rk4(&mut self, h: f64) {
        let n = self.nodes.x.len();
        let mut kx = std::mem::take(&mut self.kx);
        let mut kv = std::mem::take(&mut self.kv);
        let mut xt = std::mem::take(&mut self.xt);
        let mut vt = std::mem::take(&mut self.vt);
        // Stage 1
        kx[0].copy_from_slice(&self.nodes.v);
        self.accelerations(&self.nodes.x, &self.nodes.v, &mut kv[0]);
        // Stages 2-4
        for (s, c) in [(1usize, 0.5 * h), (2, 0.5 * h), (3, h)] {
            for i in 0..n {
                xt[i] = self.nodes.x[i] + c * kx[s - 1][i];
                vt[i] = self.nodes.v[i] + c * kv[s - 1][i];
            }
            kx[s].copy_from_slice(&vt);
            self.accelerations(&xt, &vt, &mut kv[s]);
        }
        for i in 0..n {
            let dx = (kx[0][i] + 2.0 * kx[1][i] + 2.0 * kx[2][i] + kx[3][i]) * (h / 6.0);
            let dv = (kv[0][i] + 2.0 * kv[1][i] + 2.0 * kv[2][i] + kv[3][i]) * (h / 6.0);
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.x[i][a] += dx[a];
                    self.nodes.v[i][a] += dv[a];
                }
            }
        }
        self.kx = kx;
        self.kv = kv;
        self.xt = xt;
        self.vt = vt;
    }

    fn symplectic(&mut self, h: f64) {
        let mut acc = std::mem::take(&mut self.xt);
        self.accelerations(&self.nodes.x, &self.nodes.v, &mut acc);
        for i in 0..self.nodes.x.len() {
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.v[i][a] += h * acc[i][a];
                    self.nodes.x[i][a] += h * self.nodes.v[i][a];
                }
            }
        }
        self.xt = acc;
    }

    /// BDF2: moves the state to the extrapolated start of the step, starting the history
    /// first when there is none (see [`MsdBody::step`]).
    fn extrapolate(&mut self) {
        if self.bdf2.needs_start(self.nodes.x.len()) {
            let mut acc = self.bdf2.take_buffer();
            self.accelerations(&self.nodes.x, &self.nodes.v, &mut acc);
            self.bdf2.start(&self.nodes, acc, self.config.dt);
        }
        self.bdf2.extrapolate(&mut self.nodes);
    }

    fn implicit_step(&mut self) -> Result<CgStats, MsdError> {
        let mut imp = self.implicit.take().expect("built with the integrator");
        let h = self.config.system_dt();
        self.assemble_implicit(&mut imp, false);
        // rhs = h (f(x, v) - h (K + Ka) v), with f including damping; (K + Ka) v from the
        // assembled matrix: A v = (m + h gamma) v + h^2 (K + Ka) v.
        let mut av = std::mem::take(&mut self.xt);
        imp.system.matrix.mul(&self.nodes.v, &mut av);
        let g = self.config.gravity;
        let gamma = self.config.damping;
        for i in 0..self.nodes.x.len() {
            imp.rhs[i] = self.nodes.f_ext[i] + self.nodes.mass[i] * g
                - gamma * self.nodes.v[i]
                - self.nodes.anchor_k[i] * (self.nodes.x[i] - self.nodes.anchor_target[i]);
        }
        self.add_internal_forces(&self.nodes.x, &mut imp.rhs);
        for i in 0..self.nodes.x.len() {
            let kv = (av[i] - (self.nodes.mass[i] + h * gamma) * self.nodes.v[i]) / (h * h);
            imp.rhs[i] = h * (imp.rhs[i] - h * kv);
        }
        self.xt = av;
        let stats = imp.system.solve_cg(
            &imp.rhs,
            &mut imp.dv,
            self.config.cg_tolerance,
            self.config.cg_max_iterations,
        );
        let stats = match stats {
            Ok(c) if self.config.cg_must_converge => c
                .require_converged(self.config.cg_tolerance)
                .map_err(MsdError::from),
            other => other.map_err(MsdError::from),
        };
        if stats.is_ok() {
            for i in 0..self.nodes.x.len() {
                for a in 0..3 {
                    if self.nodes.fixed[i][a] {
                        self.nodes.v[i][a] = 0.0;
                    } else {
                        self.nodes.v[i][a] += imp.dv[i][a];
                        self.nodes.x[i][a] += h * self.nodes.v[i][a];
                    }
                }
            }
        }
        self.implicit = Some(imp);
        stats
    }
}

fn identity_like(mut m: BlockSparse) -> BlockSparse {
    for i in 0..m.nodes() {
        let d = m.diag_index(i);
        m.blocks_mut()[d] = Matrix3::identity();
    }
    m
}

/// Spring Jacobian block `k (u u^T + max(0, 1 - L/l) (I - u u^T))` (positive semi-definite).
fn spring_jacobian(s: &Spring, xa: &Vec3, xb: &Vec3) -> Matrix3<f64> {
    let d = xb - xa;
    let l = d.norm();
    if l == 0.0 || l.is_nan() {
        return Matrix3::identity() * s.stiffness;
    }
    let u = d / l;
    let uu = u * u.transpose();
    let t = (1.0 - s.rest_length / l).max(0.0);
    (uu + (Matrix3::identity() - uu) * t) * s.stiffness
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
