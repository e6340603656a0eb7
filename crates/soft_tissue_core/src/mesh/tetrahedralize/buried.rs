//! Overlapping parts: which share of each triangle lies inside the union rather than on its
//! boundary (buried), probed just off both sides with the winding number, and the surface
//! samples left once the buried points are out.

use rayon::prelude::*;

use super::bounds;
use super::repair::RepairedSurface;
use crate::Vec3;
use crate::mesh::surface_tree::SurfaceTree;

/// How far off a triangle its sides are probed, at most, as a fraction of the diagonal.
const PROBE_OFFSET: f64 = 1e-7;

/// The largest probe offset for a surface: [`PROBE_OFFSET`] of its diagonal.
fn probe_offset(positions: &[Vec3]) -> f64 {
    let (lo, hi) = bounds(positions);
    PROBE_OFFSET * (hi - lo).norm()
}

/// Whether the point at barycentric weights `w` of triangle `t` is buried: not on the
/// boundary of the inside (the winding number over one half), so that just off the
/// triangle both sides are inside (a part inside another) or both outside (a cavity's wall
/// inside another cavity). The offset is at most a thousandth of the triangle's height, so
/// that the triangle itself sets the jump across it (one, less a thousandth); a sliver
/// thinner than that allows is not buried. Where the outer side's number lies in
/// (-1/2, 1/2], the inner one is over one half and the point on the boundary: one query, the
/// common case. Probing the outer side alone at 1e-7 of the diagonal took slivers of a
/// Chaste lung lobe (4) and a triangle of sofa_env's liver (1) for buried, none of them
/// crossing another (MeshLab's self-intersection check), and those meshes moved (the liver
/// from 6.1 to 15.4 s).
fn buried_at(
    tree: &SurfaceTree<'_>,
    positions: &[Vec3],
    t: &[u32; 3],
    w: [f64; 3],
    eps: f64,
) -> bool {
    let [a, b, c] = t.map(|v| positions[v as usize]);
    let cross = (b - a).cross(&(c - a));
    let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
    let eps = eps.min(1e-3 * cross.norm() / longest);
    if eps.is_nan() || eps <= 1e-4 * PROBE_OFFSET * longest {
        return false;
    }
    let n = cross.normalize();
    let p = a * w[0] + b * w[1] + c * w[2];
    let outer = tree.winding_number(&(p + n * eps));
    if -0.5 < outer && outer <= 0.5 {
        return false;
    }
    (outer > 0.5) == (tree.winding_number(&(p - n * eps)) > 0.5)
}

/// Per triangle, the share of its area buried (see [`SurfaceDefects::buried_triangles`]),
/// from 0 to 1: probed first at every centroid; where one is buried, each triangle that may
/// cross a seam between parts is probed at the centroids of its sub-triangles (16, or more
/// where it is wider than the buried-centred ones: see `sub_centroids`). Those are the triangles with a vertex on a
/// buried-centred one, and those whose box overlaps a buried-centred one's (the other
/// part's triangles across the seam, whose centroids may lie outside). Empty where no
/// centroid is: the surfaces whose parts do not overlap, and overlaps too shallow to reach
/// a centroid (their volume is counted twice, as before).
pub(super) fn buried_shares(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<f64> {
    let eps = probe_offset(positions);
    let tree = SurfaceTree::new(positions, triangles);
    let centred: Vec<bool> = triangles
        .par_iter()
        .map(|t| buried_at(&tree, positions, t, [1.0 / 3.0; 3], eps))
        .collect();
    if !centred.contains(&true) {
        return Vec::new();
    }
    let boxes: Vec<(Vec3, Vec3)> = triangles
        .iter()
        .map(|t| bounds(&t.map(|v| positions[v as usize])))
        .collect();
    let mut near = vec![false; positions.len()];
    // The buried-centred triangles' boxes, in a grid of cells as wide as the widest.
    let cell = (0..triangles.len())
        .filter(|&k| centred[k])
        .map(|k| (boxes[k].1 - boxes[k].0).max())
        .fold(0.0, f64::max);
    let key = |p: &Vec3| p.map(|c| (c / cell).floor() as i64);
    let mut cells = std::collections::HashSet::new();
    for (k, t) in triangles.iter().enumerate().filter(|&(k, _)| centred[k]) {
        for &v in t {
            near[v as usize] = true;
        }
        let (lo, hi) = (key(&boxes[k].0), key(&boxes[k].1));
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                for z in lo.z..=hi.z {
                    cells.insert([x, y, z]);
                }
            }
        }
    }
    // A triangle's box overlaps a buried-centred one's only where it meets one of its
    // cells (one spanning more than 64 cells is probed anyway).
    let across = |k: usize| {
        let (lo, hi) = (key(&boxes[k].0), key(&boxes[k].1));
        let span = (hi - lo).map(|d| d + 1);
        if span.x.saturating_mul(span.y).saturating_mul(span.z) > 64 {
            return true;
        }
        (lo.x..=hi.x)
            .any(|x| (lo.y..=hi.y).any(|y| (lo.z..=hi.z).any(|z| cells.contains(&[x, y, z]))))
    };
    triangles
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            if !(t.iter().any(|&v| near[v as usize]) || (cell > 0.0 && across(k))) {
                return 0.0;
            }
            // Sub-triangles no wider than the widest buried-centred triangle, at least 16
            // and at most 4096 (a coarse triangle with a small part through it).
            let longest = (boxes[k].1 - boxes[k].0).norm();
            let n = if cell > 0.0 {
                (longest / cell).ceil().clamp(4.0, 64.0) as usize
            } else {
                4
            };
            let points = sub_centroids(n);
            let buried = points
                .iter()
                .filter(|&&w| buried_at(&tree, positions, t, w, eps))
                .count();
            buried as f64 / points.len() as f64
        })
        .collect()
}

