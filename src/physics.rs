//! The simulation plugin: resources, the chained system sets of a step and the thin systems
//! that hand the bodies' core state to the core's stage functions
//! ([`soft_tissue_core::world`]): the plugin keeps no second world.

use std::sync::Arc;
use std::time::Instant;

use bevy::ecs::schedule::{InternedScheduleLabel, ScheduleLabel, SingleThreadedExecutor};
use bevy::prelude::*;
use bevy::transform::helper::TransformHelper;
use smallvec::SmallVec;
use soft_tissue_core::contact::{ContactConfig, Tool};
use soft_tissue_core::heat::HeatBoundary;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::precision::{BodySettings, Level};
use soft_tissue_core::timing::StageRecorder;
use soft_tissue_core::world::{
    ContactState, SimBody, StageTimes, WorldError, collide, detect_contacts, prepare, step_solvers,
    switch_precision,
};

use crate::assets::TetMeshAsset;
use crate::components::*;
use crate::convert::{to_bevy, to_core};
use crate::messages::{BodyTouched, LevelChanged};

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
    /// Contact response, grips, tool reaction forces.
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
}

impl Default for SoftTissueConfig {
    fn default() -> Self {
        SoftTissueConfig {
            dt: None,
            max_steps_per_run: 4,
            drive_fixed_timestep: false,
            gravity: bevy::math::DVec3::ZERO,
            contact: ContactConfig::for_scale(1.0),
            threads: 0,
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
    pending: f64,
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
    threads: Option<(usize, soft_tissue_core::parallel::Threads)>,
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

/// Why a step failed: the stage, the body when one is to blame, and the core's message.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{stage}{}: {message}", body.map(|e| format!(" ({e})")).unwrap_or_default())]
pub struct SoftTissueError {
    /// The stage that failed (`stepping the solvers`, `collisions`, …).
    pub stage: &'static str,
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
    fn running(&self) -> bool {
        (!self.paused || self.step_once) && self.error.is_none()
    }

    /// Whether a step stopped on an error (see [`SoftTissueStatus::error`]).
    pub fn failed(&self) -> bool {
        self.error.is_some()
    }
}

/// Contacts of the last step, by entity ([`SoftTissueContacts::iter`]).
#[derive(Resource, Default)]
pub struct SoftTissueContacts {
    /// The core's contact state (bodies and tools by their index in `bodies` / `tools`).
    pub(crate) state: ContactState,
    /// The body entities in the order the core's stage functions see them.
    pub(crate) bodies: Vec<Entity>,
    /// The tool entities in that order.
    pub(crate) tools: Vec<Entity>,
    /// The contacts by pair.
    pairs: Vec<SoftContact>,
}

/// What a body touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ContactPartner {
    /// A tool entity ([`SoftTool`]).
    Tool(Entity),
    /// Another body's entity ([`SoftBody`]).
    Body(Entity),
}

/// The contacts between a body and one partner this step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftContact {
    /// The body (for two bodies: the one whose vertices were tested).
    pub body: Entity,
    /// What it touches.
    pub partner: ContactPartner,
    /// Contact points (tool: surface triangles under the tip; bodies: vertex-triangle
    /// pairs).
    pub points: u32,
    /// Deepest penetration at detection, scene units.
    pub max_depth: f64,
}

impl SoftTissueContacts {
    /// Every body-partner pair in contact this step.
    pub fn iter(&self) -> impl Iterator<Item = &SoftContact> {
        self.pairs.iter()
    }

    /// The contacts `entity` (a body or a tool) takes part in.
    pub fn involving(&self, entity: Entity) -> impl Iterator<Item = &SoftContact> {
        self.pairs.iter().filter(move |c| {
            c.body == entity
                || matches!(c.partner, ContactPartner::Tool(t) | ContactPartner::Body(t) if t == entity)
        })
    }

    /// The core's contact state, for drawing or analysis; map its indices with
    /// [`SoftTissueContacts::body_entity`] and [`SoftTissueContacts::tool_entity`].
    pub fn core(&self) -> &ContactState {
        &self.state
    }

    /// The entity of the core's body index `index`.
    pub fn body_entity(&self, index: u32) -> Option<Entity> {
        self.bodies.get(index as usize).copied()
    }

