//! Fuzzed blade paths: random strokes of a scalpel, grown step by step as a simulation grows
//! an incision (`world::Incision`, `mesh::cut::recut_within`), through every mesh of the
//! shared real-world library and ours, with the tissue moved between the steps. Nothing may
//! panic or give a non-finite position, every kept cut keeps the volume, every element
//! positive, no new boundary edge outside two triangles and no orphan node.

mod support;

use std::path::{Path, PathBuf};

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::{CutHistory, CutOptions, check, cut, recut_within};
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::world::Incision;

/// `strokes` random strokes of `steps` steps each through `mesh`.
fn fuzz(name: &str, mesh: &TetMesh, strokes: usize, steps: usize, seed: u64) -> usize {
    let mut rng = support::Rng::new(seed);
    let mut unit = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let start = check(mesh, &cut(mesh, &[], &CutOptions::default()).unwrap());
    let tets_before = mesh.tet_count();
    let bbox = mesh.bbox();
    let d = bbox.diagonal();
    let mut mesh = mesh.clone();
    let mut history: Option<CutHistory> = None;
    let mut kept = 0;
    for s in 0..strokes {
        // A random edge through a random point, moved along a random direction that turns
        // a little every step.
        let point = |u: f64, v: f64, w: f64| {
            bbox.min + (bbox.max - bbox.min).component_mul(&Vec3::new(u, v, w))
        };
        let centre = point(unit(), unit(), unit());
        let along = Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize();
        let mut heading = Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize();
        let length = (0.2 + 0.6 * unit()) * d;
        let mut tip = centre - heading * 0.3 * d;
        let speed = (0.02 + 0.08 * unit()) * d;
        let mut incision = Incision::new((tip, tip + along * length));
        for k in 0..steps {
            let turn = Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5) * 0.3 * unit();
            heading = (heading + turn).normalize();
            tip += heading * speed;
            let stroke = incision.advance((tip, tip + along * length));
            let (strip, mark) = incision.pending(0);
            if strip.is_empty() {
                continue;
            }
            let before = mesh.clone();
            let after = recut_within(
                &mesh,
                history.as_ref(),
                &strip,
                &stroke,
                incision.id(),
                &CutOptions::default(),
            )
            .unwrap_or_else(|e| panic!("{name}: stroke {s} step {k}: {e}"));
            if after.separated > 0 {
                let c = check(&before, &after);
                assert!(c.volume_change.abs() <= 1e-9, "{name} {s}/{k}: {c:?}");
                assert!(c.smallest_volume_ratio > 0.0, "{name} {s}/{k}: {c:?}");
                assert!(
                    c.non_manifold_edges <= start.non_manifold_edges,
                    "{name} {s}/{k}: {c:?}"
                );
                assert!(
                    c.orphan_nodes <= start.orphan_nodes,
                    "{name} {s}/{k}: {c:?}"
                );
                assert!(
                    after
                        .mesh
                        .positions()
                        .iter()
                        .all(|p| p.iter().all(|v| v.is_finite())),
                    "{name} {s}/{k}: a position is not finite"
                );
                mesh = after.mesh;
                history = Some(after.history);
                incision.consumed(0, mark);
                kept += 1;
            } else if after.bisected == 0 {
                // The worlds' rule: only a strip that crossed stays pending.
                incision.consumed(0, mark);
            }
            // The tissue moves between the steps: a small smooth swirl.
            let amp = 1e-3 * d * unit();
            let moved = mesh
                .positions()
                .iter()
                .map(|p| {
                    let q = (p - bbox.min) / d;
                    p + Vec3::new((3.0 * q.y).sin(), (3.0 * q.z).sin(), (3.0 * q.x).sin()) * amp
                })
                .collect();
            let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
            // A motion that turned an element over is not taken (the cut of a body refuses
            // to cut an inverted shape the same way).
            if let Ok(m) = TetMesh::new(moved, tets)
                && m.warnings().is_empty() == mesh.warnings().is_empty()
            {
                mesh = m;
            }
        }
    }
    eprintln!(
        "{name}: {strokes} strokes of {steps} steps, {kept} kept cuts, {tets_before} -> {} \
         tetrahedra, {} -> {} pieces",
        mesh.tet_count(),
        start.pieces,
        mesh.component_count()
    );
    kept
}

fn readable(dir: &Path) -> Vec<(PathBuf, TetMesh)> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    // The library's deliberately broken files are refused by the readers (tested in
    // `formats.rs`); every mesh that reads is cut.
    files
        .into_iter()
        .filter_map(|p| read_tet_mesh(&p).ok().map(|m| (p, m.mesh)))
        .collect()
}

#[test]
fn fuzzed_blade_paths_through_every_shared_mesh_keep_it_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    let Some(dir) = support::shared_folder(
        &dir,
        "fuzzed_blade_paths_through_every_shared_mesh_keep_it_valid",
        support::shared_meshes_required(),
    ) else {
        return;
    };
    let meshes = readable(dir);
    assert!(meshes.len() >= 5, "{} meshes read", meshes.len());
    let mut cut_any = 0;
    for (k, (path, mesh)) in meshes.iter().enumerate() {
        let name = path.file_name().unwrap().to_string_lossy();
        if fuzz(&name, mesh, 6, 12, 100 + k as u64) > 0 {
            cut_any += 1;
        }
    }
    assert!(cut_any >= 3, "the strokes cut {cut_any} of the meshes");
}

#[test]
fn fuzzed_blade_paths_through_our_meshes_keep_them_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes");
    let meshes = readable(&dir);
    let mut cut_any = 0;
    for (k, (path, mesh)) in meshes.iter().enumerate() {
        let name = path.file_name().unwrap().to_string_lossy();
        if fuzz(&name, mesh, 6, 12, 200 + k as u64) > 0 {
            cut_any += 1;
        }
    }
    assert!(
        cut_any >= 3,
        "the strokes cut {cut_any} of {} meshes",
        meshes.len()
    );
}
