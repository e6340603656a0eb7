//! The boundary onto the input surface: every boundary node projected where the quality
//! bound allows, then the creases and corners the lattice rounded off fitted, interior
//! nodes moving to make room.

use rayon::prelude::*;

use super::passes::Goal;
use crate::Vec3;
use crate::mesh::TetMesh;
use crate::mesh::quality::{tet_quality_deg, tet_worst_cos};
use crate::mesh::surface_tree::SurfaceTree;

/// Projection and crease fit of a stuffed mesh toward `goal`: the mesh, the boundary nodes
/// projected and those then moved onto creases and corners.
pub(super) fn onto_surface(mesh: TetMesh, goal: &Goal<'_>) -> (TetMesh, usize, usize) {
    let (mesh, projected) = project_boundary(mesh, goal.tree, goal.min_dihedral);
    let (mesh, snapped) = fit_features(mesh, goal.surface_samples, goal.min_dihedral, goal.tol);
    (mesh, projected, snapped)
}

/// Whether node `v`'s tetrahedra are positive and keep every dihedral angle in
/// [`min_dihedral`, 180 - `min_dihedral`] at positions `x`.
pub(super) fn node_ok(mesh: &TetMesh, x: &[Vec3], v: usize, min_dihedral: f64) -> bool {
    mesh.node_tets(v).iter().all(|&t| {
        let p = mesh.tets()[t as usize].map(|i| x[i as usize]);
        tet_quality_deg(&p) >= min_dihedral
    })
}

/// Creases and corners the lattice rounded off: each sample of the input surface farther
/// than `tol` from the boundary, farthest first, pulls the nearest node of the boundary
/// triangle it is closest to onto itself, where that node's tetrahedra keep the quality
/// bound (interior nodes may move to make room, see `make_room`); a node moves once. A few
/// rounds, each against the boundary as the last left it. The moved nodes stay on the input
/// surface. Returns the mesh and the nodes moved.
fn fit_features(mesh: TetMesh, samples: &[Vec3], min_dihedral: f64, tol: f64) -> (TetMesh, usize) {
    let mut x = mesh.positions().to_vec();
    let triangles = mesh.surface().triangles().to_vec();
    let mut locked = vec![false; x.len()];
    let tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let node_tets: Vec<Vec<usize>> = (0..x.len())
        .map(|v| mesh.node_tets(v).iter().map(|&k| k as usize).collect())
        .collect();
    let mut boundary = vec![false; x.len()];
    for &v in mesh.surface().vertices() {
        boundary[v as usize] = true;
    }
    // (Which interior nodes moved does not matter here.)
    let mut moved_inside = Vec::new();
    let mut snapped = 0;
    for _round in 0..4 {
        let far: Vec<(f64, usize, usize)> = {
            let tree = SurfaceTree::new(&x, &triangles);
            let mut far: Vec<(f64, usize, usize)> = samples
                .par_iter()
                .enumerate()
                .filter_map(|(i, q)| {
                    let (_, d, t) = tree.closest_triangle(q)?;
                    (d > tol).then_some((d, i, t))
                })
                .collect();
            far.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            far
        };
        let mut moved = 0;
        for (_, i, t) in far {
            let q = samples[i];
            let corners = triangles[t].map(|n| x[n as usize]);
            let w = crate::geometry::closest_on_triangle(&q, &corners[0], &corners[1], &corners[2]);
            let c = corners[0] * w[0] + corners[1] * w[1] + corners[2] * w[2];
            if (c - q).norm() <= tol {
                continue; // an earlier move brought the boundary near enough
            }
            let mut nodes = triangles[t].map(|n| n as usize);
            nodes.sort_by(|&a, &b| {
                (x[a] - q)
                    .norm_squared()
                    .total_cmp(&(x[b] - q).norm_squared())
                    .then(a.cmp(&b))
            });
            for n in nodes {
                if locked[n] {
                    continue;
                }
                let old = x[n];
                x[n] = q;
                // Interior nodes may move to make room.
                if make_room(
                    &mut x,
                    &tets,
                    &node_tets,
                    &boundary,
                    n,
                    min_dihedral,
                    &mut moved_inside,
                ) {
                    locked[n] = true;
                    moved += 1;
                    break;
                }
                x[n] = old;
            }
        }
        snapped += moved;
        if moved == 0 {
            break;
        }
    }
    match TetMesh::new(x, tets) {
        Ok(m) => (m, snapped),
        Err(_) => (mesh, 0),
    }
}