    /// The entity of the core's tool index `index`.
    pub fn tool_entity(&self, index: u32) -> Option<Entity> {
        self.tools.get(index as usize).copied()
    }

    /// The pairs gathered from the core's state.
    fn gather(&mut self) {
        self.pairs.clear();
        let mut add = |body: Option<Entity>, partner: Option<ContactPartner>, depth: f64| {
            let (Some(body), Some(partner)) = (body, partner) else {
                return;
            };
            match self
                .pairs
                .iter_mut()
                .find(|c| c.body == body && c.partner == partner)
            {
                Some(c) => {
                    c.points += 1;
                    c.max_depth = c.max_depth.max(depth);
                }
                None => self.pairs.push(SoftContact {
                    body,
                    partner,
                    points: 1,
                    max_depth: depth,
                }),
            }
        };
        for t in &self.state.tool_contacts {
            add(
                self.bodies.get(t.body as usize).copied(),
                self.tools
                    .get(t.tool as usize)
                    .copied()
                    .map(ContactPartner::Tool),
                t.depth,
            );
        }
        for b in &self.state.body_contacts {
            add(
                self.bodies.get(b.a as usize).copied(),
                self.bodies
                    .get(b.b as usize)
                    .copied()
                    .map(ContactPartner::Body),
                b.depth,
            );
        }
    }

    fn clear(&mut self) {
        self.state.clear();
        self.pairs.clear();
    }
}

/// Asks for every body and tool to go back to its initial state at the next step.
#[derive(Message, Clone, Copy, Debug, Default)]
pub struct ResetSimulation;

/// A body that could not be built, and why (the entity keeps its [`SoftBody`]; writing
/// any of its inputs tries again).
#[derive(Component, Debug, thiserror::Error)]
pub enum SoftBodyError {
    /// The mesh could not be placed at the entity's global transform.
    #[error("soft body `{body}`: placing its mesh: {message}")]
    Placement {
        /// The body's name (or entity).
        body: String,
        /// What is wrong.
        message: String,
    },
    /// A setting is out of range (the message names it).
    #[error("soft body `{body}`: {message}")]
    Settings {
        /// The body's name (or entity).
        body: String,
        /// What is wrong.
        message: String,
    },
    /// The core refused to build it (its error names the level and what failed).
    #[error(transparent)]
    Build(#[from] WorldError),
}

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
                    prepare_stage,
                )
                    .chain()
                    .in_set(S::Prepare),
                detect_stage.in_set(S::DetectContact),
                switch_stage.in_set(S::SwitchPrecision),
                solve_stage.in_set(S::StepSolvers),
                collide_stage.in_set(S::Collide),
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
                    stage: "the step",
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
    stage: &'static str,
    body: Option<Entity>,
    message: impl ToString,
) -> SoftTissueError {
    SoftTissueError {
        stage,
        body,
        message: message.to_string(),
    }
}

/// The body's mesh with `placement` applied (the same `Arc` when it is the identity).
fn placed(mesh: &Arc<TetMesh>, placement: &GlobalTransform) -> Result<Arc<TetMesh>, String> {
    if placement.affine() == bevy::math::Affine3A::IDENTITY {
        return Ok(mesh.clone());
    }
    let m = placement.to_matrix().as_dmat4();
    let positions = mesh
        .positions()
        .iter()
        .map(|p| {
            let q = m.transform_point3(bevy::math::DVec3::new(p.x, p.y, p.z));
            soft_tissue_core::Vec3::new(q.x, q.y, q.z)
        })
        .collect();
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    TetMesh::new(positions, tets)
        .map(Arc::new)
        .map_err(|e| e.to_string())
}

/// The core settings of a body from its components.
fn body_settings(
    spec: &SoftBody,
    material: &TissueMaterial,
    tuning: Option<&SoftBodyTuning>,
    mesh: &TetMesh,
    dt: f64,
    gravity: bevy::math::DVec3,
) -> Result<BodySettings, String> {
    spec.anchor.validate()?;
    let (msd, springs) = material.msd_params(mesh.node_count());
    let mut s = BodySettings::new(material.fem, msd, dt);
    s.precise = spec.method;
    s.msd_spring_stiffness = springs;
    s.cage = spec.cage;
    s.boundary = spec.anchor.boundary(mesh);
    s.gravity = soft_tissue_core::Vec3::new(gravity.x, gravity.y, gravity.z);
    if let Some(t) = tuning {
        s.fem_integrator = t.fem_integrator;
        s.cage_dynamics = t.cage_dynamics;
        s.cage_msd = t.cage_msd;
        s.policy = t.policy;
    }
    Ok(s)
}

