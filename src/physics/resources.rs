//! The simulation's settings, clock, thread pool and status.

use super::*;
use soft_tissue_core::mesh::cut::CutOptions;

/// Settings of the simulation. Time (pause, speed, the step) is not here: it is the clock
/// `Time<`[`SoftPhysics`]`>`, which steps at the app's fixed timestep.
#[derive(Resource, Clone, Copy, Debug)]
pub struct SoftTissueConfig {
    /// Most steps one run of the host schedule takes (default 4): at a speed above 1 a run
    /// owes several, and a slow frame run outside `FixedUpdate` cannot snowball; steps owed
    /// beyond it are dropped.
    pub max_steps_per_run: u32,
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
            max_steps_per_run: 4,
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

/// The simulation's clock, `Time<SoftPhysics>` (a resource the plugin inserts): the one
/// owner of pause, speed and the step, as Avian's `Time<Physics>` is.
///
/// - **The step** is the app's fixed timestep (`Time<Fixed>`, 1/64 s unless the app sets
///   it; a scene root sets it to its scene's): the simulation runs in `FixedUpdate`, one
///   step per fixed run at speed 1. [`SoftPhysicsTime::timestep`] reads the step in use.
///   Changing the fixed timestep builds every body again (a step length is factored into
///   the implicit solvers).
/// - **Pause**: [`SoftPhysicsTime::pause`], [`SoftPhysicsTime::unpause`],
///   [`SoftPhysicsTime::is_paused`]; [`SoftPhysicsTime::step_once`] runs one step while
///   paused. A step that fails pauses the clock (see [`SoftTissueStatus::error`]).
/// - **Speed** ([`SoftPhysicsTime::relative_speed`], default 1): simulated seconds per
///   second of the host schedule's clock. Avian scales the step's length by it; here a step
///   length is factored into the precise solvers, so the speed scales how many steps run:
///   each fixed run owes `speed` steps (0.5: one step every second run, 2: two per run, at
///   most [`SoftTissueConfig::max_steps_per_run`]), and the step stays the fixed timestep.
///
/// Its elapsed time is simulated time (it advances by one step per step) and its delta the
/// step. While [`SoftTissueSchedule`] runs, the generic `Time` resource is this clock (as
/// Avian does for its schedule), so a system added there reads the step from `Res<Time>`.
#[derive(Clone, Copy, Debug, Reflect)]
pub struct SoftPhysics {
    paused: bool,
    relative_speed: f64,
    /// Steps owed and not yet run (a fraction at speeds other than 1).
    owed: f64,
    /// Steps asked for by [`SoftPhysicsTime::step_once`] while paused.
    queued: u32,
    /// The step in use: the fixed timestep at the last run.
    timestep: std::time::Duration,
}

impl Default for SoftPhysics {
    fn default() -> Self {
        SoftPhysics {
            paused: false,
            relative_speed: 1.0,
            owed: 0.0,
            queued: 0,
            timestep: Time::<Fixed>::default().timestep(),
        }
    }
}

/// A speed the clock refused (negative or not finite).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("relative speed must be finite and >= 0, found {0}")]
pub struct BadSpeed(pub f64);

/// Pause, speed and the step of `Time<`[`SoftPhysics`]`>` (the names of Avian's
/// `PhysicsTime`).
pub trait SoftPhysicsTime: Sized {
    /// Simulated seconds per second of the host schedule's clock (default 1).
    fn relative_speed(&self) -> f64;
    /// Sets the relative speed (0 holds the simulation as a pause does; a negative or
    /// non-finite value is refused and the speed kept).
    fn set_relative_speed(&mut self, ratio: f64) -> Result<(), BadSpeed>;
    /// The clock with another relative speed (see [`SoftPhysicsTime::set_relative_speed`]).
    fn with_relative_speed(self, ratio: f64) -> Result<Self, BadSpeed>;
    /// Whether the simulation is paused.
    fn is_paused(&self) -> bool;
    /// Stops the simulation: no step runs (bodies and tools keep their state).
    fn pause(&mut self);
    /// Lets the simulation run again.
    fn unpause(&mut self);
    /// While paused, runs one more step at the next run of the host schedule (ignored while
    /// running).
    fn step_once(&mut self);
    /// The length of a step: the app's fixed timestep as of the last run (its default,
    /// 1/64 s, before the first).
    fn timestep(&self) -> std::time::Duration;
}

impl SoftPhysicsTime for Time<SoftPhysics> {
    fn relative_speed(&self) -> f64 {
        self.context().relative_speed
    }

    fn set_relative_speed(&mut self, ratio: f64) -> Result<(), BadSpeed> {
        if !(ratio.is_finite() && ratio >= 0.0) {
            return Err(BadSpeed(ratio));
        }
        self.context_mut().relative_speed = ratio;
        Ok(())
    }

    fn with_relative_speed(mut self, ratio: f64) -> Result<Self, BadSpeed> {
        self.set_relative_speed(ratio)?;
        Ok(self)
    }

