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
//! 3. **Isosurface stuffing** of that field ([`stuff_fn_sign`]: its cut points bisected on the
//!    winding number alone), the interior-node removal within the quality bound
//!    ([`coarsen_interior`]), then every boundary node moved onto the input surface where the
//!    move keeps its tetrahedra above the quality bound.
//!
//! The lattice spacing comes from an edge length, or from a tetrahedron count (two or three
//! passes: a first guess from the enclosed volume, then corrected by the counts found).
//!
//! The winding number and the distances come from a hierarchy over the triangles
//! ([`SurfaceTree`]): near triangles exactly, far clusters by their dipole.

use std::collections::HashMap;

use rayon::prelude::*;

use super::generate::{GenerateError, coarsen_interior, stuff_fn_sign};
use super::io::SurfaceMesh;
use super::quality::{tet_quality_deg, tet_worst_cos};
use super::surface_tree::SurfaceTree;
use super::{QualityReport, TetMesh};
use crate::Vec3;
use crate::geometry::solid_angle;

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

/// A repaired surface: welded, without degenerate triangles or unused vertices, oriented.
#[derive(Debug, Clone)]
pub struct RepairedSurface {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles, oriented outward where the surface allows (a cavity's face into it).
    pub triangles: Vec<[u32; 3]>,
    /// What was found.
    pub defects: SurfaceDefects,
    /// Volume enclosed (the divergence theorem over the oriented triangles; where parts
    /// overlap, over the parts of them that bound the union).
    pub enclosed_volume: f64,
    /// Per triangle, the share of its area buried (see
    /// [`SurfaceDefects::buried_triangles`]), from 0 to 1; empty where none is.
    pub buried: Vec<f64>,
}

/// Repairs `surface` (see the module docs).
pub fn repair(surface: &SurfaceMesh) -> Result<RepairedSurface, TetrahedralizeError> {
    let n = surface.positions.len();
    if let Some(vertex) = surface
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(TetrahedralizeError::NotFinite { vertex });
    }
    for (triangle, t) in surface.triangles.iter().enumerate() {
        if let Some(&vertex) = t.iter().find(|&&v| v as usize >= n) {
            return Err(TetrahedralizeError::BadIndex {
                triangle,
                vertex,
                vertices: n,
            });
        }
    }
    let mut defects = SurfaceDefects::default();
    let (lo, hi) = bounds(&surface.positions);
    let diagonal = (hi - lo).norm();
    // Weld: positions equal to 1e-9 of the diagonal are one vertex.
    let tol = 1e-9 * diagonal.max(f64::MIN_POSITIVE);
    let key = |p: &Vec3| p.map(|c| (c / tol).round() as i64);
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut welded = Vec::with_capacity(n);
    let mut map = vec![0u32; n];
    for (i, p) in surface.positions.iter().enumerate() {
        let k = key(p);
        let k = [k.x, k.y, k.z];
        map[i] = *index.entry(k).or_insert_with(|| {
            welded.push(*p);
            (welded.len() - 1) as u32
        });
    }
    defects.duplicate_vertices = n - welded.len();
    let area_tol = 1e-14 * diagonal * diagonal;
    let mut triangles = Vec::with_capacity(surface.triangles.len());
    for t in &surface.triangles {
        let t = t.map(|v| map[v as usize]);
        let [a, b, c] = t.map(|v| welded[v as usize]);
        if t[0] == t[1]
            || t[1] == t[2]
            || t[0] == t[2]
            || (b - a).cross(&(c - a)).norm() <= area_tol
        {
            defects.degenerate_triangles += 1;
            continue;
        }
        triangles.push(t);
    }
    let (triangles, duplicates) = drop_duplicate_triangles(triangles);
    defects.duplicate_triangles = duplicates;
    if triangles.is_empty() {
        return Err(TetrahedralizeError::Empty);
    }
    // Unused vertices dropped, the rest renumbered in order.
    let (positions, mut triangles) = keep(&welded, &triangles, |_| true);
    defects.unused_vertices = welded.len() - positions.len();
    // Edges: which triangles hold each (and in which direction).
    let mut edges: HashMap<(u32, u32), Vec<(usize, bool)>> = HashMap::new();
    for (k, t) in triangles.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push((k, a < b));
        }
    }
    defects.boundary_edges = edges.values().filter(|v| v.len() == 1).count();
    defects.non_manifold_edges = edges.values().filter(|v| v.len() > 2).count();
    // Orientation: across every manifold edge the two triangles run opposite ways; a
    // breadth-first walk from each unvisited triangle flips those that disagree.
    let mut flip = vec![false; triangles.len()];
    let mut seen = vec![false; triangles.len()];
    let mut components: Vec<Vec<usize>> = Vec::new();
    for start in 0..triangles.len() {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut queue = std::collections::VecDeque::from([start]);
        let mut members = Vec::new();
        while let Some(k) = queue.pop_front() {
            members.push(k);
            let t = triangles[k];
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                let list = &edges[&(a.min(b), a.max(b))];
                if list.len() != 2 {
                    continue;
                }
                let forward_k = (a < b) != flip[k];
                for &(j, forward) in list {
                    if j == k || seen[j] {
                        continue;
                    }
                    // Consistent neighbours use the shared edge in opposite directions.
                    flip[j] = forward == forward_k;
                    seen[j] = true;
                    queue.push_back(j);
                }
            }
        }
        components.push(members);
    }
    for (k, t) in triangles.iter_mut().enumerate() {
        if flip[k] {
            t.swap(1, 2);
        }
    }
    // Each piece faces outward: its enclosed volume positive. Volumes are summed about the
    // origin, as before (the spacing a count asks for follows the volume's last bits, and
    // the mesh the spacing's: surfaces near the origin mesh as they did), but about the
    // box's centre for a surface more than 100 diagonals away: about the origin, each term
    // is about (distance / diagonal)^3 times the volume, so past that the sum keeps fewer
    // than 10 of its 16 digits (a unit sphere 2e6 away was refused: its volume cancelled).
    let centre = {
        let (lo, hi) = bounds(&positions);
        let centre = (lo + hi) / 2.0;
        if centre.norm() > 100.0 * (hi - lo).norm() {
            centre
        } else {
            Vec3::zeros()
        }
    };
    for members in &components {
        let v: f64 = members
            .iter()
            .map(|&k| signed_volume(&triangles[k], &positions, &centre))
            .sum();
        if v < 0.0 {
            for &k in members {
                triangles[k].swap(1, 2);
                flip[k] = !flip[k];
            }
        }
    }
    // A piece is closed where each of its edges has two triangles (an open one, a patch
    // that non-manifold edges cut off, bounds nothing and takes no part in the nesting).
    let closed: Vec<bool> = components
        .iter()
        .map(|members| {
            members.iter().all(|&k| {
                let t = triangles[k];
                (0..3).all(|e| {
                    let (a, b) = (t[e], t[(e + 1) % 3]);
                    edges[&(a.min(b), a.max(b))].len() == 2
                })
            })
        })
        .collect();
    // Specks first (whole pieces joined through vertices), so that the nesting and its
    // counts see only what is meshed; the pieces and turns renumbered to what is kept.
    let (positions, triangles, specks, kept) = drop_specks(positions, triangles, &centre);
    defects.specks_dropped = specks;
    let mut renumbered = vec![usize::MAX; kept.len()];
    for (new, old) in (0..kept.len()).filter(|&k| kept[k]).enumerate() {
        renumbered[old] = new;
    }
    let mut flip: Vec<bool> = (0..kept.len())
        .filter(|&k| kept[k])
        .map(|k| flip[k])
        .collect();
    let mut triangles = triangles;
    let pieces: Vec<Piece> = components
        .into_iter()
        .zip(closed)
        .filter(|(members, _)| kept[members[0]])
        .map(|(members, closed)| {
            let members: Vec<usize> = members.into_iter().map(|k| renumbered[k]).collect();
            Piece::new(members, closed, &triangles, &positions, &flip, &centre)
        })
        .collect();
    // Then a piece inside another that the file turned the other way from it faces inward
    // again (a cavity); one it turned the same way is inside the union, and dropped.
    let facing = nesting(&pieces, &triangles, &positions);
    let mut inner = vec![false; triangles.len()];
    for (piece, facing) in pieces.iter().zip(&facing) {
        match facing {
            Facing::Outward => {}
            Facing::Inward => {
                defects.cavities += 1;
                for &k in &piece.members {
                    triangles[k].swap(1, 2);
                    flip[k] = !flip[k];
                }
            }
            Facing::Inner => {
                defects.inner_pieces_dropped += 1;
                for &k in &piece.members {
                    inner[k] = true;
                }
            }
        }
    }
    defects.flipped_triangles = (0..flip.len()).filter(|&k| flip[k] && !inner[k]).count();
    let (positions, triangles) = keep(&positions, &triangles, |k| !inner[k]);
    // The pieces' volumes, a cavity's taken away (summed piece by piece, as before: the same
    // bits, so the same spacing and mesh); where specks went, over the kept triangles.
    let enclosed = if specks == 0 {
        pieces
            .iter()
            .zip(&facing)
            .map(|(p, f)| match f {
                Facing::Outward => p.volume,
                Facing::Inward => -p.volume,
                Facing::Inner => 0.0,
            })
            .sum::<f64>()
            .abs()
    } else {
        triangles
            .iter()
            .map(|t| signed_volume(t, &positions, &centre))
            .sum::<f64>()
            .abs()
    };
    // Overlapping parts: the union's volume from the parts of its triangles that bound it
    // (on a flat triangle the divergence theorem's integrand is constant, so its term
    // scales with the share of its area kept).
    let buried = buried_shares(&positions, &triangles);
    let enclosed = if buried.is_empty() {
        enclosed
    } else {
        defects.buried_triangles = buried.iter().filter(|&&b| b > 0.0).count();
        triangles
            .iter()
            .zip(&buried)
            .map(|(t, b)| signed_volume(t, &positions, &centre) * (1.0 - b))
            .sum::<f64>()
            .abs()
    };
    Ok(RepairedSurface {
        positions,
        triangles,
        defects,
        enclosed_volume: enclosed,
        buried,
    })
}

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
fn buried_shares(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<f64> {
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

/// Pieces (triangles joined through shared vertices) that enclose less than 0.1 % of the
/// whole volume and hold less than 1 % of the area: specks a segmentation leaves floating
/// beside an organ, far too small for any lattice to mesh, which would only stand off the
/// mesh. Returns the rest, renumbered, how many pieces were dropped, and which of the
/// triangles were kept.
fn drop_specks(
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    centre: &Vec3,
) -> (Vec<Vec3>, Vec<[u32; 3]>, usize, Vec<bool>) {
    let mut parent: Vec<u32> = (0..positions.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            parent[v as usize] = parent[parent[v as usize] as usize];
            v = parent[v as usize];
        }
        v
    }
    for t in &triangles {
        for e in 1..3 {
            let (a, b) = (root(&mut parent, t[0]), root(&mut parent, t[e]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    // Volume and area per piece.
    let mut piece: HashMap<u32, (f64, f64)> = HashMap::new();
    let (mut volume, mut area) = (0.0, 0.0);
    let piece_of: Vec<u32> = triangles.iter().map(|t| root(&mut parent, t[0])).collect();
    for (t, &r) in triangles.iter().zip(&piece_of) {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let (v, s) = (
            signed_volume(t, &positions, centre),
            0.5 * (b - a).cross(&(c - a)).norm(),
        );
        let e = piece.entry(r).or_default();
        e.0 += v;
        e.1 += s;
        area += s;
    }
    // (In the pieces' order, so that the sum's last bits do not follow the hash.)
    let mut roots: Vec<u32> = piece.keys().copied().collect();
    roots.sort_unstable();
    for r in &roots {
        volume += piece[r].0.abs();
    }
    let speck = |r: &u32| {
        let (v, s) = piece[r];
        piece.len() > 1 && v.abs() < 1e-3 * volume && s < 1e-2 * area
    };
    let dropped = roots.iter().filter(|r| speck(r)).count();
    let kept: Vec<bool> = piece_of.iter().map(|r| !speck(r)).collect();
    if dropped == 0 {
        return (positions, triangles, 0, kept);
    }
    let (positions, triangles) = keep(&positions, &triangles, |k| kept[k]);
    (positions, triangles, dropped, kept)
}

/// The triangles `kept` says to keep (by index), and the vertices they use, renumbered in
/// order.
fn keep(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    kept: impl Fn(usize) -> bool,
) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut map = vec![u32::MAX; positions.len()];
    let mut kept_positions = Vec::new();
    let kept_triangles = (0..triangles.len())
        .filter(|&k| kept(k))
        .map(|k| {
            triangles[k].map(|v| {
                if map[v as usize] == u32::MAX {
                    map[v as usize] = kept_positions.len() as u32;
                    kept_positions.push(positions[v as usize]);
                }
                map[v as usize]
            })
        })
        .collect();
    (kept_positions, kept_triangles)
}

/// The signed volume of the tetrahedron from `centre` to triangle `t`: summed over a closed
/// surface, the volume it encloses (the divergence theorem), positive where it faces out.
fn signed_volume(t: &[u32; 3], positions: &[Vec3], centre: &Vec3) -> f64 {
    let [a, b, c] = t.map(|v| positions[v as usize] - centre);
    a.dot(&b.cross(&c)) / 6.0
}

/// Triangles over the same three vertices: where more run one way than the other, one is
/// kept (a face written twice); where as many run each way, none (a wall of no thickness
/// between two parts, which their union does not have). Returns the rest, in order, and how
/// many were dropped.
fn drop_duplicate_triangles(triangles: Vec<[u32; 3]>) -> (Vec<[u32; 3]>, usize) {
    // Per vertex set: how many more run the way of its sorted order than against it.
    let mut balance: HashMap<[u32; 3], i64> = HashMap::new();
    let key = |t: &[u32; 3]| {
        let mut k = *t;
        k.sort_unstable();
        // A rotation of the sorted order runs its way; a swap of two runs against it.
        let along = [k, [k[1], k[2], k[0]], [k[2], k[0], k[1]]].contains(t);
        (k, if along { 1 } else { -1 })
    };
    for t in &triangles {
        let (k, way) = key(t);
        *balance.entry(k).or_default() += way;
    }
    let total = triangles.len();
    let mut kept_sets = std::collections::HashSet::new();
    let kept: Vec<[u32; 3]> = triangles
        .into_iter()
        .filter(|t| {
            let (k, way) = key(t);
            balance[&k].signum() == way && kept_sets.insert(k)
        })
        .collect();
    let dropped = total - kept.len();
    (kept, dropped)
}

/// A piece of the surface joined across manifold edges, faced outward.
struct Piece {
    members: Vec<usize>,
    /// Whether every edge of it has two triangles.
    closed: bool,
    volume: f64,
    lo: Vec3,
    hi: Vec3,
    /// Whether the file had it facing outward (most of its area not turned).
    outward_in_file: bool,
}

impl Piece {
    fn new(
        members: Vec<usize>,
        closed: bool,
        triangles: &[[u32; 3]],
        positions: &[Vec3],
        flip: &[bool],
        centre: &Vec3,
    ) -> Piece {
        let volume = members
            .iter()
            .map(|&k| signed_volume(&triangles[k], positions, centre))
            .sum();
        let corners: Vec<Vec3> = members
            .iter()
            .flat_map(|&k| triangles[k].map(|v| positions[v as usize]))
            .collect();
        let (lo, hi) = bounds(&corners);
        let (mut kept, mut turned) = (0.0, 0.0);
        for &k in &members {
            let [a, b, c] = triangles[k].map(|v| positions[v as usize]);
            let area = (b - a).cross(&(c - a)).norm();
            if flip[k] {
                turned += area;
            } else {
                kept += area;
            }
        }
        Piece {
            members,
            closed,
            volume,
            lo,
            hi,
            outward_in_file: kept >= turned,
        }
    }
}

/// Which way a piece of the surface faces once nesting is read.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Facing {
    Outward,
    /// A cavity.
    Inward,
    /// Inside a piece that faces the same way: inside the union, no part of its boundary.
    Inner,
}

/// Which way each piece faces. A closed piece lies inside another when the other's box
/// holds its box and the other's winding number exceeds one half at the centroids of (up
/// to) eight of its triangles; the smallest such is around it. Open pieces face outward. A piece around nothing faces outward. One inside another
/// faces the other way from it where the file turned the two apart: a hollow organ's inner
/// wall (written facing inward, as segmentations write it) is a cavity, and a stone inside
/// the cavity is solid again. Where the file turned them alike (a tumour written as a second
/// outward surface inside its organ), the inner one lies inside the union: not a boundary.
fn nesting(pieces: &[Piece], triangles: &[[u32; 3]], positions: &[Vec3]) -> Vec<Facing> {
    let mut facing = vec![Facing::Outward; pieces.len()];
    if pieces.iter().filter(|p| p.closed).count() < 2 {
        return facing;
    }
    let mut order: Vec<usize> = (0..pieces.len()).filter(|&c| pieces[c].closed).collect();
    order.sort_by(|&a, &b| {
        pieces[b]
            .volume
            .total_cmp(&pieces[a].volume)
            .then(a.cmp(&b))
    });
    // Each piece's own triangles, a tree over them (built where a smaller piece may be
    // inside), and whether it ends up facing outward.
    let own: Vec<Vec<[u32; 3]>> = pieces
        .iter()
        .map(|p| match p.closed {
            true => p.members.iter().map(|&k| triangles[k]).collect(),
            false => Vec::new(),
        })
        .collect();
    let mut trees: Vec<Option<SurfaceTree<'_>>> = (0..pieces.len()).map(|_| None).collect();
    let mut outward = vec![true; pieces.len()];
    for (rank, &c) in order.iter().enumerate() {
        let piece = &pieces[c];
        let probes: Vec<Vec3> = piece
            .members
            .iter()
            .step_by(piece.members.len().div_ceil(8))
            .map(|&k| {
                triangles[k]
                    .iter()
                    .map(|&v| positions[v as usize])
                    .sum::<Vec3>()
                    / 3.0
            })
            .collect();
        // The smallest larger piece around this one: the last in volume order that holds it.
        let around = order[..rank].iter().rev().copied().find(|&a| {
            let other = &pieces[a];
            let boxed = (0..3).all(|i| other.lo[i] <= piece.lo[i] && piece.hi[i] <= other.hi[i]);
            boxed && {
                // (Every piece faces outward here: the cavities turn after.)
                let tree = trees[a].get_or_insert_with(|| SurfaceTree::new(positions, &own[a]));
                probes.iter().all(|p| tree.winding_number(p) > 0.5)
            }
        });
        if let Some(a) = around {
            if piece.outward_in_file == pieces[a].outward_in_file {
                facing[c] = Facing::Inner;
                // (What lies inside it is inside the union too: it faces as its outer one.)
                outward[c] = outward[a];
            } else {
                outward[c] = !outward[a];
                if !outward[c] {
                    facing[c] = Facing::Inward;
                }
            }
        }
    }
    facing
}

fn bounds(p: &[Vec3]) -> (Vec3, Vec3) {
    p.iter().fold(
        (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
        |(lo, hi), q| (lo.inf(q), hi.sup(q)),
    )
}

impl RepairedSurface {
    /// The generalized winding number at `p` (one inside, zero outside), summed exactly
    /// over every triangle (the reference for [`SurfaceTree::winding_number`]).
    pub fn winding_number(&self, p: &Vec3) -> f64 {
        let s: f64 = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| self.positions[v as usize] - p);
                solid_angle(&a, &b, &c)
            })
            .sum();
        s / (4.0 * std::f64::consts::PI)
    }

    /// A hierarchy over the surface: fast distances and winding numbers.
    pub fn tree(&self) -> SurfaceTree<'_> {
        SurfaceTree::new(&self.positions, &self.triangles)
    }
}

