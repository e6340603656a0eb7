//! Levels of precision for one body: the cheap cage level and the body's precise method,
//! the state transfer between them without a visible jump, and the policy that decides when
//! a body may drop back to its cage (paper section III, Fig. 2).
//!
//! A [`LeveledBody`] always has its cage (a [`CageBody`] embedding every mesh node) and the
//! solver of its chosen precise method, built once (a body whose method is MSD has no FEM
//! state). It starts at [`Level::Cage`].
//!
//! - **Up** ([`LeveledBody::raise`], called by contact before the contact is resolved): node
//!   positions are the cage's exact (`f64`) Green-coordinate evaluation, node velocities its
//!   derivative along the cage vertex velocities (the map is linear in the vertices and face
//!   terms: one evaluation with the face terms' rate). A FEM body's element rotations start
//!   from the ones it held at its last down-switch, turned by how far the cage turned since
//!   (its best rigid fit), and are brought to the new state eight elements at a time.
//! - **Down** ([`LeveledBody::lower`], or automatically at the start of a step, which is then
//!   a cage step): the cage is
//!   fitted so its coordinates reproduce the current surface in the least-squares sense
//!   ([`crate::cage::fit`]: face terms refreshed by an Anderson-accelerated fixed point whose
//!   iterations cost `O(cage vertices x cage faces)`, warm-started from the last fit), cage
//!   velocities the same way. The fit that decides the switch is the one the switch uses. The
//!   cage keeps its rest shape, the body's settled equilibrium ([`LeveledBody::settle`]), so
//!   what motion is left dies out toward it.
//! - Every switch records the largest surface-vertex jump ([`SwitchRecord`]).
//! - Automatic down-switch ([`PrecisionPolicy`]): no contact, largest nodal speed and the cage
//!   fit residual (the distance from a cage-reproducible shape) below thresholds for
//!   `rest_steps` consecutive steps, and at least `min_precise_steps` steps at the precise
//!   level (hysteresis: a body never flickers). The speed is the one the last step left, after
//!   its contact response: bodies resting against each other are at rest there. The fit is computed once the body has been
//!   slow for `rest_steps` steps, not every step.
//!
//! - Error of the cage level: the fit residual at every down-switch ([`SwitchRecord`]) and,
//!   on request ([`LeveledBody::set_shadow`]), a shadow precise simulation that runs beside
//!   the cage level under the same loads so the distance between the two surfaces can be
//!   read every step ([`ShadowError`]). It costs a precise step per step: a validation tool.
//!
//! Steps do not allocate; a switch (a rare event) may.

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::boundary::{Boundary, BoundaryError};
use crate::cage::reduced::{ModelKey, PreciseOperators, cached_model};
use crate::cage::{
    CageBody, CageBodyConfig, CageDynamics, CageError, FitOptions, FitReport, ReducedModel,
    SurfaceFit, box_cage, fitted_cage,
};
use crate::fem::{FemBody, FemConfig, FemError, FemIntegrator, FemModel};
use crate::linalg::CgStats;
use crate::material::{FemParams, MsdParams, PAPER_CAGE_MSD};
use crate::mesh::TetMesh;
use crate::msd::{MsdBody, MsdConfig, MsdError, MsdIntegrator, SpringStiffness};
use crate::scenario::CageKind;
use crate::state::NodalBody;

mod undo;
pub use undo::LevelSnapshot;

/// The level a body runs at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum Level {
    /// Green coordinates of an MSD-driven cage (where every body starts).
    #[default]
    Cage,
    /// The body's precise method.
    Precise,
}

/// The precise method of a body: one type for the core, scene files, the plugin and the
/// command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum PreciseMethod {
    /// Linear tetrahedral FEM, implicit (the paper).
    LinearFem,
    /// Corotational tetrahedral FEM, implicit: right under large rotations (the default).
    #[default]
    CorotationalFem,
    /// Corotational FEM with a constant prefactored system: a fixed, low cost per step on
    /// large meshes, numerically damped in stiff, slow motion (see
    /// [`FemModel::CorotationalPrefactored`]).
    PrefactoredFem,
    /// Mass-spring-damper, classical Runge-Kutta (the paper).
    MsdRk4,
    /// Mass-spring-damper, symplectic Euler.
    MsdSymplectic,
    /// Mass-spring-damper, linearised implicit Euler (stable at any step). Scene files
    /// written before the methods were one type name it `Msd`.
    #[serde(alias = "Msd")]
    MsdImplicit,
    /// Mass-spring-damper, linearised BDF2 (second order).
    MsdBdf2,
}

impl PreciseMethod {
    /// Every method, in display order.
    pub const ALL: [PreciseMethod; 7] = [
        PreciseMethod::LinearFem,
        PreciseMethod::CorotationalFem,
        PreciseMethod::PrefactoredFem,
        PreciseMethod::MsdRk4,
        PreciseMethod::MsdSymplectic,
        PreciseMethod::MsdImplicit,
        PreciseMethod::MsdBdf2,
    ];

    /// The FEM method of `model`.
    pub fn fem(model: FemModel) -> Self {
        match model {
            FemModel::Linear => PreciseMethod::LinearFem,
            FemModel::Corotational => PreciseMethod::CorotationalFem,
            FemModel::CorotationalPrefactored => PreciseMethod::PrefactoredFem,
        }
    }

    /// The MSD method of `integrator`.
    pub fn msd(integrator: MsdIntegrator) -> Self {
        match integrator {
            MsdIntegrator::Rk4 => PreciseMethod::MsdRk4,
            MsdIntegrator::SymplecticEuler => PreciseMethod::MsdSymplectic,
            MsdIntegrator::ImplicitEuler => PreciseMethod::MsdImplicit,
            MsdIntegrator::ImplicitBdf2 => PreciseMethod::MsdBdf2,
        }
    }

    /// The solver of the method: a FEM model or an MSD integrator.
    pub fn solver(self) -> Result<FemModel, MsdIntegrator> {
        match self {
            PreciseMethod::LinearFem => Ok(FemModel::Linear),
            PreciseMethod::CorotationalFem => Ok(FemModel::Corotational),
            PreciseMethod::PrefactoredFem => Ok(FemModel::CorotationalPrefactored),
            PreciseMethod::MsdRk4 => Err(MsdIntegrator::Rk4),
            PreciseMethod::MsdSymplectic => Err(MsdIntegrator::SymplecticEuler),
            PreciseMethod::MsdImplicit => Err(MsdIntegrator::ImplicitEuler),
            PreciseMethod::MsdBdf2 => Err(MsdIntegrator::ImplicitBdf2),
        }
    }

    /// The FEM model, for a FEM method.
    pub fn fem_model(self) -> Option<FemModel> {
        self.solver().ok()
    }

    /// The MSD integrator, for an MSD method.
    pub fn msd_integrator(self) -> Option<MsdIntegrator> {
        self.solver().err()
    }

    /// Whether the method is a FEM one.
    pub fn is_fem(self) -> bool {
        self.fem_model().is_some()
    }

