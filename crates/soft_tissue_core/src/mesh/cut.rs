//! Cutting a tetrahedral mesh along a blade's swept surface, by conforming subdivision and
//! separation.
//!
//! A blade sweeps a surface between two steps; it reaches this module as planar triangles
//! ([`CutTriangle`]). Each triangle cuts in three moves:
//!
//! 1. **Conforming subdivision.** Every edge that crosses the triangle's plane at a point
//!    inside the triangle is bisected there, and every tetrahedron holding that edge is
//!    split in two by the new node (edge bisection, as in Bielser et al.'s subdivision
//!    cutting, 2003, but driven by the plane rather than a lookup table of cases). Splitting
//!    every tetrahedron around an edge keeps the mesh conforming, each child keeps its
//!    parent's orientation, and the children fill their parent exactly, so volume and mass
//!    are those of the mesh before. Once the crossing edges are bisected, no edge crosses
//!    the plane inside the triangle: the cut lies on faces.
//! 2. **Fewer slivers.** A node closer to the plane than `snap` of its shortest edge, and
//!    the end of an edge crossed within `snap` of it, count as on the plane instead of being
//!    cut off, so no child is shorter than `snap` of its parent along the bisected edge. The
//!    cut surface then passes through that node, off the plane by at most `snap` of an edge
//!    (the cut follows the mesh, not exactly the blade). Bisection does not bound the angles:
//!    repeated cuts through one region make thinner elements (see the tests' report of the
//!    smallest dihedral angle).
//! 3. **Separation.** A face whose three corners lie on the plane, whose centre lies inside
//!    the triangle and whose two tetrahedra lie on opposite sides is separated: the nodes
//!    on it are duplicated, one copy for each group of their tetrahedra still joined
//!    through faces that are not separated. Nodes at the cut's front keep one copy, so a
//!    partial cut is a crack that ends there. A separation that would leave an edge in
//!    more than two boundary triangles (two separated faces meeting at an edge whose ends
//!    stay whole) is taken back, face by face, until every edge of the new boundary is in
//!    exactly two.
//!
//! The result keeps where every node and tetrahedron came from ([`CutMesh::node_origin`],
//! [`CutMesh::tet_origin`]), so a body's state (positions, velocities, temperature,
//! damage) carries over, and names the new boundary faces of the cut
//! ([`CutMesh::cut_faces`]) to draw them as the inside of the tissue. Pieces that came
//! loose are the mesh's connected components.

use std::collections::HashMap;

use thiserror::Error;

use super::{MeshError, TetMesh, tet_dihedral_angles, tet_signed_volume};
use crate::Vec3;

/// A planar piece of the surface a blade swept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutTriangle {
    /// Corners.
    pub corners: [Vec3; 3],
}

/// Settings of a cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutOptions {
    /// A crossing closer than this fraction of its edge to an end moves the cut to that end
    /// instead of bisecting (in `[0.01, 0.5)`; larger keeps children fatter, smaller follows
    /// the blade more closely).
    pub snap: f64,
}

/// Smallest [`CutOptions::snap`]: below it children would be flatter than a mesh accepts.
pub const MIN_SNAP: f64 = 0.01;

impl Default for CutOptions {
    fn default() -> Self {
        CutOptions { snap: 0.3 }
    }
}

/// Why a cut was refused (the mesh is left as it was).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CutError {
    /// A blade triangle has a non-finite corner or no area.
    #[error("blade triangle {index}: {reason}")]
    BadTriangle {
        /// Index of the triangle.
        index: usize,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// The snap fraction is outside `[0.01, 0.5)`.
    #[error("snap fraction {0} is outside [0.01, 0.5)")]
    BadSnap(f64),
    /// A child tetrahedron came out inverted or flat (a bug: bisection keeps orientation).
    #[error("tetrahedron {tet} came out with {ratio:e} of its parent's volume")]
    Inverted {
        /// Index of the child.
        tet: usize,
        /// Its signed volume over its parent's.
        ratio: f64,
    },
    /// The cut mesh failed validation (a bug: a cut keeps every tetrahedron's orientation).
    #[error("the cut mesh is invalid: {0}")]
    Mesh(#[from] MeshError),
}

/// Where a node of a cut mesh came from: a point of one tetrahedron of the mesh before, as
/// weights of up to four of its nodes (`weights` sum to 1; unused entries have weight 0).
/// Exact for the linear fields of the mesh before (positions, velocities, temperature).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeOrigin {
    /// Nodes of the mesh before.
    pub nodes: [u32; 4],
    /// Their weights.
    pub weights: [f64; 4],
}

