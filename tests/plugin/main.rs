//! The plugin in a headless app (`MinimalPlugins`): bodies built from meshes with only the
//! components they use, a scripted tool raising and releasing a body, the render mesh
//! written, parity with the engine-free `SoftTissueWorld`, determinism, no system-order
//! ambiguity, and errors surfaced. The tests are in the modules beside this file; the
//! helpers they share are here.

mod assets;
mod burn;
mod contact;
mod cut;
mod inputs;
mod steps;
mod teleport;
mod visual;

use std::path::Path;
use std::time::Duration;

use bevy::asset::LoadState;
use bevy::ecs::schedule::{LogLevel, ScheduleBuildSettings, ScheduleLabel};
use bevy::mesh::{Mesh, Mesh3d, VertexAttributeValues};
use bevy::prelude::*;
use bevy::time::TimeUpdateStrategy;
use bevy_soft_tissue::core::contact::ToolShape;
use bevy_soft_tissue::core::scenario::{PreciseMethod, Scene};
use bevy_soft_tissue::core::world::{Script, ScriptAction, SoftTissueWorld};
use bevy_soft_tissue::prelude::*;
use bevy_soft_tissue::{
    SceneLoaderSettings, SoftBodyError, SoftBodyState, SoftTissueAssetPlugin, SoftTissueConfig,
    SoftTissueMeshPlugin, SoftTissuePhysicsPlugin, SoftTissueThreads,
};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets"))
}

/// A headless app in which every `update` advances exactly one fixed step of `dt`.
fn app(dt: f64) -> App {
    let mut app = App::new();
    app.add_plugins((
        MinimalPlugins,
        TransformPlugin,
        AssetPlugin {
            file_path: assets().display().to_string(),
            ..default()
        },
        SoftTissueAssetPlugin,
        SoftTissuePhysicsPlugin::default(),
        SoftTissueMeshPlugin,
    ));
    // The simulation steps at the fixed timestep.
    app.insert_resource(Time::<Fixed>::from_seconds(dt));
    app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
        dt,
    )));
    // The first frame has no elapsed time (no fixed step): spend it before any body exists.
    app.update();
    app
}

const CYLINDERS: &str = "scenes/cylinders.scene.ron";
const ORGANS: &str = "scenes/organs.scene.ron";

/// The scene file `file` (relative to the assets folder).
fn scene_file(file: &str) -> Scene {
    let text = std::fs::read_to_string(assets().join(file)).unwrap();
    Scene::from_ron(&text, file).unwrap()
}

/// An app with the scene file `file` spawned through the asset server, and the core world
/// of the same scene.
fn scene_app(file: &str) -> (App, Vec<Entity>, SoftTissueWorld) {
    let world = SoftTissueWorld::from_scene(&scene_file(file), assets()).unwrap();
    let mut app = app(world.config().dt);
    let entities = bevy_soft_tissue::spawn_scene_and_wait(&mut app, file).unwrap();
    (app, entities, world)
}

/// The tool pose of a script at time `t` as a `Transform` (what a game would set).
fn tool_transform(script: &Script, t: f64) -> Transform {
    let (p, a) = script.pose_at(t);
    let axis = Vec3::new(a.x as f32, a.y as f32, a.z as f32).normalize();
    Transform::from_xyz(p.x as f32, p.y as f32, p.z as f32)
        .with_rotation(Quat::from_rotation_arc(Vec3::Y, axis))
}

/// Sets the tool entity from the script for step `k` (1-based) and returns the pose the
/// plugin sees, in core vectors, so the core world can be fed the very same input.
fn drive_tool(
    app: &mut App,
    tool: Entity,
    script: &Script,
    k: usize,
    dt: f64,
) -> (
    bevy_soft_tissue::core::Vec3,
    nalgebra::UnitQuaternion<f64>,
    Vec<ScriptAction>,
) {
    let t = k as f64 * dt;
    let tf = tool_transform(script, t);
    let actions: Vec<ScriptAction> = script.events_in(t - dt, t).map(|e| e.action).collect();
    let mut e = app.world_mut().entity_mut(tool);
    *e.get_mut::<Transform>().unwrap() = tf;
    let mut spec = e.get_mut::<SoftTool>().unwrap();
    for a in &actions {
        match a {
            ScriptAction::Grab => spec.grab = true,
            ScriptAction::Release => spec.grab = false,
            ScriptAction::Cautery(w) => spec.cautery_watts = *w,
            ScriptAction::Jaws(w) => spec.jaws = *w,
            ScriptAction::Cut(on) => spec.cut = *on,
        }
    }
    // The rotation as the plugin reads it: from the global transform's matrix (its bits
    // may differ from the `Transform`'s quaternion).
    let (_, rotation, translation) = GlobalTransform::from(tf).to_scale_rotation_translation();
    (
        bevy_soft_tissue::convert::to_core(translation),
        bevy_soft_tissue::convert::to_core_rotation(rotation),
        actions,
    )
}