/// What a built body was built from, beyond what changes in place (method, material,
/// heat, pin, shadow): a change of any of it builds the body again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BuiltFrom {
    mesh: AssetId<TetMeshAsset>,
    cage: soft_tissue_core::scenario::CageKind,
    anchor: soft_tissue_core::scenario::Anchor,
    tuning: Option<SoftBodyTuning>,
    dt: f64,
    gravity: bevy::math::DVec3,
}

/// Builds the simulation of every [`SoftBody`] whose mesh has loaded.
#[allow(clippy::type_complexity)]
fn build_bodies(
    mut commands: Commands,
    config: Res<SoftTissueConfig>,
    status: Res<SoftTissueStatus>,
    meshes: Res<Assets<TetMeshAsset>>,
    new: Query<
        (
            Entity,
            &SoftBody,
            &TissueMaterial,
            Option<&TissueHeat>,
            Option<&SoftBodyTuning>,
            Option<&Name>,
            Has<ShadowSimulation>,
            Option<&PinnedLevel>,
        ),
        (Without<SimulatedBody>, Without<SoftBodyError>),
    >,
    poses: TransformHelper,
    mut next: Local<u64>,
) {
    let Some(dt) = status.dt else {
        return;
    };
    for (entity, spec, material, heat, tuning, name, shadow, pin) in &new {
        let Some(asset) = meshes.get(&spec.mesh) else {
            continue;
        };
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        // Computed now, not the one propagated at the end of the last frame.
        let placement = poses.compute_global_transform(entity).unwrap_or_default();
        let result = (|| -> Result<SimBody, SoftBodyError> {
            let mesh =
                placed(&asset.0, &placement).map_err(|message| SoftBodyError::Placement {
                    body: name.clone(),
                    message,
                })?;
            let settings = body_settings(spec, material, tuning, &mesh, dt, config.gravity)
                .map_err(|message| SoftBodyError::Settings {
                    body: name.clone(),
                    message,
                })?;
            let heat = heat.map(|h| (h.0, HeatBoundary::insulated()));
            let mut body = SimBody::new(name.clone(), mesh, settings, heat)?;
            if shadow {
                body.set_shadow(true)?;
            }
            if let Some(p) = pin {
                body.body_mut()
                    .pin(Some(p.0))
                    .map_err(|e| SoftBodyError::Settings {
                        body: name.clone(),
                        message: format!("pinning: {e}"),
                    })?;
            }
            Ok(body)
        })();
        match result {
            Ok(body) => {
                let method = body.body().settings().precise;
                let mut e = commands.entity(entity);
                e.insert((
                    PrecisionLevel {
                        level: body.body().level(),
                        method,
                        switches: 0,
                        last_jump_ratio: None,
                    },
                    GreenCage::default(),
                    SoftBodyDiagnostics::default(),
                ));
                if method.is_fem() {
                    e.insert(FemState::default()).remove::<MsdState>();
                } else {
                    e.insert(MsdState::default()).remove::<FemState>();
                }
                if body.heat().is_some() {
                    e.insert(Temperature::default());
                } else {
                    e.remove::<Temperature>();
                }
                let to_local = (placement.affine() != bevy::math::Affine3A::IDENTITY)
                    .then(|| placement.affine().inverse());
                e.insert(SimulatedBody {
                    body,
                    order: *next,
                    dirty: true,
                    placement,
                    to_local,
                    built_from: BuiltFrom {
                        mesh: spec.mesh.id(),
                        cage: spec.cage,
                        anchor: spec.anchor,
                        tuning: tuning.copied(),
                        dt,
                        gravity: config.gravity,
                    },
                });
                *next += 1;
            }
            Err(error) => {
                error!("{error}; the body is not simulated");
                commands.entity(entity).insert(error);
            }
        }
    }
}

