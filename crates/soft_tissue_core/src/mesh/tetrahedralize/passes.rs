//! The passes after the boundary fit: boundary edges split toward the surface, the volume
//! the chords lost restored, and the distances both ways measured.

use rayon::prelude::*;

use super::fitting::{make_room, node_ok};
use crate::Vec3;
use crate::mesh::TetMesh;
use crate::mesh::io::SurfaceMesh;
use crate::mesh::surface_tree::SurfaceTree;

/// What the boundary steps fit the mesh to.
#[derive(Clone, Copy)]
pub(super) struct Goal<'a> {
    pub(super) tree: &'a SurfaceTree<'a>,
    pub(super) surface_samples: &'a [Vec3],
    pub(super) min_dihedral: f64,
    pub(super) tol: f64,
    pub(super) enclosed_volume: f64,
}

/// A mesh after the boundary steps, with what they did and the distances both ways.
pub(super) struct Finished {
    pub(super) mesh: TetMesh,
    pub(super) chord_volume: f64,
    pub(super) projected: usize,
    pub(super) snapped: usize,
    pub(super) split: usize,
    pub(super) mesh_to_surface: f64,
    pub(super) surface_to_mesh: f64,
}

impl Finished {
    pub(super) fn split_and_measure(
        mesh: TetMesh,
        goal: &Goal<'_>,
        projected: usize,
        snapped: usize,
    ) -> Finished {
        let Goal {
            tree,
            surface_samples,
            min_dihedral,
            tol,
            enclosed_volume,
        } = *goal;
        let (mesh, split) = split_boundary_edges(mesh, tree, surface_samples, min_dihedral, tol);
        let chord_volume = mesh.volume();
        let mesh = restore_volume(mesh, enclosed_volume, min_dihedral, tol);
        let boundary = SurfaceMesh::boundary_of(&mesh);
        let distance = |t: &SurfaceTree<'_>, p: &Vec3| t.closest(p).map_or(f64::INFINITY, |c| c.1);
        let mesh_to_surface = samples(&boundary.positions, &boundary.triangles)
            .par_iter()
            .map(|p| distance(tree, p))
            .reduce(|| 0.0, f64::max);
        let boundary_tree = SurfaceTree::new(&boundary.positions, &boundary.triangles);
        let surface_to_mesh = surface_samples
            .par_iter()
            .map(|p| distance(&boundary_tree, p))
            .reduce(|| 0.0, f64::max);
        Finished {
            mesh,
            projected,
            snapped,
            split,
            mesh_to_surface,
            surface_to_mesh,
            chord_volume,
        }
    }

    pub(super) fn worst(&self) -> f64 {
        self.mesh_to_surface.max(self.surface_to_mesh)
    }

    /// Takes `other` in place of this mesh where it is nearer the surface; whether it did.
    pub(super) fn take_if_nearer(&mut self, other: Finished) -> bool {
        let nearer = other.worst() < self.worst();
        if nearer {
            *self = other;
        }
        nearer
    }
}

/// The volume the chords lose: a boundary whose nodes lie on the surface cuts inside it
/// wherever the surface is convex, so the mesh comes out a little small. Every boundary node
/// moves outward along its normal (area-weighted over its boundary triangles) by the lost
/// volume over the boundary's area, at most `max_offset`, where its tetrahedra keep the
/// quality bound. The nodes then straddle the surface by that offset instead of touching it.
fn restore_volume(mesh: TetMesh, enclosed: f64, min_dihedral: f64, max_offset: f64) -> TetMesh {
    let surface = mesh.surface();
    let x0 = mesh.positions();
    let mut normals = vec![Vec3::zeros(); x0.len()];
    let mut area = 0.0;
    let mut outward = 0.0;
    for t in surface.triangles() {
        let [a, b, c] = t.map(|v| x0[v as usize]);
        let n = (b - a).cross(&(c - a));
        area += 0.5 * n.norm();
        outward += a.dot(&b.cross(&c));
        for &v in t {
            normals[v as usize] += n;
        }
    }
    let lost = enclosed - mesh.volume();
    if !(area > 0.0 && lost.is_finite() && lost > 0.0) {
        return mesh;
    }
    let sign = if outward >= 0.0 { 1.0 } else { -1.0 };
    let offset = (lost / area).min(max_offset);
    let mut x = x0.to_vec();
    for &v in surface.vertices() {
        let v = v as usize;
        let Some(n) = normals[v].try_normalize(1e-300) else {
            continue;
        };
        let old = x[v];
        x[v] = old + n * (sign * offset);
        if !node_ok(&mesh, &x, v, min_dihedral) {
            x[v] = old;
        }
    }
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    TetMesh::new(x, tets).unwrap_or(mesh)
}

