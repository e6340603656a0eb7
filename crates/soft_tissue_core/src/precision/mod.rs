//! Levels of precision for one body: the cheap cage level and the body's precise method,
//! the state transfer between them without a visible jump, and the policy that decides when
//! a body may drop back to its cage (paper section III, Fig. 2).
//!
//! A [`LeveledModel`] always has its cage (a [`CageModel`] embedding every mesh node) and the
//! solver of its chosen precise method, built once (a body whose method is MSD has no FEM
//! state). It starts at [`Level::Cage`].
//!
//! - **Up** ([`LeveledModel::raise`], called by contact before the contact is resolved): node
//!   positions are the cage's exact (`f64`) Green-coordinate evaluation, node velocities its
//!   derivative along the cage vertex velocities (the map is linear in the vertices and face
//!   terms: one evaluation with the face terms' rate). A FEM body's element rotations start
//!   from the ones it held at its last down-switch, turned by how far the cage turned since
//!   (its best rigid fit), and are brought to the new state eight elements at a time.
//! - **Down** ([`LeveledModel::lower`], or automatically at the start of a step, which is then
//!   a cage step): the cage is
//!   fitted so its coordinates reproduce the current surface in the least-squares sense
//!   ([`crate::cage::fit`]: face terms refreshed by an Anderson-accelerated fixed point whose
//!   iterations cost `O(cage vertices x cage faces)`, warm-started from the last fit), cage
//!   velocities the same way. The fit that decides the switch is the one the switch uses. The
//!   cage keeps its rest shape, the body's settled equilibrium ([`LeveledModel::settle`]), so
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
//!   on request ([`LeveledModel::set_shadow`]), a shadow precise simulation that runs beside
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
    CageDynamics, CageError, CageModel, CageModelConfig, FitOptions, FitReport, ReducedModel,
    SurfaceFit, box_cage, fitted_cage,
};
use crate::fem::{FemBody, FemConfig, FemError, FemIntegrator, FemModel};
use crate::linalg::CgStats;
use crate::material::{FemParams, MsdParams, PAPER_CAGE_MSD};
use crate::mesh::TetMesh;
use crate::msd::{MsdBody, MsdConfig, MsdError, SpringStiffness};
use crate::scenario::CageKind;
use crate::state::NodalModel;

mod build;
mod contact;
mod cut;
mod fit;
mod method;
mod shadow;
mod switch;
mod teleport;
mod undo;

use build::{build_cage, build_precise, calibrated_model};
pub use method::{Level, PreciseMethod};
pub use shadow::ShadowError;
use switch::load_state;
pub use undo::LevelSnapshot;

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

/// Everything a [`LeveledModel`] is built from.
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

/// Errors of a leveled model, naming the level that failed.
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
    /// A rigid move ([`LeveledModel::teleport`]) that cannot be made (the model is left as
    /// it was): not finite, or a turn of nodes held along some of their axes only (held axes
    /// are world axes).
    #[error("rigid move: {0}")]
    Move(String),
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

    fn model(&self) -> &dyn NodalModel {
        match self {
            Precise::Fem(b) => b.as_ref(),
            Precise::Msd(b) => b.as_ref(),
        }
    }
    fn model_mut(&mut self) -> &mut dyn NodalModel {
        match self {
            Precise::Fem(b) => b.as_mut(),
            Precise::Msd(b) => b.as_mut(),
        }
    }
}

