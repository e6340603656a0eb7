//! Carving balls out of a tetrahedral mesh: the tissue an electrode vaporized leaves the
//! mesh even where the crater is far smaller than the elements.
//!
//! Removing whole elements cannot follow a millimetre crater in centimetre elements, so a
//! carve first makes the mesh fine where the ball's sphere passes and then cuts along it,
//! with the cut's own moves (edge bisection, snapping):
//!
//! 1. **Refinement.** While an element the sphere passes through (its corners neither all
//!    inside nor its nearest point outside) has an edge longer than
//!    [`CARVE_SPACING`] of the radius, the longest such edge of all is bisected at its
//!    middle, splitting every element around it (after Rivara's longest-edge bisection,
//!    1984, without its propagation: a neighbour is split along that edge whether or not it
//!    is its own longest, so shapes next to the crater can degrade; the tests report the
//!    smallest dihedral angle). The mesh stays conforming, and every child lies in its
//!    parent (until move 2's warps), so volume and mass are unchanged.
//! 2. **The sphere as a cut.** First a node inside the mesh whose edge the sphere crosses
//!    within [`WARP`] of it is moved onto the sphere along that edge, nearest first, where no
//!    element around it comes out much worse than it was and it is not a support
//!    ([`carve_keeping`]) (isosurface stuffing's warping, Labelle and
//!    Shewchuk 2007; its origin moves with it, so the fields follow, and the domain is
//!    unchanged). Then each edge whose ends still lie on opposite sides of the sphere is
//!    bisected where it crosses it (the exact crossing on the straight edge), a crossing
//!    within `snap` of an end putting that end on the sphere instead (as a blade's cut
//!    does; [`OUTWARD_SNAP`] of it for an end outside, which bounds how far beyond the
//!    radius tissue leaves), so no edge crosses it after.
//! 3. **Removal.** The elements with every corner inside or on the sphere and their centre
//!    inside leave the mesh ([`super::remove_tets`]). Elements around an edge that would
//!    lie in more than two boundary triangles are kept (the crater shrinks there rather than
//!    the surface pinching), and a loose crumb the crater would cut off near it goes with it.
//!
//! The removed volume is that of the ball's part inside the mesh, up to the polyhedral
//! sphere's error (its vertices lie on the sphere, within `snap` of an edge where snapped).

use std::collections::{BinaryHeap, HashMap};

use super::{CutHistory, CutMesh, RemoveError, Work, face_key, remove_tets};
use crate::Vec3;
use crate::geometry::point_triangle_distance;
use crate::mesh::TetMesh;
use crate::mesh::quality::tet_quality_deg;

/// A ball to carve out (scene units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ball {
    /// Centre.
    pub centre: Vec3,
    /// Radius (> 0).
    pub radius: f64,
}

/// Elements the sphere passes through are refined until their edges are at most this
/// fraction of its radius.
pub const CARVE_SPACING: f64 = 0.75;

/// A node outside the sphere counts as on it only within this fraction of the cut's snap
/// (but not below [`super::MIN_SNAP`]) of its shortest edge (inside, within the whole snap):
/// a carve removes nothing farther from the centre than
/// `radius * (1 + max(OUTWARD_SNAP * snap, MIN_SNAP) * CARVE_SPACING)`, at the price of
/// children as thin as that fraction of an edge just outside the crater.
pub const OUTWARD_SNAP: f64 = 0.5;

/// A node inside the mesh whose edge crosses the sphere within this fraction of it moves
/// onto the sphere (move 2a) rather than being counted as on it where it is (within the
/// snap) or the edge being split there.
pub const WARP: f64 = 0.35;

/// A warp may leave a tetrahedron around the node no worse than this fraction of the worse
/// of its quality before and [`WARP_FLOOR`].
const WARP_QUALITY: f64 = 0.8;

/// Degrees: see [`WARP_QUALITY`].
const WARP_FLOOR: f64 = 20.0;