/// A body whose inputs changed after an error is tried again.
#[allow(clippy::type_complexity)]
fn retry_failed_bodies(
    mut commands: Commands,
    failed: Query<
        Entity,
        (
            With<SoftBodyError>,
            Or<(
                Changed<SoftBody>,
                Changed<TissueMaterial>,
                Changed<SoftBodyTuning>,
                Changed<Transform>,
            )>,
        ),
    >,
) {
    for e in &failed {
        commands.entity(e).remove::<SoftBodyError>();
    }
}

/// The pose of a tool entity now: position and axis (local +Y) in core vectors.
fn tool_pose(
    poses: &TransformHelper,
    entity: Entity,
) -> Option<(soft_tissue_core::Vec3, soft_tissue_core::Vec3)> {
    // Computed now, not the one propagated at the end of the last frame.
    let pose = poses.compute_global_transform(entity).ok()?;
    let (_, rotation, translation) = pose.to_scale_rotation_translation();
    Some((to_core(translation), to_core(rotation * Vec3::Y)))
}

fn build_tools(
    mut commands: Commands,
    new: Query<(Entity, &SoftTool, Option<&Name>), Without<ToolState>>,
    poses: TransformHelper,
    mut next: Local<u64>,
) {
    for (entity, spec, name) in &new {
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        // The tool starts where its entity is (not at the origin).
        let built = Tool::new(name.clone(), spec.shape).and_then(|mut t| {
            if let Some((p, a)) = tool_pose(&poses, entity) {
                t.set_pose(p, a)?;
            }
            Ok(t)
        });
        match built {
            Ok(tool) => {
                commands.entity(entity).insert(ToolState {
                    tool,
                    order: *next,
                    grabbing: false,
                });
                *next += 1;
            }
            Err(e) => {
                error!("tool `{name}` was not built: {e}");
                commands.entity(entity).despawn();
            }
        }
    }
}

/// A reset when asked for: every body and tool back to its initial state, counters and the
/// error cleared. Runs before the step, also while the simulation is paused or stopped by an
/// error.
fn reset_simulation(
    mut requests: MessageReader<ResetSimulation>,
    mut bodies: Query<(Entity, &mut SimulatedBody)>,
    mut tools: Query<&mut ToolState>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    if requests.read().count() == 0 {
        return;
    }
    status.steps = 0;
    status.error = None;
    status.recent.clear();
    for (e, mut b) in &mut bodies {
        if let Err(err) = b.body.reset() {
            fail(&mut status, stage_error("resetting", Some(e), err));
        }
        b.dirty = true;
    }
    for mut tool in &mut tools {
        tool.tool.reset();
        tool.grabbing = false;
    }
    contacts.clear();
}

/// Whether two placements are the same to rounding.
fn same_placement(a: &GlobalTransform, b: &GlobalTransform) -> bool {
    a.affine().abs_diff_eq(b.affine(), 1e-6)
}

