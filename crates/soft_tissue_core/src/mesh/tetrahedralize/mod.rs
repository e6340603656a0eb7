//! Tetrahedral meshes from closed triangle surfaces: an organ as a segmentation or an artist
//! delivers it.
//!
//! 1. **Repair what a scan gets wrong**: duplicated vertices are welded, degenerate and
//!    duplicated triangles and unused vertices dropped, the triangles oriented consistently
//!    across their manifold edges and each piece outward (positive enclosed volume), specks
//!    dropped, and nesting read from the file's orientation: a closed piece inside another
//!    that the file turns the other way faces inward (a cavity), one it turns the same way
//!    is inside the union and dropped. What was found is counted ([`SurfaceDefects`]).
//! 2. **Inside and outside** from the generalized winding number (Jacobson, Kavan and
//!    Sorkine-Hornung 2013): the solid angle the surface subtends at a point over 4 pi, one
//!    inside a closed surface and zero outside, and still near those values where the
//!    surface has small holes. The field the mesher reads is the distance to the surface,
//!    negative where the winding number exceeds one half.
//! 3. **Isosurface stuffing** of that field ([`stuff_fn_cut`](super::generate::stuff_fn_cut): its cut points bisected on the
//!    winding number alone, read along each cut edge from the triangles it crosses,
//!    [`SurfaceTree::winding_along`](super::surface_tree::SurfaceTree::winding_along)), the interior-node removal within the quality bound
//!    ([`coarsen_interior`](super::generate::coarsen_interior)), then every boundary node moved onto the input surface where the
//!    move keeps its tetrahedra above the quality bound.
//!
//! The lattice spacing comes from an edge length, or from a tetrahedron count (two or three
//! passes: a first guess from the enclosed volume, then corrected by the counts found).
//!
//! The winding number and the distances come from a hierarchy over the triangles
//! ([`SurfaceTree`]): near triangles exactly, far clusters by their dipole.
//!
//! One concern per file: `repair.rs` (the repair, with `nesting.rs` for cavities and inner
//! pieces and `buried.rs` for overlapping parts), `stuffing.rs` (the lattice and the spacing
//! for a count), `fitting.rs` (projection onto the surface and the crease fit), `passes.rs`
//! (edge splits, the volume restored, the distances both ways), `graded.rs` (the finer
//! lattice coarsened back toward the count), `thickness.rs` (how thin the walls are) and
//! `distance.rs` (the count grown until the boundary lies within a distance); this file
//! holds the options, the report, the errors and the order of the steps.

use super::generate::GenerateError;
use super::io::SurfaceMesh;
use super::surface_tree::SurfaceTree;
use super::{QualityReport, TetMesh};
use crate::Vec3;

mod buried;
mod distance;
mod fitting;
mod graded;
mod nesting;
mod passes;
mod repair;
mod stuffing;
mod thickness;

pub use distance::{
    DistanceGoal, DistanceSearch, DistanceTry, WallAdvice, tetrahedralize_to_distance, wall_advice,
};
pub use repair::{RepairedSurface, repair};
pub use thickness::{WallThickness, wall_thickness};

use buried::unburied_samples;
use fitting::onto_surface;
use passes::{Finished, Goal, samples};
use stuffing::Stuffing;

/// What the repair found in an input surface.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SurfaceDefects {
    /// Vertices that repeat another (welded).
    pub duplicate_vertices: usize,
    /// Vertices no triangle uses (dropped).
    pub unused_vertices: usize,
    /// Triangles with a repeated vertex or no area (dropped).
    pub degenerate_triangles: usize,
    /// Triangles turned to agree with their neighbours, to face outward, or (a cavity's)
    /// inward.
    pub flipped_triangles: usize,
    /// Edges with one triangle: the rims of holes.
    pub boundary_edges: usize,
    /// Edges shared by more than two triangles.
    pub non_manifold_edges: usize,
    /// Small separate pieces dropped (under 0.1 % of the volume and 1 % of the area: specks
    /// a segmentation leaves floating).
    pub specks_dropped: usize,
    /// Triangles over the same three vertices as another (dropped: one of a pair that runs
    /// the same way, both of a pair that runs opposite ways).
    pub duplicate_triangles: usize,
    /// Closed pieces inside another that the file turns the other way from it: kept facing
    /// inward, as cavities (a hollow organ's inner wall).
    pub cavities: usize,
    /// Closed pieces inside another that the file turns the same way (a tumour written as a
    /// second surface inside its organ): inside the union the mesh fills, so dropped.
    pub inner_pieces_dropped: usize,
    /// Triangles wholly or partly buried, not on the boundary of the inside (both sides
    /// inside or both outside): where parts overlap (two labels of a segmentation through
    /// each other, a fold of a surface through itself, a cavity through another). Meshed as
    /// the union; the wholly buried triangles leave the closest-point queries (the
    /// projection, the fit, the splits, the distances), the buried points the samples, and
    /// the buried share of each triangle the enclosed volume.
    pub buried_triangles: usize,
}