impl NodeOrigin {
    /// Node `v` of the mesh before, as it was.
    pub fn node(v: u32) -> Self {
        NodeOrigin {
            nodes: [v; 4],
            weights: [1.0, 0.0, 0.0, 0.0],
        }
    }

    /// The value at this node of a field given per node of the mesh before.
    pub fn interpolate<T>(&self, field: &[T]) -> T
    where
        T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
    {
        let mut v = field[self.nodes[0] as usize] * self.weights[0];
        for k in 1..4 {
            if self.weights[k] != 0.0 {
                v = v + field[self.nodes[k] as usize] * self.weights[k];
            }
        }
        v
    }

    /// The origin of the point `(1 - s) a + s b`.
    fn blend(a: NodeOrigin, b: NodeOrigin, s: f64) -> NodeOrigin {
        let mut terms: [(u32, f64); 8] = [(u32::MAX, 0.0); 8];
        let mut n = 0;
        for (o, f) in [(a, 1.0 - s), (b, s)] {
            for k in 0..4 {
                let w = o.weights[k] * f;
                if w == 0.0 {
                    continue;
                }
                match terms[..n].iter_mut().find(|(m, _)| *m == o.nodes[k]) {
                    Some(e) => e.1 += w,
                    None => {
                        terms[n] = (o.nodes[k], w);
                        n += 1;
                    }
                }
            }
        }
        // Both ends lie in one tetrahedron of the mesh before: at most four nodes. (Keep the
        // four heaviest should rounding ever say otherwise.)
        let terms = &mut terms[..n];
        terms.sort_by(|x, y| y.1.total_cmp(&x.1));
        let kept = &terms[..n.min(4)];
        let total: f64 = kept.iter().map(|t| t.1).sum();
        let mut out = NodeOrigin {
            nodes: [kept[0].0; 4],
            weights: [0.0; 4],
        };
        for (k, (v, w)) in kept.iter().enumerate() {
            out.nodes[k] = *v;
            out.weights[k] = w / total;
        }
        out
    }
}

/// A cut mesh and where it came from.
#[derive(Debug, Clone)]
pub struct CutMesh {
    /// The mesh after the cut.
    pub mesh: TetMesh,
    /// Origin of each node, in the numbering of the mesh before the cut.
    pub node_origin: Vec<NodeOrigin>,
    /// Tetrahedron of the mesh before the cut that each tetrahedron lies in.
    pub tet_origin: Vec<u32>,
    /// The boundary triangles the cut opened (both sides; after [`recut`], those of the
    /// earlier cuts too), oriented outward from their tetrahedron.
    pub cut_faces: Vec<[u32; 3]>,
    /// Per tetrahedron, whether its face opposite each corner is a side of a cut (to pass
    /// to the next [`recut`]).
    pub sides: Vec<[bool; 4]>,
    /// Edges bisected.
    pub bisected: usize,
    /// Faces separated.
    pub separated: usize,
    /// Separated faces taken back to keep the boundary 2-manifold.
    pub taken_back: usize,
    /// Smallest signed volume of a tetrahedron over its parent's, as cut (before the mesh's
    /// own checks, which would turn an inverted one over); a cut with one at or below zero
    /// is refused ([`CutError::Inverted`]).
    pub smallest_volume_ratio: f64,
}

impl CutMesh {
    /// Area of the cut, both sides (scene units squared).
    pub fn cut_area(&self) -> f64 {
        let p = self.mesh.positions();
        self.cut_faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| p[i as usize]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }
}

/// Cuts `mesh` along the blade triangles `blade`, one after the other (see the module
/// docs). A cut that crosses nothing returns the mesh unchanged (with identity origins).
pub fn cut(
    mesh: &TetMesh,
    blade: &[CutTriangle],
    options: &CutOptions,
) -> Result<CutMesh, CutError> {
    recut(mesh, None, blade, options)
}