/// A body with a cage level and a precise level (see the module docs).
pub struct LeveledModel {
    settings: BodySettings,
    rest: Vec<Vec3>,
    surface: Vec<u32>,
    smallest: f64,
    precise: Precise,
    cage: CageModel,
    fit: SurfaceFit,
    /// The last cage fit (positions, velocities) of the current precise episode: the warm
    /// start of the next fit.
    fit_cage: Vec<Vec3>,
    fit_velocity: Vec<Vec3>,
    last_fit: FitReport,
    /// Where the cage comes to rest: its rest shape, or for a free body under gravity the
    /// shape it last came to rest in on its supports.
    equilibrium: Vec<Vec3>,
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
    /// Pressed by contacts in the last step (see [`LeveledModel::set_held`]).
    held: bool,
    /// The cage's equilibrium is a resting shape, not its rest shape.
    rebased: bool,
    /// Made by a cut under gravity (see [`LeveledModel::start_precise`]): the cage keeps the
    /// shape the body comes to rest in, as for a free body.
    rests_loaded: bool,
    asleep: bool,
    switches: u64,
    last_switch: Option<SwitchRecord>,
    residual: f64,
    shadow: Option<Box<Precise>>,
    shadow_error: Option<ShadowError>,
    /// The cage level's contact dent (see the `contact` module).
    dent: contact::ContactDent,
    /// See [`LeveledModel::set_precise_cg_must_converge`].
    cg_must_converge: bool,
    // Workspaces of the transfers.
    nodes_work: Vec<Vec3>,
    nodes_work2: Vec<Vec3>,
    cage_work: Vec<Vec3>,
    terms_work: Vec<Vec3>,
    rate_work: Vec<Vec3>,
    surface_work: Vec<Vec3>,
}

impl std::fmt::Debug for LeveledModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LeveledModel")
            .field("nodes", &self.rest.len())
            .field("level", &self.level)
            .field("method", &self.settings.precise)
            .field("switches", &self.switches)
            .finish()
    }
}

/// Most iterations of a cage fit to convergence (Anderson-accelerated; a warm-started fit
/// takes a few).
const MAX_FIT_ITERATIONS: u32 = 100;

/// A fit has converged when no cage vertex moves by more than this fraction of the body's
/// smallest dimension (positions) or of that dimension per time step (velocities).
const FIT_TOLERANCE: f64 = 1e-10;

