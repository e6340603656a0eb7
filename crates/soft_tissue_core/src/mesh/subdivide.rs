//! Loop subdivision of a triangle surface (Loop 1987): every triangle splits into four, new
//! edge points are 3/8 of the edge's ends plus 1/8 of the two opposite corners, old vertices
//! move to (1 - n beta) v + beta (sum of neighbours) with Warren's beta (3/16 for valence 3,
//! 3/(8n) otherwise). The result is a smoother, finer surface that stays inside the convex
//! hull of the input's neighbourhoods: used to render a coarse simulation surface smoothly
//! (the fine points are embedded in the tetrahedra, see [`super::embed`]).
//!
//! Edges shared by other than two triangles (open borders, non-manifold edges) are kept as
//! creases: their new points are midpoints and their end vertices do not move.

use crate::Vec3;
use std::collections::HashMap;
use thiserror::Error;

/// Why a surface cannot be subdivided.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SubdivideError {
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle} refers to vertex {vertex}, but there are only {count} vertices")]
    BadIndex {
        /// Triangle index.
        triangle: usize,
        /// The offending vertex index.
        vertex: u32,
        /// Number of vertices.
        count: usize,
    },
    /// The result would exceed 2^32 vertices or the level cap.
    #[error("{levels} levels of subdivision of {triangles} triangles is too many")]
    TooLarge {
        /// Requested levels.
        levels: u32,
        /// Input triangles.
        triangles: usize,
    },
}

/// The surface after `levels` rounds of Loop subdivision. Vertices that no triangle uses are
/// dropped; the output's vertices are numbered from zero.
pub fn loop_subdivide(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    levels: u32,
) -> Result<(Vec<Vec3>, Vec<[u32; 3]>), SubdivideError> {
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(&v) = tri.iter().find(|&&v| v as usize >= positions.len()) {
            return Err(SubdivideError::BadIndex {
                triangle: t,
                vertex: v,
                count: positions.len(),
            });
        }
    }
    if levels > 8 || (triangles.len() as u128) << (2 * levels) >= 1u128 << 31 {
        return Err(SubdivideError::TooLarge {
            levels,
            triangles: triangles.len(),
        });
    }
    // Compact the used vertices.
    let mut map = vec![u32::MAX; positions.len()];
    let mut points = Vec::new();
    let mut tris = Vec::with_capacity(triangles.len());
    for tri in triangles {
        tris.push(tri.map(|v| {
            if map[v as usize] == u32::MAX {
                map[v as usize] = points.len() as u32;
                points.push(positions[v as usize]);
            }
            map[v as usize]
        }));
    }
    for _ in 0..levels {
        (points, tris) = once(&points, &tris);
    }
    Ok((points, tris))
}

fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