/// [`cut`] of a mesh that was cut before: `sides` marks, per tetrahedron, its faces that
/// are sides of earlier cuts (a [`CutMesh::sides`]), so [`CutMesh::cut_faces`] names the
/// sides of every cut so far. A `sides` of the wrong length is ignored.
pub fn recut(
    mesh: &TetMesh,
    sides: Option<&[[bool; 4]]>,
    blade: &[CutTriangle],
    options: &CutOptions,
) -> Result<CutMesh, CutError> {
    if !(MIN_SNAP..0.5).contains(&options.snap) {
        return Err(CutError::BadSnap(options.snap));
    }
    check_blade(blade)?;
    let mut work = Work {
        positions: mesh.positions().to_vec(),
        tets: mesh.tets().to_vec(),
        node_origin: (0..mesh.node_count() as u32)
            .map(NodeOrigin::node)
            .collect(),
        tet_origin: (0..mesh.tet_count() as u32).collect(),
        cut: match sides {
            Some(s) if s.len() == mesh.tet_count() => s.to_vec(),
            _ => vec![[false; 4]; mesh.tet_count()],
        },
        bisected: 0,
        separated: 0,
        taken_back: 0,
    };
    // Every triangle bisects first, then each separates: a face one triangle's
    // bisections made on a coplanar neighbour's part of the blade is separated by that
    // neighbour, so a blade of several triangles cuts as one surface.
    // The faces of all the triangles separate together, so the front is the blade's
    // outline, not the lines between its triangles.
    let planes: Vec<Option<PlaneNodes>> = blade
        .iter()
        .map(|t| work.bisect_by(t, options.snap))
        .collect();
    let mut chosen: HashMap<[u32; 3], Vec<(u32, u8)>> = HashMap::new();
    for (t, nodes) in blade.iter().zip(planes) {
        if let Some(nodes) = nodes {
            work.separate_by(t, nodes, &mut chosen);
        }
    }
    let mut faces: Vec<[u32; 3]> = chosen.keys().copied().collect();
    faces.sort_unstable();
    let corners = blade.iter().flat_map(|t| t.corners);
    let centre = corners.fold(Vec3::zeros(), |s, c| s + c) / (3 * blade.len().max(1)) as f64;
    work.separate(&faces, &chosen, centre);
    // Orientation against the parent, before the mesh's own checks (which would turn an
    // inverted tetrahedron over).
    let mut smallest_volume_ratio = f64::INFINITY;
    for (t, tet) in work.tets.iter().enumerate() {
        let child = tet_signed_volume(&tet.map(|i| work.positions[i as usize]));
        let parent = mesh.tets()[work.tet_origin[t] as usize].map(|i| mesh.positions()[i as usize]);
        let ratio = child / tet_signed_volume(&parent);
        if ratio.is_nan() || ratio <= 0.0 {
            return Err(CutError::Inverted { tet: t, ratio });
        }
        smallest_volume_ratio = smallest_volume_ratio.min(ratio);
    }
    let tets: Vec<[usize; 4]> = work.tets.iter().map(|t| t.map(|i| i as usize)).collect();
    let new_mesh = TetMesh::new(work.positions.clone(), tets)?;
    let cut_faces = work.cut_faces();
    Ok(CutMesh {
        mesh: new_mesh,
        node_origin: work.node_origin,
        tet_origin: work.tet_origin,
        cut_faces,
        sides: work.cut,
        bisected: work.bisected,
        separated: work.separated,
        taken_back: work.taken_back,
        smallest_volume_ratio,
    })
}

/// Refuses a blade triangle with a corner that is not finite or without area.
pub fn check_blade(blade: &[CutTriangle]) -> Result<(), CutError> {
    for (index, t) in blade.iter().enumerate() {
        if !t.corners.iter().all(|c| c.iter().all(|v| v.is_finite())) {
            return Err(CutError::BadTriangle {
                index,
                reason: "a corner is not finite",
            });
        }
        let [a, b, c] = t.corners;
        if (b - a).cross(&(c - a)).norm() == 0.0 {
            return Err(CutError::BadTriangle {
                index,
                reason: "it has no area",
            });
        }
    }
    Ok(())
}

/// The mesh while it is cut.
struct Work {
    positions: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    node_origin: Vec<NodeOrigin>,
    tet_origin: Vec<u32>,
    /// Per tetrahedron, whether its face opposite each corner is a side of the cut
    /// (children of a bisection keep their parent's flags on the parts of its faces).
    cut: Vec<[bool; 4]>,
    bisected: usize,
    separated: usize,
    taken_back: usize,
}

/// The nodes near a blade triangle: signed distances to its plane and which count as on
/// it, and how far snapping reached.
struct PlaneNodes {
    distance: HashMap<u32, f64>,
    on_plane: HashMap<u32, bool>,
    reach: f64,
}

/// A node and which of its planned copies (0: the node itself).
type NodeCopy = (u32, usize);

