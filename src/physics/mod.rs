//! The simulation plugin: resources, the chained system sets of a step and the thin systems
//! that hand the bodies' core state to the core's stage functions
//! ([`soft_tissue_core::world`]): the plugin keeps no second world.

use std::sync::Arc;
use std::time::Instant;

use bevy::ecs::schedule::{InternedScheduleLabel, ScheduleLabel, SingleThreadedExecutor};
use bevy::prelude::*;
use bevy::transform::helper::TransformHelper;
use smallvec::SmallVec;
use soft_tissue_core::contact::{ContactConfig, Obstacle, Tool, ToolShape};
use soft_tissue_core::heat::HeatBoundary;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::precision::{BodySettings, Level};
use soft_tissue_core::timing::StageRecorder;
use soft_tissue_core::world::{
    ContactState, StageTimes, WorldBody, WorldError, cutting_resistance, detect_contacts,
    load_cutting, prepare, solve_contacts, step_solvers, switch_precision,
};

use crate::assets::TetMeshAsset;
use crate::components::*;
use crate::convert::{to_bevy, to_core};
use crate::messages::{BodyTouched, LevelChanged};

mod build;
mod contacts;
mod cut;
mod resources;
mod stages;

pub(crate) use build::BuiltFrom;
pub use build::SoftBodyError;
use build::*;
pub use contacts::{ContactPartner, SoftContact, SoftTissueContacts};
use cut::*;
pub use resources::*;
use stages::*;

/// The stages of a step, chained in this order in [`SoftTissueSchedule`]. `First` and `Last`
/// are empty hooks; order your systems against these sets (in [`SoftTissueSchedule`]).
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SoftTissueSystems {
    /// Before anything of the step.
    First,
    /// New bodies and tools are built, run-time changes applied, tool poses read, surfaces
    /// gathered.
    Prepare,
    /// Broad and narrow phase; touched bodies marked.
    DetectContact,
    /// Touched bodies rise to their precise method.
    SwitchPrecision,
    /// Heat and every body's level step.
    StepSolvers,
    /// The contact problem of all touching bodies, tools and obstacles after the free
    /// motion, each body's correction, grips, the forces on the tools.
    Collide,
    /// Surface positions, read-out components and messages.
    Writeback,
    /// After everything of the step.
    Last,
}

/// The schedule one simulation step runs in: the chained [`SoftTissueSystems`] sets and
/// their systems. The host schedule (`FixedUpdate` by default) runs it once per run, from the
/// system in [`SoftTissueStep`]. Its stages are one chain, so it runs on a single-threaded
/// executor: handing each stage to the task pool cost more than the physics of a resting
/// scene (on a 2-core machine, about 130 us per step of thread hand-offs against a median
/// physics step of about 25 us on the organs scene).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SoftTissueSchedule;

/// The set, in the host schedule, of the system that runs [`SoftTissueSchedule`]: order your
/// host-schedule systems against the whole step with it.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SoftTissueStep;

/// Asks for every body and tool to go back to its initial state at the next step.
#[derive(Message, Clone, Copy, Debug, Default)]
pub struct ResetSimulation;

/// The simulation: resources, messages, [`SoftTissueSchedule`] with the step's system sets
/// and systems, run from `schedule` (the host schedule, `FixedUpdate` by default).
pub struct SoftTissuePhysicsPlugin {
    schedule: InternedScheduleLabel,
}

impl SoftTissuePhysicsPlugin {
    /// The plugin running its step from `schedule` (`FixedUpdate` by default).
    pub fn new(schedule: impl ScheduleLabel) -> Self {
        SoftTissuePhysicsPlugin {
            schedule: schedule.intern(),
        }
    }
}

impl Default for SoftTissuePhysicsPlugin {
    fn default() -> Self {
        Self::new(FixedUpdate)
    }
}

