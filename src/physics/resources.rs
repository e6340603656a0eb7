//! The simulation's settings, clock, thread pool and status.

use super::*;
use soft_tissue_core::mesh::cut::CutOptions;

/// Settings of the simulation.
#[derive(Resource, Clone, Copy, Debug)]
pub struct SoftTissueConfig {
    /// Simulation step, s. `None` (the default): the app's fixed timestep (`Time<Fixed>`,
    /// 1/64 s unless the app sets it). Every run of the host schedule advances the
    /// simulation by the host's elapsed time (times [`SoftPhysics::speed`]) in steps of
    /// this size, so a body steps at it whatever the host schedule's rate; a body whose
    /// method needs a smaller step (an explicit MSD) substeps inside it. Changing the step
    /// builds every body again.
    pub dt: Option<f64>,
    /// Most steps one run of the host schedule takes; elapsed time beyond them is dropped
    /// (default 4), so a slow frame cannot snowball.
    pub max_steps_per_run: u32,
    /// Set `Time<Fixed>` to [`SoftTissueConfig::dt`] (default off: the plugin leaves the
    /// app's fixed timestep alone). With it, the default `FixedUpdate` runs exactly one
    /// step per fixed run.
    pub drive_fixed_timestep: bool,
    /// Gravity on the precise level, scene units / s^2 (default none; double precision, as
    /// the simulation). Read when a body is built: a change builds every body again.
    pub gravity: bevy::math::DVec3,
    /// Contact settings (thickness, search radius, margins, scene units; default for bodies
    /// about 1 unit across).
    pub contact: ContactConfig,
    /// Threads the solver stage runs on: 0 (the default) every available core, 1 the
    /// schedule's own thread. Independent bodies step side by side and large bodies split
    /// their element loop; the result is bit-identical for every count. Changing it takes
    /// effect at the next step (a new pool is started).
    pub threads: usize,
    /// How blades cut (default: [`CutOptions::default`] prepared on a thread of its own
    /// over [`DEFAULT_CUT_BACKGROUND_STEPS`] steps, so a cut costs no step the time of the
    /// mesh change and the new solvers; see
    /// [`CutOptions::background_steps`]).
    pub cut: CutOptions,
}

/// Steps a cut is prepared for in the background by default (at the default 1/64 s step,
/// 47 ms after the blade crossed the tissue it opens).
pub const DEFAULT_CUT_BACKGROUND_STEPS: u32 = 3;

impl Default for SoftTissueConfig {
    fn default() -> Self {
        SoftTissueConfig {
            dt: None,
            max_steps_per_run: 4,
            drive_fixed_timestep: false,
            gravity: bevy::math::DVec3::ZERO,
            contact: ContactConfig::for_scale(1.0),
            threads: 0,
            cut: CutOptions {
                background_steps: DEFAULT_CUT_BACKGROUND_STEPS,
                ..CutOptions::default()
            },
        }
    }
}

/// The simulation's clock, `Time<SoftPhysics>`: its elapsed time is simulated time (it
/// advances by one step per step), its context the speed and the time not yet stepped.
#[derive(Clone, Copy, Debug)]
pub struct SoftPhysics {
    /// Simulated seconds per host second (default 1; 0.5 is slow motion).
    pub speed: f64,
    /// Host time not yet stepped, s.
    pub(super) pending: f64,
}

impl Default for SoftPhysics {
    fn default() -> Self {
        SoftPhysics {
            speed: 1.0,
            pending: 0.0,
        }
    }
}

/// The thread pool of the solver stage, and the [`SoftTissueConfig::threads`] it was
/// started for.
#[derive(Resource, Debug, Default)]
pub struct SoftTissueThreads {
    pub(super) threads: Option<(usize, soft_tissue_core::parallel::Threads)>,
}

impl SoftTissueThreads {
    /// Threads in use (1 before the first step).
    pub fn count(&self) -> usize {
        self.threads.as_ref().map_or(1, |(_, t)| t.count())
    }
}