/// The prepare stage: run-time changes of the bodies' inputs (those that need a new body
/// are queued for building again), tool poses and actions, then the core's `prepare`. One
/// system, so the step pays one system's dispatch for all of it.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
fn prepare_stage(
    mut commands: Commands,
    mut bodies: Query<(
        Entity,
        (
            Ref<SoftBody>,
            Ref<TissueMaterial>,
            Option<&TissueHeat>,
            Option<&SoftBodyTuning>,
            Option<&PinnedLevel>,
            Has<ShadowSimulation>,
        ),
        &mut SimulatedBody,
    )>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    poses: TransformHelper,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let dt = status.dt.unwrap_or_default();
    for (entity, (spec, material, heat, tuning, pin, shadow), mut sim) in &mut bodies {
        let now = BuiltFrom {
            mesh: spec.mesh.id(),
            cage: spec.cage,
            anchor: spec.anchor,
            tuning: tuning.copied(),
            dt,
            gravity: config.gravity,
        };
        // Computed from the transforms now (the entity's or a parent's may have been written
        // since the last propagation).
        let moved = poses
            .compute_global_transform(entity)
            .is_ok_and(|g| !same_placement(&g, &sim.placement));
        if now != sim.built_from || moved {
            // Built again at the next step, at rest, from the inputs then.
            commands.entity(entity).remove::<SimulatedBody>();
            continue;
        }
        let b = &mut sim.body;
        if spec.method != b.body().settings().precise {
            let mesh = b.mesh().clone();
            let was_fem = b.body().settings().precise.is_fem();
            match b.body_mut().set_precise_method(&mesh, spec.method) {
                // The state component follows the solver's kind.
                Ok(()) if was_fem != spec.method.is_fem() => {
                    let mut e = commands.entity(entity);
                    if spec.method.is_fem() {
                        e.insert(FemState::default()).remove::<MsdState>();
                    } else {
                        e.insert(MsdState::default()).remove::<FemState>();
                    }
                }
                Ok(()) => {}
                Err(e) => fail(
                    &mut status,
                    stage_error("changing the method", Some(entity), e),
                ),
            }
        }
        if material.is_changed() {
            let (msd, springs) = material.msd_params(b.mesh().node_count());
            if let Err(e) = b.set_materials(material.fem, msd, springs) {
                fail(
                    &mut status,
                    stage_error("changing the material", Some(entity), e),
                );
            }
        }
        let want_heat = heat.map(|h| h.0);
        if want_heat != b.heat().map(|h| *h.params()) {
            let had = b.heat().is_some();
            match b.set_heat(want_heat.map(|p| (p, HeatBoundary::insulated()))) {
                Ok(()) if want_heat.is_some() && !had => {
                    commands.entity(entity).insert(Temperature::default());
                }
                Ok(()) if want_heat.is_none() => {
                    commands.entity(entity).remove::<Temperature>();
                }
                Ok(()) => {}
                Err(e) => fail(
                    &mut status,
                    stage_error("changing the heat", Some(entity), e),
                ),
            }
            sim.dirty = true;
        }
        let b = &mut sim.body;
        let pinned: Option<Level> = pin.map(|p| p.0);
        if b.body().pinned() != pinned
            && let Err(e) = b.body_mut().pin(pinned)
        {
            fail(&mut status, stage_error("pinning", Some(entity), e));
        }
        if b.body().has_shadow() != shadow
            && let Err(e) = b.set_shadow(shadow)
        {
            fail(&mut status, stage_error("shadow", Some(entity), e));
        }
    }
    for (entity, spec, mut state) in &mut tools {
        let Some((position, axis)) = tool_pose(&poses, entity) else {
            continue;
        };
        let t = &mut state.tool;
        if let Err(e) = t.set_pose(position, axis) {
            fail(&mut status, stage_error("moving a tool", Some(entity), e));
            continue;
        }
        if let Err(e) = t.set_cautery(spec.cautery_watts) {
            fail(
                &mut status,
                stage_error("a tool's cautery", Some(entity), e),
            );
        }
        if spec.grab != state.grabbing {
            if spec.grab {
                state.tool.grab();
            } else {
                state.tool.release();
            }
            state.grabbing = spec.grab;
        }
    }
    let contacts = &mut *contacts;
    in_order(
        bodies.iter_mut().map(|(e, _, b)| (e, b)),
        tools.iter_mut().map(|(e, _, t)| (e, t)),
        Some((&mut contacts.bodies, &mut contacts.tools)),
        |b, tl| prepare(b, tl, dt),
    );
    status.times.prepare_us = lap(&mut t);
}

