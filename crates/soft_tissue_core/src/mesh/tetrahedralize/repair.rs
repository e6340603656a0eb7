//! Repair of a scanned or segmented surface: welding, degenerate, duplicate and unused
//! parts dropped, orientation, specks, nesting (see `nesting.rs`) and, where parts overlap,
//! the buried share of each triangle (see `buried.rs`); the holes' size checked.

use std::collections::HashMap;

use super::buried::buried_shares;
use super::nesting::{Facing, Piece, nesting};
use super::{MAX_OPEN_FRACTION, SurfaceDefects, TetrahedralizeError, bounds};
use crate::Vec3;
use crate::geometry::solid_angle;
use crate::mesh::io::SurfaceMesh;
use crate::mesh::surface_tree::SurfaceTree;

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

/// Refuses a surface whose holes are too large for the winding number to close (see
/// [`TetrahedralizeError::TooOpen`]).
pub(super) fn check_holes(s: &RepairedSurface) -> Result<(), TetrahedralizeError> {
    if s.defects.boundary_edges == 0 {
        return Ok(());
    }
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
    Ok(())
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
pub(super) fn signed_volume(t: &[u32; 3], positions: &[Vec3], centre: &Vec3) -> f64 {
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
