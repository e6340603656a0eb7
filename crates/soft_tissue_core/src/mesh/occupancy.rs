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
use crate::Vec3;

/// Directions sampled on each sphere (a Fibonacci lattice: nearly even areas, so the share
/// of a half-space comes out within about `1 / DIRECTIONS` of 1/2).
pub const DIRECTIONS: usize = 256;

/// The grid has at most this many cells per tetrahedron (a flat or very uneven mesh gets
/// coarser cells).
const CELLS_PER_TET: f64 = 4.0;

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
    TetGrid::new(mesh).near(mesh, centre, reach, &mut found, &mut near);
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
        self.grid
            .near(mesh, centre, reach, &mut self.found, &mut self.near);
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

/// A mesh's tetrahedra in a uniform grid: each in every cell its bounding box meets.
#[derive(Debug, Default)]
struct TetGrid {
    origin: Vec3,
    cell: f64,
    dims: [usize; 3],
    /// Cell `c`'s tetrahedra are `items[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl TetGrid {
    fn new(mesh: &TetMesh) -> Self {
        let n = mesh.tet_count();
        let bbox = mesh.bbox();
        let extent = bbox.extent();
        // Cells about the size of the tetrahedra's boxes, but no more than CELLS_PER_TET per
        // tetrahedron over the mesh's box.
        let mean = mesh
            .tets()
            .iter()
            .map(|t| {
                let (lo, hi) = bounds(&corners(mesh, t));
                (hi - lo).max()
            })
            .sum::<f64>()
            / n.max(1) as f64;
        let most = CELLS_PER_TET * n as f64 + 8.0;
        let coarsest = (extent.x * extent.y * extent.z / most).cbrt();
        let mut cell = mean.max(coarsest);
        if !(cell.is_finite() && cell > 0.0) {
            cell = extent.max();
        }
        let count = |cell: f64| extent.map(|e| (e / cell).ceil().max(1.0));
        // One cell for a box that is not finite; a flat mesh's box has no volume: coarser
        // cells until they are few enough.
        let mut dims = [1; 3];
        if extent.iter().all(|e| e.is_finite()) && cell.is_finite() && cell > 0.0 {
            for _ in 0..64 {
                let c = count(cell);
                if c.product() <= most {
                    dims = [0, 1, 2].map(|a| c[a] as usize);
                    break;
                }
                cell *= 2.0;
            }
        }
        let mut grid = TetGrid {
            origin: bbox.min,
            cell,
            dims,
            starts: vec![0; dims[0] * dims[1] * dims[2] + 1],
            items: Vec::new(),
        };
        // Counting sort into the cells.
        for t in mesh.tets() {
            let r = grid.cells_of(&bounds(&corners(mesh, t)));
            grid_cells(dims, &r, |c| grid.starts[c + 1] += 1);
        }
        for c in 0..grid.starts.len() - 1 {
            grid.starts[c + 1] += grid.starts[c];
        }
        let mut fill = grid.starts.clone();
        grid.items = vec![0; grid.starts.last().map_or(0, |&k| k as usize)];
        for (k, t) in mesh.tets().iter().enumerate() {
            let r = grid.cells_of(&bounds(&corners(mesh, t)));
            let items = &mut grid.items;
            grid_cells(dims, &r, |c| {
                items[fill[c] as usize] = k as u32;
                fill[c] += 1;
            });
        }
        grid
    }

    /// The cell along `axis` that holds coordinate `x` (the first or last one beyond the
    /// grid).
    fn index(&self, x: f64, axis: usize) -> usize {
        let i = ((x - self.origin[axis]) / self.cell).floor();
        (i.max(0.0) as usize).min(self.dims[axis].saturating_sub(1))
    }

    /// The cells a box meets, as index ranges per axis.
    fn cells_of(&self, (lo, hi): &(Vec3, Vec3)) -> [[usize; 2]; 3] {
        [0, 1, 2].map(|a| [self.index(lo[a], a), self.index(hi[a], a)])
    }

    /// Into `near`, in the order of the mesh, every tetrahedron of `mesh` (the grid's)
    /// whose bounding box comes within `reach` of `centre` ([`near_tet`]); `found` is room.
    fn near(
        &self,
        mesh: &TetMesh,
        centre: &Vec3,
        reach: f64,
        found: &mut Vec<u32>,
        near: &mut Vec<NearTet>,
    ) {
        found.clear();
        near.clear();
        if self.starts.len() < 2 {
            return;
        }
        // The cube about the sphere, a little larger (a box within reach by the test below
        // meets it whatever the rounding).
        let grow = reach * (1.0 + 1e-6) + centre.amax() * 1e-12;
        let cube = (centre.add_scalar(-grow), centre.add_scalar(grow));
        let r = self.cells_of(&cube);
        grid_cells(self.dims, &r, |c| {
            found.extend_from_slice(
                &self.items[self.starts[c] as usize..self.starts[c + 1] as usize],
            );
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
}

/// Calls `f` with the linear index of every cell in the index ranges `r`.
fn grid_cells(dims: [usize; 3], r: &[[usize; 2]; 3], mut f: impl FnMut(usize)) {
    for k in r[2][0]..=r[2][1] {
        for j in r[1][0]..=r[1][1] {
            for i in r[0][0]..=r[0][1] {
                f(i + dims[0] * (j + dims[1] * k));
            }
        }
    }
}