/// Points of a triangle surface where distances are measured: its vertices, edge midpoints
/// and centroids.
pub(super) fn samples(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut out = positions.to_vec();
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        // Each edge once: from its smaller vertex index.
        for (i, j, p, q) in [(t[0], t[1], a, b), (t[1], t[2], b, c), (t[2], t[0], c, a)] {
            if i < j {
                out.push((p + q) / 2.0);
            }
        }
        out.push((a + b + c) / 3.0);
    }
    out
}

/// Where the boundary still passes farther than `tol` from the surface, or the surface from
/// it, after the node moves: the boundary edge involved is split (every tetrahedron around
/// it bisected) and the new node put on the input surface, where all the new tetrahedra
/// keep the quality bound (else three quarters, half or a quarter of the way there from the
/// edge's midpoint; at each, interior nodes may move to make room, see `make_room`); a
/// split no placement allows is undone. Candidates are boundary edges whose midpoint is far from the
/// surface (the node goes to the midpoint's closest surface point), the longest edge of a
/// boundary triangle whose centroid is far (the same), and surface samples far
/// from the boundary (the nearest edge of the boundary triangle closest to the sample is
/// split, its node on the sample). Farthest first, edges sharing no tetrahedron within a
/// round, three rounds. Returns the mesh and the edges split.
fn split_boundary_edges(
    mesh: TetMesh,
    tree: &SurfaceTree<'_>,
    samples: &[Vec3],
    min_dihedral: f64,
    tol: f64,
) -> (TetMesh, usize) {
    let mut x: Vec<Vec3> = mesh.positions().to_vec();
    let mut tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let mut node_tets: Vec<Vec<usize>> = vec![Vec::new(); x.len()];
    for (k, t) in tets.iter().enumerate() {
        for &v in t {
            node_tets[v].push(k);
        }
    }
    let mut current = mesh;
    let mut split = 0;
    for _round in 0..3 {
        let triangles: Vec<[usize; 3]> = current
            .surface()
            .triangles()
            .iter()
            .map(|t| t.map(|v| v as usize))
            .collect();
        let mut candidates: Vec<(f64, (usize, usize), Vec3)> = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for t in &triangles {
            for e in 0..3 {
                let (a, b) = edge_of(t, e);
                if !seen.insert((a, b)) {
                    continue;
                }
                let mid = (x[a] + x[b]) / 2.0;
                if let Some((q, d)) = tree.closest(&mid)
                    && d > tol
                {
                    candidates.push((d, (a, b), q));
                }
            }
        }
        // A boundary triangle whose centroid is far: its longest edge.
        for t in &triangles {
            let c = (x[t[0]] + x[t[1]] + x[t[2]]) / 3.0;
            if tree.closest(&c).is_none_or(|(_, d)| d <= tol) {
                continue;
            }
            let (a, b) = (0..3)
                .map(|e| edge_of(t, e))
                .max_by(|&(a, b), &(c2, d2)| {
                    (x[a] - x[b])
                        .norm_squared()
                        .total_cmp(&(x[c2] - x[d2]).norm_squared())
                })
                .unwrap_or((t[0].min(t[1]), t[0].max(t[1])));
            if let Some((q, d)) = tree.closest(&((x[a] + x[b]) / 2.0)) {
                candidates.push((d.max(tol), (a, b), q));
            }
        }
        {
            let tri32: Vec<[u32; 3]> = triangles.iter().map(|t| t.map(|v| v as u32)).collect();
            let boundary = SurfaceTree::new(&x, &tri32);
            let far: Vec<(f64, usize, &Vec3)> = samples
                .par_iter()
                .filter_map(|q| {
                    let (_, d, k) = boundary.closest_triangle(q)?;
                    (d > tol).then_some((d, k, q))
                })
                .collect();
            for (d, k, q) in far {
                let t = triangles[k];
                let edge = (0..3)
                    .map(|e| edge_of(&t, e))
                    .min_by(|&(a, b), &(c, d2)| {
                        ((x[a] + x[b]) / 2.0 - q)
                            .norm_squared()
                            .total_cmp(&((x[c] + x[d2]) / 2.0 - q).norm_squared())
                    })
                    .unwrap_or((t[0].min(t[1]), t[0].max(t[1])));
                candidates.push((d, edge, *q));
            }
        }
        candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut touched = vec![false; x.len()];
        let mut boundary = vec![false; x.len()];
        for t in &triangles {
            for &v in t {
                boundary[v] = true;
            }
        }
        let mut done = 0;
        for (_, (a, b), q) in candidates {
            if touched[a] || touched[b] {
                continue;
            }
            let ring: Vec<usize> = node_tets[a]
                .iter()
                .copied()
                .filter(|&k| tets[k].contains(&b))
                .collect();
            if ring.is_empty() {
                continue;
            }
            let m = x.len();
            let mid = (x[a] + x[b]) / 2.0;
            // The split, made in place and undone should no placement of the new node keep
            // the bound.
            let tets_len = tets.len();
            let mut saved_tets: Vec<(usize, [usize; 4])> = Vec::with_capacity(ring.len());
            let mut saved_links: Vec<(usize, Vec<usize>)> = Vec::new();
            {
                let mut around: Vec<usize> = ring.iter().flat_map(|&k| tets[k]).collect();
                around.sort_unstable();
                around.dedup();
                for v in around {
                    saved_links.push((v, node_tets[v].clone()));
                }
            }
            x.push(q);
            node_tets.push(Vec::new());
            boundary.push(true);
            for &k in &ring {
                let t = tets[k];
                saved_tets.push((k, t));
                // k keeps the half without a; the half without b is new.
                tets[k] = t.map(|v| if v == a { m } else { v });
                node_tets[a].retain(|&j| j != k);
                node_tets[m].push(k);
                let j = tets.len();
                let h2 = t.map(|v| if v == b { m } else { v });
                tets.push(h2);
                for &v in &h2 {
                    node_tets[v].push(j);
                }
            }
            // All the way to the surface point, else three quarters, half or a quarter of
            // the way from the edge's midpoint (a sharp rim: the gap shrinks, the node stays
            // that near the surface). Where a placement leaves a tetrahedron under the
            // bound, the interior nodes of those tetrahedra may move to make room.
            let mut moved: Vec<usize> = Vec::new();
            let ok = [1.0, 0.75, 0.5, 0.25].into_iter().any(|f| {
                x[m] = mid + (q - mid) * f;
                make_room(
                    &mut x,
                    &tets,
                    &node_tets,
                    &boundary,
                    m,
                    min_dihedral,
                    &mut moved,
                )
            });
            if !ok {
                for (k, t) in saved_tets {
                    tets[k] = t;
                }
                tets.truncate(tets_len);
                for (v, links) in saved_links {
                    node_tets[v] = links;
                }
                x.pop();
                node_tets.pop();
                boundary.pop();
                continue;
            }
            touched.push(true);
            for &k in &node_tets[m] {
                for &v in &tets[k] {
                    touched[v] = true;
                }
            }
            for &v in &moved {
                for &k in &node_tets[v] {
                    for &w in &tets[k] {
                        touched[w] = true;
                    }
                }
            }
            done += 1;
        }
        if done == 0 {
            break;
        }
        match TetMesh::new(x.clone(), tets.clone()) {
            Ok(next) => {
                current = next;
                split += done;
            }
            // Not expected (every new tetrahedron was checked); the last good mesh is kept.
            Err(_) => break,
        }
    }
    (current, split)
}

/// Edge `e` of triangle `t`, its smaller node first.
fn edge_of(t: &[usize; 3], e: usize) -> (usize, usize) {
    let (a, b) = (t[e], t[(e + 1) % 3]);
    (a.min(b), a.max(b))
}