fn once(p: &[Vec3], tris: &[[u32; 3]]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    // Per edge: the opposite corners (up to two) and how many triangles share it.
    let mut edges: HashMap<(u32, u32), (u32, [u32; 2], usize)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let e = edges.entry(key(a, b)).or_insert((0, [0; 2], 0));
            if e.2 < 2 {
                e.1[e.2] = c;
            }
            e.2 += 1;
        }
    }
    // Deterministic numbering of the edge points: sorted edges.
    let mut sorted: Vec<(u32, u32)> = edges.keys().copied().collect();
    sorted.sort_unstable();
    let n = p.len();
    let mut out = vec![Vec3::zeros(); n + sorted.len()];
    let mut crease = vec![false; n];
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (i, &(a, b)) in sorted.iter().enumerate() {
        let e = edges.get_mut(&(a, b)).expect("edge listed");
        e.0 = (n + i) as u32;
        let (pa, pb) = (p[a as usize], p[b as usize]);
        out[n + i] = if e.2 == 2 {
            let (c, d) = (p[e.1[0] as usize], p[e.1[1] as usize]);
            (pa + pb) * 0.375 + (c + d) * 0.125
        } else {
            crease[a as usize] = true;
            crease[b as usize] = true;
            (pa + pb) * 0.5
        };
        neighbours[a as usize].push(b);
        neighbours[b as usize].push(a);
    }
    for v in 0..n {
        let nb = &neighbours[v];
        out[v] = if crease[v] || nb.is_empty() {
            p[v]
        } else {
            let k = nb.len() as f64;
            let beta = if nb.len() == 3 {
                3.0 / 16.0
            } else {
                3.0 / (8.0 * k)
            };
            let sum: Vec3 = nb.iter().map(|&u| p[u as usize]).sum();
            p[v] * (1.0 - k * beta) + sum * beta
        };
    }
    let mid = |a: u32, b: u32| edges[&key(a, b)].0;
    let mut new_tris = Vec::with_capacity(tris.len() * 4);
    for &[a, b, c] in tris {
        let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
        new_tris.push([a, ab, ca]);
        new_tris.push([b, bc, ab]);
        new_tris.push([c, ca, bc]);
        new_tris.push([ab, bc, ca]);
    }
    (out, new_tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn icosahedron() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let g = (1.0 + 5f64.sqrt()) / 2.0;
        let v = [
            [-1.0, g, 0.0],
            [1.0, g, 0.0],
            [-1.0, -g, 0.0],
            [1.0, -g, 0.0],
            [0.0, -1.0, g],
            [0.0, 1.0, g],
            [0.0, -1.0, -g],
            [0.0, 1.0, -g],
            [g, 0.0, -1.0],
            [g, 0.0, 1.0],
            [-g, 0.0, -1.0],
            [-g, 0.0, 1.0],
        ];
        let t = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        (
            v.iter()
                .map(|p| Vec3::new(p[0], p[1], p[2]).normalize())
                .collect(),
            t,
        )
    }

    #[test]
    fn counts_follow_euler_and_every_edge_stays_shared_by_two() {
        let (p, t) = icosahedron();
        let (q, u) = loop_subdivide(&p, &t, 2).unwrap();
        assert_eq!(u.len(), 20 * 16);
        // Closed genus-0 surface: V - E + F = 2 with E = 3F/2.
        assert_eq!(
            q.len() as i64 - (3 * u.len() / 2) as i64 + u.len() as i64,
            2
        );
        let mut count: HashMap<(u32, u32), usize> = HashMap::new();
        for tri in &u {
            for k in 0..3 {
                *count.entry(key(tri[k], tri[(k + 1) % 3])).or_default() += 1;
            }
        }
        assert!(count.values().all(|&c| c == 2));
    }

    #[test]
    fn affine_maps_commute_with_subdivision() {
        let (p, t) = icosahedron();
        let a = nalgebra::Matrix3::new(1.5, 0.2, 0.0, -0.3, 0.7, 0.4, 0.1, 0.0, 2.0);
        let s = Vec3::new(3.0, -1.0, 0.5);
        let mapped: Vec<Vec3> = p.iter().map(|x| a * x + s).collect();
        let (q1, _) = loop_subdivide(&p, &t, 2).unwrap();
        let (q2, _) = loop_subdivide(&mapped, &t, 2).unwrap();
        for (x, y) in q1.iter().zip(&q2) {
            assert!((a * x + s - y).norm() < 1e-12);
        }
    }

    #[test]
    fn an_original_vertex_converges_to_loops_limit_position() {
        // Limit position of a vertex of valence n (Loop's limit mask with Warren's beta):
        // (1 - n chi) v + chi * (sum of neighbours), chi = 1 / (3 / (8 beta) + n). On the
        // regular icosahedron in the unit sphere (n = 5, beta = 3/40, chi = 1/10) the five
        // neighbours sum to sqrt(5) v, so the limit of every original vertex lies at radius
        // 1 - 5/10 + sqrt(5)/10 along its direction.
        let (p, t) = icosahedron();
        let limit = 0.5 + 5f64.sqrt() / 10.0;
        let mut last = f64::INFINITY;
        for level in 1..=6 {
            let (q, _) = loop_subdivide(&p, &t, level).unwrap();
            // Original vertices keep their indices (they come first, in order of use).
            let err = (q[0] - p[0] * limit).norm();
            assert!(err < last, "level {level}: {err} after {last}");
            last = err;
        }
        assert!(last < 1e-2, "{last}");
    }

    #[test]
    fn unused_vertices_are_dropped_and_bad_input_named() {
        let (mut p, t) = icosahedron();
        p.push(Vec3::new(9.0, 9.0, 9.0));
        let (q, _) = loop_subdivide(&p, &t, 1).unwrap();
        assert_eq!(q.len(), 12 + 30);
        assert_eq!(
            loop_subdivide(&p, &[[0, 1, 99]], 1),
            Err(SubdivideError::BadIndex {
                triangle: 0,
                vertex: 99,
                count: 13
            })
        );
        assert!(matches!(
            loop_subdivide(&p, &t, 20),
            Err(SubdivideError::TooLarge { .. })
        ));
    }
}