    /// Short name: `fem-linear`, `fem-corotational`, `fem-corotational-prefactored`, `msd-rk4`,
    /// `msd-symplectic`, `msd-implicit`, `msd-bdf2`.
    pub fn name(self) -> &'static str {
        match self {
            PreciseMethod::LinearFem => "fem-linear",
            PreciseMethod::CorotationalFem => "fem-corotational",
            PreciseMethod::PrefactoredFem => "fem-corotational-prefactored",
            PreciseMethod::MsdRk4 => "msd-rk4",
            PreciseMethod::MsdSymplectic => "msd-symplectic",
            PreciseMethod::MsdImplicit => "msd-implicit",
            PreciseMethod::MsdBdf2 => "msd-bdf2",
        }
    }

    /// The method of a short name ([`PreciseMethod::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        PreciseMethod::ALL.into_iter().find(|m| m.name() == name)
    }
}

impl std::fmt::Display for PreciseMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// When a body may return to its cage. Lengths are fractions of the body's smallest
/// bounding-box dimension `a`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PrecisionPolicy {
    /// Largest nodal speed at rest, in `a` per second (default 0.02).
    pub rest_speed: f64,
    /// Largest distance of a surface vertex from the cage's best fit, in `a` (default
    /// 0.002; the visible jump of a down-switch is at most this).
    pub rest_residual: f64,
    /// Consecutive steps at rest before dropping (default 10).
    pub rest_steps: u32,
    /// Fewest steps at the precise level after rising (default 25).
    pub min_precise_steps: u32,
}

impl Default for PrecisionPolicy {
    fn default() -> Self {
        PrecisionPolicy {
            rest_speed: 0.02,
            rest_residual: 0.002,
            rest_steps: 10,
            min_precise_steps: 25,
        }
    }
}

/// Everything a [`LeveledBody`] is built from.
#[derive(Debug, Clone, PartialEq)]
pub struct BodySettings {
    /// Precise method.
    pub precise: PreciseMethod,
    /// FEM material (used by FEM methods).
    pub fem: FemParams,
    /// MSD parameters (used by MSD methods).
    pub msd: MsdParams,
    /// Where the MSD method's spring stiffnesses come from: `msd.stiffness` for every spring
    /// (the paper, the default) or fitted to a material.
    pub msd_spring_stiffness: SpringStiffness,
    /// Cage shape.
    pub cage: CageKind,
    /// Cage MSD parameters (paper: stiffness 50, mass 20, damping 0.3), used with
    /// [`CageDynamics::Paper`] only.
    pub cage_msd: MsdParams,
    /// How the cage moves: calibrated against the precise model (default) or the paper's
    /// cage MSD.
    pub cage_dynamics: CageDynamics,
    /// Time step of every level, seconds.
    pub dt: f64,
    /// Time integrator of the FEM methods (their shadow included). Default backward Euler.
    pub fem_integrator: FemIntegrator,
    /// Gravity on the precise level (the cage level keeps its rest shape instead).
    pub gravity: Vec3,
    /// Fixed nodes and anchors of the precise level.
    pub boundary: Boundary,
    /// Switching policy.
    pub policy: PrecisionPolicy,
}

impl BodySettings {
    /// Corotational FEM with `fem`, `msd` for the MSD method, a box cage calibrated against
    /// the precise model (the paper's cage MSD parameters kept for
    /// [`CageDynamics::Paper`]), no gravity, a free body.
    pub fn new(fem: FemParams, msd: MsdParams, dt: f64) -> Self {
        BodySettings {
            precise: PreciseMethod::CorotationalFem,
            fem,
            msd,
            msd_spring_stiffness: SpringStiffness::Constant,
            cage: CageKind::BoundingBox,
            cage_msd: PAPER_CAGE_MSD,
            cage_dynamics: CageDynamics::Calibrated,
            dt,
            fem_integrator: FemIntegrator::BackwardEuler,
            gravity: Vec3::zeros(),
            boundary: Boundary::free(),
            policy: PrecisionPolicy::default(),
        }
    }
}

/// Errors of a leveled body, naming the level that failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PrecisionError {
    /// The FEM level.
    #[error("FEM level: {0}")]
    Fem(#[from] FemError),
    /// The MSD level.
    #[error("MSD level: {0}")]
    Msd(#[from] MsdError),
    /// The cage level.
    #[error("cage level: {0}")]
    Cage(#[from] CageError),
    /// The boundary.
    #[error("boundary: {0}")]
    Boundary(#[from] BoundaryError),
    /// A node index out of range.
    #[error("node {node} out of range ({nodes} nodes)")]
    BadNode {
        /// The index.
        node: usize,
        /// Node count.
        nodes: usize,
    },
    /// The cage fit could not be solved.
    #[error("the cage fit is singular")]
    SingularFit,
    /// A material refused (the field and why).
    #[error("material: {0}")]
    Material(String),
    /// A switch met a non-finite state (the level is left as it was).
    #[error("switch from the {from:?} level: non-finite {what} at node {node}")]
    NonFiniteSwitch {
        /// The level the switch started from.
        from: Level,
        /// "position" or "velocity".
        what: &'static str,
        /// Node of the precise mesh (from the cage) or cage vertex (from the precise level).
        node: usize,
    },
}

/// One level switch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SwitchRecord {
    /// Level before.
    pub from: Level,
    /// Level after.
    pub to: Level,
    /// Body step count at the switch.
    pub step: u64,
    /// Largest surface-vertex displacement caused by the switch, scene units.
    pub jump: f64,
    /// `jump` as a fraction of the smallest bounding-box dimension.
    pub jump_ratio: f64,
    /// Down-switches: largest distance of a surface vertex from the fitted cage's shape
    /// before the switch (the cage level's error at that moment), scene units.
    pub residual: f64,
}

/// What the last step did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LevelStepStats {
    /// Level that was stepped.
    pub level: Level,
    /// The down-switch made at the start of the step, if any (the step that followed it was
    /// a cage step).
    pub switched: Option<SwitchRecord>,
}

enum Precise {
    Fem(Box<FemBody>),
    Msd(Box<MsdBody>),
}

impl Precise {
    fn step(&mut self) -> Result<(), PrecisionError> {
        match self {
            Precise::Fem(b) => {
                b.step()?;
            }
            Precise::Msd(b) => {
                b.step()?;
            }
        }
        Ok(())
    }

    fn body(&self) -> &dyn NodalBody {
        match self {
            Precise::Fem(b) => b.as_ref(),
            Precise::Msd(b) => b.as_ref(),
        }
    }
    fn body_mut(&mut self) -> &mut dyn NodalBody {
        match self {
            Precise::Fem(b) => b.as_mut(),
            Precise::Msd(b) => b.as_mut(),
        }
    }
}

/// A body with a cage level and a precise level (see the module docs).
pub struct LeveledBody {
    settings: BodySettings,
    rest: Vec<Vec3>,
    surface: Vec<u32>,
    smallest: f64,
    precise: Precise,
    cage: CageBody,
    fit: SurfaceFit,
    /// The last cage fit (positions, velocities) of the current precise episode: the warm
    /// start of the next fit.
    fit_cage: Vec<Vec3>,
    fit_velocity: Vec<Vec3>,
    last_fit: FitReport,
    /// Rotation of the cage (best rigid fit to its rest shape) at the last down-switch: the
    /// precise solver's element rotations are from then, so an up-switch starts them turned
    /// by how far the cage turned since.
    lowered_rotation: UnitQuaternion<f64>,
    level: Level,
    pin: Option<Level>,
    steps: u64,
    steps_at_level: u64,
    rest_count: u32,
    slow_steps: u32,
    asleep: bool,
    switches: u64,
    last_switch: Option<SwitchRecord>,
    residual: f64,
    shadow: Option<Box<Precise>>,
    shadow_error: Option<ShadowError>,
    /// See [`LeveledBody::set_precise_cg_must_converge`].
    cg_must_converge: bool,
    // Workspaces of the transfers.
    nodes_work: Vec<Vec3>,
    nodes_work2: Vec<Vec3>,
    cage_work: Vec<Vec3>,
    terms_work: Vec<Vec3>,
    rate_work: Vec<Vec3>,
    surface_work: Vec<Vec3>,
}

impl std::fmt::Debug for LeveledBody {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LeveledBody")
            .field("nodes", &self.rest.len())
            .field("level", &self.level)
            .field("method", &self.settings.precise)
            .field("switches", &self.switches)
            .finish()
    }
}

