//! A new user's headless app: the plugin from a path dependency, built with this crate's own
//! profile. Times the whole plugin step with the liver pinned precise (at rest) and pinned at
//! its cage, 500 steps after 50, median, p99 and largest.
use std::time::Duration;

use bevy::prelude::*;
use bevy::time::TimeUpdateStrategy;
use bevy_soft_tissue::prelude::*;
use bevy_soft_tissue::{SoftTissueAssetPlugin, SoftTissueStatus, TetMeshAsset};

fn run(pinned: Option<Level>) -> (f64, f64, f64) {
    let dt = 0.01;
    let mut app = App::new();
    app.add_plugins((
        MinimalPlugins,
        TransformPlugin,
        AssetPlugin::default(),
        SoftTissueAssetPlugin,
        bevy_soft_tissue::SoftTissuePhysicsPlugin::default(),
    ));
    // The physics steps at Bevy's fixed timestep.
    app.insert_resource(Time::<Fixed>::from_seconds(dt));
    app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
        dt,
    )));
    app.update();
    let mesh = bevy_soft_tissue::core::mesh::io::read_tet_mesh(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../assets/meshes/liver.vtk"
    ))
    .unwrap()
    .mesh;
    let handle = app
        .world_mut()
        .resource_mut::<Assets<TetMeshAsset>>()
        .add(TetMeshAsset::from(mesh));
    let mut e = app.world_mut().spawn(SoftBody::new(handle));
    if let Some(l) = pinned {
        e.insert(PinnedLevel(l));
    }
    for _ in 0..50 {
        app.update();
    }
    app.world_mut()
        .resource_mut::<SoftTissueStatus>()
        .recent
        .clear();
    for _ in 0..500 {
        app.update();
    }
    let s = app.world().resource::<SoftTissueStatus>().recent.summary();
    (s.step.median_us, s.step.p99_us, s.step.max_us)
}

fn main() {
    for (name, pin) in [
        ("precise", Some(Level::Precise)),
        ("cage", Some(Level::Cage)),
    ] {
        let (m, p, x) = run(pin);
        println!("liver {name}: whole plugin step median {m:.1} us, p99 {p:.1}, max {x:.1}");
    }
}
