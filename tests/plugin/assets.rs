//! Meshes and scenes through the asset server.

use super::*;

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

/// A closed surface loads as a soft body: meshed on load with the `.meta` settings, its
/// surface kept as the `Surface` sub-asset to draw with, and cached so the next start reads
/// the mesh back instead of meshing again.
/// A body spawned without a `Name` is called by its mesh's file name, in the ECS and in the
/// simulation built from it (which the core's errors and the log use), not by an entity id;
/// a body with a `Name` keeps it; a mesh made in code leaves the body unnamed.
#[test]
fn a_body_without_a_name_is_called_by_its_mesh_file() {
    let mut app = app(0.02);
    let server = app.world().resource::<AssetServer>().clone();
    let liver: Handle<TetMeshAsset> = server.load("meshes/liver.vtk");
    let unnamed = app.world_mut().spawn(SoftBody::new(liver.clone())).id();
    let named = app
        .world_mut()
        .spawn((Name::new("my liver"), SoftBody::new(liver)))
        .id();
    let handle = cylinder_asset(&mut app);
    let in_code = app.world_mut().spawn(SoftBody::new(handle)).id();
    for _ in 0..3000 {
        app.update();
        if [unnamed, named, in_code]
            .iter()
            .all(|&e| app.world().get::<SoftBodyState>(e).is_some())
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let world = app.world();
    let sim_name = |e: Entity| {
        world
            .get::<SoftBodyState>(e)
            .unwrap()
            .body()
            .name()
            .to_owned()
    };
    assert_eq!(world.get::<Name>(unnamed).unwrap().as_str(), "liver.vtk");
    assert_eq!(sim_name(unnamed), "liver.vtk");
    assert_eq!(world.get::<Name>(named).unwrap().as_str(), "my liver");
    assert_eq!(sim_name(named), "my liver");
    assert!(world.get::<Name>(in_code).is_none());
    assert_eq!(sim_name(in_code), format!("{in_code}"));
    let server = world.resource::<AssetServer>();
    let label = |e: Entity| {
        bevy_soft_tissue::assets::body_label(
            e,
            world.get::<Name>(e),
            world.get::<SoftBody>(e),
            server,
        )
    };
    assert_eq!(label(unnamed), "liver.vtk");
    assert_eq!(label(in_code), format!("{in_code}"));
}

#[test]
fn a_surface_file_becomes_a_body_and_its_mesh_is_cached() {
    surface_becomes_a_cached_body("meshes/sphere.stl", "stl");
}

/// The same with a glTF file whose buffer lies in a `.bin` beside it (written by pygltflib,
/// tests/fixtures/make_surface_fixtures.py), read through the asset server.
#[test]
fn a_gltf_surface_with_its_buffer_beside_it_becomes_a_body() {
    surface_becomes_a_cached_body("meshes/sphere_external.gltf", "gltf");
}

fn surface_becomes_a_cached_body(file: &str, tag: &str) {
    use bevy_soft_tissue::SurfaceLoaderSettings;
    let cache = std::env::temp_dir().join(format!(
        "soft-tissue-surface-cache-{tag}-{}",
        std::process::id()
    ));
    std::fs::remove_dir_all(&cache).ok();
    let mut counts = Vec::new();
    for run in 0..2 {
        let mut app = app(0.01);
        // Both handles with the same settings (as a `.meta` file would give every load):
        // a load of the same file with other settings loads it again with those.
        let settings = {
            let dir = cache.clone();
            move |s: &mut SurfaceLoaderSettings| {
                s.target_tets = 600;
                s.cache_dir = Some(dir.clone());
            }
        };
        let server = app.world().resource::<AssetServer>().clone();
        let mesh: Handle<TetMeshAsset> = server
            .load_builder()
            .with_settings(settings.clone())
            .load(file.to_string());
        let surface: Handle<Mesh> = server
            .load_builder()
            .with_settings(settings)
            .load(format!("{file}#Surface"));
        let body = app
            .world_mut()
            .spawn((SoftBody::new(mesh.clone()), VisualMesh::mesh(surface)))
            .id();
        for _ in 0..3000 {
            app.update();
            if app.world().get::<SoftBodyState>(body).is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let sim = app.world().get::<SoftBodyState>(body).expect("built");
        counts.push((
            sim.body().mesh().node_count(),
            sim.body().mesh().tet_count(),
        ));
        let files: Vec<_> = std::fs::read_dir(&cache).unwrap().collect();
        assert_eq!(files.len(), 1, "run {run}: one cached mesh");
        // Drawn with the surface once its sub-asset is in `Assets<Mesh>`.
        for _ in 0..3000 {
            app.update();
            if app.world().get::<Mesh3d>(body).is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(app.world().get::<VisualMeshError>(body).is_none());
        assert!(
            app.world()
                .get::<bevy_soft_tissue::EmbeddedVisual>(body)
                .is_some(),
            "drawn with the surface"
        );
    }
    assert_eq!(
        counts[0], counts[1],
        "the second start reads the same mesh back"
    );
    assert!((400..=800).contains(&counts[0].1), "{:?}", counts[0]);
    std::fs::remove_dir_all(&cache).ok();
}