/// Distance between the cage level and its shadow precise simulation (see
/// [`LeveledBody::set_shadow`]), over the surface vertices, after the last step.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ShadowError {
    /// Steps the shadow has run beside the cage level since it was (re)started.
    pub steps: u64,
    /// Mean surface-vertex distance this step, scene units.
    pub mean: f64,
    /// Largest surface-vertex distance this step, scene units.
    pub max: f64,
    /// `max` as a fraction of the body's smallest bounding-box dimension.
    pub max_ratio: f64,
    /// Largest `max_ratio` seen since the shadow was enabled.
    pub worst_ratio: f64,
}

/// Most iterations of a cage fit to convergence (Anderson-accelerated; a warm-started fit
/// takes a few).
const MAX_FIT_ITERATIONS: u32 = 100;

/// A fit has converged when no cage vertex moves by more than this fraction of the body's
/// smallest dimension (positions) or of that dimension per time step (velocities).
const FIT_TOLERANCE: f64 = 1e-10;

/// Node positions for the cage: nodes no tetrahedron uses (real meshes have them; they carry
/// no physics) stand at a used node's place, so they neither stretch the cage nor fall
/// outside it.
fn cage_points(mesh: &TetMesh, positions: &[Vec3]) -> Vec<Vec3> {
    let used = |i: usize| !mesh.node_tets(i).is_empty();
    let mut points = positions.to_vec();
    if let Some(stand_in) = (0..points.len()).find(|&i| used(i)) {
        for (i, p) in points.iter_mut().enumerate() {
            if !used(i) {
                *p = positions[stand_in];
            }
        }
    }
    points
}

/// The cage body of the settings' kind around the nodes of `mesh` at `positions` (its surface
/// for fitted cages), embedding every node (see [`cage_points`]).
fn build_cage(
    mesh: &TetMesh,
    positions: &[Vec3],
    settings: &BodySettings,
    precise: &Precise,
) -> Result<CageBody, PrecisionError> {
    let nodes = &cage_points(mesh, positions)[..];
    let triangles = mesh.surface().triangles();
    let options = FitOptions::for_points(
        nodes,
        match settings.cage {
            CageKind::BoundingBox => 8,
            CageKind::Fitted { vertices } => vertices,
        },
    );
    let cage_shape = match settings.cage {
        CageKind::BoundingBox => box_cage(nodes, options.margin)?,
        CageKind::Fitted { .. } => fitted_cage(nodes, triangles, &options)?,
    };
    let mut cage_config = CageBodyConfig::paper(settings.dt);
    if settings.cage_dynamics == CageDynamics::Calibrated {
        let mut body = CageBody::new(cage_shape, nodes, &cage_config)?;
        let model = calibrated_model(mesh, nodes, &body, settings, precise)?;
        body.set_reduced(Some(model), settings.dt)?;
        return Ok(body);
    }
    cage_config.msd.stiffness = settings.cage_msd.stiffness;
    cage_config.msd.mass = settings.cage_msd.mass;
    cage_config.msd.damping = settings.cage_msd.damping;
    // A body held in place (anchored or fixed) cannot drift as a whole at the precise level;
    // its cage, whose springs resist only changes of shape, gets soft anchors to its rest so
    // its rigid motions are held too, at the rate the body's own supports give: the anchors'
    // total stiffness over the body's mass, or for fixed nodes the cage springs' own rate.
    let nv = cage_shape.vertices().len();
    let vertex_mass = settings.cage_msd.mass / nv as f64;
    let body_mass = if settings.precise.is_fem() {
        settings.fem.mass
    } else {
        settings.msd.mass
    };
    let anchor_total: f64 = settings
        .boundary
        .anchors
        .iter()
        .map(|&(_, k)| k.max(0.0))
        .sum();
    let rate = if !settings.boundary.fixed.is_empty() {
        settings.cage_msd.stiffness / vertex_mass
    } else if anchor_total > 0.0 && body_mass > 0.0 {
        anchor_total / body_mass
    } else {
        0.0
    };
    let boundary = if rate > 0.0 && rate.is_finite() {
        Boundary::anchored(nv, rate * vertex_mass)
    } else {
        Boundary::free()
    };
    Ok(CageBody::with_boundary(
        cage_shape,
        nodes,
        &cage_config,
        &boundary,
    )?)
}