/// How to mesh a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TetrahedralizeOptions {
    /// Lattice spacing (about the interior edge length), scene units.
    pub edge_length: Option<f64>,
    /// Tetrahedra wanted (used when no edge length is given): two or three meshing passes
    /// whose lattice spacing is corrected by the counts found; the nearest is kept.
    pub target_tets: Option<usize>,
    /// Smallest dihedral angle the interior-node removal and the projection onto the surface
    /// keep, degrees (default 8).
    pub min_dihedral_deg: f64,
}

impl Default for TetrahedralizeOptions {
    fn default() -> Self {
        TetrahedralizeOptions {
            edge_length: None,
            target_tets: Some(1500),
            min_dihedral_deg: 8.0,
        }
    }
}

/// The mesher's revision: raised whenever the same surface and options give a different
/// mesh, so that caches of meshed surfaces (the plugin's `SurfaceLoader`) key on it and an
/// upgrade meshes again. 2: a second, finer graded level for thin parts. 3: other
/// coarsening targets for a near miss, four graded levels instead of two; a spacing too
/// thick for the shape is halved. 4: nesting read from the file's orientation (cavities;
/// inner pieces dropped), duplicate triangles dropped, volumes summed about the centre.
/// 5: overlapping parts meshed toward their union's boundary (buried triangles left out of
/// the closest-point queries, the samples and the enclosed volume).
pub const REVISION: u32 = 5;

/// What [`tetrahedralize`] did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TetrahedralizeReport {
    /// What the repair found.
    pub defects: SurfaceDefects,
    /// Lattice spacing used (the finer one for a graded mesh).
    pub spacing: f64,
    /// Nodes of the mesh.
    pub nodes: usize,
    /// Tetrahedra of the mesh.
    pub tets: usize,
    /// Smallest dihedral angle, degrees.
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: f64,
    /// Volume of the mesh.
    pub volume: f64,
    /// Volume of the mesh before the boundary nodes were moved out to restore the volume
    /// the chords lost (every boundary node on the surface).
    pub chord_volume: f64,
    /// Volume the repaired surface encloses (exact for a closed surface).
    pub enclosed_volume: f64,
    /// Largest distance from the mesh's boundary to the input surface, over its nodes, edge
    /// midpoints and triangle centroids.
    pub mesh_to_surface: f64,
    /// Largest distance from the input surface to the mesh's boundary, over its vertices,
    /// edge midpoints and triangle centroids.
    pub surface_to_mesh: f64,
    /// Diagonal of the input surface's bounding box.
    pub bbox_diagonal: f64,
    /// Boundary nodes moved onto the input surface (the rest kept their stuffed place).
    pub projected_nodes: usize,
    /// Boundary nodes then moved onto a point of the input surface the boundary passed too
    /// far from (a crease or corner the lattice rounded off).
    pub snapped_nodes: usize,
    /// Boundary edges then split, their new node on the input surface (where a boundary
    /// triangle spanned a curve or a crease too coarsely).
    pub split_edges: usize,
    /// Whether the kept mesh is the graded one (meshed finer, its boundary coarsened where
    /// the surface is flat) rather than the uniform one.
    pub graded: bool,
    /// How many times finer than the uniform lattice the graded mesh's lattice was: 1 for
    /// the uniform mesh, at most 2.5 at the first level, at most 3, 3.5 or 4 where a thin
    /// part needed a finer one.
    pub finer: f64,
}