/// A face's corners, sorted (its key).
fn face_key(t: &[u32; 4], opposite: usize) -> [u32; 3] {
    let mut f = [0u32; 3];
    let mut k = 0;
    for (i, &v) in t.iter().enumerate() {
        if i != opposite {
            f[k] = v;
            k += 1;
        }
    }
    f.sort_unstable();
    f
}

/// Whether `p` (on the plane of `tri`) lies inside `tri`, with a relative tolerance.
fn inside(tri: &CutTriangle, p: &Vec3) -> bool {
    let [a, b, c] = tri.corners;
    let n = (b - a).cross(&(c - a));
    let nn = n.norm_squared();
    let tol = -1e-9 * nn;
    (b - a).cross(&(p - a)).dot(&n) >= tol
        && (c - b).cross(&(p - b)).dot(&n) >= tol
        && (a - c).cross(&(p - c)).dot(&n) >= tol
}

impl Work {
    /// Bisects the edges crossing `tri` inside it (moves 1 and 2 of the module docs);
    /// returns the nodes' distances to its plane and which count as on it, for
    /// [`Work::separate_by`], or `None` when the triangle meets no tetrahedron.
    fn bisect_by(&mut self, tri: &CutTriangle, snap: f64) -> Option<PlaneNodes> {
        let [a, b, c] = tri.corners;
        let normal = (b - a).cross(&(c - a)).normalize();
        let offset = normal.dot(&a);
        let (lo, hi) = (a.inf(&b).inf(&c), a.sup(&b).sup(&c));
        // Candidates: tetrahedra whose box meets the triangle's, grown by what snapping
        // reaches (`snap` of the longest edge there), so both tetrahedra of a face moved onto
        // the plane are among them.
        let boxes = |pad: f64| {
            (0..self.tets.len() as u32)
                .filter(|&t| {
                    let p = self.tets[t as usize].map(|i| self.positions[i as usize]);
                    let tl = p[0].inf(&p[1]).inf(&p[2]).inf(&p[3]);
                    let th = p[0].sup(&p[1]).sup(&p[2]).sup(&p[3]);
                    (0..3).all(|k| tl[k] <= hi[k] + pad && th[k] >= lo[k] - pad)
                })
                .collect::<Vec<u32>>()
        };
        let touching = boxes(1e-9 * (hi - lo).norm());
        let longest = touching
            .iter()
            .flat_map(|&t| {
                let tet = self.tets[t as usize];
                [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)].map(|(i, j)| {
                    (self.positions[tet[i] as usize] - self.positions[tet[j] as usize]).norm()
                })
            })
            .fold(0.0, f64::max);
        let reach = snap * longest;
        let mut candidates = boxes(1e-9 * (hi - lo).norm() + reach);
        if candidates.is_empty() {
            return None;
        }
        // Signed distances, and which nodes count as on the plane.
        let mut distance: HashMap<u32, f64> = HashMap::new();
        for &t in &candidates {
            for &v in &self.tets[t as usize] {
                distance
                    .entry(v)
                    .or_insert_with(|| normal.dot(&self.positions[v as usize]) - offset);
            }
        }
        // A node closer to the plane than `snap` of its shortest edge there is on it (and
        // within the candidates' reach, so both tetrahedra of a face on the plane are
        // candidates).
        let mut shortest: HashMap<u32, f64> = HashMap::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for i in 0..4 {
                for j in i + 1..4 {
                    let l =
                        (self.positions[tet[i] as usize] - self.positions[tet[j] as usize]).norm();
                    for v in [tet[i], tet[j]] {
                        let e = shortest.entry(v).or_insert(f64::INFINITY);
                        *e = e.min(l);
                    }
                }
            }
        }
        let mut on_plane: HashMap<u32, bool> = distance
            .iter()
            .map(|(&v, &d)| {
                (
                    v,
                    d == 0.0 || (d.abs() < snap * shortest[&v] && d.abs() <= reach),
                )
            })
            .collect();
        // Crossing edges with their crossing inside the triangle; a crossing near an end puts
        // that end on the plane instead (repeat until no new end joins the plane).
        let crossing = |edge: (u32, u32),
                        distance: &HashMap<u32, f64>,
                        on_plane: &HashMap<u32, bool>|
         -> Option<f64> {
            let (da, db) = (distance[&edge.0], distance[&edge.1]);
            if on_plane[&edge.0] || on_plane[&edge.1] || (da > 0.0) == (db > 0.0) {
                return None;
            }
            Some(da / (da - db))
        };
        let mut edges: Vec<(u32, u32)> = Vec::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for i in 0..4 {
                for j in i + 1..4 {
                    let (u, v) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                    edges.push((u, v));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let point = |w: &Work, e: (u32, u32), s: f64| {
            w.positions[e.0 as usize] * (1.0 - s) + w.positions[e.1 as usize] * s
        };
        loop {
            let mut changed = false;
            for &e in &edges {
                let Some(s) = crossing(e, &distance, &on_plane) else {
                    continue;
                };
                if !inside(tri, &point(self, e, s)) {
                    continue;
                }
                if s < snap {
                    on_plane.insert(e.0, true);
                    changed = true;
                } else if s > 1.0 - snap {
                    on_plane.insert(e.1, true);
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        // Bisect the crossing edges whose crossing lies inside the triangle.
        for &e in &edges {
            let Some(s) = crossing(e, &distance, &on_plane) else {
                continue;
            };
            let p = point(self, e, s);
            if !inside(tri, &p) {
                continue;
            }
            let node = self.positions.len() as u32;
            self.positions.push(p);
            let (oa, ob) = (
                self.node_origin[e.0 as usize],
                self.node_origin[e.1 as usize],
            );
            self.node_origin.push(NodeOrigin::blend(oa, ob, s));
            distance.insert(node, 0.0);
            on_plane.insert(node, true);
            self.bisected += 1;
            let holders: Vec<u32> = candidates
                .iter()
                .copied()
                .filter(|&t| {
                    let tet = &self.tets[t as usize];
                    tet.contains(&e.0) && tet.contains(&e.1)
                })
                .collect();
            for t in holders {
                let tet = self.tets[t as usize];
                let i = tet.iter().position(|&v| v == e.0).expect("holds the edge");
                let j = tet.iter().position(|&v| v == e.1).expect("holds the edge");
                let mut first = tet;
                first[j] = node;
                let mut second = tet;
                second[i] = node;
                // The face between the children is new and inside; the others are parts
                // of the parent's.
                let flags = self.cut[t as usize];
                let (mut f1, mut f2) = (flags, flags);
                f1[i] = false;
                f2[j] = false;
                self.tets[t as usize] = first;
                self.cut[t as usize] = f1;
                self.tets.push(second);
                self.cut.push(f2);
                self.tet_origin.push(self.tet_origin[t as usize]);
                candidates.push(self.tets.len() as u32 - 1);
            }
        }
        Some(PlaneNodes {
            distance,
            on_plane,
            reach,
        })
    }

    /// Chooses the faces on `tri`'s plane inside it between tetrahedra on opposite sides
    /// (move 3) into `chosen`, with their two tetrahedra, once every triangle of the blade
    /// has bisected: a face made by a neighbouring triangle's bisections but lying in this
    /// one is found here. Nodes made
    /// since [`Work::bisect_by`] classified them count as on the plane within 1e-9 of the
    /// triangle's size (a coplanar neighbour's).
    fn separate_by(
        &mut self,
        tri: &CutTriangle,
        nodes: PlaneNodes,
        chosen: &mut HashMap<[u32; 3], Vec<(u32, u8)>>,
    ) {
        let PlaneNodes {
            mut distance,
            mut on_plane,
            reach,
        } = nodes;
        let [a, b, c] = tri.corners;
        let normal = (b - a).cross(&(c - a)).normalize();
        let offset = normal.dot(&a);
        let (lo, hi) = (a.inf(&b).inf(&c), a.sup(&b).sup(&c));
        let pad = 1e-9 * (hi - lo).norm() + reach;
        let candidates: Vec<u32> = (0..self.tets.len() as u32)
            .filter(|&t| {
                let p = self.tets[t as usize].map(|i| self.positions[i as usize]);
                let tl = p[0].inf(&p[1]).inf(&p[2]).inf(&p[3]);
                let th = p[0].sup(&p[1]).sup(&p[2]).sup(&p[3]);
                (0..3).all(|k| tl[k] <= hi[k] + pad && th[k] >= lo[k] - pad)
            })
            .collect();
        let size = (hi - lo).norm();
        for &t in &candidates {
            for &v in &self.tets[t as usize] {
                if let std::collections::hash_map::Entry::Vacant(e) = distance.entry(v) {
                    let d = normal.dot(&self.positions[v as usize]) - offset;
                    e.insert(d);
                    on_plane.insert(v, d.abs() <= 1e-9 * size);
                }
            }
        }
        // Faces on the plane, inside the triangle, between tetrahedra on opposite sides.
        // A tetrahedron's side: that of its corners off the plane (one side once the
        // crossing edges are bisected); one with all four corners counted on the plane,
        // lying flat against it, goes to the side its centre leans to, the same for all its
        // faces.
        let side = |w: &Work, t: u32| {
            let d = |v: &u32| distance.get(v).copied().unwrap_or(0.0);
            let tet = &w.tets[t as usize];
            let off: f64 = tet.iter().filter(|v| !on_plane[*v]).map(d).sum();
            let all: f64 = tet.iter().map(d).sum();
            let lean = if off != 0.0 { off } else { all };
            if lean < 0.0 { -1.0 } else { 1.0 }
        };
        let mut faces: HashMap<[u32; 3], Vec<(u32, u8)>> = HashMap::new();
        for &t in &candidates {
            let tet = self.tets[t as usize];
            for opposite in 0..4 {
                let key = face_key(&tet, opposite);
                if key
                    .iter()
                    .all(|v| on_plane.get(v).copied().unwrap_or(false))
                {
                    faces.entry(key).or_default().push((t, opposite as u8));
                }
            }
        }
        let mut separate: Vec<[u32; 3]> = faces
            .iter()
            .filter(|(key, holders)| {
                if holders.len() != 2 {
                    return false;
                }
                let (s0, s1) = (side(self, holders[0].0), side(self, holders[1].0));
                if s0 == s1 {
                    return false;
                }
                let centre = key
                    .iter()
                    .fold(Vec3::zeros(), |s, &v| s + self.positions[v as usize])
                    / 3.0;
                inside(tri, &(centre - normal * (normal.dot(&centre) - offset)))
            })
            .map(|(key, _)| *key)
            .collect();
        separate.sort_unstable();
        for f in &separate {
            chosen.entry(*f).or_insert_with(|| faces[f].clone());
        }
    }

    /// Separates `faces` (with their two tetrahedra in `holders`), taking back faces until
    /// every edge of the boundary near them is in exactly two boundary triangles.
    fn separate(
        &mut self,
        faces: &[[u32; 3]],
        holders: &HashMap<[u32; 3], Vec<(u32, u8)>>,
        centre: Vec3,
    ) {
        let mut chosen: Vec<[u32; 3]> = faces.to_vec();
        loop {
            if chosen.is_empty() {
                return;
            }
            let plan = self.plan_split(&chosen);
            // A face whose two sides keep the same copies of all three corners (a patch the
            // front closes all around) would not open: it is no cut.
            let group_of = |t: u32, v: u32| match plan.binary_search_by_key(&v, |(n, _)| *n) {
                Ok(k) => plan[k].1.iter().position(|g| g.contains(&t)),
                Err(_) => None,
            };
            let before = chosen.len();
            chosen.retain(|f| {
                let h = &holders[f];
                f.iter()
                    .any(|&v| group_of(h[0].0, v) != group_of(h[1].0, v))
            });
            if chosen.len() < before {
                self.taken_back += before - chosen.len();
                continue;
            }
            let bad = self.non_manifold_edges(&plan, &chosen, holders);
            if bad.is_empty() {
                self.apply_split(plan);
                self.separated += chosen.len();
                for f in &chosen {
                    for &(t, o) in &holders[f] {
                        self.cut[t as usize][o as usize] = true;
                    }
                }
                return;
            }
            // Take back one separated face at each bad edge (the one farther from the blade's
            // centre: the front's side), then plan again.
            let before = chosen.len();
            let mut drop: Vec<usize> = Vec::new();
            for &(u, v) in &bad {
                let far = chosen
                    .iter()
                    .enumerate()
                    .filter(|(k, f)| f.contains(&u) && f.contains(&v) && !drop.contains(k))
                    .max_by(|(_, f), (_, g)| {
                        let d = |f: &[u32; 3]| {
                            let c = f
                                .iter()
                                .fold(Vec3::zeros(), |s, &i| s + self.positions[i as usize])
                                / 3.0;
                            (c - centre).norm_squared()
                        };
                        d(f).total_cmp(&d(g)).then(f.cmp(g))
                    })
                    .map(|(k, _)| k);
                if let Some(k) = far {
                    drop.push(k);
                }
            }
            drop.sort_unstable();
            for k in drop.into_iter().rev() {
                chosen.remove(k);
            }
            self.taken_back += before - chosen.len();
            if chosen.len() == before {
                // No chosen face holds a bad edge (the mesh's own defect there): cut nothing
                // rather than leave a boundary that is not 2-manifold.
                self.taken_back += chosen.len();
                return;
            }
        }
    }

    /// For every node on a separated face: the groups of its tetrahedra still joined through
    /// faces that are not separated (the first group keeps the node).
    fn plan_split(&self, separated: &[[u32; 3]]) -> Vec<(u32, Vec<Vec<u32>>)> {
        let mut nodes: Vec<u32> = separated.iter().flatten().copied().collect();
        nodes.sort_unstable();
        nodes.dedup();
        let mut around: HashMap<u32, Vec<u32>> = nodes.iter().map(|&v| (v, Vec::new())).collect();
        for (t, tet) in self.tets.iter().enumerate() {
            for v in tet {
                if let Some(list) = around.get_mut(v) {
                    list.push(t as u32);
                }
            }
        }
        let mut plan = Vec::with_capacity(nodes.len());
        for v in nodes {
            let tets = &around[&v];
            // Union-find over the tetrahedra around v, through the faces holding v.
            let mut parent: Vec<usize> = (0..tets.len()).collect();
            fn find(p: &mut [usize], mut i: usize) -> usize {
                while p[i] != i {
                    p[i] = p[p[i]];
                    i = p[i];
                }
                i
            }
            let mut by_face: HashMap<[u32; 3], usize> = HashMap::new();
            for (k, &t) in tets.iter().enumerate() {
                let tet = self.tets[t as usize];
                for opposite in 0..4 {
                    if tet[opposite] == v {
                        continue;
                    }
                    let key = face_key(&tet, opposite);
                    if separated.binary_search(&key).is_ok() {
                        continue;
                    }
                    if let Some(&other) = by_face.get(&key) {
                        let (ra, rb) = (find(&mut parent, k), find(&mut parent, other));
                        parent[ra.max(rb)] = ra.min(rb);
                    } else {
                        by_face.insert(key, k);
                    }
                }
            }
            let mut groups: Vec<Vec<u32>> = Vec::new();
            let mut root_group: HashMap<usize, usize> = HashMap::new();
            for (k, &t) in tets.iter().enumerate() {
                let r = find(&mut parent, k);
                let g = *root_group.entry(r).or_insert_with(|| {
                    groups.push(Vec::new());
                    groups.len() - 1
                });
                groups[g].push(t);
            }
            plan.push((v, groups));
        }
        plan
    }

    /// Edges of separated faces that would lie in more than two boundary triangles after
    /// `plan`.
    fn non_manifold_edges(
        &self,
        plan: &[(u32, Vec<Vec<u32>>)],
        separated: &[[u32; 3]],
        holders: &HashMap<[u32; 3], Vec<(u32, u8)>>,
    ) -> Vec<(u32, u32)> {
        // The copy of node v each tetrahedron would use: (v, group index).
        let copy = |t: u32, v: u32| -> (u32, usize) {
            match plan.binary_search_by_key(&v, |(n, _)| *n) {
                Ok(k) => (
                    v,
                    plan[k].1.iter().position(|g| g.contains(&t)).unwrap_or(0),
                ),
                Err(_) => (v, 0),
            }
        };
        // Boundary triangles that hold an edge of a separated face: the separated faces'
        // sides, and the existing boundary faces there.
        let mut count: HashMap<(NodeCopy, NodeCopy), u32> = HashMap::new();
        let mut edges_of_interest: Vec<(u32, u32)> = Vec::new();
        for f in separated {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[0], f[2])] {
                edges_of_interest.push((a.min(b), a.max(b)));
            }
        }
        edges_of_interest.sort_unstable();
        edges_of_interest.dedup();
        let mut add = |t: u32, tri: [u32; 3]| {
            for (a, b) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[0], tri[2])] {
                let e = (a.min(b), a.max(b));
                if edges_of_interest.binary_search(&e).is_ok() {
                    let (ca, cb) = (copy(t, e.0), copy(t, e.1));
                    *count.entry((ca, cb)).or_default() += 1;
                }
            }
        };
        for f in separated {
            for &(t, _) in &holders[f] {
                add(t, *f);
            }
        }
        // Existing boundary faces holding such an edge (every tetrahedron holding a face with
        // such an edge holds both its ends).
        let mut ends: Vec<u32> = edges_of_interest.iter().flat_map(|e| [e.0, e.1]).collect();
        ends.sort_unstable();
        ends.dedup();
        let mut face_count: HashMap<[u32; 3], (u32, u32)> = HashMap::new();
        for (t, tet) in self.tets.iter().enumerate() {
            if tet.iter().filter(|v| ends.binary_search(v).is_ok()).count() < 2 {
                continue;
            }
            for opposite in 0..4 {
                let key = face_key(tet, opposite);
                let e = face_count.entry(key).or_insert((0, t as u32));
                e.0 += 1;
            }
        }
        for (key, (n, t)) in face_count {
            if n == 1 {
                add(t, key);
            }
        }
        let mut bad: Vec<(u32, u32)> = count
            .into_iter()
            .filter(|&(_, n)| n > 2)
            .map(|(((a, _), (b, _)), _)| (a, b))
            .collect();
        bad.sort_unstable();
        bad.dedup();
        bad
    }

    /// Gives every group after the first of each planned node a copy of the node.
    fn apply_split(&mut self, plan: Vec<(u32, Vec<Vec<u32>>)>) {
        for (v, groups) in plan {
            for group in groups.iter().skip(1) {
                let copy = self.positions.len() as u32;
                self.positions.push(self.positions[v as usize]);
                self.node_origin.push(self.node_origin[v as usize]);
                for &t in group {
                    for c in self.tets[t as usize].iter_mut() {
                        if *c == v {
                            *c = copy;
                        }
                    }
                }
            }
        }
    }

    /// The sides of the cut, each oriented outward from the tetrahedron that keeps it (with
    /// the node copies it uses now).
    fn cut_faces(&self) -> Vec<[u32; 3]> {
        let mut out = Vec::new();
        for (tet, flags) in self.tets.iter().zip(&self.cut) {
            for (opposite, &f) in flags.iter().enumerate() {
                if f {
                    out.push(outward_face(tet, opposite, &self.positions));
                }
            }
        }
        out
    }
}

