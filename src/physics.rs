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
use soft_tissue_core::precision::{Level, PreciseMethod};
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
    /// Fixed step, s (default 0.02, the paper's cylinders). Every body's step must equal it.
    /// When the plugin runs in `FixedUpdate` (the default), the plugin sets
    /// `Time<Fixed>` to it.
    pub dt: f64,
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
            dt: 0.02,
            contact: ContactConfig::for_scale(1.0),
            threads: 0,
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
    pub error: Option<String>,
}

/// Steps [`SoftTissueStatus::recent`] keeps.
pub const STAGE_WINDOW: usize = 1000;

impl Default for SoftTissueStatus {
    fn default() -> Self {
        SoftTissueStatus {
            paused: false,
            step_once: false,
            steps: 0,
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
}

/// Contacts of the last step (the core's contact state, indices in body build order).
#[derive(Resource, Default)]
pub struct SoftTissueContacts(pub ContactState);

/// Asks for every body and tool to go back to its initial state at the next step.
#[derive(Message, Clone, Copy, Debug, Default)]
pub struct ResetSimulation;

/// A body that could not be built, and why (the entity keeps its [`SoftBody`]).
#[derive(Component, Clone, Debug)]
pub struct SoftBodyError(pub String);

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
            .add_message::<LevelChanged>()
            .add_message::<BodyTouched>()
            .add_message::<ResetSimulation>()
            .register_type::<SoftBody>()
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
                (build_bodies, build_tools, prepare_stage)
                    .chain()
                    .in_set(S::Prepare),
                detect_stage.in_set(S::DetectContact),
                switch_stage.in_set(S::SwitchPrecision),
                solve_stage.in_set(S::StepSolvers),
                collide_stage.in_set(S::Collide),
                writeback_stage.in_set(S::Writeback),
            ),
        );
        let running = |s: Res<SoftTissueStatus>| s.running();
        app.add_systems(
            self.schedule,
            (
                reset_simulation,
                run_step.in_set(SoftTissueStep).run_if(running),
            )
                .chain(),
        );
        if self.schedule == FixedUpdate.intern() {
            app.add_systems(PreUpdate, sync_fixed_timestep);
        }
    }
}

/// Runs one simulation step: [`SoftTissueSchedule`].
fn run_step(world: &mut World) {
    world.run_schedule(SoftTissueSchedule);
}

/// Keeps `Time<Fixed>` at the configured step.
fn sync_fixed_timestep(config: Res<SoftTissueConfig>, mut time: ResMut<Time<Fixed>>) {
    let want = std::time::Duration::from_secs_f64(config.dt);
    if config.is_changed() && time.timestep() != want && config.dt > 0.0 && config.dt.is_finite() {
        time.set_timestep(want);
    }
}

fn fail(status: &mut SoftTissueStatus, message: String) {
    error!("soft tissue: {message}; the simulation is paused");
    status.error = Some(message);
    status.paused = true;
    status.step_once = false;
}

/// The body's mesh with `transform` applied (the same `Arc` when it is the identity).
fn placed(mesh: &Arc<TetMesh>, transform: &Transform) -> Result<Arc<TetMesh>, String> {
    if *transform == Transform::IDENTITY {
        return Ok(mesh.clone());
    }
    let m = transform.to_matrix().as_dmat4();
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
        .map_err(|e| format!("placing the mesh: {e}"))
}

/// Builds the simulation of every [`SoftBody`] whose mesh has loaded.
#[allow(clippy::type_complexity)]
fn build_bodies(
    mut commands: Commands,
    config: Res<SoftTissueConfig>,
    meshes: Res<Assets<TetMeshAsset>>,
    mut new: Query<
        (
            Entity,
            &SoftBody,
            &mut Transform,
            Option<&Name>,
            Has<ShadowSimulation>,
            Option<&PinnedLevel>,
        ),
        (Without<SimulatedBody>, Without<SoftBodyError>),
    >,
    mut next: Local<u64>,
) {
    for (entity, spec, mut transform, name, shadow, pin) in &mut new {
        let Some(asset) = meshes.get(&spec.mesh) else {
            continue;
        };
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        let result = (|| -> Result<SimBody, String> {
            let mut settings = spec.settings.clone();
            settings.precise = spec.method;
            if (settings.dt - config.dt).abs() > 1e-12 * config.dt {
                return Err(format!(
                    "its step {} s differs from the simulation's {} s (SoftTissueConfig::dt)",
                    settings.dt, config.dt
                ));
            }
            let mesh = placed(&asset.0, &transform)?;
            let heat = spec.heat.map(|h| (h, HeatBoundary::insulated()));
            let mut body =
                SimBody::new(name.clone(), mesh, settings, heat).map_err(|e| e.to_string())?;
            if shadow {
                body.set_shadow(true).map_err(|e| e.to_string())?;
            }
            if let Some(p) = pin {
                body.body_mut().pin(Some(p.0)).map_err(|e| e.to_string())?;
            }
            Ok(body)
        })();
        match result {
            Ok(body) => {
                let placement = *transform;
                *transform = Transform::IDENTITY;
                let method: PreciseMethod = body.body().settings().precise;
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
                if body.body().settings().precise.is_fem() {
                    e.insert(FemState::default());
                } else {
                    e.insert(MsdState::default());
                }
                if body.heat().is_some() {
                    e.insert(Temperature::default());
                }
                e.insert(SimulatedBody {
                    body,
                    order: *next,
                    dirty: true,
                    placement,
                });
                *next += 1;
            }
            Err(message) => {
                error!("soft body `{name}` was not built: {message}");
                commands.entity(entity).insert(SoftBodyError(message));
            }
        }
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
            fail(&mut status, format!("resetting {e}: {err}"));
        }
        b.dirty = true;
    }
    for mut tool in &mut tools {
        tool.tool.reset();
        tool.grabbing = false;
    }
    contacts.0.clear();
}

