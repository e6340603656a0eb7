//! Boundary coarsening against a surface: boundary-edge collapses that keep the mesh's
//! boundary within a tolerance of the input surface and every tetrahedron above a
//! dihedral-angle bound. Meshed finely and then coarsened where the surface is flat, a body
//! keeps its tetrahedra where the surface curves (rims, creases, folds) and spends few where
//! it does not: a graded boundary from a uniform lattice.

use super::quality::tet_quality_deg as quality;
use super::surface_tree::SurfaceTree;
use super::{MeshError, TetMesh};
use crate::Vec3;
use crate::geometry::closest_on_triangle;

/// What a boundary coarsening may do.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BoundaryCoarsening {
    /// Smallest dihedral angle every changed tetrahedron keeps, degrees.
    pub min_dihedral_deg: f64,
    /// Distance between the changed boundary and the surface, both ways, that the levels
    /// multiply.
    pub tolerance: f64,
    /// Stop once the mesh has this many tetrahedra or fewer.
    pub target_tets: usize,
    /// Passes of growing tolerance, as multiples of `tolerance`.
    pub levels: &'static [f64],
}

fn point_triangle(p: &Vec3, t: &[Vec3; 3]) -> f64 {
    let w = closest_on_triangle(p, &t[0], &t[1], &t[2]);
    (t[0] * w[0] + t[1] * w[1] + t[2] * w[2] - p).norm()
}

/// The faces of tetrahedron `t` (outward for a positive tetrahedron).
fn faces(t: &[usize; 4]) -> [[usize; 3]; 4] {
    [
        [t[1], t[2], t[3]],
        [t[0], t[3], t[2]],
        [t[0], t[1], t[3]],
        [t[0], t[2], t[1]],
    ]
}

struct Work {
    tets: Vec<[usize; 4]>,
    alive: Vec<bool>,
    star: Vec<Vec<usize>>,
}

impl Work {
    /// Whether face `f` of a live tetrahedron is on the boundary (no other live tetrahedron
    /// holds its three nodes).
    fn is_boundary(&self, f: &[usize; 3], owner: usize) -> bool {
        !self.star[f[0]]
            .iter()
            .any(|&t| t != owner && f.iter().all(|v| self.tets[t].contains(v)))
    }

    /// The boundary faces around node `v`.
    fn boundary_faces(&self, v: usize) -> Vec<[usize; 3]> {
        let mut out = Vec::new();
        for &t in &self.star[v] {
            for f in faces(&self.tets[t]) {
                if f.contains(&v) && self.is_boundary(&f, t) {
                    out.push(f);
                }
            }
        }
        out
    }

    fn neighbours(&self, v: usize) -> Vec<usize> {
        let mut n: Vec<usize> = self.star[v]
            .iter()
            .flat_map(|&t| self.tets[t])
            .filter(|&u| u != v)
            .collect();
        n.sort_unstable();
        n.dedup();
        n
    }

    /// Collapses `v` onto `w` (the caller checked it).
    fn collapse(&mut self, v: usize, w: usize) {
        let old = std::mem::take(&mut self.star[v]);
        for t in old {
            if self.tets[t].contains(&w) {
                self.alive[t] = false;
                for u in self.tets[t] {
                    if u != v {
                        self.star[u].retain(|&x| x != t);
                    }
                }
            } else {
                for slot in self.tets[t].iter_mut() {
                    if *slot == v {
                        *slot = w;
                    }
                }
                self.star[w].push(t);
            }
        }
    }
}