/// Runs `f` on the built bodies and the tools, each in build order, as the core's stage
/// functions take them (slices of `&mut`, so indices in the contact state stay valid).
/// With `entities`, writes the bodies' and tools' entities in that order.
fn in_order<'a, R>(
    bodies: impl Iterator<Item = (Entity, Mut<'a, SimulatedBody>)>,
    tools: impl Iterator<Item = (Entity, Mut<'a, ToolState>)>,
    entities: Option<(&mut Vec<Entity>, &mut Vec<Entity>)>,
    f: impl FnOnce(&mut [&mut SimBody], &mut [&mut Tool]) -> R,
) -> R {
    let mut b: SmallVec<[(Entity, &mut SimulatedBody); 16]> =
        bodies.map(|(e, b)| (e, b.into_inner())).collect();
    b.sort_unstable_by_key(|(_, b)| b.order);
    let mut t: SmallVec<[(Entity, &mut ToolState); 4]> =
        tools.map(|(e, t)| (e, t.into_inner())).collect();
    t.sort_unstable_by_key(|(_, t)| t.order);
    if let Some((be, te)) = entities {
        be.clear();
        be.extend(b.iter().map(|(e, _)| *e));
        te.clear();
        te.extend(t.iter().map(|(e, _)| *e));
    }
    let mut b: SmallVec<[&mut SimBody; 16]> = b.into_iter().map(|(_, b)| &mut b.body).collect();
    let mut t: SmallVec<[&mut Tool; 4]> = t.into_iter().map(|(_, t)| &mut t.tool).collect();
    f(&mut b, &mut t)
}

fn lap(t: &mut Instant) -> f64 {
    let e = t.elapsed().as_secs_f64() * 1e6;
    *t = Instant::now();
    e
}

/// A stage's result: a failure names the body the core's error names, by entity.
fn report<'a>(
    status: &mut SoftTissueStatus,
    stage: &'static str,
    r: Result<(), WorldError>,
    mut bodies: impl Iterator<Item = (Entity, &'a SimulatedBody)>,
) {
    if let Err(e) = r {
        let body = e
            .subject()
            .and_then(|n| bodies.find(|(_, b)| b.body.name() == n).map(|(e, _)| e));
        fail(status, stage_error(stage, body, e));
    }
}

fn detect_stage(
    mut bodies: Query<(Entity, &mut SimulatedBody)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        detect_contacts(b, tl, &config.contact, &mut contacts.state)
    });
    status.times.detect_us = lap(&mut t);
}

fn switch_stage(
    mut bodies: Query<(Entity, &mut SimulatedBody)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, _| {
        switch_precision(b)
    });
    report(&mut status, "switching precision", r, bodies.iter());
    status.times.switch_us = lap(&mut t);
}

fn solve_stage(
    mut bodies: Query<(Entity, &mut SimulatedBody)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    contacts: Res<SoftTissueContacts>,
    config: Res<SoftTissueConfig>,
    mut pool: ResMut<SoftTissueThreads>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    if pool.threads.as_ref().map(|(asked, _)| *asked) != Some(config.threads) {
        let threads =
            soft_tissue_core::parallel::Threads::new(config.threads).unwrap_or_else(|e| {
                fail(
                    &mut status,
                    stage_error("thread pool", None, format!("{e}; stepping on one thread")),
                );
                soft_tissue_core::parallel::Threads::single()
            });
        pool.threads = Some((config.threads, threads));
    }
    let threads = &pool.threads.as_ref().expect("set above").1;
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        threads.run(|| step_solvers(b, tl, &contacts.state))
    });
    report(&mut status, "stepping the solvers", r, bodies.iter());
    status.times.solve_us = lap(&mut t);
}

fn collide_stage(
    mut bodies: Query<(Entity, &mut SimulatedBody)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let dt = status.dt.unwrap_or_default();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        collide(b, tl, &config.contact, &mut contacts.state, dt)
    });
    contacts.gather();
    report(&mut status, "collisions", r, bodies.iter());
    status.times.collide_us = lap(&mut t);
}