    fn is_paused(&self) -> bool {
        self.context().paused
    }

    fn pause(&mut self) {
        self.context_mut().paused = true;
    }

    fn unpause(&mut self) {
        let c = self.context_mut();
        c.paused = false;
        c.queued = 0;
    }

    fn step_once(&mut self) {
        let c = self.context_mut();
        if c.paused {
            c.queued = c.queued.saturating_add(1);
        }
    }

    fn timestep(&self) -> std::time::Duration {
        self.context().timestep
    }
}

impl SoftPhysics {
    /// The steps a run of the host schedule runs, its clock having advanced `host`, at most
    /// `max`; the fixed timestep `step` becomes the step in use.
    pub(super) fn steps_due(
        &mut self,
        host: std::time::Duration,
        step: std::time::Duration,
        max: u32,
    ) -> u32 {
        self.timestep = step;
        if self.paused {
            let n = self.queued.min(max);
            self.queued -= n;
            return n;
        }
        // In `FixedUpdate` the host's time is the step: `speed` steps owed per run.
        self.owed += host.as_secs_f64() / step.as_secs_f64() * self.relative_speed;
        // A step is due when its time has come, to rounding.
        let due = (self.owed + 1e-9).floor().max(0.0);
        let n = due.min(f64::from(max));
        // Steps owed beyond the cap are dropped (a slow frame does not snowball).
        self.owed = if n < due {
            0.0
        } else {
            (self.owed - n).max(0.0)
        };
        n as u32
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

/// State of the simulation as a whole: counters, stage times and the last error (pause and
/// the step are the clock's, `Time<`[`SoftPhysics`]`>`).
#[derive(Resource, Clone, Debug)]
pub struct SoftTissueStatus {
    /// Steps run so far.
    pub steps: u64,
    /// Wall time of each stage of the last step (this machine).
    pub times: StageTimes,
    /// Stage times of the last [`STAGE_WINDOW`] steps: their median, 99th percentile and
    /// largest on request ([`StageRecorder::summary`]), as the inspector shows them.
    pub recent: StageRecorder,
    /// The error of the step that failed (a solver that failed, a NaN caught), if one did.
    /// The stages after the failing one do not run, the failing one leaves the bodies as it
    /// found them (see [`soft_tissue_core::world::SoftTissueWorld::step_fixed`]), no
    /// non-finite position reaches a mesh, and the clock pauses. No step runs while it is
    /// set: a [`ResetSimulation`] clears it, or set it to `None` (and unpause the clock) to
    /// carry on from the state the failed step left.
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
/// and the error itself, typed: the core's (`WorldError`, `ContactError`, `PrecisionError`,
/// `CutError`, ...) or the plugin's own ([`SoftTissueStepError`]), found with
/// [`SoftTissueError::downcast_ref`] and matched on like any error of that type.
///
/// Its display ends with that error's, so [`std::error::Error::source`] goes on from that
/// error's own source (a chain printed in full shows each message once).
#[derive(Clone, Debug)]
pub struct SoftTissueError {
    /// The stage that failed.
    pub stage: SoftTissueStage,
    /// What it was doing (`stepping the solvers`, `changing the material`, …).
    pub what: &'static str,
    /// The body (or tool, obstacle) the error names, if it names one.
    pub body: Option<Entity>,
    /// What went wrong (shared, so the status stays `Clone`).
    pub error: Arc<dyn std::error::Error + Send + Sync + 'static>,
}

impl SoftTissueError {
    /// The error that failed the step as `E`, if it is one (`WorldError`, `ContactError`,
    /// [`SoftTissueStepError`], ...).
    pub fn downcast_ref<E: std::error::Error + 'static>(&self) -> Option<&E> {
        self.error.downcast_ref::<E>()
    }
}

impl std::fmt::Display for SoftTissueError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.what)?;
        if let Some(e) = self.body {
            write!(f, " ({e})")?;
        }
        write!(f, ": {}", self.error)
    }
}

impl std::error::Error for SoftTissueError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.error.source()
    }
}

/// What the plugin itself refuses in a step (the core's errors come as they are).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SoftTissueStepError {
    /// `Time<Fixed>`'s timestep is zero: no step can be taken.
    #[error("the fixed timestep is 0 s")]
    ZeroTimestep,
    /// The thread pool could not be built; the steps go on on one thread.
    #[error("{0}; stepping on one thread")]
    ThreadPool(soft_tissue_core::parallel::ThreadsError),
}

/// Steps [`SoftTissueStatus::recent`] keeps.
pub const STAGE_WINDOW: usize = 1000;

impl Default for SoftTissueStatus {
    fn default() -> Self {
        SoftTissueStatus {
            steps: 0,
            times: StageTimes::default(),
            recent: StageRecorder::windowed(STAGE_WINDOW),
            error: None,
        }
    }
}

impl SoftTissueStatus {
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