/// Most tetrahedra one carve may add by refinement (a ball far finer than the mesh is
/// refused rather than refined without end).
pub const MAX_CARVE_TETS: usize = 40_000;

/// `mesh` with the balls `balls` carved out (see the module docs), with where every node and
/// tetrahedron came from; `history` (that of earlier cuts) is carried and the crater's walls
/// are marked as cut sides. A carve that removes nothing returns the mesh unchanged (no
/// bisection, nothing separated). `snap` is a cut's [`super::CutOptions::snap`].
pub fn carve(
    mesh: &TetMesh,
    history: Option<&CutHistory>,
    balls: &[Ball],
    snap: f64,
) -> Result<CutMesh, RemoveError> {
    carve_keeping(mesh, history, balls, snap, &[])
}

/// [`carve`] with the nodes of `mesh` marked in `pinned` (supports: fixed nodes, anchors,
/// fixed temperatures) kept where they are, and new nodes made from them only: no warp
/// moves them (a node past the end of `pinned` is free).
pub fn carve_keeping(
    mesh: &TetMesh,
    history: Option<&CutHistory>,
    balls: &[Ball],
    snap: f64,
    pinned: &[bool],
) -> Result<CutMesh, RemoveError> {
    if !(super::MIN_SNAP..0.5).contains(&snap) {
        return Err(super::CutError::BadSnap(snap).into());
    }
    for (index, b) in balls.iter().enumerate() {
        if !b.centre.iter().all(|c| c.is_finite()) {
            return Err(RemoveError::BadBall {
                index,
                reason: "its centre is not finite",
            });
        }
        if !(b.radius.is_finite() && b.radius > 0.0) {
            return Err(RemoveError::BadBall {
                index,
                reason: "its radius is not finite and positive",
            });
        }
    }
    let size = mesh.bbox().diagonal();
    if let Some(index) = balls.iter().position(|b| b.radius < 1e-6 * size) {
        return Err(RemoveError::BadBall {
            index,
            reason: "its radius is below 1e-6 of the mesh's size",
        });
    }
    let history = history
        .filter(|h| h.sides.len() == mesh.tet_count() && h.on_blade.len() == mesh.node_count());
    let mut work = Work::new(mesh, history, 0);
    let start = work.tets.len();
    // The tetrahedra at each node, kept through every split (so a split finds every
    // tetrahedron around its edge, wherever it lies), and which leave.
    let mut state = Carving {
        around: vec![Vec::new(); work.positions.len()],
        gone: vec![false; work.tets.len()],
        pinned,
    };
    for (t, tet) in work.tets.iter().enumerate() {
        for &v in tet {
            state.around[v as usize].push(t as u32);
        }
    }
    // Ball by ball: what a ball's cut leaves inside it is marked before the next refines
    // (whose splits hand the mark to the children).
    for ball in balls {
        let mut candidates: Vec<u32> = (0..work.tets.len() as u32)
            .filter(|&t| work.box_meets(t, ball))
            .collect();
        work.refine_near(ball, &mut candidates, &mut state, start + MAX_CARVE_TETS)?;
        let on = work.bisect_sphere(ball, snap, &mut candidates, &mut state);
        // What leaves: every corner inside or on the sphere, the centre inside it.
        for &t in &candidates {
            let tet = work.tets[t as usize];
            let p = tet.map(|v| work.positions[v as usize]);
            let centre = (p[0] + p[1] + p[2] + p[3]) / 4.0;
            if (centre - ball.centre).norm() < ball.radius
                && tet.iter().zip(&p).all(|(&v, q)| {
                    on.get(v as usize).copied().unwrap_or(false)
                        || (q - ball.centre).norm() <= ball.radius
                })
            {
                state.gone[t as usize] = true;
            }
        }
    }
    let mut gone = state.gone;
    if !gone.iter().any(|&g| g) {
        return Ok(unchanged(mesh, history));
    }
    let closed_before = super::manifold(mesh.surface().triangles());
    keep_manifold(&work.tets, &mut gone, closed_before);
    if drop_crumbs(&work, balls, &mut gone) {
        keep_manifold(&work.tets, &mut gone, closed_before);
    }
    let removed: Vec<u32> = (0..gone.len() as u32)
        .filter(|&t| gone[t as usize])
        .collect();
    if removed.is_empty() {
        return Ok(unchanged(mesh, history));
    }
    let smallest_volume_ratio = work.smallest_volume_ratio(mesh)?;
    let refined = TetMesh::new(
        work.positions.clone(),
        work.tets.iter().map(|t| t.map(|i| i as usize)).collect(),
    )
    .map_err(super::CutError::from)?;
    let refined_history = CutHistory {
        sides: work.cut.clone(),
        on_blade: work.marked.clone(),
    };
    let mut out = remove_tets(&refined, Some(&refined_history), &removed)?;
    // Origins through both changes: the removal's are single nodes of the refined mesh.
    for o in &mut out.node_origin {
        *o = work.node_origin[o.nodes[0] as usize];
    }
    for t in &mut out.tet_origin {
        *t = work.tet_origin[*t as usize];
    }
    out.bisected = work.bisected;
    out.smallest_volume_ratio = smallest_volume_ratio;
    Ok(out)
}