/// The prepare stage: run-time changes (precise method, pins,
/// shadows, tool poses and actions), then the core's `prepare`. One system, so the step pays
/// one system's dispatch for all of it.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
fn prepare_stage(
    mut bodies: Query<(
        Entity,
        Ref<SoftBody>,
        &mut SimulatedBody,
        Option<Ref<PinnedLevel>>,
        Has<ShadowSimulation>,
    )>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    poses: TransformHelper,
    config: Res<SoftTissueConfig>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    for (entity, spec, mut sim, pin, shadow) in &mut bodies {
        let b = &mut sim.body;
        let want: PreciseMethod = spec.method;
        if spec.is_changed() && b.body().settings().precise != want {
            let mesh = b.mesh().clone();
            if let Err(e) = b.body_mut().set_precise_method(&mesh, want) {
                fail(&mut status, format!("{}: changing method: {e}", b.name()));
            }
        }
        let pinned: Option<Level> = pin.as_ref().map(|p| p.0);
        if b.body().pinned() != pinned
            && let Err(e) = b.body_mut().pin(pinned)
        {
            fail(&mut status, format!("{}: pinning: {e}", b.name()));
        }
        if b.body().has_shadow() != shadow
            && let Err(e) = b.set_shadow(shadow)
        {
            fail(&mut status, format!("{entity}: shadow: {e}"));
        }
    }
    for (entity, spec, mut state) in &mut tools {
        let Some((position, axis)) = tool_pose(&poses, entity) else {
            continue;
        };
        let t = &mut state.tool;
        if let Err(e) = t.set_pose(position, axis) {
            fail(&mut status, format!("tool {}: {e}", t.name()));
            continue;
        }
        if let Err(e) = t.set_cautery(spec.cautery_watts) {
            fail(&mut status, format!("tool {}: {e}", t.name()));
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
    in_order(
        bodies.iter_mut().map(|(_, _, b, _, _)| b),
        tools.iter_mut().map(|(_, _, t)| t),
        |b, tl| prepare(b, tl, config.dt),
    );
    status.times.prepare_us = lap(&mut t);
}

/// Runs `f` on the built bodies and the tools, each in build order, as the core's stage
/// functions take them (slices of `&mut`, so indices in the contact state stay valid).
fn in_order<'a, R>(
    bodies: impl Iterator<Item = Mut<'a, SimulatedBody>>,
    tools: impl Iterator<Item = Mut<'a, ToolState>>,
    f: impl FnOnce(&mut [&mut SimBody], &mut [&mut Tool]) -> R,
) -> R {
    let mut b: SmallVec<[&mut SimulatedBody; 16]> = bodies.map(Mut::into_inner).collect();
    b.sort_unstable_by_key(|b| b.order);
    let mut b: SmallVec<[&mut SimBody; 16]> = b.into_iter().map(|b| &mut b.body).collect();
    let mut t: SmallVec<[&mut ToolState; 4]> = tools.map(Mut::into_inner).collect();
    t.sort_unstable_by_key(|t| t.order);
    let mut t: SmallVec<[&mut Tool; 4]> = t.into_iter().map(|t| &mut t.tool).collect();
    f(&mut b, &mut t)
}

fn lap(t: &mut Instant) -> f64 {
    let e = t.elapsed().as_secs_f64() * 1e6;
    *t = Instant::now();
    e
}

fn report(status: &mut SoftTissueStatus, stage: &str, r: Result<(), WorldError>) {
    if let Err(e) = r {
        fail(status, format!("{stage}: {e}"));
    }
}

fn detect_stage(
    mut bodies: Query<&mut SimulatedBody>,
    mut tools: Query<&mut ToolState>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    in_order(bodies.iter_mut(), tools.iter_mut(), |b, tl| {
        detect_contacts(b, tl, &config.contact, &mut contacts.0)
    });
    status.times.detect_us = lap(&mut t);
}

fn switch_stage(
    mut bodies: Query<&mut SimulatedBody>,
    mut tools: Query<&mut ToolState>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), |b, _| {
        switch_precision(b)
    });
    report(&mut status, "switching precision", r);
    status.times.switch_us = lap(&mut t);
}

fn solve_stage(
    mut bodies: Query<&mut SimulatedBody>,
    mut tools: Query<&mut ToolState>,
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
                    format!("thread pool: {e}; stepping on one thread"),
                );
                soft_tissue_core::parallel::Threads::single()
            });
        pool.threads = Some((config.threads, threads));
    }
    let threads = &pool.threads.as_ref().expect("set above").1;
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), |b, tl| {
        threads.run(|| step_solvers(b, tl, &contacts.0))
    });
    report(&mut status, "stepping the solvers", r);
    status.times.solve_us = lap(&mut t);
}

fn collide_stage(
    mut bodies: Query<&mut SimulatedBody>,
    mut tools: Query<&mut ToolState>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), |b, tl| {
        collide(b, tl, &config.contact, &mut contacts.0, config.dt)
    });
    report(&mut status, "collisions", r);
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
            fail(&mut status, format!("writeback: {e}"));
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