/// State of the simulation as a whole: pause, single step, counters, stage times and the
/// last error.
#[derive(Resource, Clone, Debug)]
pub struct SoftTissueStatus {
    /// No steps run while set (bodies and tools keep their state).
    pub paused: bool,
    /// Runs exactly one step while paused, then clears itself.
    pub step_once: bool,
    /// Steps run so far.
    pub steps: u64,
    /// The step in use, s (resolved from [`SoftTissueConfig::dt`] at the first step).
    pub dt: Option<f64>,
    /// Wall time of each stage of the last step (this machine).
    pub times: StageTimes,
    /// Stage times of the last [`STAGE_WINDOW`] steps: their median, 99th percentile and
    /// largest on request ([`StageRecorder::summary`]), as the inspector shows them.
    pub recent: StageRecorder,
    /// The error of the step that failed (a solver that failed, a NaN caught), if one did.
    /// The stages after the failing one do not run, the failing one leaves the bodies as it
    /// found them (see [`soft_tissue_core::world::SoftTissueWorld::step_fixed`]), no
    /// non-finite position reaches a mesh, and the simulation pauses. No step runs while it
    /// is set: a [`ResetSimulation`] clears it, or set it to `None` (and unpause) to carry on
    /// from the state the failed step left.
    pub error: Option<SoftTissueError>,
}

/// The part of a step that failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SoftTissueStage {
    /// The step itself (its time step).
    Step,
    /// A [`crate::ResetSimulation`].
    Reset,
    /// Applying the components' changes before the step ([`SoftTissueSystems::Prepare`]).
    Prepare,
    /// Cutting the bodies a blade's incision crosses (in [`SoftTissueSystems::Prepare`]).
    Cut,
    /// Raising and lowering bodies ([`SoftTissueSystems::SwitchPrecision`]).
    SwitchPrecision,
    /// The solvers' free step ([`SoftTissueSystems::StepSolvers`]).
    StepSolvers,
    /// The contact solve ([`SoftTissueSystems::Collide`]).
    Collide,
    /// Writing positions back to meshes ([`SoftTissueSystems::Writeback`]).
    Writeback,
}

/// Why a step failed: the stage, what it was doing, the body or tool when one is to blame,
/// and the core's message.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{what}{}: {message}", body.map(|e| format!(" ({e})")).unwrap_or_default())]
pub struct SoftTissueError {
    /// The stage that failed.
    pub stage: SoftTissueStage,
    /// What it was doing (`stepping the solvers`, `changing the material`, …).
    pub what: &'static str,
    /// The body the error names, if it names one.
    pub body: Option<Entity>,
    /// What went wrong.
    pub message: String,
}

/// Steps [`SoftTissueStatus::recent`] keeps.
pub const STAGE_WINDOW: usize = 1000;

impl Default for SoftTissueStatus {
    fn default() -> Self {
        SoftTissueStatus {
            paused: false,
            step_once: false,
            steps: 0,
            dt: None,
            times: StageTimes::default(),
            recent: StageRecorder::windowed(STAGE_WINDOW),
            error: None,
        }
    }
}

impl SoftTissueStatus {
    pub(super) fn running(&self) -> bool {
        (!self.paused || self.step_once) && self.error.is_none()
    }

    /// Whether a step stopped on an error (see [`SoftTissueStatus::error`]).
    pub fn failed(&self) -> bool {
        self.error.is_some()
    }
}

/// The core obstacles of the [`SoftObstacle`] entities, built again when one changes.
#[derive(Resource, Default)]
pub struct SoftTissueObstacles {
    pub(crate) obstacles: Vec<Obstacle>,
    pub(crate) entities: Vec<Entity>,
}

impl SoftTissueObstacles {
    /// The core obstacles, in the order the contact solve indexes them.
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    /// The entity of the core's obstacle index `index`.
    pub fn entity(&self, index: u32) -> Option<Entity> {
        self.entities.get(index as usize).copied()
    }
}

/// The build order the next body gets (bodies are stepped in build order; a cut's pieces
/// come after every body built before them).
#[derive(Resource, Default, Debug)]
pub(crate) struct NextBodyOrder(pub(crate) u64);

/// Cuts being prepared on threads of their own, in the order they began.
#[derive(Resource, Default, Debug)]
pub(crate) struct CutJobs(pub(crate) Vec<PendingCut>);

/// A cut being prepared: the body's entity, the blade's and its incision's, the incision's
/// mark of the strips it cuts with, and the step it lands in.
#[derive(Debug)]
pub(crate) struct PendingCut {
    pub(crate) body: Entity,
    pub(crate) blade: Entity,
    pub(crate) incision: u64,
    pub(crate) mark: u64,
    pub(crate) due: u64,
    pub(crate) job: soft_tissue_core::world::CutJob,
    /// Balls of vaporized tissue it carves out (none: a blade's cut; for a carve its blade
    /// is a placeholder).
    pub(crate) vaporized: Vec<soft_tissue_core::mesh::cut::Ball>,
}