/// The signed field the mesher reads: the distance to the surface's boundary part (`near`),
/// negative inside the whole surface (`whole`).
fn signed_distance(near: &SurfaceTree<'_>, whole: &SurfaceTree<'_>, p: &Vec3) -> f64 {
    let d = near.closest(p).map_or(f64::INFINITY, |(_, d)| d);
    if inside(whole, p) { -d } else { d }
}

/// Whether `p` is inside: the generalized winding number over one half. It agrees with
/// `signed_distance < 0` everywhere but exactly on the surface (there -0, not below 0),
/// where either answer leaves the cut point within the bisection's precision.
fn inside(tree: &SurfaceTree<'_>, p: &Vec3) -> bool {
    tree.winding_number(p) > 0.5
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
    if s.defects.boundary_edges > 0 {
        let mut count: HashMap<(u32, u32), usize> = HashMap::new();
        for t in &s.triangles {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let rim: f64 = count
            .iter()
            .filter(|&(_, &c)| c == 1)
            .map(|(&(a, b), _)| (s.positions[a as usize] - s.positions[b as usize]).norm())
            .sum();
        let area: f64 = s
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| s.positions[v as usize]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum();
        // One disc with the rims' whole length as circumference: an upper bound for several
        // holes, exact for one round hole.
        let holes = rim * rim / (4.0 * std::f64::consts::PI);
        if holes > MAX_OPEN_FRACTION * area {
            return Err(TetrahedralizeError::TooOpen {
                boundary_edges: s.defects.boundary_edges,
                rim_length: rim,
                percent: 100.0 * holes / area,
            });
        }
    }
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
    let mesh_at = |h: f64| -> Result<TetMesh, TetrahedralizeError> {
        // 16 bisections (h / 65536): the boundary nodes are moved onto the surface after.
        // The bisections need only the side (the winding number), not the distance.
        let stuffed = stuff_fn_sign(
            |p| signed_distance(near, &tree, p),
            |p| inside(&tree, p),
            (lo, hi),
            h,
            16,
        )?;
        Ok(coarsen_interior(&stuffed, min_dihedral).map_err(GenerateError::from)?)
    };
    let (mesh, mut spacing) = match (options.edge_length, options.target_tets) {
        (Some(h), _) if h.is_finite() && h > 0.0 => (mesh_at(h)?, h),
        (Some(h), _) => {
            return Err(TetrahedralizeError::Options(format!(
                "the edge length must be positive and finite, found {h}"
            )));
        }
        (None, Some(n)) if n >= 1 => {
            // About five tetrahedra per lattice cube of the volume after the removal; then
            // corrected by the counts found. After the interior removal the count grows
            // between h^-2 (most tetrahedra in the boundary layer) and h^-3, so the second
            // pass assumes 2.5 and a third, where the second is more than 8 % off, takes
            // the exponent the first two measured. The pass nearest the target is kept.
            // A shape thinner than the spacing the count asks for (a wafer, a membrane)
            // leaves no lattice tetrahedron inside: that spacing is halved until one
            // fits, up to 256 times finer, and the count comes out over the target.
            let fitting = |mut h: f64| -> Result<(TetMesh, f64), TetrahedralizeError> {
                for _ in 0..8 {
                    match mesh_at(h) {
                        Err(TetrahedralizeError::Generate(GenerateError::Empty(_))) => h *= 0.5,
                        other => return Ok((other?, h)),
                    }
                }
                Ok((mesh_at(h)?, h))
            };
            let want = n as f64;
            let off = |m: &TetMesh| (m.tet_count().max(1) as f64 / want).ln().abs();
            let (m1, h1) = fitting((5.0 * s.enclosed_volume / want).cbrt())?;
            let n1 = m1.tet_count().max(1) as f64;
            let (m2, h2) = fitting(h1 * (n1 / want).powf(1.0 / 2.5))?;
            let n2 = m2.tet_count().max(1) as f64;
            let mut best = if off(&m2) <= off(&m1) {
                (m2, h2)
            } else {
                (m1, h1)
            };
            if (n2 / want - 1.0).abs() > 0.08 && (h1 / h2 - 1.0).abs() > 1e-3 {
                let p = ((n2 / n1).ln() / (h1 / h2).ln()).clamp(1.5, 3.5);
                let (m3, h3) = fitting(h2 * (n2 / want).powf(1.0 / p))?;
                if off(&m3) < off(&best.0) {
                    best = (m3, h3);
                }
            }
            best
        }
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
    let onto_surface = |mesh: TetMesh| -> (TetMesh, usize, usize) {
        let (mesh, projected) = project_boundary(mesh, near, min_dihedral);
        let (mesh, snapped) = fit_features(mesh, &surface_samples, min_dihedral, tol);
        (mesh, projected, snapped)
    };
    let (mesh, projected, snapped) = onto_surface(mesh);
    let mut done = Finished::split_and_measure(mesh, &goal, projected, snapped);
    // Graded: where the uniform lattice leaves the boundary more than 1 % of the diagonal
    // off the surface (or the surface off it), mesh finer, fit that, coarsen its boundary
    // where the surface is flat down to the target, and keep the nearer of the two.
    // The fine mesh has about factor^2.5 times the tetrahedra (most in the boundary layer):
    // at most 2.5 times finer, and at most about 25k tetrahedra, so that large targets stay
    // fast; below 1.2 times finer there is nothing to gain. Where the kept mesh still
    // misses 1 % but stays within 2.5 % (a thin part: where it is about two fine
    // lattice spacings thick, its tetrahedra have every node on the boundary and no split
    // there keeps the bound; a tip folded nearly flat), again from finer meshes in turn:
    // at most 3, 3.5 and 4 times finer and about 45k, 60k and 90k tetrahedra (see `levels`
    // for which misses each runs for), until one is within 1 %. Each finer lattice puts interior nodes where the last had none, and each
    // gives the coarsening and the splits after it other nodes to work with (where a result
    // lies near 1 %, which side it falls on changes with the lattice, not steadily).
    // Surfaces that need it pay for it; the others stop at the first level.
    // The distance the graded mesh is there to reach: 1 % of the diagonal.
    let one_percent = AIMED_DISTANCE * diagonal;
    // The fine mesh's boundary coarsened toward `target` tetrahedra (the same at each level).
    // First within the tolerance; while the count stays a tenth over the target, again
    // within up to twice it, then, a fifth over, three times (a surface too detailed for
    // the count: the count first, within 1.5 % of the diagonal, since the edge splits
    // after it add tetrahedra).
    let coarsened = |fine: &TetMesh, target: usize| -> Option<TetMesh> {
        use super::coarsen_boundary::{BoundaryCoarsening, coarsen_boundary};
        let mut settings = BoundaryCoarsening {
            min_dihedral_deg: min_dihedral,
            tolerance: GRADED_TOLERANCE * diagonal,
            target_tets: target,
            levels: &[0.25, 0.5, 1.0],
        };
        let mut coarse = coarsen_boundary(fine, near, &settings).ok()?;
        if coarse.tet_count() as f64 > 1.1 * target as f64 {
            settings.levels = &[1.25, 1.5, 1.75, 2.0];
            coarse = coarsen_boundary(&coarse, near, &settings).ok()?;
        }
        if coarse.tet_count() as f64 > 1.2 * target as f64 {
            settings.levels = &[2.25, 2.5, 2.75, 3.0];
            coarse = coarsen_boundary(&coarse, near, &settings).ok()?;
        }
        Some(coarse)
    };
    // How many times finer the kept mesh's lattice is than the uniform one (1: uniform).
    let mut finer = 1.0;
    // Each level: the count, how many times finer, and the largest miss (in % of the
    // diagonal) it runs for. The finer levels only after the first ran: the one 3.5 times
    // finer for a miss up to 2.5 % (1.4 times finer than the first's, it shrinks a chord's
    // distance about 1.4^2 = 2 times); those 3 and 4 times finer only for a near miss, up
    // to 1.5 %, where another lattice is another chance (a far miss, a thin-walled heart
    // at 1.8 %, gained nothing from them, and a small intestine at 10000 tetrahedra took
    // over 120 s instead of 53 s). A surface farther off (a long tube) is not followed at
    // this count by any.
    let levels: Vec<(usize, f64, f64)> = match (options.edge_length, options.target_tets) {
        (None, Some(n)) => {
            let factor = |budget: f64, cap: f64| (budget / n as f64).powf(0.4).min(cap);
            [
                (25_000.0, 2.5, f64::INFINITY),
                (45_000.0, 3.0, NEAR_MISS),
                (60_000.0, 3.5, 2.5),
                (90_000.0, 4.0, NEAR_MISS),
            ]
            .map(|(budget, cap, reach)| (n, factor(budget, cap), reach))
            .to_vec()
        }
        _ => Vec::new(),
    };
    for (n, factor, reach) in levels {
        let worst = done.worst();
        if worst <= one_percent || factor < 1.2 {
            break;
        }
        if worst > reach * one_percent {
            continue;
        }
        // The graded mesh is an improvement on the uniform one: should any step of it fail
        // (a lattice too large, a mesh the coarsening left invalid), the uniform one stays.
        let Some((fine, projected, snapped)) = mesh_at(spacing / factor).ok().map(onto_surface)
        else {
            break;
        };
        // Kept when nearer the surface and within a third of the target. Where the count
        // came out farther off (the edge splits add tetrahedra, the interior removal after
        // the coarsening takes some), the coarsening runs again from the fine mesh toward a
        // corrected target.
        // The count after the splits follows the coarsening's target only roughly: the
        // next target comes from the last two tries (a secant), or from the ratio after
        // the first.
        let try_target = |target: f64| {
            let coarse = coarsened(&fine, target.max(1.0) as usize)?;
            Some(Finished::split_and_measure(
                coarse, &goal, projected, snapped,
            ))
        };
        let within_third = |m: &Finished| {
            (2.0 / 3.0..=4.0 / 3.0).contains(&(m.mesh.tet_count() as f64 / n as f64))
        };
        let mut target = n as f64;
        let mut tried: Vec<(f64, f64)> = Vec::new();
        let mut in_window = None;
        for _attempt in 0..4 {
            let Some(graded) = try_target(target.round()) else {
                break;
            };
            let count = graded.mesh.tet_count() as f64;
            tried.push((target, count));
            if within_third(&graded) {
                if done.take_if_nearer(graded) {
                    finer = factor;
                }
                in_window = Some(target);
                break;
            }
            target = match tried[..] {
                [.., (t0, c0), (t1, c1)] if (c1 - c0) * (t1 - t0) > 0.0 => {
                    t1 + (n as f64 - c1) * (t1 - t0) / (c1 - c0)
                }
                _ => target * n as f64 / count.max(1.0),
            };
            if !(target.is_finite() && target >= 1.0) {
                break;
            }
        }
        // A near miss (over 1 %, by at most half as much again): which boundary nodes the
        // coarsening keeps, and so where the splits can reach, changes with its target,
        // and not steadily (a tolerance level stalls, the interior removal after it takes
        // a share that varies). Other targets around the one that gave the count, while
        // the kept mesh misses; a result outside the third is not kept.
        if let Some(t) = in_window {
            for f in [1.2, 0.85, 1.4, 0.7] {
                if !(one_percent..=NEAR_MISS * one_percent).contains(&done.worst()) {
                    break;
                }
                if let Some(graded) = try_target((t * f).round()).filter(within_third)
                    && done.take_if_nearer(graded)
                {
                    finer = factor;
                }
            }
        }
    }
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

/// What the boundary steps fit the mesh to.
#[derive(Clone, Copy)]
struct Goal<'a> {
    tree: &'a SurfaceTree<'a>,
    surface_samples: &'a [Vec3],
    min_dihedral: f64,
    tol: f64,
    enclosed_volume: f64,
}

/// A mesh after the boundary steps, with what they did and the distances both ways.
struct Finished {
    mesh: TetMesh,
    chord_volume: f64,
    projected: usize,
    snapped: usize,
    split: usize,
    mesh_to_surface: f64,
    surface_to_mesh: f64,
}

impl Finished {
    fn split_and_measure(
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

    fn worst(&self) -> f64 {
        self.mesh_to_surface.max(self.surface_to_mesh)
    }

    /// Takes `other` in place of this mesh where it is nearer the surface; whether it did.
    fn take_if_nearer(&mut self, other: Finished) -> bool {
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

/// The boundary coarsening's first tolerance on a graded mesh, as a fraction of the bounding
/// box's diagonal; while the count is above the target it goes up to twice this (1 %), then
/// three times (1.5 %).
pub const GRADED_TOLERANCE: f64 = 0.005;

/// What the mesher aims at, as fractions: the boundary within this much of the bounding
/// box's diagonal of the surface, both ways (twice [`GRADED_TOLERANCE`])...
pub const AIMED_DISTANCE: f64 = 2.0 * GRADED_TOLERANCE;

/// ... and the volume within this much of the enclosed one.
pub const AIMED_VOLUME: f64 = 0.03;

/// A near miss, as a multiple of [`AIMED_DISTANCE`]: the misses the near-miss search and
/// the graded levels 3 and 4 times finer run for.
const NEAR_MISS: f64 = 1.5;

/// How near the boundary must come to every sample of the input surface before the feature
/// fit stops, as a fraction of the bounding box's diagonal.
pub const FIT_TOLERANCE: f64 = 0.004;

/// Points of a triangle surface where distances are measured: its vertices, edge midpoints
/// and centroids.
fn samples(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
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

/// [`samples`] of a surface whose parts overlap, those buried left out: each point is
/// probed from the triangles it lies on (see [`buried_at`]) and kept where one keeps it.
fn unburied_samples(s: &RepairedSurface, tree: &SurfaceTree<'_>) -> Vec<Vec3> {
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

/// Whether node `v`'s tetrahedra are positive and keep every dihedral angle in
/// [`min_dihedral`, 180 - `min_dihedral`] at positions `x`.
fn node_ok(mesh: &TetMesh, x: &[Vec3], v: usize, min_dihedral: f64) -> bool {
    mesh.node_tets(v).iter().all(|&t| {
        let p = mesh.tets()[t as usize].map(|i| x[i as usize]);
        tet_quality_deg(&p) >= min_dihedral
    })
}

/// Creases and corners the lattice rounded off: each sample of the input surface farther
/// than `tol` from the boundary, farthest first, pulls the nearest node of the boundary
/// triangle it is closest to onto itself, where that node's tetrahedra keep the quality
/// bound (interior nodes may move to make room, see `make_room`); a node moves once. A few
/// rounds, each against the boundary as the last left it. The moved nodes stay on the input
/// surface. Returns the mesh and the nodes moved.
fn fit_features(mesh: TetMesh, samples: &[Vec3], min_dihedral: f64, tol: f64) -> (TetMesh, usize) {
    let mut x = mesh.positions().to_vec();
    let triangles = mesh.surface().triangles().to_vec();
    let mut locked = vec![false; x.len()];
    let tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let node_tets: Vec<Vec<usize>> = (0..x.len())
        .map(|v| mesh.node_tets(v).iter().map(|&k| k as usize).collect())
        .collect();
    let mut boundary = vec![false; x.len()];
    for &v in mesh.surface().vertices() {
        boundary[v as usize] = true;
    }
    // (Which interior nodes moved does not matter here.)
    let mut moved_inside = Vec::new();
    let mut snapped = 0;
    for _round in 0..4 {
        let far: Vec<(f64, usize, usize)> = {
            let tree = SurfaceTree::new(&x, &triangles);
            let mut far: Vec<(f64, usize, usize)> = samples
                .par_iter()
                .enumerate()
                .filter_map(|(i, q)| {
                    let (_, d, t) = tree.closest_triangle(q)?;
                    (d > tol).then_some((d, i, t))
                })
                .collect();
            far.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            far
        };
        let mut moved = 0;
        for (_, i, t) in far {
            let q = samples[i];
            let corners = triangles[t].map(|n| x[n as usize]);
            let w = crate::geometry::closest_on_triangle(&q, &corners[0], &corners[1], &corners[2]);
            let c = corners[0] * w[0] + corners[1] * w[1] + corners[2] * w[2];
            if (c - q).norm() <= tol {
                continue; // an earlier move brought the boundary near enough
            }
            let mut nodes = triangles[t].map(|n| n as usize);
            nodes.sort_by(|&a, &b| {
                (x[a] - q)
                    .norm_squared()
                    .total_cmp(&(x[b] - q).norm_squared())
                    .then(a.cmp(&b))
            });
            for n in nodes {
                if locked[n] {
                    continue;
                }
                let old = x[n];
                x[n] = q;
                // Interior nodes may move to make room.
                if make_room(
                    &mut x,
                    &tets,
                    &node_tets,
                    &boundary,
                    n,
                    min_dihedral,
                    &mut moved_inside,
                ) {
                    locked[n] = true;
                    moved += 1;
                    break;
                }
                x[n] = old;
            }
        }
        snapped += moved;
        if moved == 0 {
            break;
        }
    }
    match TetMesh::new(x, tets) {
        Ok(m) => (m, snapped),
        Err(_) => (mesh, 0),
    }
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

/// Whether every tetrahedron around node `m` keeps the quality bound at positions `x`, after
/// moving the interior nodes of those that do not, if need be: each such node in turn goes
/// where the worst of its own tetrahedra is best (a compass search: steps along the axes,
/// halved when none helps). On failure every moved node goes back; on success the nodes
/// moved are appended to `moved`.
fn make_room(
    x: &mut [Vec3],
    tets: &[[usize; 4]],
    node_tets: &[Vec<usize>],
    boundary: &[bool],
    m: usize,
    min_dihedral: f64,
    moved: &mut Vec<usize>,
) -> bool {
    // The search compares cosines (smaller is better): no acos in it.
    let cos = |x: &[Vec3], k: usize| tet_worst_cos(&tets[k].map(|v| x[v]));
    let worst_at =
        |x: &[Vec3], v: usize| node_tets[v].iter().map(|&k| cos(x, k)).fold(0.0, f64::max);
    // The same worst, or `None` as soon as one tetrahedron reaches `bound`: a step the
    // search would not take, found without the rest.
    let worst_below = |x: &[Vec3], v: usize, bound: f64| -> Option<f64> {
        let mut worst: f64 = 0.0;
        for &k in &node_tets[v] {
            worst = worst.max(cos(x, k));
            if worst >= bound {
                return None;
            }
        }
        Some(worst)
    };
    // Accepted by the bound's own check, as everywhere else in the mesher.
    let holds = |x: &[Vec3], k: usize| tet_quality_deg(&tets[k].map(|v| x[v])) >= min_dihedral;
    let bad = |x: &[Vec3]| -> Vec<usize> {
        node_tets[m]
            .iter()
            .copied()
            .filter(|&k| !holds(x, k))
            .collect()
    };
    let mut first = bad(x);
    if first.is_empty() {
        return true;
    }
    // A tetrahedron with all four nodes on the boundary cannot be helped here, nor (for this
    // search, which compares angles) a flat or inverted one.
    if first
        .iter()
        .any(|&k| tets[k].iter().all(|&v| boundary[v]) || !cos(x, k).is_finite())
    {
        return false;
    }
    let mut undo: Vec<(usize, Vec3)> = Vec::new();
    for _pass in 0..2 {
        let mut nodes: Vec<usize> = first
            .iter()
            .flat_map(|&k| tets[k])
            .filter(|&v| !boundary[v])
            .collect();
        nodes.sort_unstable();
        nodes.dedup();
        for n in nodes {
            let length = node_tets[n]
                .iter()
                .flat_map(|&k| tets[k])
                .map(|v| (x[v] - x[n]).norm())
                .fold(0.0, f64::max);
            let mut step = 0.2 * length;
            let mut best = worst_at(x, n);
            let start = x[n];
            for _ in 0..40 {
                if step < 0.005 * length {
                    break;
                }
                let here = x[n];
                let mut found = None;
                for axis in 0..3 {
                    for sign in [-1.0, 1.0] {
                        let mut p = here;
                        p[axis] += sign * step;
                        x[n] = p;
                        if let Some(w) = worst_below(x, n, best) {
                            best = w;
                            found = Some(p);
                        }
                    }
                }
                x[n] = found.unwrap_or(here);
                if found.is_none() {
                    step *= 0.5;
                }
            }
            if x[n] != start {
                undo.push((n, start));
            }
        }
        first = bad(x);
        let around_ok = undo
            .iter()
            .all(|&(n, _)| node_tets[n].iter().all(|&k| holds(x, k)));
        if first.is_empty() && around_ok {
            moved.extend(undo.iter().map(|&(n, _)| n));
            return true;
        }
    }
    for &(n, p) in undo.iter().rev() {
        x[n] = p;
    }
    false
}

/// Moves every boundary node onto the surface where its tetrahedra stay positive and above
/// `min_dihedral`; returns the mesh and the nodes moved.
fn project_boundary(mesh: TetMesh, tree: &SurfaceTree<'_>, min_dihedral: f64) -> (TetMesh, usize) {
    let mut x = mesh.positions().to_vec();
    let tets: Vec<[u32; 4]> = mesh.tets().to_vec();
    let mut moved = 0;
    for &v in mesh.surface().vertices() {
        let v = v as usize;
        let old = x[v];
        x[v] = tree.closest(&old).map_or(old, |c| c.0);
        let ok = node_ok(&mesh, &x, v, min_dihedral);
        if ok {
            moved += 1;
        } else {
            x[v] = old;
        }
    }
    let tets = tets.iter().map(|t| t.map(|i| i as usize)).collect();
    match TetMesh::new(x, tets) {
        Ok(m) => (m, moved),
        // The checks above keep every tetrahedron positive; should the mesh still refuse
        // the moved nodes, the stuffed one is kept.
        Err(_) => (mesh, 0),
    }
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
