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
    ContactState, StageTimes, WorldBody, WorldError, detect_contacts, prepare, solve_contacts,
    step_solvers, switch_precision,
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
                    cut_stage,
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
        app.add_systems(PreUpdate, drive_fixed_timestep);
    }
}

/// The step a run uses: the configured one, or the app's fixed timestep.
fn resolved_dt(world: &World) -> f64 {
    let config = world.resource::<SoftTissueConfig>();
    config.dt.unwrap_or_else(|| {
        world
            .get_resource::<Time<Fixed>>()
            .map_or(1.0 / 64.0, |t| t.timestep().as_secs_f64())
    })
}

/// Runs the simulation steps the host's elapsed time asks for ([`SoftTissueSchedule`] once
/// per step), or one while paused with `step_once`.
fn run_steps(world: &mut World) {
    let dt = resolved_dt(world);
    let host = world.resource::<Time>().delta_secs_f64();
    let max_steps = world.resource::<SoftTissueConfig>().max_steps_per_run;
    let mut status = world.resource_mut::<SoftTissueStatus>();
    if !(dt.is_finite() && dt > 0.0) {
        if status.error.is_none() {
            fail(
                &mut status,
                SoftTissueError {
                    stage: SoftTissueStage::Step,
                    what: "the step",
                    body: None,
                    message: format!("the step must be positive and finite, found {dt} s"),
                },
            );
        }
        return;
    }
    status.dt = Some(dt);
    if !status.running() {
        return;
    }
    let steps = if status.paused {
        1
    } else {
        let mut clock = world.resource_mut::<Time<SoftPhysics>>();
        let c = clock.context_mut();
        let pending = c.pending + host * c.speed.max(0.0);
        // A step is due when its time has come, to rounding.
        let due = ((pending + 1e-9 * dt) / dt).floor().max(0.0) as u64;
        let steps = due.min(u64::from(max_steps));
        c.pending = if steps < due {
            0.0
        } else {
            (pending - steps as f64 * dt).max(0.0)
        };
        steps
    };
    for _ in 0..steps {
        world.run_schedule(SoftTissueSchedule);
        world
            .resource_mut::<Time<SoftPhysics>>()
            .advance_by(std::time::Duration::from_secs_f64(dt));
        if world.resource::<SoftTissueStatus>().error.is_some() {
            break;
        }
    }
}

/// Sets `Time<Fixed>` to the configured step when [`SoftTissueConfig::drive_fixed_timestep`]
/// asks for it.
fn drive_fixed_timestep(config: Res<SoftTissueConfig>, time: Option<ResMut<Time<Fixed>>>) {
    let (Some(dt), true, Some(mut time)) = (config.dt, config.drive_fixed_timestep, time) else {
        return;
    };
    let want = std::time::Duration::from_secs_f64(dt);
    if dt > 0.0 && dt.is_finite() && time.timestep() != want {
        time.set_timestep(want);
    }
}

fn fail(status: &mut SoftTissueStatus, error: SoftTissueError) {
    error!("soft tissue: {error}; the simulation is paused");
    status.error = Some(error);
    status.paused = true;
    status.step_once = false;
}

/// A stage's error about `body` (or the whole step).
fn stage_error(
    stage: SoftTissueStage,
    what: &'static str,
    body: Option<Entity>,
    message: impl ToString,
) -> SoftTissueError {
    SoftTissueError {
        stage,
        what,
        body,
        message: message.to_string(),
    }
}