/// The cage dynamics projected from `precise` linearised at `nodes` (see
/// [`ReducedModel`]), from the process-wide cache when an identical body (same nodes, mesh,
/// cage, method, material and supports) was built before.
fn calibrated_model(
    mesh: &TetMesh,
    nodes: &[Vec3],
    cage: &CageBody,
    settings: &BodySettings,
    precise: &Precise,
) -> Result<std::sync::Arc<ReducedModel>, PrecisionError> {
    let body = precise.body();
    // Linearised where the cage's points stand at rest (unused nodes carry no stiffness).
    let x = nodes.to_vec();
    let anchor_k = &body.nodes().anchor_k;
    let free =
        !body.fixed().iter().any(|f| f.iter().any(|&b| b)) && anchor_k.iter().all(|&k| k == 0.0);
    let mut key = ModelKey::default();
    key.add(settings.precise.name())
        .floats(nodes.iter().flat_map(|p| p.iter().copied()))
        .add(mesh.tets())
        .floats(
            cage.cage()
                .vertices()
                .iter()
                .flat_map(|p| p.iter().copied()),
        )
        .add(cage.cage().triangles())
        .floats(body.masses().iter().copied())
        .floats(anchor_k.iter().copied())
        .add(body.fixed());
    let key = match precise {
        Precise::Fem(b) => {
            let c = b.config();
            key.floats([
                c.young_modulus,
                c.poisson_ratio,
                c.mass_damping,
                c.stiffness_damping,
            ])
        }
        Precise::Msd(b) => {
            // The springs themselves: their stiffnesses come from the constant or from a
            // material.
            let c = b.config();
            key.floats([c.mass, c.damping, c.volume_stiffness])
                .floats(
                    b.springs()
                        .iter()
                        .flat_map(|s| [s.stiffness, s.rest_length]),
                )
                .add(b.springs().iter().map(|s| [s.a, s.b]).collect::<Vec<_>>())
        }
    }
    .finish();
    let coords = cage.coordinates().clone();
    let model = cached_model(key, || {
        let masses = body.masses();
        let fixed = body.fixed();
        // The precise model's `K u` and its damping `(alpha, beta, gamma)`.
        type Mul<'a> = Box<dyn FnMut(&[Vec3], &mut [Vec3]) + 'a>;
        let (mut mul, damping): (Mul<'_>, (f64, f64, f64)) = match precise {
            Precise::Fem(b) => {
                let k = b.stiffness_at(&x, b.model());
                let c = b.config();
                (
                    Box::new(move |u: &[Vec3], out: &mut [Vec3]| k.mul(u, out)),
                    (c.mass_damping, c.stiffness_damping, 0.0),
                )
            }
            Precise::Msd(b) => {
                // K u by central differences of the spring, volume and anchor forces.
                let size = mesh.bbox().diagonal();
                let (mut xp, mut fp, mut fm) = (
                    x.clone(),
                    vec![Vec3::zeros(); x.len()],
                    vec![Vec3::zeros(); x.len()],
                );
                let x = &x;
                (
                    Box::new(move |u: &[Vec3], out: &mut [Vec3]| {
                        let umax = u.iter().map(|v| v.amax()).fold(0.0, f64::max);
                        if umax == 0.0 {
                            out.fill(Vec3::zeros());
                            return;
                        }
                        let eps = 1e-6 * size / umax;
                        for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                            *p = x0 + ui * eps;
                        }
                        b.spring_forces(&xp, &mut fp);
                        for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                            *p = x0 - ui * eps;
                        }
                        b.spring_forces(&xp, &mut fm);
                        for ((o, a), m) in out.iter_mut().zip(&fp).zip(&fm) {
                            *o = (m - a) / (2.0 * eps);
                        }
                    }),
                    (0.0, 0.0, b.config().damping),
                )
            }
        };
        ReducedModel::project(
            cage.cage(),
            &coords,
            PreciseOperators {
                masses,
                fixed,
                stiffness: &mut *mul,
                damping,
                free,
            },
        )
    })?;
    Ok(model)
}

fn build_precise(mesh: &TetMesh, s: &BodySettings) -> Result<Precise, PrecisionError> {
    Ok(match s.precise.solver() {
        Ok(model) => {
            let mut c = FemConfig::paper(&s.fem, s.dt);
            c.model = model;
            c.gravity = s.gravity;
            c.integrator = s.fem_integrator;
            Precise::Fem(Box::new(FemBody::new(mesh, c, &s.boundary)?))
        }
        Err(integrator) => {
            let mut c = MsdConfig::paper(&s.msd, s.dt);
            c.integrator = integrator;
            c.spring_stiffness = s.msd_spring_stiffness;
            c.gravity = s.gravity;
            Precise::Msd(Box::new(MsdBody::from_mesh(mesh, c, &s.boundary)?))
        }
    })
}

impl LeveledBody {
    /// Builds the cage (embedding every node), the precise solver and the cage fit; the body
    /// starts at rest at the cage level.
    pub fn new(mesh: &TetMesh, settings: BodySettings) -> Result<Self, PrecisionError> {
        let nodes = mesh.positions();
        let precise = build_precise(mesh, &settings)?;
        let cage = build_cage(mesh, nodes, &settings, &precise)?;
        let surface = mesh.surface().vertices().to_vec();
        let fit = SurfaceFit::new(cage.coordinates(), &surface)?;
        let n = nodes.len();
        let nv = cage.cage().vertices().len();
        let nf = cage.cage().triangles().len();
        Ok(LeveledBody {
            smallest: mesh.bbox().smallest_dimension(),
            rest: nodes.to_vec(),
            precise,
            fit,
            fit_cage: cage.cage_positions().to_vec(),
            fit_velocity: vec![Vec3::zeros(); nv],
            last_fit: FitReport::default(),
            lowered_rotation: UnitQuaternion::identity(),
            level: Level::Cage,
            pin: None,
            steps: 0,
            steps_at_level: 0,
            rest_count: 0,
            slow_steps: 0,
            asleep: true,
            switches: 0,
            last_switch: None,
            residual: 0.0,
            shadow: None,
            cg_must_converge: false,
            shadow_error: None,
            nodes_work: vec![Vec3::zeros(); n],
            nodes_work2: vec![Vec3::zeros(); n],
            cage_work: vec![Vec3::zeros(); nv],
            terms_work: vec![Vec3::zeros(); nf],
            rate_work: vec![Vec3::zeros(); nf],
            surface_work: vec![Vec3::zeros(); surface.len()],
            surface,
            cage,
            settings,
        })
    }

    /// Replaces the cage: its fit and the workspaces sized by it follow.
    fn install_cage(&mut self, cage: CageBody) -> Result<(), PrecisionError> {
        let nv = cage.cage().vertices().len();
        let nf = cage.cage().triangles().len();
        self.fit = SurfaceFit::new(cage.coordinates(), &self.surface)?;
        self.fit_cage = cage.cage_positions().to_vec();
        self.fit_velocity = vec![Vec3::zeros(); nv];
        self.cage = cage;
        self.cage_work = vec![Vec3::zeros(); nv];
        self.terms_work = vec![Vec3::zeros(); nf];
        self.rate_work = vec![Vec3::zeros(); nf];
        Ok(())
    }

    /// Whether the body sleeps: at the cage level, in its rest shape, at rest, with no load,
    /// so its steps cost nothing and its points do not change. A load, a contact or a switch
    /// wakes it; a cage that comes back within 1e-4 of the smallest dimension of its rest
    /// shape, slower than 1e-4 of it per second, is put to sleep there (snapped to rest).
    pub fn is_asleep(&self) -> bool {
        self.asleep && self.level == Level::Cage
    }

    fn try_sleep(&mut self) -> Result<(), PrecisionError> {
        let eps = 1e-4 * self.smallest;
        let msd = self.cage.msd();
        let near = msd
            .positions()
            .iter()
            .zip(self.cage.cage().vertices())
            .all(|(x, r)| (x - r).norm() < eps);
        let pending = msd.external_forces().iter().any(|f| *f != Vec3::zeros());
        if near && !pending && msd.max_speed() < eps {
            self.cage_work.copy_from_slice(self.cage.cage().vertices());
            let msd = self.cage.msd_mut();
            msd.positions_mut().copy_from_slice(&self.cage_work);
            msd.velocities_mut().fill(Vec3::zeros());
            self.cage.update_points()?;
            self.asleep = true;
        }
        Ok(())
    }

    /// Whether the body is at the precise level and has not been slow (by the policy's rest
    /// speed) for `rest_steps` consecutive steps, whatever its contacts: what a neighbour
    /// uses to decide that a contact with this body still presses it.
    pub fn is_moving(&self) -> bool {
        self.level == Level::Precise && self.slow_steps < self.settings.policy.rest_steps
    }

