//! How thick a surface's walls are: at each triangle's centroid the largest ball inside the
//! surface that touches it there (shrinking-ball method, Ma, Bae, Choi, Hsu and Vemuri
//! 2012), whose diameter is the wall's thickness where the wall is a plate. A lattice
//! follows a wall only where its spacing is about that thickness or finer; this says,
//! before any meshing, how thin the thinnest walls are (see `distance.rs` for the spacing
//! and count that follow them).

use rayon::prelude::*;

use crate::Vec3;
use crate::mesh::surface_tree::SurfaceTree;

/// The walls' thickness over a surface, area-weighted.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct WallThickness {
    /// The thickness under which 5 % of the surface's area lies, scene units: the thin
    /// walls.
    pub thin: f64,
    /// The thickness under which half the area lies.
    pub median: f64,
    /// Triangles probed (every one, or an even share of a large surface).
    pub probed: usize,
}

/// Probes at most this many triangles (an even share of a larger surface).
const MAX_PROBES: usize = 20_000;

/// The walls' thickness of the closed surface `positions`, `triangles` (oriented outward),
/// `tree` over the same triangles. `None` where no triangle has an area.
pub fn wall_thickness(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    tree: &SurfaceTree<'_>,
) -> Option<WallThickness> {
    let step = triangles.len().div_ceil(MAX_PROBES).max(1);
    let (lo, hi) = positions.iter().fold(
        (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
        |(lo, hi), q| (lo.inf(q), hi.sup(q)),
    );
    let diagonal = (hi - lo).norm();
    let mut probes: Vec<(f64, f64)> = triangles
        .par_iter()
        .step_by(step)
        .filter_map(|t| {
            let [a, b, c] = t.map(|v| positions[v as usize]);
            let cross = (b - a).cross(&(c - a));
            let area = 0.5 * cross.norm();
            let inward = -cross.try_normalize(0.0)?;
            let p = (a + b + c) / 3.0;
            Some((2.0 * inscribed_radius(tree, &p, &inward, diagonal), area))
        })
        .collect();
    if probes.is_empty() {
        return None;
    }
    probes.sort_by(|x, y| x.0.total_cmp(&y.0));
    let total: f64 = probes.iter().map(|x| x.1).sum();
    let at = |share: f64| {
        let mut sum = 0.0;
        for &(d, w) in &probes {
            sum += w;
            if sum >= share * total {
                return d;
            }
        }
        probes[probes.len() - 1].0
    };
    Some(WallThickness {
        thin: at(0.05),
        median: at(0.5),
        probed: probes.len(),
    })
}

/// The radius of the largest ball inside the surface that touches it at `p` (inward normal
/// `n`): from a ball as large as the diagonal, each step shrinks it to the ball tangent at
/// `p` through the surface point closest to its centre, until that point lies on it.
fn inscribed_radius(tree: &SurfaceTree<'_>, p: &Vec3, n: &Vec3, diagonal: f64) -> f64 {
    let mut r = diagonal;
    for _ in 0..64 {
        let c = p + n * r;
        let Some((q, d)) = tree.closest(&c) else {
            return r;
        };
        let pq = q - p;
        let along = n.dot(&pq);
        // Empty (within a part in a million of the radius), or the closest point is `p`'s
        // own neighbourhood.
        if d >= r * (1.0 - 1e-6) || along <= 1e-12 * diagonal {
            return r;
        }
        let next = pq.norm_squared() / (2.0 * along);
        if next.is_nan() || next >= r {
            return r;
        }
        r = next;
    }
    r
}