/// The mesh as it was (a carve that removes nothing).
fn unchanged(mesh: &TetMesh, history: Option<&CutHistory>) -> CutMesh {
    CutMesh {
        mesh: mesh.clone(),
        node_origin: (0..mesh.node_count() as u32)
            .map(super::NodeOrigin::node)
            .collect(),
        tet_origin: (0..mesh.tet_count() as u32).collect(),
        cut_faces: Vec::new(),
        history: history.cloned().unwrap_or_else(|| CutHistory {
            sides: vec![[false; 4]; mesh.tet_count()],
            on_blade: vec![0; mesh.node_count()],
        }),
        bisected: 0,
        separated: 0,
        taken_back: 0,
        smallest_volume_ratio: 1.0,
    }
}

/// A carve's bookkeeping kept through every split: the tetrahedra at each node, and which
/// leave.
struct Carving<'p> {
    around: Vec<Vec<u32>>,
    gone: Vec<bool>,
    /// Nodes of the mesh before that no warp moves.
    pinned: &'p [bool],
}

impl Work<'_> {
    /// Corners of tetrahedron `t`.
    fn corners(&self, t: u32) -> [Vec3; 4] {
        self.tets[t as usize].map(|v| self.positions[v as usize])
    }

    /// Whether tetrahedron `t`'s box meets the ball's.
    fn box_meets(&self, t: u32, ball: &Ball) -> bool {
        let p = self.corners(t);
        let lo = p[0].inf(&p[1]).inf(&p[2]).inf(&p[3]);
        let hi = p[0].sup(&p[1]).sup(&p[2]).sup(&p[3]);
        (0..3)
            .all(|k| lo[k] <= ball.centre[k] + ball.radius && hi[k] >= ball.centre[k] - ball.radius)
    }

    /// Whether the ball's sphere passes through tetrahedron `t`: some corner outside, and
    /// its nearest point to the centre inside.
    fn sphere_passes(&self, t: u32, ball: &Ball) -> bool {
        let p = self.corners(t);
        let c = ball.centre;
        if p.iter().all(|q| (q - c).norm() <= ball.radius) {
            return false;
        }
        let faces = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
        // Inside the tetrahedron: on the inner side of every face.
        let inside = faces.iter().all(|f| {
            let [a, b, d] = f.map(|i| p[i]);
            (b - a).cross(&(d - a)).dot(&(c - a)) <= 0.0
        });
        inside
            || faces.iter().any(|f| {
                let [a, b, d] = f.map(|i| p[i]);
                point_triangle_distance(&c, &a, &b, &d) < ball.radius
            })
    }

    /// The longest edge of tetrahedron `t` and its length.
    fn longest_edge(&self, t: u32) -> ((u32, u32), f64) {
        let tet = self.tets[t as usize];
        let mut best = ((tet[0], tet[1]), -1.0);
        for i in 0..4 {
            for j in i + 1..4 {
                let (a, b) = (tet[i].min(tet[j]), tet[i].max(tet[j]));
                let l = (self.positions[a as usize] - self.positions[b as usize]).norm();
                if l > best.1 {
                    best = ((a, b), l);
                }
            }
        }
        best
    }

    /// [`Work::split_edge`] of edge `e` at `s` among the tetrahedra `state.around` says hold
    /// it, keeping `around` true and each child leaving where its parent does; children
    /// whose boxes meet `ball`'s join `candidates`.
    /// Returns the new node and the tetrahedra changed (the parents, now first children, and
    /// the second children).
    fn split_around(
        &mut self,
        e: (u32, u32),
        s: f64,
        ball: &Ball,
        candidates: &mut Vec<u32>,
        state: &mut Carving<'_>,
    ) -> (u32, Vec<u32>) {
        let around = &mut state.around;
        let mut holders: Vec<u32> = around[e.0 as usize]
            .iter()
            .copied()
            .filter(|&t| self.tets[t as usize].contains(&e.1))
            .collect();
        let parents = holders.len();
        let before = self.tets.len() as u32;
        let node = self.split_edge(e, s, &mut holders);
        around.push(Vec::new());
        // A parent now holds the node in place of e.1.
        for &t in &holders[..parents] {
            around[e.1 as usize].retain(|&u| u != t);
            around[node as usize].push(t);
        }
        // The second children come in the order of their parents.
        for &t in &holders[..parents] {
            let g = state.gone[t as usize];
            state.gone.push(g);
        }
        for t in before..self.tets.len() as u32 {
            for &v in &self.tets[t as usize] {
                around[v as usize].push(t);
            }
            if self.box_meets(t, ball) {
                candidates.push(t);
            }
        }
        (node, holders)
    }

    /// Move 1: bisects the longest edge of the elements the sphere passes through, longest
    /// first, until none is longer than [`CARVE_SPACING`] of the radius. `candidates` (the
    /// tetrahedra whose boxes meet the ball's) gains the children.
    fn refine_near(
        &mut self,
        ball: &Ball,
        candidates: &mut Vec<u32>,
        state: &mut Carving<'_>,
        limit: usize,
    ) -> Result<(), RemoveError> {
        let h = CARVE_SPACING * ball.radius;
        // Lengths are finite and non-negative: their bits order as they do.
        let mut heap: BinaryHeap<(u64, u32, [u32; 4])> = BinaryHeap::new();
        let push = |w: &Work, heap: &mut BinaryHeap<(u64, u32, [u32; 4])>, t: u32| {
            let (_, l) = w.longest_edge(t);
            if l > h && w.sphere_passes(t, ball) {
                heap.push((l.to_bits(), t, w.tets[t as usize]));
            }
        };
        for &t in candidates.iter() {
            push(self, &mut heap, t);
        }
        while let Some((_, t, corners)) = heap.pop() {
            if self.tets[t as usize] != corners {
                continue; // split since
            }
            if self.tets.len() > limit {
                return Err(RemoveError::TooFine {
                    radius: ball.radius,
                    added: self.tets.len() - (limit - MAX_CARVE_TETS),
                });
            }
            let (e, _) = self.longest_edge(t);
            let (_, changed) = self.split_around(e, 0.5, ball, candidates, state);
            for u in changed {
                push(self, &mut heap, u);
            }
        }
        Ok(())
    }

    /// Move 2: bisects the edges among `candidates` that cross the ball's sphere where they
    /// cross it (a crossing within `snap` of an end puts that end on it instead). Returns
    /// which nodes count as on the sphere.
    fn bisect_sphere(
        &mut self,
        ball: &Ball,
        snap: f64,
        candidates: &mut Vec<u32>,
        state: &mut Carving<'_>,
    ) -> Vec<bool> {
        let c = ball.centre;
        let r = ball.radius;
        let mut phi: HashMap<u32, f64> = HashMap::new();
        let mut shortest: HashMap<u32, f64> = HashMap::new();
        let mut edges: Vec<(u32, u32)> = Vec::new();
        for &t in candidates.iter() {
            let tet = self.tets[t as usize];
            for i in 0..4 {
                phi.entry(tet[i])
                    .or_insert_with(|| (self.positions[tet[i] as usize] - c).norm() - r);
                for j in i + 1..4 {
                    edges.push((tet[i].min(tet[j]), tet[i].max(tet[j])));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        self.warp_to_sphere(ball, &edges, &mut phi, state);
        // Shortest edges at each node, as the warps left them.
        for &(a, b) in &edges {
            let l = (self.positions[a as usize] - self.positions[b as usize]).norm();
            for v in [a, b] {
                let e = shortest.entry(v).or_insert(f64::INFINITY);
                *e = e.min(l);
            }
        }
        // Outside the sphere a node snaps onto it only within `OUTWARD_SNAP` of `snap` (not
        // below the smallest snap): tissue beyond the radius leaves by no more than that.
        let outward = (OUTWARD_SNAP * snap).max(super::MIN_SNAP);
        let mut on = vec![false; self.positions.len()];
        for (&v, &d) in &phi {
            let reach = if d > 0.0 { outward } else { snap };
            on[v as usize] = d == 0.0 || d.abs() < reach * shortest[&v];
        }
        // Where edge (a, b) crosses the sphere, as a fraction from a (None: it does not,
        // or an end is on it).
        let crossing = |w: &Work, on: &[bool], (a, b): (u32, u32)| -> Option<f64> {
            if on[a as usize] || on[b as usize] || (phi[&a] > 0.0) == (phi[&b] > 0.0) {
                return None;
            }
            Some(w.sphere_crossing(a, b, ball))
        };
        loop {
            let mut changed = false;
            for &e in &edges {
                let Some(s) = crossing(self, &on, e) else {
                    continue;
                };
                let (near_a, near_b) = if phi[&e.0] > 0.0 {
                    (outward, snap)
                } else {
                    (snap, outward)
                };
                if s < near_a {
                    on[e.0 as usize] = true;
                    changed = true;
                } else if s > 1.0 - near_b {
                    on[e.1 as usize] = true;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        for &e in &edges {
            let Some(s) = crossing(self, &on, e) else {
                continue;
            };
            let (node, _) = self.split_around(e, s, ball, candidates, state);
            on.resize(self.positions.len(), false);
            on[node as usize] = true;
        }
        on
    }
}

impl Work<'_> {
    /// Move 2a: moves nodes onto the sphere where it crosses one of their edges within
    /// [`WARP`] of them (after isosurface stuffing's warping, Labelle and Shewchuk 2007),
    /// nearest first, so the sphere's cut then splits edges only away from their ends. A node
    /// moves only when it is not pinned ([`carve_keeping`]) and lies inside the mesh (every
    /// face around it shared by two tetrahedra, none gone),
    /// along its edge to the crossing, and only where no tetrahedron around it comes out worse
    /// than [`WARP_QUALITY`] of the worse of its old shape and [`WARP_FLOOR`] degrees. Its
    /// origin moves with it (the blend of its edge's ends), so the fields follow, and the
    /// mesh's domain is what it was (volume and mass unchanged); an element around a moved
    /// node may then reach into a neighbour of the element its origin names. Warped nodes
    /// get `phi` 0. Returns how many moved.
    fn warp_to_sphere(
        &mut self,
        ball: &Ball,
        edges: &[(u32, u32)],
        phi: &mut HashMap<u32, f64>,
        state: &Carving<'_>,
    ) -> usize {
        let crosses = |phi: &HashMap<u32, f64>, a: u32, b: u32| {
            let (pa, pb) = (phi[&a], phi[&b]);
            pa != 0.0 && pb != 0.0 && (pa > 0.0) != (pb > 0.0)
        };
        let mut links: HashMap<u32, Vec<u32>> = HashMap::new();
        let mut order: Vec<(f64, u32)> = Vec::new();
        for &(a, b) in edges {
            if !crosses(phi, a, b) {
                continue;
            }
            let s = self.sphere_crossing(a, b, ball);
            order.push((s, a));
            order.push((1.0 - s, b));
            links.entry(a).or_default().push(b);
            links.entry(b).or_default().push(a);
        }
        order.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        // Each element's quality before any warp: warps of its corners one after the other
        // are held to it, not to what the last one left.
        let mut first: HashMap<u32, f64> = HashMap::new();
        let mut moved = 0;
        for (frac, v) in order {
            if frac >= WARP {
                break;
            }
            if phi[&v] == 0.0 {
                continue;
            }
            // Its nearest crossing now (an edge to a node warped since no longer crosses).
            let Some((f, u)) = links[&v]
                .iter()
                .filter(|&&u| crosses(phi, v, u))
                .map(|&u| (self.sphere_crossing(v, u, ball), u))
                .min_by(|x, y| x.0.total_cmp(&y.0))
            else {
                continue;
            };
            if f >= WARP || self.pinned(state, v) || !self.interior(state, v) {
                continue;
            }
            let target = self.positions[v as usize] * (1.0 - f) + self.positions[u as usize] * f;
            if !self.warp_keeps_shapes(state, v, target, &mut first) {
                continue;
            }
            let origin = self.origin_on_edge(v, u, f);
            self.positions[v as usize] = target;
            self.node_origin[v as usize] = origin;
            phi.insert(v, 0.0);
            moved += 1;
        }
        moved
    }

    /// Where edge `(a, b)` (ends on opposite sides of the sphere) crosses it, as a fraction
    /// from `a`.
    fn sphere_crossing(&self, a: u32, b: u32, ball: &Ball) -> f64 {
        let f = self.positions[a as usize] - ball.centre;
        let d = self.positions[b as usize] - self.positions[a as usize];
        let r = ball.radius;
        let (qa, qb, qc) = (d.dot(&d), 2.0 * f.dot(&d), f.dot(&f) - r * r);
        let root = (qb * qb - 4.0 * qa * qc).max(0.0).sqrt();
        // From inside (qc < 0) the far root; from outside the near one.
        let s = if qc < 0.0 {
            (-qb + root) / (2.0 * qa)
        } else {
            (-qb - root) / (2.0 * qa)
        };
        s.clamp(0.0, 1.0)
    }

    /// Whether node `v` lies inside the mesh: every face at it shared by two of its
    /// tetrahedra, none of them removed.
    fn interior(&self, state: &Carving<'_>, v: u32) -> bool {
        let mut faces: HashMap<[u32; 3], u8> = HashMap::new();
        for &t in &state.around[v as usize] {
            if state.gone[t as usize] {
                return false;
            }
            let tet = self.tets[t as usize];
            for (o, &w) in tet.iter().enumerate() {
                if w != v {
                    *faces.entry(face_key(&tet, o)).or_insert(0) += 1;
                }
            }
        }
        faces.values().all(|&n| n == 2)
    }

    /// Whether node `v` must stay where it is: a node of the mesh before that `state` pins
    /// (a support), or a new node made from pinned nodes only (the supports carry to it).
    fn pinned(&self, state: &Carving<'_>, v: u32) -> bool {
        let o = &self.node_origin[v as usize];
        let mut named = (0..4).filter(|&k| o.weights[k] != 0.0).map(|k| o.nodes[k]);
        named.all(|n| state.pinned.get(n as usize).copied().unwrap_or(false))
    }

    /// Whether moving node `v` to `target` leaves every tetrahedron around it at least
    /// [`WARP_QUALITY`] of the worse of its quality before any warp (kept in `first`) and
    /// [`WARP_FLOOR`] (the smallest of `min(b, 180 - b)` over its dihedral angles `b`).
    fn warp_keeps_shapes(
        &self,
        state: &Carving<'_>,
        v: u32,
        target: Vec3,
        first: &mut HashMap<u32, f64>,
    ) -> bool {
        state.around[v as usize].iter().all(|&t| {
            let tet = self.tets[t as usize];
            let q0 = *first
                .entry(t)
                .or_insert_with(|| tet_quality_deg(&tet.map(|w| self.positions[w as usize])));
            let after = tet.map(|w| {
                if w == v {
                    target
                } else {
                    self.positions[w as usize]
                }
            });
            let q1 = tet_quality_deg(&after);
            q1 > 0.0 && q1 >= WARP_QUALITY * q0.min(WARP_FLOOR)
        })
    }
}

/// Keeps (does not remove) the tetrahedra around each edge that the boundary left would have
/// in more than two triangles, until there is none (where the mesh's boundary was closed).
fn keep_manifold(tets: &[[u32; 4]], gone: &mut [bool], closed_before: bool) {
    if !closed_before {
        return;
    }
    for _ in 0..16 {
        let bad = super::check::bad_edges(tets, gone);
        if bad.is_empty() {
            return;
        }
        for (t, tet) in tets.iter().enumerate() {
            if gone[t]
                && bad
                    .iter()
                    .any(|&(a, b)| tet.contains(&a) && tet.contains(&b))
            {
                gone[t] = false;
            }
        }
    }
}

/// Removes too the pieces the removal cuts loose (joined through faces) that lie wholly
/// within twice a ball's radius of its centre and touch the removed tetrahedra: crumbs of
/// the crater's rim, not tissue a body goes on with. Returns whether it removed any.
fn drop_crumbs(work: &Work, balls: &[Ball], gone: &mut [bool]) -> bool {
    let n = work.tets.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    let mut owner: HashMap<[u32; 3], usize> = HashMap::new();
    for (t, tet) in work.tets.iter().enumerate() {
        if gone[t] {
            continue;
        }
        for o in 0..4 {
            if let Some(&u) = owner.get(&face_key(tet, o)) {
                let (a, b) = (root(&mut parent, t), root(&mut parent, u));
                parent[a] = b;
            } else {
                owner.insert(face_key(tet, o), t);
            }
        }
    }
    // Faces of removed tetrahedra: a piece with one of them as a face touches the crater.
    let mut opened: std::collections::HashSet<[u32; 3]> = std::collections::HashSet::new();
    for (t, tet) in work.tets.iter().enumerate() {
        if gone[t] {
            for o in 0..4 {
                opened.insert(face_key(tet, o));
            }
        }
    }
    // Components the carve made: within reach of a ball, touching the crater.
    let mut near: HashMap<usize, (bool, bool)> = HashMap::new();
    for (t, tet) in work.tets.iter().enumerate() {
        if gone[t] {
            continue;
        }
        let r = root(&mut parent, t);
        let within = tet.iter().all(|&v| {
            balls
                .iter()
                .any(|b| (work.positions[v as usize] - b.centre).norm() <= 2.0 * b.radius)
        });
        let touches = (0..4).any(|o| opened.contains(&face_key(tet, o)));
        let e = near.entry(r).or_insert((true, false));
        e.0 &= within;
        e.1 |= touches;
    }
    let crumb = |e: &(bool, bool)| e.0 && e.1;
    // Only where some piece goes on (a mesh wholly within reach is left to the removal's
    // own check).
    if near.len() < 2 || near.values().all(crumb) || !near.values().any(crumb) {
        return false;
    }
    for t in 0..n {
        if !gone[t] && crumb(&near[&root(&mut parent, t)]) {
            gone[t] = true;
        }
    }
    true
}