    /// Current level.
    pub fn level(&self) -> Level {
        self.level
    }

    /// Settings the body was built with (the method as last set).
    pub fn settings(&self) -> &BodySettings {
        &self.settings
    }

    /// Pins the body to a level (`None` lets the policy decide). Pinning to a level other than
    /// the current one switches now.
    pub fn pin(&mut self, level: Option<Level>) -> Result<Option<SwitchRecord>, PrecisionError> {
        self.pin = None;
        let record = match level {
            Some(Level::Cage) => self.lower()?,
            Some(Level::Precise) => self.raise()?,
            None => None,
        };
        self.pin = level;
        Ok(record)
    }

    /// The pinned level, if any.
    pub fn pinned(&self) -> Option<Level> {
        self.pin
    }

    /// Number of level switches so far.
    pub fn switch_count(&self) -> u64 {
        self.switches
    }

    /// The last switch.
    pub fn last_switch(&self) -> Option<SwitchRecord> {
        self.last_switch
    }

    /// The cage level's current error estimate: the largest distance of a surface vertex
    /// from the cage's best fit, as of the last fit (every step at rest at the precise level,
    /// and at each down-switch).
    pub fn cage_residual(&self) -> f64 {
        self.residual
    }

    /// Fits the cage to the precise level's current surface now, as a down-switch would
    /// (warm-started from the last fit), and returns the largest distance between a surface
    /// vertex and the fitted cage's image of it: how close a cage of this shape can follow
    /// the precise state, whatever its dynamics. Reads the precise level's state at either
    /// level (at the cage level that is the state it left, or was handed at the last switch).
    pub fn fit_cage_now(&mut self) -> Result<f64, PrecisionError> {
        self.fit_cage(MAX_FIT_ITERATIONS)
    }

    /// Smallest bounding-box dimension of the rest mesh.
    pub fn smallest_dimension(&self) -> f64 {
        self.smallest
    }

    /// The cage body.
    pub fn cage(&self) -> &CageBody {
        &self.cage
    }

    /// The cage body, mutable (for example to set cage velocities; call
    /// [`CageBody::update_points`] after moving cage vertices).
    pub fn cage_mut(&mut self) -> &mut CageBody {
        self.asleep = false;
        &mut self.cage
    }

    /// The precise body's nodal state.
    pub fn precise(&self) -> &dyn NodalBody {
        self.precise.body()
    }

    /// The precise body's nodal state, mutable (positions, velocities, forces). Setting
    /// positions far from the last step's on a corotational FEM body should be followed by
    /// [`FemBody::sync_rotations`] (the next switch up does it).
    pub fn precise_mut(&mut self) -> &mut dyn NodalBody {
        self.precise.body_mut()
    }