impl Plugin for SoftTissuePhysicsPlugin {
    fn build(&self, app: &mut App) {
        use SoftTissueSystems as S;
        app.init_resource::<SoftTissueConfig>()
            .init_resource::<SoftTissueThreads>()
            .init_resource::<SoftTissueStatus>()
            .init_resource::<SoftTissueContacts>()
            .init_resource::<SoftTissueObstacles>()
            .init_resource::<NextBodyOrder>()
            .init_resource::<CutJobs>()
            .init_resource::<stages::CutLoads>()
            .insert_resource(Time::<SoftPhysics>::default())
            .add_message::<LevelChanged>()
            .add_message::<BodyTouched>()
            .add_message::<ResetSimulation>()
            .register_type::<SoftBody>()
            .register_type::<TissueMaterial>()
            .register_type::<TissueHeat>()
            .register_type::<SoftBodyTuning>()
            .register_type::<PrecisionLevel>()
            .register_type::<PinnedLevel>()
            .register_type::<GreenCage>()
            .register_type::<FemState>()
            .register_type::<MsdState>()
            .register_type::<Temperature>()
            .register_type::<SoftBodyDiagnostics>()
            .register_type::<ShadowSimulation>()
            .register_type::<SoftTool>()
            .register_type::<CutPiece>()
            .register_type::<CutShare>()
            .register_type::<ToolReaction>();
        let mut schedule = Schedule::new(SoftTissueSchedule);
        schedule.set_executor(SingleThreadedExecutor::new());
        app.add_schedule(schedule);
        app.configure_sets(
            SoftTissueSchedule,
            (
                S::First,
                S::Prepare,
                S::DetectContact,
                S::SwitchPrecision,
                S::StepSolvers,
                S::Collide,
                S::Writeback,
                S::Last,
            )
                .chain(),
        );
        // A stage that fails sets the status's error: the stages after it in this step do
        // not run (a set's condition is checked when the set is reached, after the stages
        // before it ran).
        let no_error = |s: Res<SoftTissueStatus>| s.error.is_none();
        for set in [
            S::DetectContact,
            S::SwitchPrecision,
            S::StepSolvers,
            S::Collide,
            S::Writeback,
        ] {
            app.configure_sets(SoftTissueSchedule, set.run_if(no_error));
        }
        app.add_systems(
            SoftTissueSchedule,
            (
                (
                    retry_failed_bodies,
                    build_bodies,
                    build_tools,
                    build_obstacles,
                    resistance_stage,
                    cut_stage,
                    cut_load_stage,
                    prepare_stage,
                )
                    .chain()
                    .in_set(S::Prepare),
                detect_stage.in_set(S::DetectContact),
                switch_stage.in_set(S::SwitchPrecision),
                solve_stage.in_set(S::StepSolvers),
                contact_stage.in_set(S::Collide),
                writeback_stage.in_set(S::Writeback),
            ),
        );
        app.add_systems(
            self.schedule,
            (reset_simulation, run_steps.in_set(SoftTissueStep)).chain(),
        );
    }
}

/// Runs the simulation steps the clock owes ([`SoftTissueSchedule`] once per step): at
/// speed 1 in `FixedUpdate`, one per run; while paused, those `step_once` asked for.
fn run_steps(world: &mut World) {
    let step = world
        .get_resource::<Time<Fixed>>()
        .map_or_else(|| Time::<Fixed>::default().timestep(), |t| t.timestep());
    let host = world.resource::<Time>().delta();
    let max = world.resource::<SoftTissueConfig>().max_steps_per_run;
    if world.resource::<SoftTissueStatus>().error.is_some() {
        return;
    }
    if step.is_zero() {
        let mut status = world.resource_mut::<SoftTissueStatus>();
        fail(
            &mut status,
            stage_error(
                SoftTissueStage::Step,
                "the step",
                None,
                SoftTissueStepError::ZeroTimestep,
            ),
        );
        world.resource_mut::<Time<SoftPhysics>>().pause();
        return;
    }
    let steps = world
        .resource_mut::<Time<SoftPhysics>>()
        .context_mut()
        .steps_due(host, step, max);
    for _ in 0..steps {
        let mut clock = world.resource_mut::<Time<SoftPhysics>>();
        clock.advance_by(step);
        // The step's systems see the simulation's clock as the generic `Time`.
        let physics = clock.as_generic();
        let host_clock = std::mem::replace(&mut *world.resource_mut::<Time>(), physics);
        world.run_schedule(SoftTissueSchedule);
        *world.resource_mut::<Time>() = host_clock;
        if world.resource::<SoftTissueStatus>().error.is_some() {
            // A failed step pauses the simulation.
            world.resource_mut::<Time<SoftPhysics>>().pause();
            break;
        }
    }
}

/// Records a step's error (the stages after it in this step do not run, and the clock
/// pauses when the step ends).
fn fail(status: &mut SoftTissueStatus, error: SoftTissueError) {
    error!("soft tissue: {error}; the simulation is paused");
    status.error = Some(error);
}

/// A stage's error about `body` (or the whole step).
fn stage_error(
    stage: SoftTissueStage,
    what: &'static str,
    body: Option<Entity>,
    error: impl std::error::Error + Send + Sync + 'static,
) -> SoftTissueError {
    SoftTissueError {
        stage,
        what,
        body,
        error: Arc::new(error),
    }
}