impl TetrahedralizeReport {
    /// What the mesh misses of what the mesher aims at (the boundary within 1 % of the
    /// bounding box's diagonal of the surface both ways, the volume within 3 % of the
    /// enclosed one), in words; `None` where it reaches both. A mesh that misses is still
    /// valid and keeps the quality bound; it follows the surface only that closely.
    pub fn shortfall(&self) -> Option<String> {
        let mut missed = Vec::new();
        let worst = self.mesh_to_surface.max(self.surface_to_mesh) / self.bbox_diagonal;
        if worst > AIMED_DISTANCE {
            missed.push(format!(
                "the boundary lies up to {:.2} % of the bounding box's diagonal from the surface \
                 (aimed at {:.0} %)",
                100.0 * worst,
                100.0 * AIMED_DISTANCE
            ));
        }
        let volume = self.volume / self.enclosed_volume - 1.0;
        if volume.abs() > AIMED_VOLUME {
            missed.push(format!(
                "the volume is off by {:+.2} % (aimed at {:.0} %)",
                100.0 * volume,
                100.0 * AIMED_VOLUME
            ));
        }
        (!missed.is_empty()).then(|| {
            format!(
                "{}: parts thinner, narrower or more folded than {} tetrahedra can follow \
                 (a larger target count or a smaller edge length follows them closer)",
                missed.join(" and "),
                self.tets
            )
        })
    }
}

/// Why a surface could not be meshed.
#[derive(Debug, thiserror::Error)]
pub enum TetrahedralizeError {
    /// No triangles (after dropping degenerate ones).
    #[error("the surface has no triangles with an area")]
    Empty,
    /// A coordinate is not finite.
    #[error("vertex {vertex} is not finite")]
    NotFinite {
        /// The vertex.
        vertex: usize,
    },
    /// A triangle names a vertex that does not exist.
    #[error("triangle {triangle} names vertex {vertex}, but there are {vertices}")]
    BadIndex {
        /// The triangle.
        triangle: usize,
        /// The index.
        vertex: u32,
        /// Vertex count.
        vertices: usize,
    },
    /// The surface encloses no volume (an open sheet, or holes too large).
    #[error(
        "the surface encloses no volume ({enclosed:.3e} against a bounding box of {bbox:.3e}; \
         {boundary_edges} boundary edges)"
    )]
    NoEnclosedVolume {
        /// The enclosed volume found.
        enclosed: f64,
        /// The bounding box's volume.
        bbox: f64,
        /// Boundary edges (hole rims).
        boundary_edges: usize,
    },
    /// The holes are too large for the winding number to close: the area their rims could
    /// span (a disc of the rims' total length as circumference) is more than
    /// [`MAX_OPEN_FRACTION`] of the surface's area.
    #[error(
        "holes too large: {boundary_edges} boundary edges, {rim_length:.4} long in all; a disc \
         with that circumference would cover {percent:.1} % of the surface's area (at most \
         {max:.0} %)",
        max = 100.0 * MAX_OPEN_FRACTION
    )]
    TooOpen {
        /// Boundary edges.
        boundary_edges: usize,
        /// Their total length (the rims of the holes), in the surface's units.
        rim_length: f64,
        /// The area of a disc with the rims' total length as circumference, as a percentage
        /// of the surface's area: an upper bound on the holes' share (exact for one round
        /// hole), so it can pass 100 %.
        percent: f64,
    },
    /// An option is out of range.
    #[error("{0}")]
    Options(String),
    /// The mesher failed.
    #[error(transparent)]
    Generate(#[from] GenerateError),
}

/// Largest share of the surface's area that holes may take (estimated from their rims).
pub const MAX_OPEN_FRACTION: f64 = 0.05;

/// The boundary coarsening's first tolerance on a graded mesh, as a fraction of the bounding
/// box's diagonal; while the count is above the target it goes up to twice this (1 %), then
/// three times (1.5 %).
pub const GRADED_TOLERANCE: f64 = 0.005;

/// What the mesher aims at, as fractions: the boundary within this much of the bounding
/// box's diagonal of the surface, both ways (twice [`GRADED_TOLERANCE`])...
pub const AIMED_DISTANCE: f64 = 2.0 * GRADED_TOLERANCE;

/// ... and the volume within this much of the enclosed one.
pub const AIMED_VOLUME: f64 = 0.03;
/// How near the boundary must come to every sample of the input surface before the feature
/// fit stops, as a fraction of the bounding box's diagonal.
pub const FIT_TOLERANCE: f64 = 0.004;

