//! How much of a sphere about a point lies inside a tetrahedral mesh: the share of an
//! electrode's surroundings that is tissue (1/2 on a flat surface, 1/4 on a right-angled
//! edge, more than 1/2 at the floor of a crater).

use super::TetMesh;
use crate::Vec3;

/// Directions sampled on each sphere (a Fibonacci lattice: nearly even areas, so the share
/// of a half-space comes out within about `1 / DIRECTIONS` of 1/2).
pub const DIRECTIONS: usize = 256;

/// The share of the spheres of `radii` (scene units) about `centre` that lies inside the
/// mesh's tetrahedra, averaged over the radii: the fraction of [`DIRECTIONS`] points on
/// each sphere inside some tetrahedron. Only the tetrahedra whose bounding box meets the
/// largest sphere are tested. 0 for no radii or non-finite input.
pub fn sphere_share_inside(mesh: &TetMesh, centre: &Vec3, radii: &[f64]) -> f64 {
    let reach = radii.iter().copied().fold(0.0, f64::max);
    if radii.is_empty()
        || !(reach.is_finite() && reach > 0.0)
        || !centre.iter().all(|c| c.is_finite())
    {
        return 0.0;
    }
    let p = mesh.positions();
    // The tetrahedra near the sphere, with what their barycentric test needs.
    let near: Vec<(Vec3, nalgebra::Matrix3<f64>)> = mesh
        .tets()
        .iter()
        .filter_map(|t| {
            let x = t.map(|n| p[n as usize]);
            let (lo, hi) = x
                .iter()
                .fold((x[0], x[0]), |(lo, hi), v| (lo.inf(v), hi.sup(v)));
            let gap = (lo - centre).sup(&(centre - hi)).sup(&Vec3::zeros());
            if gap.norm() > reach {
                return None;
            }
            let e = nalgebra::Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
            e.try_inverse().map(|inv| (x[0], inv))
        })
        .collect();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut inside = 0usize;
    for &r in radii {
        for i in 0..DIRECTIONS {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / DIRECTIONS as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f64;
            let q = centre + Vec3::new(s * a.cos(), s * a.sin(), z) * r;
            let hit = near.iter().any(|(x0, inv)| {
                let b = inv * (q - x0);
                let tol = -1e-12;
                b.x >= tol && b.y >= tol && b.z >= tol && b.x + b.y + b.z <= 1.0 - tol
            });
            inside += usize::from(hit);
        }
    }
    inside as f64 / (DIRECTIONS * radii.len()) as f64
}