impl LeveledModel {
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
        Ok(LeveledModel {
            smallest: mesh.bbox().smallest_dimension(),
            rest: nodes.to_vec(),
            precise,
            fit,
            fit_cage: cage.cage_positions().to_vec(),
            fit_velocity: vec![Vec3::zeros(); nv],
            last_fit: FitReport::default(),
            equilibrium: cage.cage().vertices().to_vec(),
            lowered_rotation: UnitQuaternion::identity(),
            level: Level::Cage,
            pin: None,
            steps: 0,
            steps_at_level: 0,
            rest_count: 0,
            slow_steps: 0,
            held: false,
            rebased: false,
            rests_loaded: false,
            asleep: true,
            switches: 0,
            last_switch: None,
            residual: 0.0,
            shadow: None,
            cg_must_converge: false,
            shadow_error: None,
            dent: Default::default(),
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
            .zip(&self.equilibrium)
            .all(|(x, r)| (x - r).norm() < eps);
        let pending = msd.external_forces().iter().any(|f| *f != Vec3::zeros());
        if near && !pending && msd.max_speed() < eps {
            self.cage_work.copy_from_slice(&self.equilibrium);
            let msd = self.cage.msd_mut();
            msd.positions_mut().copy_from_slice(&self.cage_work);
            msd.velocities_mut().fill(Vec3::zeros());
            self.cage.update_points()?;
            self.asleep = true;
        }
        Ok(())
    }

    /// Whether the body is free (no fixed components, no anchors): under gravity it finds its
    /// rest on what supports it in the world (obstacles, other bodies), not alone.
    pub fn is_free(&self) -> bool {
        let n = self.precise.model().nodes();
        n.fixed.iter().all(|f| !f.iter().any(|&a| a)) && n.anchor_k.iter().all(|&k| k == 0.0)
    }

    /// A free body under gravity: it starts, and starts again after a reset, at its precise
    /// level (its cage level has no gravity: it holds the shape the body last came to rest
    /// in).
    pub fn falls(&self) -> bool {
        self.is_free() && self.settings.gravity.norm() > 0.0
    }

    /// Tells the body whether contacts pressed it in the last step (its supports, or
    /// neighbours resting against it): at rest it then drops to its cage whatever the cage's
    /// fit, the cage keeping the pressed shape as its equilibrium and what it misses of it as
    /// a detail (no jump), as a free body on its supports does. Two organs whose meshes
    /// overlap at rest push each other into shapes a box cage cannot reproduce, and would
    /// otherwise stay precise for ever. The world sets it each step.
    pub fn set_held(&mut self, held: bool) {
        self.held = held;
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

    /// Smallest bounding-box dimension of the rest mesh.
    pub fn smallest_dimension(&self) -> f64 {
        self.smallest
    }

    /// The cage body.
    pub fn cage(&self) -> &CageModel {
        &self.cage
    }

    /// The cage body, mutable (for example to set cage velocities; call
    /// [`CageModel::update_points`] after moving cage vertices).
    pub fn cage_mut(&mut self) -> &mut CageModel {
        self.asleep = false;
        &mut self.cage
    }

    /// The precise body's nodal state.
    pub fn precise(&self) -> &dyn NodalModel {
        self.precise.model()
    }

    /// The precise body's nodal state, mutable (positions, velocities, forces). Setting
    /// positions far from the last step's on a corotational FEM body should be followed by
    /// [`FemBody::sync_rotations`] (the next switch up does it).
    pub fn precise_mut(&mut self) -> &mut dyn NodalModel {
        self.precise.model_mut()
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

    /// See [`LeveledModel::set_precise_cg_must_converge`].
    pub fn cg_must_converge(&self) -> bool {
        self.cg_must_converge
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
            Level::Precise => self.precise.model().positions(),
        }
    }

    /// Current position of surface vertex `k` (index into [`LeveledModel::surface_vertices`]).
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
            Level::Precise => self.precise.model_mut().add_force(node, force),
        }
        Ok(())
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
            let old = self.precise.model();
            let new = next.model_mut();
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
            let slow = self.precise.model().max_speed() <= p.rest_speed * self.smallest;
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
                    let residual = self.fit_cage(MAX_FIT_ITERATIONS, fit::STEP_NEWTON_STEPS)?;
                    self.residual = residual;
                    // A free body at rest on its supports keeps what its cage misses as a
                    // detail (see `lower_fitted`): it may drop whatever the residual.
                    if residual <= p.rest_residual * self.smallest
                        || self.falls()
                        || self.held
                        || self.rests_loaded
                    {
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
                    // Not while a contact dents it: the loads that hold its cage are on.
                    if self.cage.dent().is_none() {
                        self.try_sleep()?;
                    }
                    self.step_shadow()?;
                }
            }
            Level::Precise => self.precise.step()?,
        }
        if self.renew_dent() {
            self.cage.update_points()?;
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
        if self.settings.gravity.norm() == 0.0 || self.is_free() {
            // Nothing to settle against alone (a free body comes to rest on its supports in
            // the world).
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
            if self.precise.model().max_speed() <= 0.1 * p.rest_speed * self.smallest {
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
        let settled = self.precise.model().positions().to_vec();
        let cage = build_cage(mesh, &settled, &self.settings, &self.precise)?;
        self.install_cage(cage)?;
        self.level = Level::Cage;
        self.pin = pin;
        self.reset()?;
        Ok((steps, rested))
    }

    /// Back to the initial state: cage level, at rest, in the rest shape (the settled shape
    /// after [`LeveledModel::settle`]; the cage's rest shape too), counters cleared; the pin is
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
        self.cage.rebase_equilibrium(false);
        self.cage.set_detail(None)?;
        self.equilibrium.copy_from_slice(&rest_cage);
        self.cage.update_points()?;
        self.level = Level::Cage;
        self.steps = 0;
        self.steps_at_level = 0;
        self.rest_count = 0;
        self.slow_steps = 0;
        self.held = false;
        self.rebased = false;
        self.asleep = true;
        self.switches = 0;
        self.last_switch = None;
        self.residual = 0.0;
        self.lowered_rotation = UnitQuaternion::identity();
        if self.pin == Some(Level::Precise) {
            self.pin = None;
            self.raise()?;
            self.pin = Some(Level::Precise);
        } else if self.falls() && self.pin.is_none() {
            self.raise()?;
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

/// `out = x + h u`: the cage moved along its velocities, for central differences.
fn shifted(x: &[Vec3], u: &[Vec3], h: f64, out: &mut [Vec3]) {
    for (o, (xi, ui)) in out.iter_mut().zip(x.iter().zip(u)) {
        *o = xi + ui * h;
    }
}

fn _assert_send_sync() {
    fn check<T: Send + Sync>() {}
    check::<LeveledModel>();
}
