//! How much of a sphere about a point lies inside a tetrahedral mesh: the share of an
//! electrode's surroundings that is tissue (1/2 on a flat surface, 1/4 on a right-angled
//! edge, more than 1/2 at the floor of a crater).
//!
//! The tetrahedra near the point are found in a uniform grid of their bounding boxes, built
//! once per mesh ([`Occupancy`] keeps it, with the room a query needs, so a world asks again
//! without scanning the mesh or allocating).

use std::sync::{Arc, Weak};

use nalgebra::Matrix3;

use super::TetMesh;
use super::tet_grid::{TetGrid, grid_cells};
use crate::Vec3;

/// Directions sampled on each sphere (a Fibonacci lattice: nearly even areas, so the share
/// of a half-space comes out within about `1 / DIRECTIONS` of 1/2).
pub const DIRECTIONS: usize = 256;

/// A tetrahedron near the sphere: its first corner and the inverse of its edge matrix (what
/// the barycentric test needs).
type NearTet = (Vec3, Matrix3<f64>);

/// The share of the spheres of `radii` (scene units) about `centre` that lies inside the
/// mesh's tetrahedra, averaged over the radii: the fraction of [`DIRECTIONS`] points on
/// each sphere inside some tetrahedron. Only the tetrahedra whose bounding box meets the
/// largest sphere are tested. 0 for no radii or non-finite input. Builds the mesh's grid for
/// this one call: a caller that asks again keeps an [`Occupancy`].
pub fn sphere_share_inside(mesh: &TetMesh, centre: &Vec3, radii: &[f64]) -> f64 {
    let Some(reach) = reach_of(centre, radii) else {
        return 0.0;
    };
    let (mut found, mut near) = (Vec::new(), Vec::new());
    near_tets(
        &TetGrid::new(mesh),
        mesh,
        centre,
        reach,
        &mut found,
        &mut near,
    );
    share(centre, radii, &near)
}

/// [`sphere_share_inside`] for a caller that asks again: the grid of the mesh's tetrahedra
/// is built at the first question about a mesh (again when asked about another one), and a
/// question after that scans only the grid's cells about the sphere and allocates nothing
/// once its lists have grown to the tetrahedra near a sphere.
#[derive(Debug, Default)]
pub struct Occupancy {
    /// The mesh the grid is of (a weak reference keeps its address from being reused while
    /// the grid is kept).
    mesh: Weak<TetMesh>,
    grid: TetGrid,
    /// The tetrahedra in the cells about the sphere, and those near it.
    found: Vec<u32>,
    near: Vec<NearTet>,
}

impl Occupancy {
    /// The share of the spheres of `radii` about `centre` inside `mesh` (see
    /// [`sphere_share_inside`]; the same number).
    pub fn sphere_share_inside(
        &mut self,
        mesh: &Arc<TetMesh>,
        centre: &Vec3,
        radii: &[f64],
    ) -> f64 {
        let Some(reach) = reach_of(centre, radii) else {
            return 0.0;
        };
        if !std::ptr::eq(self.mesh.as_ptr(), Arc::as_ptr(mesh)) {
            self.grid = TetGrid::new(mesh);
            self.mesh = Arc::downgrade(mesh);
        }
        near_tets(
            &self.grid,
            mesh,
            centre,
            reach,
            &mut self.found,
            &mut self.near,
        );
        share(centre, radii, &self.near)
    }
}

/// The largest of `radii` when it and `centre` are usable.
fn reach_of(centre: &Vec3, radii: &[f64]) -> Option<f64> {
    let reach = radii.iter().copied().fold(0.0, f64::max);
    (!radii.is_empty() && reach.is_finite() && reach > 0.0 && centre.iter().all(|c| c.is_finite()))
        .then_some(reach)
}

/// Tetrahedron `x` if its bounding box comes within `reach` of `centre` and its edges span
/// a volume.
fn near_tet(x: &[Vec3; 4], centre: &Vec3, reach: f64) -> Option<NearTet> {
    let (lo, hi) = bounds(x);
    let gap = (lo - centre).sup(&(centre - hi)).sup(&Vec3::zeros());
    if gap.norm() > reach {
        return None;
    }
    let e = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    e.try_inverse().map(|inv| (x[0], inv))
}

fn bounds(x: &[Vec3; 4]) -> (Vec3, Vec3) {
    x.iter()
        .fold((x[0], x[0]), |(lo, hi), v| (lo.inf(v), hi.sup(v)))
}

fn corners(mesh: &TetMesh, t: &[u32; 4]) -> [Vec3; 4] {
    let p = mesh.positions();
    t.map(|n| p[n as usize])
}

/// The share of [`DIRECTIONS`] points on each sphere of `radii` about `centre` inside one of
/// the `near` tetrahedra.
fn share(centre: &Vec3, radii: &[f64], near: &[NearTet]) -> f64 {
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

/// Into `near`, in the order of the mesh, every tetrahedron of `mesh` (`grid`'s) whose
/// bounding box comes within `reach` of `centre` ([`near_tet`]); `found` is room.
fn near_tets(
    grid: &TetGrid,
    mesh: &TetMesh,
    centre: &Vec3,
    reach: f64,
    found: &mut Vec<u32>,
    near: &mut Vec<NearTet>,
) {
    found.clear();
    near.clear();
    // The cube about the sphere, a little larger (a box within reach by the test below
    // meets it whatever the rounding).
    let grow = reach * (1.0 + 1e-6) + centre.amax() * 1e-12;
    let r = grid.cells_of(&centre.add_scalar(-grow), &centre.add_scalar(grow));
    grid_cells(grid.dims, &r, |c| {
        found.extend_from_slice(grid.cell_items(c))
    });
    found.sort_unstable();
    found.dedup();
    let tets = mesh.tets();
    near.extend(
        found
            .iter()
            .filter_map(|&t| tets.get(t as usize))
            .filter_map(|t| near_tet(&corners(mesh, t), centre, reach)),
    );
}
