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