/// A core tool of the script's shape in `world`, at the script's start as the plugin reads
/// a tool entity's pose there (see [`spawn_tool`]); returns its index.
fn add_core_tool(world: &mut SoftTissueWorld, script: &Script) -> usize {
    let ti =
        world.add_tool(bevy_soft_tissue::core::contact::Tool::new("tool", script.tool).unwrap());
    let start = tool_transform(script, 0.0);
    let (_, rotation, translation) = GlobalTransform::from(start).to_scale_rotation_translation();
    world.tools_mut()[ti]
        .set_pose_rotation(
            bevy_soft_tissue::convert::to_core(translation),
            bevy_soft_tissue::convert::to_core_rotation(rotation),
        )
        .unwrap();
    ti
}

/// One step of the plugin and of the core world `world` under the script: the tool entity
/// set for step `k` (1-based), the app updated, the core tool `ti` given the very pose and
/// actions the plugin read, the core world stepped.
fn step_both(
    app: &mut App,
    world: &mut SoftTissueWorld,
    (tool, ti): (Entity, usize),
    script: &Script,
    k: usize,
    dt: f64,
) {
    let (p, r, actions) = drive_tool(app, tool, script, k, dt);
    app.update();
    let t = &mut world.tools_mut()[ti];
    t.set_pose_rotation(p, r).unwrap();
    for act in actions {
        act.apply(t).unwrap();
    }
    world.step_fixed().unwrap();
}

/// A tool of `shape`, idle: not holding, not burning, jaws closed, not cutting, a 1 mm
/// electrode, the default friction.
fn soft_tool(shape: ToolShape) -> SoftTool {
    SoftTool {
        shape,
        grab: false,
        cautery_watts: 0.0,
        electrode_radius: Some(1e-3),
        jaws: 0.0,
        cut: false,
        friction: Default::default(),
    }
}

/// A tool entity with the script's shape, at the script's start.
fn spawn_tool(app: &mut App, script: &Script) -> Entity {
    app.world_mut()
        .spawn((soft_tool(script.tool), tool_transform(script, 0.0)))
        .id()
}

/// The built-in script `name` for the scene of `world`, its tool spawned in `app` at its
/// start, and the scene's step.
fn scripted_tool(app: &mut App, world: &SoftTissueWorld, name: &str) -> (Script, Entity, f64) {
    let script = Script::builtin(name, world).unwrap();
    let tool = spawn_tool(app, &script);
    (script, tool, world.config().dt)
}

fn level(app: &App, e: Entity) -> Level {
    app.world().get::<PrecisionLevel>(e).unwrap().level
}

/// The cylinder mesh file, read and added to the app's tetrahedral mesh assets.
fn cylinder_asset(app: &mut App) -> Handle<TetMeshAsset> {
    let m = bevy_soft_tissue::core::mesh::io::read_tet_mesh(assets().join("meshes/cylinder.vtk"))
        .unwrap()
        .mesh;
    app.world_mut()
        .resource_mut::<Assets<TetMeshAsset>>()
        .add(TetMeshAsset::from(m))
}

fn mesh_positions(mesh: &Mesh) -> Vec<[f32; 3]> {
    match mesh.attribute(Mesh::ATTRIBUTE_POSITION).unwrap() {
        VertexAttributeValues::Float32x3(v) => v.clone(),
        _ => panic!("positions are Float32x3"),
    }
}

fn positions(app: &App, handle: &Handle<Mesh>) -> Vec<[f32; 3]> {
    mesh_positions(app.world().resource::<Assets<Mesh>>().get(handle).unwrap())
}

/// The largest distance between matching points of `a` and `b`.
fn max_distance(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(p, q)| Vec3::from_array(*p).distance(Vec3::from_array(*q)))
        .fold(0.0, f32::max)
}

/// The haptic thread's settings of the plugin's haptic tests: 30 s of recording and
/// statistics, sleeping until 200 us before each deadline (gentler on a shared machine).
#[cfg(feature = "haptics")]
fn haptic_config() -> bevy_soft_tissue::core::haptics::HapticConfig {
    bevy_soft_tissue::core::haptics::HapticConfig {
        record_seconds: 30.0,
        stats_seconds: 30.0,
        spin_us: 200.0,
        ..Default::default()
    }
}

/// Every body's surface positions, in scene order.
fn surfaces(app: &App, bodies: &[Entity]) -> Vec<Vec<[f32; 3]>> {
    bodies
        .iter()
        .map(|&e| {
            app.world()
                .get::<SoftBodyState>(e)
                .unwrap()
                .body()
                .surface_positions()
                .to_vec()
        })
        .collect()
}