/// Collapses boundary nodes onto boundary neighbours (along boundary edges) while the mesh
/// has more than `target_tets` tetrahedra: in passes of growing tolerance (`levels`, so flat
/// regions go first), a collapse is taken when every tetrahedron it
/// changes stays positive and above the bound, the vertex links agree (no pinch), the new
/// boundary triangles' corners, edge midpoints and centroids lie within the tolerance of the
/// surface, and the removed node and the old triangles' centroids lie within it of the new
/// boundary. Then the interior nodes are removed again within the bound.
pub(crate) fn coarsen_boundary(
    mesh: &TetMesh,
    surface: &SurfaceTree<'_>,
    options: &BoundaryCoarsening,
) -> Result<TetMesh, MeshError> {
    let pos = mesh.positions();
    let tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|v| v as usize)).collect();
    let mut star: Vec<Vec<usize>> = vec![Vec::new(); pos.len()];
    for (i, t) in tets.iter().enumerate() {
        for &v in t {
            star[v].push(i);
        }
    }
    let mut boundary: Vec<bool> = (0..pos.len())
        .map(|v| mesh.surface().surface_index(v).is_some())
        .collect();
    let mut count = tets.len();
    let mut work = Work {
        alive: vec![true; tets.len()],
        tets,
        star,
    };
    let to_surface = |p: &Vec3| surface.closest(p).map_or(f64::INFINITY, |c| c.1);
    'levels: for &level in options.levels {
        let tol = options.tolerance * level;
        for _pass in 0..3 {
            let mut changed = false;
            for v in 0..pos.len() {
                if count <= options.target_tets {
                    break 'levels;
                }
                if !boundary[v] || work.star[v].is_empty() {
                    continue;
                }
                let old_faces = work.boundary_faces(v);
                let nv = work.neighbours(v);
                let mut best: Option<(f64, usize)> = None;
                for &w in &nv {
                    if !boundary[w] || !old_faces.iter().any(|f| f.contains(&w)) {
                        continue; // only along a boundary edge
                    }
                    // Link condition on nodes: the common neighbours are the edge's link.
                    let nw = work.neighbours(w);
                    let edge_link: Vec<usize> = {
                        let mut l: Vec<usize> = work.star[v]
                            .iter()
                            .filter(|&&t| work.tets[t].contains(&w))
                            .flat_map(|&t| work.tets[t])
                            .filter(|&u| u != v && u != w)
                            .collect();
                        l.sort_unstable();
                        l.dedup();
                        l
                    };
                    let common: Vec<usize> = nv
                        .iter()
                        .copied()
                        .filter(|u| *u != w && nw.binary_search(u).is_ok())
                        .collect();
                    if common != edge_link {
                        continue;
                    }
                    // Quality of every changed tetrahedron.
                    let ok = work.star[v].iter().all(|&t| {
                        let tet = work.tets[t];
                        tet.contains(&w)
                            || quality(&tet.map(|u| if u == v { pos[w] } else { pos[u] }))
                                >= options.min_dihedral_deg
                    });
                    if !ok {
                        continue;
                    }
                    // The new boundary near the surface, both ways.
                    let new_faces: Vec<[Vec3; 3]> = old_faces
                        .iter()
                        .filter(|f| !f.contains(&w))
                        .map(|f| f.map(|u| if u == v { pos[w] } else { pos[u] }))
                        .collect();
                    if new_faces.is_empty() {
                        continue;
                    }
                    let mut err: f64 = 0.0;
                    for f in &new_faces {
                        for p in [
                            (f[0] + f[1] + f[2]) / 3.0,
                            (f[0] + f[1]) / 2.0,
                            (f[1] + f[2]) / 2.0,
                            (f[2] + f[0]) / 2.0,
                        ] {
                            err = err.max(to_surface(&p));
                            if err > tol {
                                break;
                            }
                        }
                        if err > tol {
                            break;
                        }
                    }
                    if err > tol {
                        continue;
                    }
                    let to_new = |p: &Vec3| {
                        new_faces
                            .iter()
                            .map(|f| point_triangle(p, f))
                            .fold(f64::INFINITY, f64::min)
                    };
                    err = err.max(to_new(&pos[v]));
                    for f in &old_faces {
                        let [a, b, c] = f.map(|u| pos[u]);
                        err = err.max(to_new(&((a + b + c) / 3.0)));
                    }
                    if err <= tol && best.is_none_or(|(e, _)| err < e) {
                        best = Some((err, w));
                    }
                }
                let Some((_, w)) = best else { continue };
                let dying = work.star[v]
                    .iter()
                    .filter(|&&t| work.tets[t].contains(&w))
                    .count();
                work.collapse(v, w);
                boundary[v] = false;
                count -= dying;
                changed = true;
            }
            if !changed {
                break;
            }
        }
    }
    let coarse = super::coarsen::compact(pos, &work.tets, &work.alive)?;
    super::coarsen::coarsen_interior(&coarse, options.min_dihedral_deg)
}