/// Whether every tetrahedron around node `m` keeps the quality bound at positions `x`, after
/// moving the interior nodes of those that do not, if need be: each such node in turn goes
/// where the worst of its own tetrahedra is best (a compass search: steps along the axes,
/// halved when none helps). On failure every moved node goes back; on success the nodes
/// moved are appended to `moved`.
pub(super) fn make_room(
    x: &mut [Vec3],
    tets: &[[usize; 4]],
    node_tets: &[Vec<usize>],
    boundary: &[bool],
    m: usize,
    min_dihedral: f64,
    moved: &mut Vec<usize>,
) -> bool {
    // The search compares cosines (smaller is better): no acos in it.
    let cos = |x: &[Vec3], k: usize| tet_worst_cos(&tets[k].map(|v| x[v]));
    let worst_at =
        |x: &[Vec3], v: usize| node_tets[v].iter().map(|&k| cos(x, k)).fold(0.0, f64::max);
    // The same worst, or `None` as soon as one tetrahedron reaches `bound`: a step the
    // search would not take, found without the rest.
    let worst_below = |x: &[Vec3], v: usize, bound: f64| -> Option<f64> {
        let mut worst: f64 = 0.0;
        for &k in &node_tets[v] {
            worst = worst.max(cos(x, k));
            if worst >= bound {
                return None;
            }
        }
        Some(worst)
    };
    // Accepted by the bound's own check, as everywhere else in the mesher.
    let holds = |x: &[Vec3], k: usize| tet_quality_deg(&tets[k].map(|v| x[v])) >= min_dihedral;
    let bad = |x: &[Vec3]| -> Vec<usize> {
        node_tets[m]
            .iter()
            .copied()
            .filter(|&k| !holds(x, k))
            .collect()
    };
    let mut first = bad(x);
    if first.is_empty() {
        return true;
    }
    // A tetrahedron with all four nodes on the boundary cannot be helped here, nor (for this
    // search, which compares angles) a flat or inverted one.
    if first
        .iter()
        .any(|&k| tets[k].iter().all(|&v| boundary[v]) || !cos(x, k).is_finite())
    {
        return false;
    }
    let mut undo: Vec<(usize, Vec3)> = Vec::new();
    for _pass in 0..2 {
        let mut nodes: Vec<usize> = first
            .iter()
            .flat_map(|&k| tets[k])
            .filter(|&v| !boundary[v])
            .collect();
        nodes.sort_unstable();
        nodes.dedup();
        for n in nodes {
            let length = node_tets[n]
                .iter()
                .flat_map(|&k| tets[k])
                .map(|v| (x[v] - x[n]).norm())
                .fold(0.0, f64::max);
            let mut step = 0.2 * length;
            let mut best = worst_at(x, n);
            let start = x[n];
            for _ in 0..40 {
                if step < 0.005 * length {
                    break;
                }
                let here = x[n];
                let mut found = None;
                for axis in 0..3 {
                    for sign in [-1.0, 1.0] {
                        let mut p = here;
                        p[axis] += sign * step;
                        x[n] = p;
                        if let Some(w) = worst_below(x, n, best) {
                            best = w;
                            found = Some(p);
                        }
                    }
                }
                x[n] = found.unwrap_or(here);
                if found.is_none() {
                    step *= 0.5;
                }
            }
            if x[n] != start {
                undo.push((n, start));
            }
        }
        first = bad(x);
        let around_ok = undo
            .iter()
            .all(|&(n, _)| node_tets[n].iter().all(|&k| holds(x, k)));
        if first.is_empty() && around_ok {
            moved.extend(undo.iter().map(|&(n, _)| n));
            return true;
        }
    }
    for &(n, p) in undo.iter().rev() {
        x[n] = p;
    }
    false
}

/// Moves every boundary node onto the surface where its tetrahedra stay positive and above
/// `min_dihedral`; returns the mesh and the nodes moved.
fn project_boundary(mesh: TetMesh, tree: &SurfaceTree<'_>, min_dihedral: f64) -> (TetMesh, usize) {
    let mut x = mesh.positions().to_vec();
    let tets: Vec<[u32; 4]> = mesh.tets().to_vec();
    let mut moved = 0;
    for &v in mesh.surface().vertices() {
        let v = v as usize;
        let old = x[v];
        x[v] = tree.closest(&old).map_or(old, |c| c.0);
        let ok = node_ok(&mesh, &x, v, min_dihedral);
        if ok {
            moved += 1;
        } else {
            x[v] = old;
        }
    }
    let tets = tets.iter().map(|t| t.map(|i| i as usize)).collect();
    match TetMesh::new(x, tets) {
        Ok(m) => (m, moved),
        // The checks above keep every tetrahedron positive; should the mesh still refuse
        // the moved nodes, the stuffed one is kept.
        Err(_) => (mesh, 0),
    }
}