/// The face of `tet` opposite corner `opposite`, ordered so its normal points away from that
/// corner.
fn outward_face(tet: &[u32; 4], opposite: usize, positions: &[Vec3]) -> [u32; 3] {
    let f = face_key(tet, opposite);
    let [a, b, c] = f.map(|i| positions[i as usize]);
    let o = positions[tet[opposite] as usize];
    if (b - a).cross(&(c - a)).dot(&(o - a)) > 0.0 {
        [f[0], f[2], f[1]]
    } else {
        f
    }
}

/// Checks of a cut mesh against the mesh before it.
#[derive(Debug, Clone, PartialEq)]
pub struct CutCheck {
    /// Relative change of the total volume.
    pub volume_change: f64,
    /// Smallest tetrahedron volume over its parent's, signed, as cut
    /// ([`CutMesh::smallest_volume_ratio`]).
    pub smallest_volume_ratio: f64,
    /// Smallest dihedral angle of any tetrahedron, degrees.
    pub smallest_dihedral: f64,
    /// Edges of the boundary in other than two boundary triangles.
    pub non_manifold_edges: usize,
    /// Nodes in no tetrahedron.
    pub orphan_nodes: usize,
    /// Connected pieces.
    pub pieces: usize,
}

/// Measures a cut against the mesh before it (see [`CutCheck`]).
pub fn check(before: &TetMesh, after: &CutMesh) -> CutCheck {
    let m = &after.mesh;
    let p = m.positions();
    let smallest_volume_ratio = after.smallest_volume_ratio;
    let mut smallest_dihedral = f64::INFINITY;
    for tet in m.tets() {
        let mut corners = tet.map(|i| p[i as usize]);
        if tet_signed_volume(&corners) < 0.0 {
            corners.swap(0, 1);
        }
        for a in tet_dihedral_angles(&corners) {
            smallest_dihedral = smallest_dihedral.min(a);
        }
    }
    let mut used = vec![false; m.node_count()];
    for tet in m.tets() {
        for &v in tet {
            used[v as usize] = true;
        }
    }
    let mut faces: HashMap<[u32; 3], u32> = HashMap::new();
    for tet in m.tets() {
        for o in 0..4 {
            *faces.entry(face_key(tet, o)).or_default() += 1;
        }
    }
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for (f, n) in &faces {
        if *n == 1 {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[0], f[2])] {
                *edges.entry((a, b)).or_default() += 1;
            }
        }
    }
    CutCheck {
        volume_change: (m.volume() - before.volume()) / before.volume(),
        smallest_volume_ratio,
        smallest_dihedral,
        non_manifold_edges: edges.values().filter(|&&n| n != 2).count(),
        orphan_nodes: used.iter().filter(|u| !**u).count(),
        pieces: m.component_count(),
    }
}