    /// Sets the CG tolerance and iteration cap of the precise level's iterative solve
    /// (corotational FEM, implicit MSD; the others ignore it).
    pub fn set_precise_cg(
        &mut self,
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<(), PrecisionError> {
        match &mut self.precise {
            Precise::Fem(b) => b.set_cg(tolerance, max_iterations)?,
            Precise::Msd(b) => b.set_cg(tolerance, max_iterations)?,
        }
        Ok(())
    }

    /// Whether the precise method's iterative solve must converge (see
    /// [`FemConfig::cg_must_converge`], [`MsdConfig::cg_must_converge`]); kept across
    /// changes of method. A step whose solve does not then fails and leaves the body as it
    /// was ([`PrecisionError::Fem`] holding [`FemError::NotConverged`], or the MSD's).
    pub fn set_precise_cg_must_converge(&mut self, on: bool) {
        self.cg_must_converge = on;
        match &mut self.precise {
            Precise::Fem(b) => b.set_cg_must_converge(on),
            Precise::Msd(b) => b.set_cg_must_converge(on),
        }
    }

    /// The iterative solve of the last precise step, for the methods that have one
    /// (corotational FEM, implicit MSD).
    pub fn precise_cg(&self) -> Option<CgStats> {
        match &self.precise {
            Precise::Fem(b) if b.model() == FemModel::Corotational => Some(b.last_step().cg),
            Precise::Msd(b) if b.config().integrator.is_implicit() => Some(b.last_step().cg),
            _ => None,
        }
    }

    /// The FEM body, when the precise method is FEM.
    pub fn fem(&self) -> Option<&FemBody> {
        match &self.precise {
            Precise::Fem(b) => Some(b),
            Precise::Msd(_) => None,
        }
    }

    /// The MSD body, when the precise method is MSD.
    pub fn msd(&self) -> Option<&MsdBody> {
        match &self.precise {
            Precise::Msd(b) => Some(b),
            Precise::Fem(_) => None,
        }
    }

    /// Indices of the surface vertices among the nodes.
    pub fn surface_vertices(&self) -> &[u32] {
        &self.surface
    }

    /// Current positions of every node, at whichever level the body is.
    pub fn node_positions(&self) -> &[Vec3] {
        match self.level {
            Level::Cage => self.cage.points(),
            Level::Precise => self.precise.body().positions(),
        }
    }

    /// Current position of surface vertex `k` (index into [`LeveledBody::surface_vertices`]).
    pub fn surface_position(&self, k: usize) -> Vec3 {
        self.node_positions()[self.surface[k] as usize]
    }

    /// Adds an external force on node `node` for the next step: on the precise body, or
    /// mapped onto the cage through the coordinates.
    pub fn add_force(&mut self, node: usize, force: Vec3) -> Result<(), PrecisionError> {
        let n = self.rest.len();
        if node >= n {
            return Err(PrecisionError::BadNode { node, nodes: n });
        }
        match self.level {
            Level::Cage => {
                self.asleep = false;
                self.cage.apply_point_force(node, force)?;
                self.add_shadow_force(node, force);
            }
            Level::Precise => self.precise.body_mut().add_force(node, force),
        }
        Ok(())
    }

    /// Adds a force on node `node` of the shadow simulation only, for loads applied to the
    /// cage some other way (a contact displacing the cage directly). No effect without a
    /// shadow, at the precise level or for a node out of range.
    pub fn add_shadow_force(&mut self, node: usize, force: Vec3) {
        if self.level != Level::Cage || node >= self.rest.len() {
            return;
        }
        if let Some(s) = self.shadow.as_mut() {
            s.body_mut().add_force(node, force);
        }
    }

    /// Time integrator of the FEM methods ([`BodySettings::fem_integrator`]).
    pub fn fem_integrator(&self) -> FemIntegrator {
        self.settings.fem_integrator
    }

    /// Changes the time integrator of the FEM methods at run time (the precise solver and
    /// its shadow, when FEM; kept for a later switch to FEM otherwise). The state is kept;
    /// BDF2 starts a new history from it. Fails, keeping the integrator, when a
    /// refactorization fails.
    pub fn set_fem_integrator(&mut self, integrator: FemIntegrator) -> Result<(), PrecisionError> {
        if let Precise::Fem(b) = &mut self.precise {
            b.set_integrator(integrator)?;
        }
        if let Some(Precise::Fem(s)) = self.shadow.as_deref_mut() {
            s.set_integrator(integrator)?;
        }
        self.settings.fem_integrator = integrator;
        Ok(())
    }

    /// Changes the precise method at run time. At the precise level the new solver takes the
    /// current positions and velocities (no jump).
    pub fn set_precise_method(
        &mut self,
        mesh: &TetMesh,
        method: PreciseMethod,
    ) -> Result<(), PrecisionError> {
        if method == self.settings.precise {
            return Ok(());
        }
        // Between FEM models: same FEM body.
        if let (Precise::Fem(b), Some(model)) = (&mut self.precise, method.fem_model()) {
            b.set_model(model)?;
            if let Some(Precise::Fem(s)) = self.shadow.as_deref_mut() {
                s.set_model(model)?;
            }
            self.settings.precise = method;
            return Ok(());
        }
        let mut settings = self.settings.clone();
        settings.precise = method;
        self.rebuild_precise(mesh, settings)
    }

    /// Changes the materials at run time: the FEM parameters, the MSD parameters and where
    /// the MSD's springs come from. The precise solver (its shadow too) is built again from
    /// them and, at the precise level, takes the current positions and velocities (no jump);
    /// a calibrated cage is projected again from the new model. Fails, keeping the old
    /// materials, when the new ones are refused.
    pub fn set_materials(
        &mut self,
        mesh: &TetMesh,
        fem: FemParams,
        msd: MsdParams,
        springs: SpringStiffness,
    ) -> Result<(), PrecisionError> {
        if (fem, msd, springs)
            == (
                self.settings.fem,
                self.settings.msd,
                self.settings.msd_spring_stiffness,
            )
        {
            return Ok(());
        }
        fem.validate()
            .map_err(|e| PrecisionError::Material(format!("fem: {e}")))?;
        msd.validate()
            .map_err(|e| PrecisionError::Material(format!("msd: {e}")))?;
        springs
            .validate()
            .map_err(|(field, e)| PrecisionError::Material(format!("msd springs: {field} {e}")))?;
        let mut settings = self.settings.clone();
        settings.fem = fem;
        settings.msd = msd;
        settings.msd_spring_stiffness = springs;
        self.rebuild_precise(mesh, settings)
    }

    /// The precise solver built again from `settings`, taking the current state.
    fn rebuild_precise(
        &mut self,
        mesh: &TetMesh,
        settings: BodySettings,
    ) -> Result<(), PrecisionError> {
        let mut next = build_precise(mesh, &settings)?;
        if self.level == Level::Precise {
            let old = self.precise.body();
            let new = next.body_mut();
            new.positions_mut().copy_from_slice(old.positions());
            new.velocities_mut().copy_from_slice(old.velocities());
            if let Precise::Fem(b) = &mut next {
                b.sync_rotations();
            }
        }
        self.precise = next;
        // A calibrated cage follows its precise model: projected again from the new one.
        if self.cage.reduced().is_some() {
            let nodes = self.cage.coordinates().rest_points().to_vec();
            let model = calibrated_model(mesh, &nodes, &self.cage, &settings, &self.precise)?;
            self.cage.set_reduced(Some(model), settings.dt)?;
        }
        if self.cg_must_converge {
            self.set_precise_cg_must_converge(true);
        }
        self.settings = settings;
        // The new solver's rotations are held at the rest orientation, not at the last
        // down-switch's: an up-switch turns them by the cage's whole rotation.
        self.lowered_rotation = UnitQuaternion::identity();
        if self.shadow.is_some() {
            self.shadow = Some(Box::new(build_precise(mesh, &self.settings)?));
            self.restart_shadow()?;
        }
        Ok(())
    }

    fn max_surface_jump(&self, before: &[Vec3]) -> f64 {
        let now = self.node_positions();
        self.surface
            .iter()
            .zip(before)
            .map(|(&i, b)| (now[i as usize] - b).norm())
            .fold(0.0, f64::max)
    }

    fn snapshot_surface(&mut self) {
        let now = match self.level {
            Level::Cage => self.cage.points(),
            Level::Precise => self.precise.body().positions(),
        };
        for (o, &i) in self.surface_work.iter_mut().zip(&self.surface) {
            *o = now[i as usize];
        }
    }

    fn record(&mut self, from: Level, to: Level, residual: f64) -> SwitchRecord {
        let before = std::mem::take(&mut self.surface_work);
        let jump = self.max_surface_jump(&before);
        self.surface_work = before;
        let r = SwitchRecord {
            from,
            to,
            step: self.steps,
            jump,
            jump_ratio: jump / self.smallest,
            residual,
        };
        self.switches += 1;
        self.last_switch = Some(r);
        self.steps_at_level = 0;
        self.rest_count = 0;
        self.slow_steps = 0;
        self.asleep = false;
        r
    }

    /// Cage to precise (contact, or a pin). No effect at the precise level or when pinned to
    /// the cage. Returns the switch.
    pub fn raise(&mut self) -> Result<Option<SwitchRecord>, PrecisionError> {
        if self.level == Level::Precise || self.pin == Some(Level::Cage) {
            return Ok(None);
        }
        self.cage_state()?;
        if let Some((what, node)) =
            crate::state::first_non_finite_state(&self.nodes_work, &self.nodes_work2)
        {
            return Err(PrecisionError::NonFiniteSwitch {
                from: Level::Cage,
                what,
                node,
            });
        }
        self.snapshot_surface();
        let turned =
            self.cage_rotation(self.cage.cage_positions()) * self.lowered_rotation.inverse();
        load_state(
            &mut self.precise,
            &self.nodes_work,
            &self.nodes_work2,
            turned,
        );
        // The cage this state came from is the exact fit of it: the next fit starts there.
        self.fit_cage.copy_from_slice(self.cage.cage_positions());
        self.fit_velocity
            .copy_from_slice(self.cage.msd().velocities());
        self.level = Level::Precise;
        Ok(Some(self.record(Level::Cage, Level::Precise, 0.0)))
    }

    /// The state the cage gives every node: positions (the exact map) into `nodes_work`,
    /// velocities (central difference of the exact map along the cage vertex velocities)
    /// into `nodes_work2`.
    fn cage_state(&mut self) -> Result<(), PrecisionError> {
        let coords = self.cage.coordinates().clone();
        let x = self.cage.msd().positions();
        let u = self.cage.msd().velocities();
        coords.face_terms(x, &mut self.terms_work);
        coords.evaluate(x, &self.terms_work, &mut self.nodes_work)?;
        // The map is linear in (vertices, face terms): the velocity is the map of the vertex
        // velocities and the face terms' rate (central difference along them), one evaluation.
        let h = 1e-3 * self.settings.dt;
        shifted(x, u, h, &mut self.cage_work);
        coords.face_terms(&self.cage_work, &mut self.rate_work);
        shifted(x, u, -h, &mut self.cage_work);
        coords.face_terms(&self.cage_work, &mut self.terms_work);
        for (r, t) in self.rate_work.iter_mut().zip(&self.terms_work) {
            *r = (*r - t) / (2.0 * h);
        }
        coords.evaluate(u, &self.rate_work, &mut self.nodes_work2)?;
        Ok(())
    }

    /// Turns the shadow precise simulation on or off (`mesh` is the body's mesh). The shadow
    /// is a second solver of the body's precise method that, while the body is at the cage
    /// level, starts from the cage's state, takes the same external forces and steps beside
    /// it, so [`LeveledBody::shadow_error`] measures how far the cage level is from what the
    /// precise method would do under the same loads. At the precise level it waits, and it
    /// restarts from the precise state at each down-switch. Costs one precise step per step.
    pub fn set_shadow(&mut self, mesh: &TetMesh, on: bool) -> Result<(), PrecisionError> {
        if !on {
            self.shadow = None;
            self.shadow_error = None;
            return Ok(());
        }
        if self.shadow.is_none() {
            self.shadow = Some(Box::new(build_precise(mesh, &self.settings)?));
            self.restart_shadow()?;
        }
        Ok(())
    }

    /// Whether a shadow precise simulation runs (see [`LeveledBody::set_shadow`]).
    pub fn has_shadow(&self) -> bool {
        self.shadow.is_some()
    }

    /// Distance between the cage level and its shadow after the last step; `None` without a
    /// shadow or while the body is at the precise level.
    pub fn shadow_error(&self) -> Option<ShadowError> {
        self.shadow_error
    }

    /// The shadow's node positions (`None` without a shadow).
    pub fn shadow_positions(&self) -> Option<&[Vec3]> {
        self.shadow.as_ref().map(|s| s.body().positions())
    }

    /// Puts the shadow in the body's current state (from the cage or the precise solver).
    fn restart_shadow(&mut self) -> Result<(), PrecisionError> {
        let Some(mut shadow) = self.shadow.take() else {
            return Ok(());
        };
        let worst = self.shadow_error.map_or(0.0, |e| e.worst_ratio);
        match self.level {
            Level::Cage => {
                self.cage_state()?;
                load_state(
                    &mut shadow,
                    &self.nodes_work,
                    &self.nodes_work2,
                    UnitQuaternion::identity(),
                );
            }
            Level::Precise => {
                let from = self.precise.body();
                let to = shadow.body_mut();
                to.positions_mut().copy_from_slice(from.positions());
                to.velocities_mut().copy_from_slice(from.velocities());
                match shadow.as_mut() {
                    Precise::Fem(b) => {
                        b.restart_history();
                        b.sync_rotations();
                    }
                    Precise::Msd(b) => b.restart_history(),
                }
            }
        }
        self.shadow = Some(shadow);
        self.shadow_error = Some(ShadowError {
            worst_ratio: worst,
            ..ShadowError::default()
        });
        Ok(())
    }

    /// Steps the shadow beside a cage step and measures the distance of the two surfaces.
    fn step_shadow(&mut self) -> Result<(), PrecisionError> {
        let Some(shadow) = self.shadow.as_mut() else {
            return Ok(());
        };
        shadow.step()?;
        let a = self.cage.points();
        let b = shadow.body().positions();
        let (mut sum, mut max) = (0.0, 0.0_f64);
        for &i in &self.surface {
            let d = (a[i as usize] - b[i as usize]).norm();
            sum += d;
            max = max.max(d);
        }
        let e = self.shadow_error.get_or_insert_with(ShadowError::default);
        e.steps += 1;
        e.mean = sum / self.surface.len().max(1) as f64;
        e.max = max;
        e.max_ratio = max / self.smallest;
        e.worst_ratio = e.worst_ratio.max(e.max_ratio);
        Ok(())
    }

    /// The rotation of the rigid motion that best maps the rest cage onto `cage` (Kabsch).
    fn cage_rotation(&self, cage: &[Vec3]) -> UnitQuaternion<f64> {
        let rest = self.cage.cage().vertices();
        let n = rest.len().max(1) as f64;
        let (c0, c1) = (rest.iter().sum::<Vec3>() / n, cage.iter().sum::<Vec3>() / n);
        let mut h = nalgebra::Matrix3::zeros();
        for (x, x0) in cage.iter().zip(rest) {
            h += (x - c1) * (x0 - c0).transpose();
        }
        let mut q = UnitQuaternion::identity();
        let mut r = nalgebra::Matrix3::identity();
        crate::fem::rotation::extract_rotation(&h, &mut q, &mut r, 100, 1e-12);
        q
    }

    /// Iterates the cage fit on the precise body's current surface, at most `max_iterations`
    /// times from the last fit, and returns the largest surface distance of the fit (the cage
    /// level's error if the body dropped now).
    fn fit_cage(&mut self, max_iterations: u32) -> Result<f64, PrecisionError> {
        let coords = self.cage.coordinates().clone();
        let points = self.precise.body().positions();
        self.last_fit = self.fit.positions(
            &coords,
            points,
            &mut self.fit_cage,
            FIT_TOLERANCE * self.smallest,
            max_iterations,
        );
        let residual = self.fit.residual(&coords, &self.fit_cage, points);
        if !residual.is_finite() {
            // Start the next fit from the cage, not from a broken estimate.
            self.fit_cage.copy_from_slice(self.cage.cage_positions());
            return Err(PrecisionError::SingularFit);
        }
        Ok(residual)
    }

    /// Iterates the cage velocity fit (linearised at the fitted positions) from the last one.
    fn fit_velocities(&mut self, max_iterations: u32) -> FitReport {
        let coords = self.cage.coordinates().clone();
        let dt = self.settings.dt;
        self.fit.velocities(
            &coords,
            &self.fit_cage,
            self.precise.body().velocities(),
            &mut self.fit_velocity,
            1e-3 * dt,
            FIT_TOLERANCE * self.smallest / dt,
            max_iterations,
        )
    }

    /// The last cage fit: iterations, last change, whether it converged.
    pub fn last_fit(&self) -> FitReport {
        self.last_fit
    }

    /// Precise to cage (rest, or a pin). No effect at the cage level or when pinned to the
    /// precise level. Returns the switch.
    pub fn lower(&mut self) -> Result<Option<SwitchRecord>, PrecisionError> {
        if self.level == Level::Cage || self.pin == Some(Level::Precise) {
            return Ok(None);
        }
        let residual = self.fit_cage(MAX_FIT_ITERATIONS)?;
        self.lower_fitted(residual).map(Some)
    }

    /// The down-switch onto the converged fit (`residual` its error).
    fn lower_fitted(&mut self, residual: f64) -> Result<SwitchRecord, PrecisionError> {
        self.fit_velocities(MAX_FIT_ITERATIONS);
        if let Some((what, node)) =
            crate::state::first_non_finite_state(&self.fit_cage, &self.fit_velocity)
        {
            return Err(PrecisionError::NonFiniteSwitch {
                from: Level::Precise,
                what,
                node,
            });
        }
        self.snapshot_surface();
        self.residual = residual;
        self.lowered_rotation = self.cage_rotation(&self.fit_cage);
        let msd = self.cage.msd_mut();
        msd.positions_mut().copy_from_slice(&self.fit_cage);
        msd.velocities_mut().copy_from_slice(&self.fit_velocity);
        // The cage keeps its rest shape (the body's equilibrium, see `settle`): whatever
        // motion is left carries on at the cage level and its springs bring it back to rest.
        self.cage.update_points()?;
        // The shadow carries on from the precise state the cage now stands for.
        self.restart_shadow()?;
        self.level = Level::Cage;
        Ok(self.record(Level::Precise, Level::Cage, residual))
    }

    /// Advances the current level by one step. `in_contact` (from the contact stage) keeps
    /// the body from dropping; a body at rest at the precise level with no contact drops to
    /// its cage per the policy. On a solver error the state of that level is unchanged.
    pub fn step(&mut self, in_contact: bool) -> Result<LevelStepStats, PrecisionError> {
        // Rest is judged on the state the last step left, after its contact response: a body
        // pressed against another sits still there, though within a solver step alone the
        // contact's push is missing and its nodes near the contact move (at about the contact
        // force times the step over their mass, every step). So the down-switch is decided,
        // and made, at the start of a step, on that state; the step is then a cage step.
        let mut switched = None;
        if self.level == Level::Precise && self.pin.is_none() {
            let p = self.settings.policy;
            let slow = self.precise.body().max_speed() <= p.rest_speed * self.smallest;
            self.slow_steps = if slow { self.slow_steps + 1 } else { 0 };
            if in_contact || !slow {
                self.rest_count = 0;
            } else {
                self.rest_count += 1;
                // The fit (the distance from a cage-reproducible shape) is checked once the
                // body has been slow long enough, not every step, warm-started from the last
                // one; a down-switch then uses it as it is.
                if self.rest_count >= p.rest_steps
                    && self.steps_at_level >= p.min_precise_steps as u64
                {
                    let residual = self.fit_cage(MAX_FIT_ITERATIONS)?;
                    self.residual = residual;
                    if residual <= p.rest_residual * self.smallest {
                        switched = Some(self.lower_fitted(residual)?);
                    } else {
                        self.rest_count = 0;
                    }
                }
            }
        }
        let level = self.level;
        match level {
            Level::Cage => {
                if self.asleep && !in_contact {
                    // At rest in its rest shape with no load: stepping would change nothing.
                    self.step_shadow()?;
                } else {
                    self.cage.step()?;
                    self.try_sleep()?;
                    self.step_shadow()?;
                }
            }
            Level::Precise => self.precise.step()?,
        }
        self.steps += 1;
        self.steps_at_level += 1;
        Ok(LevelStepStats { level, switched })
    }

    /// Lets the precise method find the body's equilibrium under its loads (gravity against
    /// its supports) and makes that the cage level's rest state and the initial state, so the
    /// first touch does not start a visible sag and the body can return to its cage once it is
    /// back at that equilibrium. Steps the precise level until it is at rest by a tenth of
    /// the policy's speed test for `rest_steps` steps (at most `max_steps`), then rebuilds
    /// the cage around the settled shape (`mesh` is the body's mesh). Returns the steps taken and whether it came to rest. A body without gravity is
    /// already at equilibrium: nothing is done. Counters are cleared afterwards.
    pub fn settle(
        &mut self,
        mesh: &TetMesh,
        max_steps: u32,
    ) -> Result<(u32, bool), PrecisionError> {
        if self.settings.gravity.norm() == 0.0 {
            return Ok((0, true));
        }
        let pin = self.pin.take();
        self.raise()?;
        let p = self.settings.policy;
        let mut slow = 0;
        let mut steps = 0;
        let mut rested = false;
        while steps < max_steps {
            self.precise.step()?;
            steps += 1;
            if self.precise.body().max_speed() <= 0.1 * p.rest_speed * self.smallest {
                slow += 1;
                if slow >= p.rest_steps && steps >= p.min_precise_steps {
                    rested = true;
                    break;
                }
            } else {
                slow = 0;
            }
        }
        // The cage is rebuilt around the settled shape, which it then reproduces exactly at
        // rest: the settled shape is the cage level's rest state and the initial state.
        let settled = self.precise.body().positions().to_vec();
        let cage = build_cage(mesh, &settled, &self.settings, &self.precise)?;
        self.install_cage(cage)?;
        self.level = Level::Cage;
        self.pin = pin;
        self.reset()?;
        Ok((steps, rested))
    }

    /// Back to the initial state: cage level, at rest, in the rest shape (the settled shape
    /// after [`LeveledBody::settle`]; the cage's rest shape too), counters cleared; the pin is
    /// kept.
    pub fn reset(&mut self) -> Result<(), PrecisionError> {
        match &mut self.precise {
            Precise::Fem(b) => b.reset(),
            Precise::Msd(b) => b.reset(),
        }
        let rest_cage = self.cage.cage().vertices().to_vec();
        let msd = self.cage.msd_mut();
        msd.positions_mut().copy_from_slice(&rest_cage);
        msd.velocities_mut().fill(Vec3::zeros());
        msd.rebase_rest();
        self.cage.update_points()?;
        self.level = Level::Cage;
        self.steps = 0;
        self.steps_at_level = 0;
        self.rest_count = 0;
        self.slow_steps = 0;
        self.asleep = true;
        self.switches = 0;
        self.last_switch = None;
        self.residual = 0.0;
        self.lowered_rotation = UnitQuaternion::identity();
        if self.pin == Some(Level::Precise) {
            self.pin = None;
            self.raise()?;
            self.pin = Some(Level::Precise);
        }
        if let Some(shadow) = self.shadow.as_mut() {
            match shadow.as_mut() {
                Precise::Fem(b) => b.reset(),
                Precise::Msd(b) => b.reset(),
            }
            self.shadow_error = None;
            self.restart_shadow()?;
        }
        Ok(())
    }
}

/// Sets a precise solver's nodes to `x`, `v`; components it holds fixed keep their position
/// and get no velocity.
fn load_state(target: &mut Precise, x: &[Vec3], v: &[Vec3], turned: UnitQuaternion<f64>) {
    let nodes = target.body_mut().nodes_mut();
    for i in 0..nodes.x.len() {
        for a in 0..3 {
            if !nodes.fixed[i][a] {
                nodes.x[i][a] = x[i][a];
                nodes.v[i][a] = v[i][a];
            } else {
                nodes.v[i][a] = 0.0;
            }
        }
    }
    // A state from elsewhere: BDF2 starts a new history. Element rotations matter to the
    // corotational model only (a switch to it syncs them).
    if let Precise::Msd(b) = target {
        b.restart_history();
    }
    if let Precise::Fem(b) = target {
        b.restart_history();
        if b.model().is_corotational() {
            b.sync_rotations_from(turned);
        }
    }
}

/// `out = x + h u`: the cage moved along its velocities, for central differences.
fn shifted(x: &[Vec3], u: &[Vec3], h: f64, out: &mut [Vec3]) {
    for (o, (xi, ui)) in out.iter_mut().zip(x.iter().zip(u)) {
        *o = xi + ui * h;
    }
}

fn _assert_send_sync() {
    fn check<T: Send + Sync>() {}
    check::<LeveledBody>();
}
