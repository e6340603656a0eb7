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

mod bisect;
mod carve;
mod check;
mod remove;
mod separate;

pub use carve::{Ball, CARVE_SPACING, MAX_CARVE_TETS, OUTWARD_SNAP, WARP, carve, carve_keeping};
pub use check::{CutCheck, check};
pub(crate) use remove::manifold;
pub use remove::{RemoveError, remove_tets};

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
    /// Steps a world's cut is prepared for on a thread of its own before it lands (0: it
    /// is made within the step the blade crossed the body). The mesh change and the build
    /// of the cut body's solvers, heat, contact surface and cage then take no step's time:
    /// the body steps on as it was meanwhile, and the step `background_steps` later hands
    /// its state at that step to the cut body (waiting for the thread if it is not done,
    /// which keeps runs the same whatever the machine's speed). Meshes ignore it. A carve of
    /// vaporized tissue is prepared for [`CARVE_STEPS_FACTOR`] times as many steps.
    pub background_steps: u32,
    /// A cut prepared in the background whose thread is not done when it is due lands at the
    /// first step after that in which it is done, instead of that step waiting for it (false,
    /// the default). No step then waits for a cut, whatever the machine's speed, but the step
    /// a cut lands in, and so the run, depend on how fast its thread was: runs are no longer
    /// the same from one to the next or across thread counts. For an app in real time on a
    /// machine too slow for `background_steps` (`CutRecord::wait_us` says how long landings
    /// waited).
    pub land_when_ready: bool,
}

/// A carve of vaporized tissue ([`crate::world::WorldBody::begin_vaporize`]) in the
/// background lands this many times [`CutOptions::background_steps`] after it began: its
/// preparation also computes the compliance columns of the crater's nodes the tool presses
/// on (so the landing step's contact solves for none), which on the organs' liver doubles
/// it (75-82 ms on this project's 2-core VM: with 4 background steps of 10 ms, twice as
/// many steps left one landing of three waiting about 3 ms for the thread), and a crater
/// that appears a few tens of milliseconds later is not seen (it grew over seconds).
pub const CARVE_STEPS_FACTOR: u32 = 3;

/// A piece a cut would make of fewer tetrahedra than this, or one element thick along the
/// cut, and under 2 % of the mesh's tetrahedra, is a crumb: it is not cut off.
pub const CRUMB_TETS: usize = 16;

/// Smallest [`CutOptions::snap`]: below it children would be flatter than a mesh accepts.
pub const MIN_SNAP: f64 = 0.01;

impl CutOptions {
    /// Steps a carve of vaporized tissue is prepared for in the background:
    /// [`CARVE_STEPS_FACTOR`] times [`CutOptions::background_steps`].
    pub fn carve_steps(&self) -> u32 {
        self.background_steps.saturating_mul(CARVE_STEPS_FACTOR)
    }
}

