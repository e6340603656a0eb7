//! The plugin in a headless app (`MinimalPlugins`): bodies built from meshes with only the
//! components they use, a scripted tool raising and releasing a body, the render mesh
//! written, parity with the engine-free `SoftTissueWorld`, determinism, no system-order
//! ambiguity, and errors surfaced.

use std::path::Path;
use std::time::Duration;

use bevy::asset::LoadState;
use bevy::ecs::schedule::{LogLevel, ScheduleBuildSettings, ScheduleLabel};
use bevy::mesh::{Mesh, Mesh3d, VertexAttributeValues};
use bevy::prelude::*;
use bevy::time::TimeUpdateStrategy;
use bevy_soft_tissue::core::scenario::{PreciseMethod, Scene};
use bevy_soft_tissue::core::world::{Script, ScriptAction, SoftTissueWorld};
use bevy_soft_tissue::prelude::*;
use bevy_soft_tissue::{
    SceneLoaderSettings, SimulatedBody, SoftBodyError, SoftTissueAssetPlugin, SoftTissueConfig,
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
    app.insert_resource(Time::<Fixed>::from_seconds(dt));
    app.insert_resource(SoftTissueConfig {
        dt: Some(dt),
        ..default()
    });
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
    bevy_soft_tissue::core::Vec3,
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
        }
    }
    let axis = tf.rotation * Vec3::Y;
    (
        bevy_soft_tissue::convert::to_core(tf.translation),
        bevy_soft_tissue::convert::to_core(axis),
        actions,
    )
}

