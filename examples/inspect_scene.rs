//! Headless example: load the paper's organs scene from `assets/scenes/organs.scene.ron`, load each
//! body's tetrahedral mesh and print its size, quality and precise-method settings.
//!
//! Run: `cargo run --example inspect_scene [-- path/to/scene.ron]`

use bevy_soft_tissue::core::mesh::io::read_tet_mesh;
use bevy_soft_tissue::core::scenario::{MeshSource, Scene};
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    let scene_path = std::env::args()
        .nth(1)
        .map(Into::into)
        .unwrap_or_else(|| assets.join("scenes/organs.scene.ron"));
    let text = std::fs::read_to_string(&scene_path)?;
    let scene = Scene::from_ron(&text, &scene_path.display().to_string())?;
    println!("scene '{}', gravity {:?}", scene.name, scene.gravity);
    for body in &scene.bodies {
        let mesh = match &body.mesh {
            MeshSource::File(f) => read_tet_mesh(assets.join(f))?.mesh,
            MeshSource::Generated { organ, resolution } => organ.generate(*resolution)?,
        };
        let q = mesh.quality();
        println!(
            "{:10} {:?}: {} nodes, {} tets, {} surface triangles, volume {:.3}, dihedral {:.1}..{:.1} deg",
            body.name,
            body.precise,
            mesh.node_count(),
            mesh.tet_count(),
            mesh.surface().triangles().len(),
            mesh.volume(),
            q.min_dihedral_deg,
            q.max_dihedral_deg
        );
    }
    Ok(())
}