impl Default for CutOptions {
    fn default() -> Self {
        CutOptions {
            snap: 0.3,
            background_steps: 0,
            land_when_ready: false,
        }
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

    /// The origin of the point `(1 - s) a + s b`, when both lie in one tetrahedron of the
    /// mesh before (`None` where the blend names more than four of its nodes).
    fn blend(a: NodeOrigin, b: NodeOrigin, s: f64) -> Option<NodeOrigin> {
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
        if n > 4 {
            return None;
        }
        let kept = &terms[..n];
        let total: f64 = kept.iter().map(|t| t.1).sum();
        let mut out = NodeOrigin {
            nodes: [kept[0].0; 4],
            weights: [0.0; 4],
        };
        for (k, (v, w)) in kept.iter().enumerate() {
            out.nodes[k] = *v;
            out.weights[k] = w / total;
        }
        Some(out)
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
    /// What the next [`recut`] of this mesh needs to know of this cut and the ones before.
    pub history: CutHistory,
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

/// What a cut mesh remembers of its cuts (see [`recut`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CutHistory {
    /// Per tetrahedron, whether its face opposite each corner is a side of a cut.
    pub sides: Vec<[bool; 4]>,
    /// Per node, the incision whose blade passed through it (a node made on the blade, or
    /// counted as on it; 0: none): as an incision grows, the part of the cut surface it
    /// made is found by these marks, wherever the tissue has moved since (see
    /// [`recut_within`]).
    pub on_blade: Vec<u64>,
}

/// [`cut`] of a mesh that was cut before, with what it remembers of those cuts (a
/// [`CutMesh::history`]): [`CutMesh::cut_faces`] then names the sides of every cut so far.
/// A history whose sizes do not fit the mesh is ignored.
pub fn recut(
    mesh: &TetMesh,
    history: Option<&CutHistory>,
    blade: &[CutTriangle],
    options: &CutOptions,
) -> Result<CutMesh, CutError> {
    recut_within(mesh, history, blade, &[], 0, options)
}

/// [`recut`] by the newest part of a growing incision `incision` (a number no other
/// incision has, not 0): `blade` (the strip swept since its last cut) bisects the edges it
/// crosses, and faces on its plane are separated where they lie in it or in a triangle of
/// `region` in the same plane (the incision so far). A node the incision passed through
/// before ([`CutHistory::on_blade`]) counts as on its plane wherever the tissue has moved
/// since, so a face wider than one step's strip is separated once the strip that completes
/// it has passed, and the part already cut is not cut again.
pub fn recut_within(
    mesh: &TetMesh,
    history: Option<&CutHistory>,
    blade: &[CutTriangle],
    region: &[CutTriangle],
    incision: u64,
    options: &CutOptions,
) -> Result<CutMesh, CutError> {
    if !(MIN_SNAP..0.5).contains(&options.snap) {
        return Err(CutError::BadSnap(options.snap));
    }
    check_blade(blade)?;
    check_blade(region)?;
    let mut work = Work::new(mesh, history, incision);
    // Every triangle bisects first, then each separates: a face one triangle's
    // bisections made on a coplanar neighbour's part of the blade is separated by that
    // neighbour, so a blade of several triangles cuts as one surface.
    // The faces of all the triangles separate together, so the front is the blade's
    // outline, not the lines between its triangles.
    // The region bisects too, within two elements of the newest strip: an edge the tissue's
    // motion carried across the plane just behind the blade, after its strip passed, is
    // cut there (an edge from a node the incision passed does not cross: that node counts
    // as on the plane). Farther back the tissue is no longer where the blade was (a piece
    // falling through the plane is not cut by it).
    let all: Vec<CutTriangle> = blade.iter().chain(region).copied().collect();
    let element = mesh.bbox().diagonal() / (mesh.tet_count().max(1) as f64).cbrt();
    // The newest strip: the last two triangles of the blade (its strips are in order).
    let newest = &blade[blade.len().saturating_sub(2)..];
    let near = newest
        .iter()
        .flat_map(|t| t.corners)
        .fold(None, |b: Option<(Vec3, Vec3)>, p| {
            Some(b.map_or((p, p), |(l, h)| (l.inf(&p), h.sup(&p))))
        });
    let near = near.map(|(l, h)| {
        let g = Vec3::repeat(2.0 * element);
        (l - g, h + g)
    });
    let planes: Vec<Option<PlaneNodes>> = all
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let limit = if k < blade.len() { None } else { near };
            work.bisect_by(t, options.snap, limit)
        })
        .collect();
    let mut chosen: HashMap<[u32; 3], Vec<(u32, u8)>> = HashMap::new();
    for (t, nodes) in all.iter().zip(planes) {
        if let Some(nodes) = nodes {
            work.separate_by(t, nodes, region, &mut chosen);
        }
    }
    let mut faces: Vec<[u32; 3]> = chosen.keys().copied().collect();
    faces.sort_unstable();
    let corners = blade.iter().flat_map(|t| t.corners);
    let centre = corners.fold(Vec3::zeros(), |s, c| s + c) / (3 * blade.len().max(1)) as f64;
    work.separate(&faces, &chosen, centre);
    // Orientation against the parent, before the mesh's own checks (which would turn an
    // inverted tetrahedron over).
    let smallest_volume_ratio = work.smallest_volume_ratio(mesh)?;
    let tets: Vec<[usize; 4]> = work.tets.iter().map(|t| t.map(|i| i as usize)).collect();
    let new_mesh = TetMesh::new(work.positions.clone(), tets)?;
    let cut_faces = work.cut_faces();
    Ok(CutMesh {
        mesh: new_mesh,
        node_origin: work.node_origin,
        tet_origin: work.tet_origin,
        cut_faces,
        history: CutHistory {
            sides: work.cut,
            on_blade: work.marked,
        },
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
struct Work<'m> {
    /// The mesh before (where origins are looked for when a blend cannot give them, see
    /// [`Work::origin_on_edge`]).
    before: &'m TetMesh,
    positions: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    node_origin: Vec<NodeOrigin>,
    tet_origin: Vec<u32>,
    /// Per tetrahedron, whether its face opposite each corner is a side of the cut
    /// (children of a bisection keep their parent's flags on the parts of its faces).
    cut: Vec<[bool; 4]>,
    /// Per node, the incision whose blade passed through it (see [`CutHistory::on_blade`]).
    marked: Vec<u64>,
    /// The incision cutting now (0: a cut of its own, which marks nothing).
    incision: u64,
    bisected: usize,
    separated: usize,
    taken_back: usize,
}

impl Work<'_> {
    /// The smallest signed volume of a tetrahedron over its parent's in `before` (the mesh
    /// the work started from), checked before the mesh's own checks (which would turn an
    /// inverted tetrahedron over): one at or below zero is refused.
    fn smallest_volume_ratio(&self, before: &TetMesh) -> Result<f64, CutError> {
        let mut smallest = f64::INFINITY;
        for (t, tet) in self.tets.iter().enumerate() {
            let child = tet_signed_volume(&tet.map(|i| self.positions[i as usize]));
            let parent =
                before.tets()[self.tet_origin[t] as usize].map(|i| before.positions()[i as usize]);
            let ratio = child / tet_signed_volume(&parent);
            if ratio.is_nan() || ratio <= 0.0 {
                return Err(CutError::Inverted { tet: t, ratio });
            }
            smallest = smallest.min(ratio);
        }
        Ok(smallest)
    }

    /// The origin of the point `(1 - s) a + s b` of edge `(a, b)`: the blend of its ends'
    /// origins where it names nodes of one tetrahedron of the mesh before (an edge of a
    /// subdivision always does: its children lie in their parents); else (an end a carve
    /// moved onto its sphere, into a neighbour of its element) the point located in the
    /// mesh before ([`Work::locate`]).
    fn origin_on_edge(&self, a: u32, b: u32, s: f64) -> NodeOrigin {
        let (oa, ob) = (self.node_origin[a as usize], self.node_origin[b as usize]);
        if let Some(o) = NodeOrigin::blend(oa, ob, s)
            && self.in_one_tet(&o)
        {
            return o;
        }
        let p = self.positions[a as usize] * (1.0 - s) + self.positions[b as usize] * s;
        let mut seeds: Vec<u32> = [oa, ob]
            .iter()
            .flat_map(|o| (0..4).filter(|&k| o.weights[k] != 0.0).map(|k| o.nodes[k]))
            .collect();
        seeds.sort_unstable();
        seeds.dedup();
        self.locate(&p, &seeds)
    }

    /// Whether the nodes `o` weighs are all corners of one tetrahedron of the mesh before.
    fn in_one_tet(&self, o: &NodeOrigin) -> bool {
        let named = || (0..4).filter(|&k| o.weights[k] != 0.0).map(|k| o.nodes[k]);
        let Some(first) = named().next() else {
            return true;
        };
        let tets = self.before.tets();
        self.before
            .node_tets(first as usize)
            .iter()
            .any(|&t| named().all(|v| tets[t as usize].contains(&v)))
    }

    /// The origin of point `p` (in the mesh before): its barycentric coordinates in the
    /// tetrahedron around the nodes `seeds` that holds it (the one it is least outside of;
    /// the ring around those tetrahedra too when none holds it). Coordinates within 1e-12
    /// of 0 are 0 (so a point on a face names that face's nodes only).
    fn locate(&self, p: &Vec3, seeds: &[u32]) -> NodeOrigin {
        let tets = self.before.tets();
        let x = self.before.positions();
        let mut ring: Vec<u32> = seeds
            .iter()
            .flat_map(|&v| self.before.node_tets(v as usize).iter().copied())
            .collect();
        ring.sort_unstable();
        ring.dedup();
        let best_of = |ring: &[u32]| {
            let mut best: Option<(f64, u32, [f64; 4])> = None;
            for &t in ring {
                let [x0, x1, x2, x3] = tets[t as usize].map(|v| x[v as usize]);
                let m = nalgebra::Matrix3::from_columns(&[x1 - x0, x2 - x0, x3 - x0]);
                let Some(inv) = m.try_inverse() else {
                    continue;
                };
                let l = inv * (p - x0);
                let w = [1.0 - l.x - l.y - l.z, l.x, l.y, l.z];
                let inside = w.iter().copied().fold(f64::INFINITY, f64::min);
                if best.is_none_or(|(b, _, _)| inside > b) {
                    best = Some((inside, t, w));
                }
            }
            best
        };
        let mut best = best_of(&ring);
        if best.is_none_or(|(inside, _, _)| inside < -1e-9) {
            let mut wider: Vec<u32> = ring
                .iter()
                .flat_map(|&t| tets[t as usize])
                .flat_map(|v| self.before.node_tets(v as usize).iter().copied())
                .collect();
            wider.sort_unstable();
            wider.dedup();
            best = best_of(&wider).or(best);
        }
        let Some((_, t, mut w)) = best else {
            // A mesh without a proper tetrahedron there: the first seed.
            return NodeOrigin::node(seeds.first().copied().unwrap_or(0));
        };
        for wk in &mut w {
            if wk.abs() < 1e-12 {
                *wk = 0.0;
            }
        }
        let total: f64 = w.iter().sum();
        NodeOrigin {
            nodes: tets[t as usize],
            weights: w.map(|wk| wk / total),
        }
    }

    /// `mesh` as it is, with what `history` remembers of its cuts (ignored where its sizes
    /// do not fit), to be cut by incision `incision` (0: none).
    fn new<'m>(mesh: &'m TetMesh, history: Option<&CutHistory>, incision: u64) -> Work<'m> {
        Work {
            positions: mesh.positions().to_vec(),
            tets: mesh.tets().to_vec(),
            node_origin: (0..mesh.node_count() as u32)
                .map(NodeOrigin::node)
                .collect(),
            tet_origin: (0..mesh.tet_count() as u32).collect(),
            cut: match history {
                Some(h) if h.sides.len() == mesh.tet_count() => h.sides.clone(),
                _ => vec![[false; 4]; mesh.tet_count()],
            },
            marked: match history {
                Some(h) if h.on_blade.len() == mesh.node_count() => h.on_blade.clone(),
                _ => vec![0; mesh.node_count()],
            },
            incision,
            before: mesh,
            bisected: 0,
            separated: 0,
            taken_back: 0,
        }
    }
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