/// A tool entity with the script's shape, at the script's start.
fn spawn_tool(app: &mut App, script: &Script) -> Entity {
    let tool = SoftTool {
        shape: script.tool,
        grab: false,
        cautery_watts: 0.0,
    };
    app.world_mut()
        .spawn((tool, tool_transform(script, 0.0)))
        .id()
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

#[test]
fn bodies_get_only_the_components_they_use() {
    let mut app = app(0.02);
    let mesh = cylinder_asset(&mut app);
    let fem = app.world_mut().spawn(SoftBody::new(mesh.clone())).id();
    let msd_body = SoftBody::new(mesh.clone()).with_method(PreciseMethod::MsdImplicit);
    let msd = app
        .world_mut()
        .spawn((msd_body, Transform::from_xyz(3.0, 0.0, 0.0)))
        .id();
    let hot = app
        .world_mut()
        .spawn((
            SoftBody::new(mesh.clone()),
            TissueHeat::default(),
            Transform::from_xyz(-3.0, 0.0, 0.0),
        ))
        .id();
    let bad_anchor = SoftBody::new(mesh).with_anchor(Anchor::FixedBottom { fraction: 2.0 });
    let bad = app.world_mut().spawn(bad_anchor).id();
    app.update();
    app.update();
    let w = app.world();
    for e in [fem, msd, hot] {
        assert!(w.get::<SimulatedBody>(e).is_some());
        assert!(w.get::<PrecisionLevel>(e).is_some());
        assert!(w.get::<GreenCage>(e).is_some());
        assert!(w.get::<Mesh3d>(e).is_some(), "the render mesh is created");
        assert_eq!(level(&app, e), Level::Cage, "every body starts at its cage");
        assert_eq!(w.get::<TissueMaterial>(e), Some(&TissueMaterial::default()));
    }
    assert!(w.get::<FemState>(fem).is_some() && w.get::<MsdState>(fem).is_none());
    assert!(w.get::<MsdState>(msd).is_some() && w.get::<FemState>(msd).is_none());
    assert!(w.get::<Temperature>(fem).is_none() && w.get::<Temperature>(msd).is_none());
    let t = w.get::<Temperature>(hot).unwrap();
    assert!((t.max - 37.0).abs() < 1e-9 && !t.surface.is_empty());
    // The transform placed the mesh (the MSD body sits 3 units along x) and stays as set:
    // the rendered mesh is in the entity's frame.
    assert_eq!(
        *w.get::<Transform>(msd).unwrap(),
        Transform::from_xyz(3.0, 0.0, 0.0)
    );
    let sim = w.get::<SimulatedBody>(msd).unwrap().body();
    let cx = sim.mesh().bbox().min.x + 0.5 * sim.mesh().bbox().extent().x;
    assert!((cx - 3.0).abs() < 0.1, "centre x {cx}");
    let drawn = w.get::<Mesh3d>(msd).unwrap().0.clone();
    let local_cx = positions(&app, &drawn)
        .iter()
        .map(|p| p[0])
        .fold(f32::NEG_INFINITY, f32::max);
    assert!(
        local_cx < 1.0,
        "drawn in the entity's frame: largest x {local_cx}"
    );
    // A body with a setting out of range is refused, naming it.
    let err = w.get::<SoftBodyError>(bad).expect("refused");
    assert!(err.to_string().contains("fraction"), "{err}");
    assert!(w.get::<SimulatedBody>(bad).is_none());
}

/// The mesh of the body `e` in world coordinates now (its simulated nodes).
fn nodes(app: &App, e: Entity) -> Vec<bevy_soft_tissue::core::Vec3> {
    let sim = app.world().get::<SimulatedBody>(e).unwrap().body();
    sim.body().node_positions().to_vec()
}

fn centre(p: &[bevy_soft_tissue::core::Vec3]) -> Vec3 {
    let s = p
        .iter()
        .fold(bevy_soft_tissue::core::Vec3::zeros(), |a, b| a + b)
        / p.len() as f64;
    Vec3::new(s.x as f32, s.y as f32, s.z as f32)
}

/// Spawns a body with the defaults through the asset server and waits for it to be built.
fn spawn_liver(app: &mut App, extra: impl Bundle) -> Entity {
    let mesh: Handle<TetMeshAsset> = app
        .world()
        .resource::<AssetServer>()
        .load("meshes/liver.vtk");
    let e = app.world_mut().spawn((SoftBody::new(mesh), extra)).id();
    for _ in 0..2000 {
        app.update();
        if app.world().get::<SimulatedBody>(e).is_some() {
            return e;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    panic!("the liver was not built");
}

#[test]
fn a_body_with_defaults_spawns_through_the_asset_server_and_each_input_takes_effect() {
    let mut app = app(0.01);
    // Two livers side by side: `a` is written, `b` is the control.
    let a = spawn_liver(&mut app, Name::new("a"));
    let b = spawn_liver(
        &mut app,
        (Name::new("b"), Transform::from_xyz(0.0, 0.0, 3.0)),
    );
    let pl = *app.world().get::<PrecisionLevel>(a).unwrap();
    assert_eq!(
        pl.method,
        PreciseMethod::CorotationalFem,
        "the default method"
    );
    let settings = |app: &App, e| {
        app.world()
            .get::<SimulatedBody>(e)
            .unwrap()
            .body()
            .body()
            .settings()
            .clone()
    };
    assert_eq!(settings(&app, a).fem, TissueMaterial::default().fem);
    assert_eq!(settings(&app, a).cage, CageKind::BoundingBox);

    // Pin: both raised, then pushed the same way by the same load on their top nodes.
    for e in [a, b] {
        app.world_mut()
            .entity_mut(e)
            .insert(PinnedLevel(Level::Precise));
    }
    app.update();
    assert_eq!(level(&app, a), Level::Precise);
    assert_eq!(level(&app, b), Level::Precise);

    // Material: four times stiffer; the same gravity-free push then moves `a` less.
    app.world_mut()
        .get_mut::<TissueMaterial>(a)
        .unwrap()
        .fem
        .young_modulus *= 4.0;
    app.update();
    assert_eq!(
        settings(&app, a).fem.young_modulus,
        4.0 * TissueMaterial::default().fem.young_modulus
    );
    let rest_a = nodes(&app, a);
    let rest_b = nodes(&app, b);
    for _ in 0..20 {
        for (e, rest) in [(a, &rest_a), (b, &rest_b)] {
            let mut w = app.world_mut().entity_mut(e);
            let mut sim = w.get_mut::<SimulatedBody>().unwrap();
            let top = (0..rest.len())
                .max_by(|&i, &j| rest[i].y.total_cmp(&rest[j].y))
                .unwrap();
            sim.body_mut()
                .body_mut()
                .add_force(top, bevy_soft_tissue::core::Vec3::new(0.0, 0.0, 2.0))
                .unwrap();
        }
        app.update();
    }
    let moved = |app: &App, e, rest: &[bevy_soft_tissue::core::Vec3]| {
        nodes(app, e)
            .iter()
            .zip(rest)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    };
    let (ma, mb) = (moved(&app, a, &rest_a), moved(&app, b, &rest_b));
    assert!(mb > 1e-3, "the push moves the control ({mb})");
    assert!(ma < 0.7 * mb, "stiffer moves less: {ma} against {mb}");

    // Method: written on `SoftBody`, the solver and the state components follow.
    app.world_mut().get_mut::<SoftBody>(a).unwrap().method = PreciseMethod::MsdImplicit;
    app.update();
    app.update();
    assert_eq!(settings(&app, a).precise, PreciseMethod::MsdImplicit);
    assert!(app.world().get::<MsdState>(a).is_some());
    assert!(app.world().get::<FemState>(a).is_none());

    // Heat: added, a temperature field appears; removed, it goes.
    app.world_mut().entity_mut(a).insert(TissueHeat::default());
    app.update();
    app.update();
    assert!(app.world().get::<Temperature>(a).is_some());
    assert!(
        app.world()
            .get::<SimulatedBody>(a)
            .unwrap()
            .body()
            .heat()
            .is_some()
    );
    app.world_mut().entity_mut(a).remove::<TissueHeat>();
    app.update();
    app.update();
    assert!(app.world().get::<Temperature>(a).is_none());
    assert!(
        app.world()
            .get::<SimulatedBody>(a)
            .unwrap()
            .body()
            .heat()
            .is_none()
    );

    // Pin to the cage: it drops.
    app.world_mut()
        .entity_mut(a)
        .insert(PinnedLevel(Level::Cage));
    app.update();
    assert_eq!(level(&app, a), Level::Cage);

    // Cage, anchor and tuning: the body is built again with them.
    app.world_mut().get_mut::<SoftBody>(a).unwrap().anchor = Anchor::SoftToRest { stiffness: 2.0 };
    app.world_mut().get_mut::<SoftBody>(a).unwrap().cage = CageKind::Fitted { vertices: 32 };
    for _ in 0..3 {
        app.update();
    }
    let s = settings(&app, a);
    assert_eq!(s.cage, CageKind::Fitted { vertices: 32 });
    assert!(
        s.boundary != settings(&app, b).boundary,
        "the anchor holds it now"
    );
    app.world_mut().entity_mut(a).insert(SoftBodyTuning {
        fem_integrator: bevy_soft_tissue::core::fem::FemIntegrator::Bdf2,
        ..default()
    });
    for _ in 0..3 {
        app.update();
    }
    assert_eq!(
        settings(&app, a).fem_integrator,
        bevy_soft_tissue::core::fem::FemIntegrator::Bdf2
    );

    // Transform: moved 2 units up, the body is placed there.
    let before = centre(&nodes(&app, a));
    app.world_mut()
        .get_mut::<Transform>(a)
        .unwrap()
        .translation
        .y += 2.0;
    for _ in 0..3 {
        app.update();
    }
    let after = centre(&nodes(&app, a));
    assert!(
        (after - before - Vec3::Y * 2.0).length() < 0.05,
        "{before} -> {after}"
    );
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
}

#[test]
fn a_parented_body_lands_at_its_global_pose() {
    let mut app = app(0.01);
    let parent = Transform::from_xyz(1.0, 2.0, 3.0)
        .with_rotation(Quat::from_rotation_y(std::f32::consts::FRAC_PI_2))
        .with_scale(Vec3::splat(0.5));
    let child = Transform::from_xyz(0.5, 0.0, 0.0);
    let root = app.world_mut().spawn(parent).id();
    let body = spawn_liver(&mut app, (child, ChildOf(root)));
    let file = bevy_soft_tissue::core::mesh::io::read_tet_mesh(assets().join("meshes/liver.vtk"))
        .unwrap()
        .mesh;
    let global = parent * child;
    let sim = nodes(&app, body);
    let off = file
        .positions()
        .iter()
        .zip(&sim)
        .map(|(p, q)| {
            let want = global.transform_point(Vec3::new(p.x as f32, p.y as f32, p.z as f32));
            (want - Vec3::new(q.x as f32, q.y as f32, q.z as f32)).length()
        })
        .fold(0.0, f32::max);
    assert!(off < 1e-4, "simulated nodes {off} from the global pose");
    // The rendered mesh is in the body's own frame: the file's coordinates.
    app.update();
    let drawn = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    let sb = app.world().get::<SimulatedBody>(body).unwrap().body();
    let off = positions(&app, &drawn)
        .iter()
        .zip(sb.surface_nodes())
        .map(|(p, &i)| {
            let q = file.positions()[i as usize];
            (Vec3::from_array(*p) - Vec3::new(q.x as f32, q.y as f32, q.z as f32)).length()
        })
        .fold(0.0, f32::max);
    assert!(off < 1e-4, "drawn surface {off} from the file's");
    // Moving the parent moves the body.
    app.world_mut()
        .get_mut::<Transform>(root)
        .unwrap()
        .translation
        .x += 1.0;
    for _ in 0..4 {
        app.update();
    }
    let moved = centre(&nodes(&app, body)) - centre(&sim);
    assert!((moved - Vec3::X).length() < 1e-3, "{moved}");
}

#[test]
fn contacts_name_entities() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let script = Script::builtin("push-a-into-b", &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let (a, b) = (bodies[0], bodies[1]);
    app.update();
    let (mut tool_seen, mut body_seen) = (false, false);
    let mut touched = Vec::new();
    for k in 1..=600 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        let contacts = app.world().resource::<SoftTissueContacts>();
        for c in contacts.iter() {
            assert!(bodies.contains(&c.body), "{c:?}");
            assert!(c.points > 0 && c.max_depth.is_finite());
            match c.partner {
                ContactPartner::Tool(t) => {
                    assert_eq!(t, tool);
                    tool_seen |= c.body == a;
                }
                ContactPartner::Body(o) => {
                    assert!(o != c.body && (o == a || o == b), "{c:?}");
                    body_seen = true;
                    assert!(contacts.involving(o).any(|d| d == c));
                }
            }
        }
        let msgs = app.world().resource::<Messages<BodyTouched>>();
        touched.extend(msgs.iter_current_update_messages().map(|m| m.entity));
    }
    assert!(tool_seen, "the tool touched A");
    assert!(body_seen, "A was pushed into B");
    assert!(touched.contains(&a) && touched.contains(&b));
}

#[test]
fn meshes_load_through_the_asset_server_and_errors_name_the_file() {
    let mut app = app(0.02);
    let server = app.world().resource::<AssetServer>().clone();
    let good: Handle<TetMeshAsset> = server.load("meshes/liver.vtk");
    let missing: Handle<TetMeshAsset> = server.load("meshes/no-such-organ.vtk");
    let scene: Handle<bevy_soft_tissue::SceneAsset> = server.load("scenes/organs.scene.ron");
    for _ in 0..200 {
        app.update();
        let done = |id| {
            matches!(
                server.load_state(id),
                LoadState::Loaded | LoadState::Failed(_)
            )
        };
        if done(good.id().untyped()) && done(missing.id().untyped()) && done(scene.id().untyped()) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let meshes = app.world().resource::<Assets<TetMeshAsset>>();
    let liver = meshes.get(&good).expect("liver loaded");
    assert!(liver.0.tet_count() > 1000);
    match server.load_state(missing.id()) {
        LoadState::Failed(e) => assert!(e.to_string().contains("no-such-organ"), "{e}"),
        s => panic!("expected a failure, got {s:?}"),
    }
    let scenes = app
        .world()
        .resource::<Assets<bevy_soft_tissue::SceneAsset>>();
    let s = scenes.get(&scene).expect("scene loaded");
    assert_eq!(s.scene.bodies.len(), 4);
    assert_eq!(s.meshes.len(), 4);
    let meshes = app.world().resource::<Assets<TetMeshAsset>>();
    assert!(
        s.meshes.iter().all(|h| meshes.get(h).is_some()),
        "the meshes load with it"
    );
}

#[test]
fn scene_assets_keep_mesh_paths_inside_the_assets_folder_unless_allowed() {
    let top = std::env::temp_dir().join(format!("soft-tissue-scene-paths-{}", std::process::id()));
    let dir = top.join("assets");
    std::fs::create_dir_all(dir.join("scenes")).unwrap();
    // The meshes the scene names: one inside the assets folder, one beside it.
    for sub in ["assets/meshes", "outside"] {
        std::fs::create_dir_all(top.join(sub)).unwrap();
        std::fs::copy(
            assets().join("meshes/cylinder.vtk"),
            top.join(sub).join("cylinder.vtk"),
        )
        .unwrap();
    }
    let text = std::fs::read_to_string(assets().join("scenes/cylinders.scene.ron"))
        .unwrap()
        .replacen("meshes/", "../outside/", 1);
    assert!(text.contains("../outside/"));
    std::fs::write(dir.join("scenes/escape.scene.ron"), &text).unwrap();
    std::fs::write(dir.join("scenes/escape-allowed.scene.ron"), &text).unwrap();
    let mut app = App::new();
    app.add_plugins((
        MinimalPlugins,
        AssetPlugin {
            file_path: dir.display().to_string(),
            ..default()
        },
        SoftTissueAssetPlugin,
    ));
    let server = app.world().resource::<AssetServer>().clone();
    let refused: Handle<bevy_soft_tissue::SceneAsset> = server.load("scenes/escape.scene.ron");
    let allowed: Handle<bevy_soft_tissue::SceneAsset> = server
        .load_builder()
        .with_settings(|s: &mut SceneLoaderSettings| s.allow_outside_assets = true)
        .load("scenes/escape-allowed.scene.ron");
    let done = |id| {
        matches!(
            server.load_state(id),
            LoadState::Loaded | LoadState::Failed(_)
        )
    };
    for _ in 0..300 {
        app.update();
        if done(refused.id().untyped()) && done(allowed.id().untyped()) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    match server.load_state(refused.id()) {
        LoadState::Failed(e) => {
            let e = e.to_string();
            assert!(
                e.contains("Model A") && e.contains("../outside/") && e.contains("assets folder"),
                "{e}"
            );
        }
        s => panic!("expected a failure, got {s:?}"),
    }
    assert!(
        matches!(server.load_state(allowed.id()), LoadState::Loaded),
        "{:?}",
        server.load_state(allowed.id())
    );
    std::fs::remove_dir_all(&top).ok();
}

#[test]
fn a_tool_raises_a_body_its_release_returns_it_and_the_mesh_follows() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let script = Script::builtin("poke-a", &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let (a, b) = (bodies[0], bodies[1]);
    app.update();
    let handle = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    let initial = positions(&app, &handle);
    let mut raised = false;
    let mut changes = Vec::new();
    let mut moved: f32 = 0.0;
    for k in 1..=900 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        raised |= level(&app, a) == Level::Precise;
        assert_eq!(level(&app, b), Level::Cage, "B is never touched");
        let now = positions(&app, &handle);
        moved = moved.max(
            now.iter()
                .zip(&initial)
                .map(|(p, q)| Vec3::from_array(*p).distance(Vec3::from_array(*q)))
                .fold(0.0, f32::max),
        );
        let msgs = app.world().resource::<Messages<LevelChanged>>();
        changes.extend(msgs.iter_current_update_messages().copied());
    }
    assert!(raised, "the poke raised A");
    assert_eq!(level(&app, a), Level::Cage, "A returned to its cage");
    assert!(
        moved > 0.01,
        "the rendered mesh followed the poke ({moved})"
    );
    assert_eq!(changes.len(), 2, "{changes:?}");
    assert_eq!((changes[0].entity, changes[0].to), (a, Level::Precise));
    assert_eq!((changes[1].entity, changes[1].to), (a, Level::Cage));
    assert!(changes.iter().all(|c| c.jump_ratio < 0.005));
    let reaction = app.world().get::<ToolReaction>(tool).unwrap();
    assert!(reaction.force.is_finite());
}

fn positions(app: &App, handle: &Handle<Mesh>) -> Vec<[f32; 3]> {
    let mesh = app.world().resource::<Assets<Mesh>>().get(handle).unwrap();
    match mesh.attribute(Mesh::ATTRIBUTE_POSITION).unwrap() {
        VertexAttributeValues::Float32x3(v) => v.clone(),
        _ => panic!("positions are Float32x3"),
    }
}

/// Every body's surface positions, in scene order.
fn surfaces(app: &App, bodies: &[Entity]) -> Vec<Vec<[f32; 3]>> {
    bodies
        .iter()
        .map(|&e| {
            app.world()
                .get::<SimulatedBody>(e)
                .unwrap()
                .body()
                .surface_positions()
                .to_vec()
        })
        .collect()
}

fn run_plugin(file: &str, script_name: &str, steps: usize) -> Vec<Vec<Vec<[f32; 3]>>> {
    run_plugin_on(file, script_name, steps, None)
}

/// [`run_plugin`] with `SoftTissueConfig::threads` set (`None`: the default).
fn run_plugin_on(
    file: &str,
    script_name: &str,
    steps: usize,
    threads: Option<usize>,
) -> Vec<Vec<Vec<[f32; 3]>>> {
    let (mut app, bodies, world) = scene_app(file);
    if let Some(n) = threads {
        app.world_mut().resource_mut::<SoftTissueConfig>().threads = n;
    }
    let script = Script::builtin(script_name, &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let mut out = Vec::new();
    app.update();
    for k in 1..=steps {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        out.push(surfaces(&app, &bodies));
    }
    out
}

#[test]
fn the_plugin_and_the_core_world_give_the_same_states() {
    let (mut app, bodies, mut world) = scene_app(CYLINDERS);
    let script = Script::builtin("push-a-into-b", &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let ti =
        world.add_tool(bevy_soft_tissue::core::contact::Tool::new("tool", script.tool).unwrap());
    let start = tool_transform(&script, 0.0);
    world.tools_mut()[ti]
        .set_pose(
            bevy_soft_tissue::convert::to_core(start.translation),
            bevy_soft_tissue::convert::to_core(start.rotation * Vec3::Y),
        )
        .unwrap();
    // The first update builds the bodies (and steps once with the tool at its start).
    app.update();
    world.step_fixed().unwrap();
    let mut precise_steps = 0;
    for k in 1..=600 {
        let (p, a, actions) = drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        let t = &mut world.tools_mut()[ti];
        t.set_pose(p, a).unwrap();
        for act in actions {
            match act {
                ScriptAction::Grab => t.grab(),
                ScriptAction::Release => t.release(),
                ScriptAction::Cautery(w) => t.set_cautery(w).unwrap(),
            }
        }
        world.step_fixed().unwrap();
        for (e, b) in bodies.iter().zip(world.bodies()) {
            let plugin = app.world().get::<SimulatedBody>(*e).unwrap().body();
            assert_eq!(
                plugin.surface_positions(),
                b.surface_positions(),
                "{} differs at step {k}",
                b.name()
            );
            assert_eq!(plugin.body().level(), b.body().level());
            if b.body().level() == bevy_soft_tissue::core::precision::Level::Precise {
                precise_steps += 1;
            }
        }
    }
    assert!(precise_steps > 100, "the push must raise the bodies");
    assert_eq!(
        app.world().resource::<SoftTissueStatus>().steps,
        world.step_count()
    );
}

#[test]
fn two_runs_are_bit_identical() {
    let a = run_plugin(CYLINDERS, "poke-a", 300);
    let b = run_plugin(CYLINDERS, "poke-a", 300);
    assert_eq!(a, b);
}

/// The organs under a poke of the liver, every body at its precise level most of the time:
/// the same surfaces at every step on one thread and on two (and the pool is used).
#[test]
fn one_and_two_threads_give_bit_identical_states() {
    let one = run_plugin_on(ORGANS, "poke-liver", 200, Some(1));
    let two = run_plugin_on(ORGANS, "poke-liver", 200, Some(2));
    assert_eq!(one.len(), 200);
    assert_eq!(one, two);
    let (mut app, _, _) = scene_app(ORGANS);
    app.world_mut().resource_mut::<SoftTissueConfig>().threads = 2;
    app.update();
    app.update();
    assert_eq!(app.world().resource::<SoftTissueThreads>().count(), 2);
}

#[test]
fn the_step_has_no_system_order_ambiguity() {
    let (mut app, _, _) = scene_app(CYLINDERS);
    let labels = [
        SoftTissueSchedule.intern(),
        FixedUpdate.intern(),
        PostUpdate.intern(),
    ];
    for label in labels {
        app.edit_schedule(label, |s| {
            s.set_build_settings(ScheduleBuildSettings {
                ambiguity_detection: LogLevel::Error,
                ..default()
            });
        });
    }
    let world = app.world_mut();
    for label in labels {
        world.schedule_scope(label, |world, schedule| {
            schedule
                .initialize(world)
                .unwrap_or_else(|e| panic!("{label:?}: {e}"));
        });
    }
}

#[test]
fn pause_single_step_method_change_and_reset() {
    let (mut app, bodies, _) = scene_app(CYLINDERS);
    app.update();
    let steps = |app: &App| app.world().resource::<SoftTissueStatus>().steps;
    assert_eq!(steps(&app), 1);
    app.world_mut().resource_mut::<SoftTissueStatus>().paused = true;
    app.update();
    app.update();
    assert_eq!(steps(&app), 1, "paused");
    app.world_mut().resource_mut::<SoftTissueStatus>().step_once = true;
    app.update();
    app.update();
    assert_eq!(steps(&app), 2, "exactly one step");
    app.world_mut().resource_mut::<SoftTissueStatus>().paused = false;
    // Method changed at run time.
    app.world_mut()
        .get_mut::<SoftBody>(bodies[0])
        .unwrap()
        .method = PreciseMethod::CorotationalFem;
    app.update();
    let pl = *app.world().get::<PrecisionLevel>(bodies[0]).unwrap();
    assert_eq!(pl.method, PreciseMethod::CorotationalFem);
    // Pinned up, then reset.
    app.world_mut()
        .entity_mut(bodies[1])
        .insert(PinnedLevel(Level::Precise));
    app.update();
    assert_eq!(level(&app, bodies[1]), Level::Precise);
    // Unpinned it stays up until it rests; a reset brings everything back to the start.
    app.world_mut()
        .entity_mut(bodies[1])
        .remove::<PinnedLevel>();
    app.update();
    app.world_mut().write_message(ResetSimulation);
    app.update();
    assert_eq!(steps(&app), 1, "reset, then one step");
    assert_eq!(level(&app, bodies[1]), Level::Cage);
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    // The read-out components follow the reset though the body now sleeps: its cage is the
    // active level again, at rest.
    let cage = app.world().get::<GreenCage>(bodies[1]).unwrap();
    assert!(
        cage.active,
        "the cage component still shows the precise level"
    );
    let sim = app.world().get::<SimulatedBody>(bodies[1]).unwrap().body();
    let rest = sim.body().cage().cage().vertices();
    for (v, r) in cage.vertices.iter().zip(rest) {
        assert!((*v - bevy_soft_tissue::convert::to_bevy(r)).length() < 1e-5);
    }
}

#[test]
fn a_failed_stage_stops_the_step_there_and_no_nan_reaches_a_mesh() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let script = Script::builtin("poke-a", &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let a = bodies[0];
    app.update();
    let mut k = 0;
    while level(&app, a) != Level::Precise {
        k += 1;
        assert!(k < 400, "the poke never raised A");
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
    }
    let status = |app: &App| app.world().resource::<SoftTissueStatus>().clone();
    let handle = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    let mesh_before = positions(&app, &handle);
    let surfaces_before = surfaces(&app, &bodies);
    let steps = status(&app).steps;
    // The tool's pose goes bad: the prepare stage fails on it.
    app.world_mut()
        .get_mut::<Transform>(tool)
        .unwrap()
        .translation
        .x = f32::NAN;
    app.update();
    let s = status(&app);
    let error = s.error.clone().expect("the step failed");
    assert!(error.to_string().contains("tool"), "{error}");
    assert_eq!(error.body, Some(tool), "the error names the tool's entity");
    assert!(s.paused);
    // The stages after the failing one did not run: no step was counted, no state moved,
    // and the rendered mesh kept its finite positions.
    assert_eq!(s.steps, steps);
    assert_eq!(surfaces(&app, &bodies), surfaces_before);
    let mesh_now = positions(&app, &handle);
    assert_eq!(mesh_now, mesh_before);
    assert!(mesh_now.iter().flatten().all(|c| c.is_finite()));
    // Unpaused with the error still set, nothing runs.
    app.world_mut().resource_mut::<SoftTissueStatus>().paused = false;
    app.update();
    assert_eq!(status(&app).steps, steps);
    // A reset clears the error though the simulation is stopped, and steps run again.
    drive_tool(&mut app, tool, &script, 0, dt);
    app.world_mut().write_message(ResetSimulation);
    app.update();
    let s = status(&app);
    assert!(s.error.is_none(), "{:?}", s.error);
    assert_eq!(s.steps, 1);
    assert!(
        positions(&app, &handle)
            .iter()
            .flatten()
            .all(|c| c.is_finite())
    );
}

/// A finer cylinder than the simulation's (Bevy's primitive mesh, 48 around, axis y) of the
/// paper's size times `scale`, turned by `rotation` and moved by `shift`.
fn fine_cylinder(scale: f32, rotation: Quat, shift: Vec3) -> Mesh {
    Cylinder::new(0.62 * scale, 1.72 * scale)
        .mesh()
        .resolution(48)
        .segments(8)
        .build()
        .rotated_by(rotation)
        .translated_by(shift)
}

/// In the coordinates of the cylinder mesh file (axis z).
fn y_to_z() -> Quat {
    Quat::from_rotation_arc(Vec3::Y, Vec3::Z)
}

fn mesh_positions(mesh: &Mesh) -> Vec<[f32; 3]> {
    match mesh.attribute(Mesh::ATTRIBUTE_POSITION).unwrap() {
        VertexAttributeValues::Float32x3(v) => v.clone(),
        _ => panic!("positions are Float32x3"),
    }
}

fn max_distance(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(p, q)| Vec3::from_array(*p).distance(Vec3::from_array(*q)))
        .fold(0.0, f32::max)
}

#[test]
fn finer_visual_meshes_follow_the_simulation() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let (a, b) = (bodies[0], bodies[1]);
    let centre = world.bodies()[0].mesh().bbox().center();
    // The scene stands the cylinders along y.
    let source = fine_cylinder(
        1.0,
        Quat::IDENTITY,
        bevy_soft_tissue::convert::to_bevy(&centre),
    );
    let source_positions = mesh_positions(&source);
    let handle = app.world_mut().resource_mut::<Assets<Mesh>>().add(source);
    app.world_mut()
        .entity_mut(a)
        .insert(VisualMesh::mesh(handle.clone()));
    app.world_mut()
        .entity_mut(b)
        .insert(VisualMesh::Subdivided { levels: 2 });
    let script = Script::builtin("poke-a", &world).unwrap();
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    app.update();
    // Settled under gravity, the visual mesh is where it was given, up to the sag of the
    // simulated surface; the asset itself is not touched.
    assert_eq!(app.world().get::<VisualMeshError>(a), None);
    assert_eq!(app.world().get::<VisualMeshError>(b), None);
    let drawn = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    assert_ne!(drawn, handle);
    let initial = positions(&app, &drawn);
    assert_eq!(initial.len(), source_positions.len());
    let sim = app.world().get::<SimulatedBody>(a).unwrap().body();
    let file: Vec<[f32; 3]> = sim
        .surface_nodes()
        .iter()
        .map(|&i| bevy_soft_tissue::convert::to_bevy(&sim.mesh().positions()[i as usize]).into())
        .collect();
    let sag = max_distance(sim.surface_positions(), &file);
    let off = max_distance(&initial, &source_positions);
    assert!(off <= 1.2 * sag + 1e-5, "{off} vs sag {sag}");
    // The subdivided surface has 16 times the simulation's triangles.
    let sub = app.world().get::<Mesh3d>(b).unwrap().0.clone();
    let sub_mesh = app.world().resource::<Assets<Mesh>>().get(&sub).unwrap();
    let sim_triangles = world.bodies()[1].surface_triangles().len();
    assert_eq!(sub_mesh.indices().unwrap().len(), 3 * 16 * sim_triangles);
    let surface0 = surfaces(&app, &[a])[0].clone();
    let (mut visual_moved, mut surface_moved) = (0.0f32, 0.0f32);
    for k in 1..=900 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        visual_moved = visual_moved.max(max_distance(&positions(&app, &drawn), &initial));
        surface_moved = surface_moved.max(max_distance(&surfaces(&app, &[a])[0], &surface0));
    }
    // The fine mesh deforms with the simulated surface: by as much, within what linear
    // interpolation inside the tetrahedra loses at a poke between nodes.
    assert!(surface_moved > 0.01, "{surface_moved}");
    assert!(
        visual_moved > 0.5 * surface_moved && visual_moved < 1.2 * surface_moved,
        "visual {visual_moved} vs surface {surface_moved}"
    );
    // Back at rest, the visual mesh is back where it started.
    assert_eq!(level(&app, a), Level::Cage);
    let back = max_distance(&positions(&app, &drawn), &initial);
    let surface_back = max_distance(&surfaces(&app, &[a])[0], &surface0);
    assert!(
        back <= 1.5 * surface_back + 1e-5,
        "{back} vs {surface_back}"
    );
    assert_eq!(
        app.world()
            .resource::<Assets<Mesh>>()
            .get(&handle)
            .map(mesh_positions),
        Some(source_positions)
    );
}

#[test]
fn visual_meshes_are_placed_with_the_body_and_mismatched_ones_refused() {
    let mut app = app(0.02);
    let mesh = cylinder_asset(&mut app);
    // No gravity (the default): the body stays in its file shape, so the drawn mesh must be
    // exactly the visual mesh (drawn in the entity's frame, placed by its transform).
    let place = Transform::from_xyz(3.0, -1.0, 0.5)
        .with_rotation(Quat::from_rotation_x(1.0))
        .with_scale(Vec3::splat(0.5));
    let fine = fine_cylinder(1.0, y_to_z(), Vec3::ZERO);
    let want: Vec<[f32; 3]> = mesh_positions(&fine);
    let fine = app.world_mut().resource_mut::<Assets<Mesh>>().add(fine);
    let placed = app
        .world_mut()
        .spawn((SoftBody::new(mesh.clone()), place, VisualMesh::mesh(fine)))
        .id();
    // Ten times too large: most vertices are far outside the body.
    let huge = app
        .world_mut()
        .resource_mut::<Assets<Mesh>>()
        .add(fine_cylinder(10.0, y_to_z(), Vec3::ZERO));
    let wrong = app
        .world_mut()
        .spawn((
            Name::new("wrong"),
            SoftBody::new(mesh),
            VisualMesh::mesh(huge),
        ))
        .id();
    app.update();
    let drawn = app.world().get::<Mesh3d>(placed).unwrap().0.clone();
    let off = max_distance(&positions(&app, &drawn), &want);
    assert!(off < 1e-4, "{off}");
    assert!(app.world().get::<VisualMeshError>(placed).is_none());
    let error = app.world().get::<VisualMeshError>(wrong).expect("refused");
    let text = error.to_string();
    assert!(
        text.contains("`wrong`") && text.contains("farther than the limit"),
        "{text}"
    );
    // The refused body is drawn with its simulation surface.
    let drawn = app.world().get::<Mesh3d>(wrong).unwrap().0.clone();
    let sim = app.world().get::<SimulatedBody>(wrong).unwrap();
    assert_eq!(
        positions(&app, &drawn).len(),
        sim.body().surface_positions().len()
    );
}

#[cfg(feature = "haptics")]
#[test]
fn a_haptic_device_pokes_through_the_haptic_thread_and_feels_the_tissue() {
    use bevy_soft_tissue::core::haptics::{HapticConfig, VirtualDevice};
    use bevy_soft_tissue::haptics::{HapticTool, SoftTissueHapticsPlugin};
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    app.add_plugins(SoftTissueHapticsPlugin);
    let a = bodies[0];
    let (lo, hi) = world.bodies()[0].collider().bounds();
    let y = 0.5 * (lo[1] + hi[1]);
    let outside = bevy_soft_tissue::core::Vec3::new(lo[0] - 0.2, y, 0.5 * (lo[2] + hi[2]));
    let (device, handle) = VirtualDevice::new(outside, 8.0);
    let config = HapticConfig {
        record_seconds: 30.0,
        stats_seconds: 30.0,
        spin_us: 200.0,
        ..HapticConfig::default()
    };
    let haptic = HapticTool::start(Box::new(device), config, 0.0).unwrap();
    let tool = app
        .world_mut()
        .spawn((SoftTool::sphere(0.05), Transform::default(), haptic))
        .id();
    app.update();
    // Push the device 0.1 into A from its -x side, in small steps (a hand, not a jump: a
    // proxy that crosses the surface between two physics steps would pass through it).
    let inside = bevy_soft_tissue::core::Vec3::new(lo[0] + 0.1, outside.y, outside.z);
    let mut felt = false;
    for k in 0..1500 {
        let s = (k as f64 / 300.0).min(1.0);
        handle.set(outside + (inside - outside) * s, 0);
        app.update();
        std::thread::sleep(Duration::from_millis(2));
        if s == 1.0 && level(&app, a) == Level::Precise && handle.force().x < -0.1 {
            felt = true;
            break;
        }
    }
    assert!(
        felt,
        "force {:?}, level {:?}",
        handle.force(),
        level(&app, a)
    );
    // The tool is where the thread's proxy is: held back by the tissue, short of the device.
    let tool_x = app.world().get::<Transform>(tool).unwrap().translation.x as f64;
    assert!(tool_x < inside.x, "tool {tool_x} vs device {}", inside.x);
    assert!(handle.force().norm() <= 8.0 + 1e-9);
    let h = app.world().get::<HapticTool>(tool).unwrap();
    // The thread got the real time it asks for by default, or says why not.
    let p = h.priority();
    assert!(p.is_real_time() || p.refused.is_some(), "{p}");
    assert!(
        h.model().active && h.model().normal.x < 0.0,
        "{:?}",
        h.model()
    );
    // Removing the component stops the thread and leaves the device with no force.
    app.world_mut().entity_mut(tool).remove::<HapticTool>();
    assert_eq!(handle.force(), bevy_soft_tissue::core::Vec3::zeros());
}

/// A mesh with the defects real meshes have (two cubes meeting along an edge only, so
/// non-manifold boundary edges and vertices, and a node no tetrahedron uses) is built,
/// drawn with a Loop-subdivided visual mesh, poked at its pinch, rises and comes back; the
/// drawn mesh follows.
#[test]
fn a_non_manifold_mesh_simulates_and_draws_in_the_plugin() {
    use bevy_soft_tissue::core::mesh::TetMesh;
    use bevy_soft_tissue::core::mesh::generate::block;
    use bevy_soft_tissue::core::{Vec3 as V, contact::ToolShape};
    let a = block(V::zeros(), V::repeat(0.5), [3, 3, 3]).unwrap();
    let b = block(V::new(0.5, 0.5, 0.0), V::new(1.0, 1.0, 0.5), [3, 3, 3]).unwrap();
    let mut points: Vec<V> = Vec::new();
    let mut tets = Vec::new();
    for m in [&a, &b] {
        let map: Vec<usize> = m
            .positions()
            .iter()
            .map(|p| match points.iter().position(|q| q == p) {
                Some(i) => i,
                None => {
                    points.push(*p);
                    points.len() - 1
                }
            })
            .collect();
        tets.extend(m.tets().iter().map(|t| t.map(|i| map[i as usize])));
    }
    points.push(V::new(3.0, 3.0, 3.0));
    let mesh = TetMesh::new(points, tets).unwrap();
    let nodes = mesh.node_count();
    let mut app = app(0.01);
    let handle = app
        .world_mut()
        .resource_mut::<Assets<TetMeshAsset>>()
        .add(TetMeshAsset::from(mesh));
    assert!(nodes > 0);
    app.world_mut().resource_mut::<SoftTissueConfig>().contact =
        bevy_soft_tissue::core::contact::ContactConfig::for_scale(0.5);
    let body = app
        .world_mut()
        .spawn((
            SoftBody::new(handle).with_anchor(Anchor::SoftToRest { stiffness: 1.0 }),
            VisualMesh::Subdivided { levels: 1 },
        ))
        .id();
    // A ball pressed into the notch where the two cubes meet.
    let r = 0.08f32;
    let dir = Vec3::new(1.0, -1.0, 0.0).normalize();
    let start = Vec3::new(0.5 - r, 0.5 + r, 0.25) - dir * 0.1;
    let tool = app
        .world_mut()
        .spawn((
            SoftTool {
                shape: ToolShape::Sphere { radius: r as f64 },
                grab: false,
                cautery_watts: 0.0,
            },
            Transform::from_translation(start),
        ))
        .id();
    app.update();
    app.update();
    assert!(
        app.world().get::<SoftBodyError>(body).is_none(),
        "{:?}",
        app.world().get::<SoftBodyError>(body)
    );
    assert_eq!(app.world().get::<VisualMeshError>(body), None);
    let drawn = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    let initial = positions(&app, &drawn);
    let (mut raised, mut moved, mut elastic) = (false, 0.0f32, 0.0f64);
    for k in 1..=400 {
        let t = k as f32 * 0.01;
        let depth = 0.15 * if t < 1.0 { t } else { (2.0 - t).max(0.0) };
        app.world_mut()
            .entity_mut(tool)
            .get_mut::<Transform>()
            .unwrap()
            .translation = start + dir * depth;
        app.update();
        raised |= level(&app, body) == Level::Precise;
        moved = moved.max(max_distance(&positions(&app, &drawn), &initial));
        // Energies on request: finite, and the pressed body stores elastic energy.
        let e = app.world().get::<SimulatedBody>(body).unwrap().energies();
        assert!(e.kinetic.is_finite() && e.kinetic >= 0.0 && e.elastic.is_finite());
        elastic = elastic.max(e.elastic);
        assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    }
    assert!(raised, "the poke did not raise the body");
    assert!(moved > 0.01, "the drawn mesh did not follow ({moved})");
    assert!(elastic > 0.0, "no elastic energy while pressed");
    assert_eq!(level(&app, body), Level::Cage, "it did not come back");
}
