#![no_main]
//! Fuzz target: a scene file (RON) is parsed and validated, then every body is placed on a
//! small mesh and given its level settings: each step returns Ok or a typed error.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::{body_settings, placed_mesh};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(scene) = Scene::from_ron(text, "fuzz.scene.ron") else {
        return;
    };
    let Ok(tet) = TetMesh::new(
        vec![Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()],
        vec![[0, 1, 2, 3]],
    ) else {
        return;
    };
    for body in &scene.bodies {
        if let Ok(mesh) = placed_mesh(&tet, &body.placement) {
            let _ = body_settings(body, &mesh, Vec3::from(scene.gravity));
        }
    }
});
