//! Interior-node removal within a dihedral-angle bound: fewer tetrahedra, the same surface.

use super::{MeshError, TetMesh};
use crate::Vec3;

/// Removes interior nodes by collapsing each onto a neighbour when every tetrahedron the
/// collapse changes keeps a dihedral angle of at least `min_dihedral_deg`. The boundary is
/// untouched (only interior nodes move away), so the surface stays exactly as it was.
///
/// A collapse of interior node `v` onto neighbour `w` deletes the tets holding both and
/// replaces `v` by `w` in the rest of `v`'s star; when every replaced tet keeps a positive
/// volume, the new tets tile the same star (a cone from `w` over the star's boundary), so the
/// mesh stays conforming.
pub fn coarsen_interior(mesh: &TetMesh, min_dihedral_deg: f64) -> Result<TetMesh, MeshError> {
    let pos = mesh.positions();
    let mut tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|v| v as usize)).collect();
    let mut alive = vec![true; tets.len()];
    let mut star: Vec<Vec<usize>> = vec![Vec::new(); pos.len()];
    for (i, t) in tets.iter().enumerate() {
        for &v in t {
            star[v].push(i);
        }
    }
    let boundary: Vec<bool> = (0..pos.len())
        .map(|v| mesh.surface().surface_index(v).is_some())
        .collect();
    let quality = super::quality::tet_quality_deg;
    let mut removed = vec![false; pos.len()];
    for _pass in 0..3 {
        let mut changed = false;
        for v in 0..pos.len() {
            if boundary[v] || removed[v] || star[v].is_empty() {
                continue;
            }
            let mut nbrs: Vec<usize> = star[v]
                .iter()
                .flat_map(|&t| tets[t])
                .filter(|&w| w != v)
                .collect();
            nbrs.sort_unstable();
            nbrs.dedup();
            let mut best: Option<(f64, usize)> = None;
            for &w in &nbrs {
                let mut worst = f64::INFINITY;
                for &t in &star[v] {
                    let tet = tets[t];
                    if tet.contains(&w) {
                        continue;
                    }
                    let p = tet.map(|u| if u == v { pos[w] } else { pos[u] });
                    worst = worst.min(quality(&p));
                    if worst < min_dihedral_deg {
                        break;
                    }
                }
                if worst >= min_dihedral_deg && best.is_none_or(|(q, _)| worst > q) {
                    best = Some((worst, w));
                }
            }
            let Some((_, w)) = best else { continue };
            let old_star = std::mem::take(&mut star[v]);
            for t in old_star {
                if tets[t].contains(&w) {
                    alive[t] = false;
                    for &u in &tets[t] {
                        if u != v {
                            star[u].retain(|&x| x != t);
                        }
                    }
                } else {
                    for slot in tets[t].iter_mut() {
                        if *slot == v {
                            *slot = w;
                        }
                    }
                    star[w].push(t);
                }
            }
            removed[v] = true;
            changed = true;
        }
        if !changed {
            break;
        }
    }
    compact(pos, &tets, &alive)
}

/// The live tetrahedra (`alive`) as a mesh, with the nodes they use renumbered in order of
/// first use.
pub(super) fn compact(
    pos: &[Vec3],
    tets: &[[usize; 4]],
    alive: &[bool],
) -> Result<TetMesh, MeshError> {
    let mut map = vec![usize::MAX; pos.len()];
    let mut positions = Vec::new();
    let mut out = Vec::new();
    for (t, tet) in tets.iter().enumerate() {
        if !alive[t] {
            continue;
        }
        out.push(tet.map(|v| {
            if map[v] == usize::MAX {
                map[v] = positions.len();
                positions.push(pos[v]);
            }
            map[v]
        }));
    }
    TetMesh::new(positions, out)
}