/// The bounding box of `p`: its smallest and largest coordinates.
fn bounds(p: &[Vec3]) -> (Vec3, Vec3) {
    p.iter().fold(
        (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
        |(lo, hi), q| (lo.inf(q), hi.sup(q)),
    )
}

/// Meshes the inside of a triangle surface (see the module docs).
pub fn tetrahedralize(
    surface: &SurfaceMesh,
    options: &TetrahedralizeOptions,
) -> Result<(TetMesh, TetrahedralizeReport), TetrahedralizeError> {
    let min_dihedral = options.min_dihedral_deg;
    if !(min_dihedral.is_finite() && (0.0..60.0).contains(&min_dihedral)) {
        return Err(TetrahedralizeError::Options(format!(
            "the smallest dihedral angle must be in [0, 60) degrees, found {min_dihedral}"
        )));
    }
    let s = repair(surface)?;
    let (lo, hi) = bounds(&s.positions);
    let extent = hi - lo;
    let bbox = extent.x * extent.y * extent.z;
    // (A NaN volume is refused too.)
    if s.enclosed_volume.is_nan() || s.enclosed_volume <= 1e-9 * bbox.max(f64::MIN_POSITIVE) {
        return Err(TetrahedralizeError::NoEnclosedVolume {
            enclosed: s.enclosed_volume,
            bbox,
            boundary_edges: s.defects.boundary_edges,
        });
    }
    repair::check_holes(&s)?;
    let tree = s.tree();
    // Where parts overlap, what lies inside the union is not its boundary: the closest
    // points, the projection and the distances take the triangles not wholly buried (those
    // partly buried cross where the parts meet); inside and outside still the whole.
    let outer: Option<Vec<[u32; 3]>> = (!s.buried.is_empty()).then(|| {
        s.triangles
            .iter()
            .zip(&s.buried)
            .filter(|&(_, &b)| b < 1.0)
            .map(|(t, _)| *t)
            .collect()
    });
    let outer_tree = outer.as_deref().map(|o| SurfaceTree::new(&s.positions, o));
    let near = outer_tree.as_ref().unwrap_or(&tree);
    let stuffing = Stuffing {
        near,
        whole: &tree,
        bounds: (lo, hi),
        min_dihedral,
    };
    let (mesh, mut spacing) = match (options.edge_length, options.target_tets) {
        (Some(h), _) if h.is_finite() && h > 0.0 => (stuffing.mesh_at(h)?, h),
        (Some(h), _) => {
            return Err(TetrahedralizeError::Options(format!(
                "the edge length must be positive and finite, found {h}"
            )));
        }
        (None, Some(n)) if n >= 1 => stuffing.for_count(s.enclosed_volume, n)?,
        _ => {
            return Err(TetrahedralizeError::Options(
                "give an edge length or a positive tetrahedron count".into(),
            ));
        }
    };
    let diagonal = extent.norm();
    let tol = FIT_TOLERANCE * diagonal;
    let surface_samples = if s.buried.is_empty() {
        samples(&s.positions, &s.triangles)
    } else {
        unburied_samples(&s, &tree)
    };
    let goal = Goal {
        tree: near,
        surface_samples: &surface_samples,
        min_dihedral,
        tol,
        enclosed_volume: s.enclosed_volume,
    };
    // Projection and crease fit; then (in `Finished`) edge splits, the volume the chords
    // lost and the distances both ways.
    let (mesh, projected, snapped) = onto_surface(mesh, &goal);
    let mut done = Finished::split_and_measure(mesh, &goal, projected, snapped);
    // Graded where the uniform mesh misses (see `graded.rs`).
    let finer = graded::grade(&mut done, &stuffing, &goal, options, spacing, diagonal);
    // The report gives the lattice spacing the kept mesh came from.
    spacing /= finer;
    let Finished {
        mesh,
        chord_volume,
        projected,
        snapped,
        split,
        mesh_to_surface,
        surface_to_mesh,
    } = done;
    let q: QualityReport = mesh.quality();
    let report = TetrahedralizeReport {
        defects: s.defects,
        spacing,
        nodes: mesh.node_count(),
        tets: mesh.tet_count(),
        min_dihedral_deg: q.min_dihedral_deg,
        max_dihedral_deg: q.max_dihedral_deg,
        volume: mesh.volume(),
        enclosed_volume: s.enclosed_volume,
        chord_volume,
        mesh_to_surface,
        surface_to_mesh,
        bbox_diagonal: diagonal,
        projected_nodes: projected,
        snapped_nodes: snapped,
        split_edges: split,
        graded: finer > 1.0,
        finer,
    };
    Ok((mesh, report))
}