/// Barycentric weights of the centroids of a triangle's `n` x `n` equal sub-triangles (each
/// edge cut in `n`): n (n + 1) / 2 upright (corners i + j + k = n - 1 steps of 1/n, plus a
/// third of a step each) and n (n - 1) / 2 upside down (i + j + k = n - 2, plus two thirds).
fn sub_centroids(n: usize) -> Vec<[f64; 3]> {
    let step = 1.0 / n as f64;
    let mut out = Vec::with_capacity(n * n);
    for (sum, extra) in [(n as isize - 1, 1.0 / 3.0), (n as isize - 2, 2.0 / 3.0)] {
        for i in 0..=sum {
            for j in 0..=sum - i {
                let k = sum - i - j;
                out.push([i, j, k].map(|c| (c as f64 + extra) * step));
            }
        }
    }
    out
}

/// [`samples`] of a surface whose parts overlap, those buried left out: each point is
/// probed from the triangles it lies on (see [`buried_at`]) and kept where one keeps it.
pub(super) fn unburied_samples(s: &RepairedSurface, tree: &SurfaceTree<'_>) -> Vec<Vec3> {
    let eps = probe_offset(&s.positions);
    // Corners, edge midpoints (edge k from corner k to k + 1), centroid: each probed a
    // fiftieth of the way toward the centroid (off a corner or an edge, the probe may cross a
    // neighbour's plane at a crease), the point itself kept.
    const AT: [[f64; 3]; 7] = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.5, 0.5, 0.0],
        [0.0, 0.5, 0.5],
        [0.5, 0.0, 0.5],
        [1.0 / 3.0; 3],
    ];
    let kept: Vec<[bool; 7]> = s
        .triangles
        .par_iter()
        .zip(&s.buried)
        .map(|(t, &b)| {
            AT.map(|w| {
                let w = w.map(|c| 0.98 * c + 0.02 / 3.0);
                b < 1.0 && (b == 0.0 || !buried_at(tree, &s.positions, t, w, eps))
            })
        })
        .collect();
    let mut vertex = vec![false; s.positions.len()];
    let mut edge = std::collections::HashSet::new();
    let mut out = Vec::new();
    for (t, keep) in s.triangles.iter().zip(&kept) {
        for k in 0..3 {
            if keep[k] && !std::mem::replace(&mut vertex[t[k] as usize], true) {
                out.push(s.positions[t[k] as usize]);
            }
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if keep[3 + k] && edge.insert((a.min(b), a.max(b))) {
                out.push((s.positions[a as usize] + s.positions[b as usize]) / 2.0);
            }
        }
        if keep[6] {
            out.push(t.map(|v| s.positions[v as usize]).iter().sum::<Vec3>() / 3.0);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    /// The sub-triangles' centroids: n^2 of them, distinct, inside the triangle, and their
    /// mean the triangle's centroid (the sub-triangles are equal, so the mean of their
    /// centroids is the whole's).
    #[test]
    fn sub_centroids_are_the_centroids_of_equal_sub_triangles() {
        for n in [1, 2, 4, 7, 64] {
            let points = super::sub_centroids(n);
            assert_eq!(points.len(), n * n);
            let mut mean = [0.0; 3];
            for w in &points {
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(w.iter().all(|&c| c > 0.0 && c < 1.0));
                for (m, c) in mean.iter_mut().zip(w) {
                    *m += c / points.len() as f64;
                }
            }
            assert!(
                mean.iter().all(|m| (m - 1.0 / 3.0).abs() < 1e-12),
                "{n}: {mean:?}"
            );
            for (a, p) in points.iter().enumerate() {
                for q in &points[a + 1..] {
                    assert!((0..3).any(|c| (p[c] - q[c]).abs() > 1e-9 / n as f64));
                }
            }
        }
    }
}