#[allow(clippy::type_complexity)]
fn writeback_stage(
    mut bodies: Query<(
        Entity,
        &mut SimulatedBody,
        &mut PrecisionLevel,
        &mut GreenCage,
        &mut SoftBodyDiagnostics,
        Option<&mut FemState>,
        Option<&mut MsdState>,
        Option<&mut Temperature>,
    )>,
    mut tools: Query<(&ToolState, &mut ToolReaction)>,
    mut level_changes: MessageWriter<LevelChanged>,
    mut touches: MessageWriter<BodyTouched>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    for (entity, mut sim, mut level, mut cage, mut diag, fem, msd, temp) in &mut bodies {
        // The core's writeback, body by body (bodies are independent here). A surface that
        // is not finite is not written (the mesh keeps its last positions) and stops the
        // simulation.
        if let Err(e) = sim.body.writeback() {
            fail(&mut status, stage_error("writeback", Some(entity), e));
            continue;
        }
        let b = &sim.body;
        let d = *b.diagnostics();
        let lb = b.body();
        let new_level = PrecisionLevel {
            level: d.level,
            method: lb.settings().precise,
            switches: d.switch_count,
            last_jump_ratio: d.last_switch.map(|s| s.jump_ratio),
        };
        if *level != new_level {
            *level = new_level;
        }
        // A sleeping body nothing touched changes nothing but its (tiny) step time.
        let quiet = lb.is_asleep()
            && !b.surface_written()
            && d.switched.is_none()
            && !d.touched
            && d.contacts == 0
            && b.heat().is_none_or(|h| {
                temp.as_ref()
                    .is_some_and(|t| t.version == Some(h.version()))
            })
            && !cage.vertices.is_empty();
        if quiet {
            if diag.step_us != d.step_us {
                diag.step_us = d.step_us;
            }
            continue;
        }

        if let Some(s) = d.switched {
            level_changes.write(LevelChanged {
                entity,
                from: s.from,
                to: s.to,
                jump_ratio: s.jump_ratio,
            });
        }
        if d.touched {
            touches.write(BodyTouched {
                entity,
                contacts: d.contacts,
            });
        }
        // Components change only when their contents do: the cage moves only at its own
        // level (or is handed over at a switch, or put back by a reset), temperatures only
        // while the field changes.
        let awake = !lb.is_asleep();
        let cage_moved = d.level == Level::Cage && (awake || b.surface_written());
        if cage_moved || d.switched.is_some() || cage.vertices.is_empty() {
            let c = lb.cage();
            cage.vertices.clear();
            cage.vertices.extend(c.cage_positions().iter().map(to_bevy));
            if cage.triangles.is_empty() {
                cage.triangles = c.cage().triangles().to_vec();
            }
            cage.active = d.level == Level::Cage;
        }
        diag.set_if_neq(SoftBodyDiagnostics {
            step_us: d.step_us + d.switch_us,
            contacts: d.contacts,
            max_displacement: d.max_displacement,
            shadow_error_ratio: d.shadow.map(|e| e.max_ratio),
            unconverged_solves: d.unconverged_solves,
        });
        let cg = d.cg;
        if let (Some(mut f), Some(fb)) = (fem, lb.fem()) {
            f.set_if_neq(FemState {
                corotational: fb.model().is_corotational(),
                cg_iterations: cg.map_or(0, |c| c.iterations),
                cg_residual: cg.map_or(0.0, |c| c.relative_residual),
                cg_converged: cg.is_none_or(|c| c.converged),
            });
        }
        if let (Some(mut m), Some(mb)) = (msd, lb.msd()) {
            m.set_if_neq(MsdState {
                integrator: lb.settings().precise,
                substeps: mb.last_step().substeps,
                cg_iterations: cg.map_or(0, |c| c.iterations),
                cg_converged: cg.is_none_or(|c| c.converged),
            });
        }
        let mut heat_changed = false;
        if let (Some(mut tc), Some(h)) = (temp, b.heat())
            && tc.version != Some(h.version())
        {
            heat_changed = true;
            tc.version = Some(h.version());
            let nodes = b.surface_nodes();
            let temps = h.temperatures();
            tc.surface.clear();
            tc.surface
                .extend(nodes.iter().map(|&i| temps[i as usize] as f32));
            tc.damage.clear();
            tc.damage
                .extend(nodes.iter().map(|&i| h.damaged_fraction(i as usize) as f32));
            // NaN-propagating (`f64::min`/`max` would drop a NaN and show a sound range).
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for &v in temps {
                if v.is_nan() {
                    (lo, hi) = (f64::NAN, f64::NAN);
                    break;
                }
                (lo, hi) = (lo.min(v), hi.max(v));
            }
            (tc.min, tc.max) = (lo, hi);
        }
        if awake || b.surface_written() || d.switched.is_some() || heat_changed {
            sim.dirty = true;
        }
    }
    for (state, mut reaction) in &mut tools {
        let t = &state.tool;
        *reaction = ToolReaction {
            force: to_bevy(&t.reaction_force()),
            contacts: t.contact_count(),
            grips: t.grips().len() as u32,
        };
    }
    status.times.writeback_us = lap(&mut t);
    let times = status.times;
    status.recent.push(&times);
    status.steps += 1;
    status.step_once = false;
}
