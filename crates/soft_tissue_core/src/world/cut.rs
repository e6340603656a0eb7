//! Cutting a simulated body (see `docs/cutting.md`): the blade's incision and what a cut
//! leaves (`cut_job.rs` makes the cut).
//!
//! The blade cuts the body **where it is when the cut begins**: the mesh in that (deformed)
//! shape is cut by [`crate::mesh::cut::recut`], so the wound follows the blade through the
//! tissue as it lies. Every new node is a point of one tetrahedron before (its [`NodeOrigin`]
//! weights); the deformation is linear in each tetrahedron, so the same weights give its
//! rest position, and, when the cut lands (in the same step, or steps later when it was
//! prepared in the background), its position, velocity, temperature and damage of that
//! step exactly. The body is rebuilt on the cut rest mesh: the precise solver (its factor
//! or preconditioner, springs and masses), the heat field, the contact surface and a cage
//! of the new rest shape; it starts at its precise level in the state of the step the cut
//! lands in, and drops to its cage once at rest as any body does (held precise until
//! rest: the shape a cut body rests in is not known until it rests, and its cage keeps that
//! shape). Each piece that came loose becomes a body of its own.

use super::*;
use crate::boundary::Boundary;
use crate::mesh::cut::{CutTriangle, NodeOrigin};

/// What a body made by cuts knows of them.
#[derive(Debug, Clone, Default)]
pub struct CutRecord {
    /// The uncut body's name.
    pub origin: String,
    /// The uncut body's rest volume, scene units cubed.
    pub origin_volume: f64,
    /// Cuts that changed this body or the bodies it came from.
    pub cuts: u32,
    /// What the next cut carries on (the sides of the cuts, the nodes a blade passed).
    pub(crate) history: crate::mesh::cut::CutHistory,
    /// Surface triangles (indices into [`WorldBody::surface_triangles`]) that are sides of a
    /// cut: the inside of the tissue, to draw as such.
    pub surface_faces: Vec<u32>,
    /// Area of the cut sides of this body at rest, scene units squared.
    pub area: f64,
    /// Smallest dihedral angle of this body's tetrahedra at rest, degrees.
    pub smallest_dihedral_deg: f64,
    /// Whether this body's surface is closed: every edge in exactly two triangles.
    pub closed: bool,
    /// Wall time of the last cut that made this body, microseconds: the change of the
    /// mesh (its state, the cut, the pieces) and the build of the bodies (solvers, heat,
    /// contact surface, cage) of all its pieces. Where the cut was prepared on a thread
    /// of its own ([`crate::mesh::cut::CutOptions::background_steps`]) that thread spent them, not a step.
    pub mesh_us: f64,
    /// See [`CutRecord::mesh_us`]. Includes the compliance columns computed for
    /// [`CutRecord::warmed_nodes`].
    pub build_us: f64,
    /// Nodes of this body whose contact compliance columns were computed with it, before it
    /// landed: its surface nodes nearest to where the body was pressed on (by any contact:
    /// tools, obstacles, bodies) when a cut prepared beside the steps began, at most 128 and
    /// what its column cache holds, so the contact of the step it lands in finds them kept.
    /// 0 for a cut made within the step, and for RK4.
    pub warmed_nodes: usize,
    /// What the step the cut landed in spent on it, microseconds: waiting for the thread
    /// that prepared it (0 when it was ready, or when it was prepared in the step) and
    /// handing the body's state now to its pieces.
    pub land_us: f64,
    /// Of [`CutRecord::land_us`], the time spent waiting for the thread that prepared the
    /// cut, or preparing it where its pool thread had not started it (0 when it was ready):
    /// more than a little says the cut needs more
    /// [`crate::mesh::cut::CutOptions::background_steps`] on this machine. Landings that
    /// cut nothing wait too: see [`WorldBody::landing_wait_us`] and
    /// [`crate::timing::StageTimes::cut_wait_us`].
    pub wait_us: f64,
}

/// What one blade sweep did to one body ([`WorldBody::cut_within`]).
#[derive(Debug)]
pub enum BladeOutcome {
    /// The blade reached nothing of the body, or the body could not be cut where it is
    /// now (a warning says why): nothing to do again.
    Missed,
    /// The blade crossed the body but separated nothing yet: the body is unchanged, and the
    /// incision's next strip bisects this part again, where the tissue then is.
    Crossed,
    /// The body was cut.
    Cut(Box<BladeCut>),
}

/// The cut of one body by one blade sweep.
#[derive(Debug)]
pub struct BladeCut {
    /// Faces the cut separated (0: the body was not changed).
    pub separated: usize,
    /// Edges it bisected.
    pub bisected: usize,
    /// Pieces that came loose, as bodies of their own (the body keeps one piece).
    pub pieces: Vec<WorldBody>,
    /// Where each node of the body before went: `(piece, node)`, piece 0 being the body
    /// itself and `k >= 1` `pieces[k - 1]`; the first copy of a node duplicated by the cut.
    pub node_map: Vec<(u32, u32)>,
    /// The body as it was before the cut.
    pub previous: Box<WorldBody>,
}

/// The surface a blade has swept since its cutting turned on. Each step's strip (from the
/// edge's last place to its place now) stays pending for each body until a cut of that body
/// separates something or finds nothing to cut (a strip that crossed the body without
/// separating anything stays, so it bisects its part again where the tissue then is): the
/// path the blade took, step by step, per body. While the blade moves in one plane (a
/// straight stroke) the whole stroke, one quadrilateral from where it began to where the
/// edge is now, is where faces on that plane are separated, so a face wider than one step's
/// strip (a strip is far narrower than an element) is cut once the strip that completes it
/// has passed. A turn out of the plane starts a new stroke.
///
/// Bodies are told apart by a key of the caller's (the world's body index, the plugin's
/// entity). A body first seen has every strip still kept pending; a cut's pieces start with
/// none of the strips that cut them ([`Incision::consumed`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Incision {
    id: u64,
    start: (Vec3, Vec3),
    last: (Vec3, Vec3),
    /// The strips swept so far, oldest first (at most `2 MAX_PENDING` triangles); the
    /// first has number `first`.
    strips: Vec<CutTriangle>,
    first: u64,
    /// Per body key, the number of the first strip still pending for it.
    from: Vec<(u64, u64)>,
}

/// Most strips an incision keeps pending (a blade that crosses a body for this many steps
/// without separating anything drops the oldest).
const MAX_PENDING: usize = 64;

impl Incision {
    /// An incision whose blade edge is at `(tip, back)`.
    pub fn new(edge: (Vec3, Vec3)) -> Self {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
        Incision {
            id: NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            start: edge,
            last: edge,
            strips: Vec::new(),
            first: 0,
            from: Vec::new(),
        }
    }

    /// The blade edge moved to `edge`: its strip is added, and the stroke so far is
    /// returned (where faces on the strips' plane are separated; see
    /// [`crate::mesh::cut::recut_within`]). What each body is cut with is
    /// [`Incision::pending`].
    pub fn advance(&mut self, edge: (Vec3, Vec3)) -> Vec<CutTriangle> {
        let (a0, b0) = self.start;
        let stroke = swept_triangles(a0, b0, self.last.0, self.last.1);
        if !stroke.is_empty() && !self.in_plane(edge) {
            // A new stroke (the pending strips stay: they are the path the blade took).
            self.start = self.last;
        }
        self.strips
            .extend(swept_triangles(self.last.0, self.last.1, edge.0, edge.1));
        let over = self.strips.len().saturating_sub(2 * MAX_PENDING);
        self.strips.drain(..over);
        self.first += over as u64;
        self.last = edge;
        let (a0, b0) = self.start;
        swept_triangles(a0, b0, edge.0, edge.1)
    }

    /// The strips pending for body `key` (swept step by step since its last cut that
    /// separated something or found nothing to cut), and the mark to hand to
    /// [`Incision::consumed`] once a cut with them is done.
    pub fn pending(&self, key: u64) -> (Vec<CutTriangle>, u64) {
        let end = self.first + self.strips.len() as u64;
        let from = self.first_pending(key).max(self.first);
        (self.strips[(from - self.first) as usize..].to_vec(), end)
    }

    /// A cut of body `key` with the strips [`Incision::pending`] gave with `mark`
    /// separated something (the body and each of its new pieces are consumed) or found
    /// nothing to cut: those strips are no longer pending for it (a strip that crossed
    /// without separating anything is kept instead: it cuts again where the tissue then is).
    pub fn consumed(&mut self, key: u64, mark: u64) {
        match self.from.iter_mut().find(|(k, _)| *k == key) {
            Some((_, from)) => *from = (*from).max(mark),
            None => self.from.push((key, mark)),
        }
    }

    /// Body `child` was made by a cut of body `parent` (a piece that came loose): the strips
    /// pending for it are the parent's (not every strip kept, as for a body first seen).
    pub fn inherit(&mut self, parent: u64, child: u64) {
        let from = self.first_pending(parent);
        match self.from.iter_mut().find(|(k, _)| *k == child) {
            Some((_, f)) => *f = from,
            None => self.from.push((child, from)),
        }
    }

    /// The number of the first strip pending for body `key` (what
    /// [`Incision::consumed`] with it gives another body).
    pub fn pending_from(&self, key: u64) -> u64 {
        self.first_pending(key)
    }

    fn first_pending(&self, key: u64) -> u64 {
        self.from
            .iter()
            .find(|(k, _)| *k == key)
            .map_or(0, |&(_, from)| from)
    }

    /// A number no other incision of this process has (what marks the nodes it passed).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Whether `edge` lies in the plane of the stroke so far (within 1e-6 of its size).
    fn in_plane(&self, edge: (Vec3, Vec3)) -> bool {
        let (a0, b0) = self.start;
        let (a1, b1) = self.last;
        let along = b0 - a0;
        let n = [a1 - a0, b1 - a0]
            .iter()
            .map(|d| along.cross(d))
            .max_by(|x, y| x.norm().total_cmp(&y.norm()))
            .unwrap_or_else(Vec3::zeros);
        let size = along.norm().max((a1 - a0).norm());
        // No plane yet (the edge has not moved across itself), or none to speak of.
        if n.norm() <= 1e-12 * size * size || !n.norm().is_finite() {
            return true;
        }
        let n = n.normalize();
        [edge.0, edge.1]
            .iter()
            .all(|p| n.dot(&(p - a0)).abs() <= 1e-6 * size)
    }
}

/// The two triangles a segment `(a0, b0)` sweeps moving to `(a1, b1)`; those without area
/// (a blade that did not move, or slid along itself) are left out.
pub fn swept_triangles(a0: Vec3, b0: Vec3, a1: Vec3, b1: Vec3) -> Vec<CutTriangle> {
    let scale = (b0 - a0).norm().max((b1 - a1).norm()).max((a1 - a0).norm());
    let mut out = Vec::with_capacity(2);
    for corners in [[a0, b0, b1], [a0, b1, a1]] {
        let [p, q, r] = corners;
        let area = 0.5 * (q - p).cross(&(r - p)).norm();
        if area.is_finite() && area > 1e-9 * scale * scale {
            out.push(CutTriangle { corners });
        }
    }
    out
}

impl CutRecord {
    /// The share of the uncut body's volume, and so of its mass, this body has (its rest
    /// volume over the uncut body's).
    pub fn share(&self, body: &WorldBody) -> f64 {
        body.mesh.volume() / self.origin_volume
    }
}

impl WorldBody {
    /// The cuts this body came from, if any.
    pub fn cut_record(&self) -> Option<&CutRecord> {
        self.cut.as_ref()
    }

    /// How long the last landing of a cut prepared for this body waited for its thread (or
    /// spent preparing it, where its pool thread had not started it), microseconds: also for
    /// a cut that came to nothing (crossed, missed, dropped), which leaves no
    /// [`CutRecord`]. 0 when it was ready, or before any landing.
    pub fn landing_wait_us(&self) -> f64 {
        self.landing_wait_us
    }
}

/// Grips of `tools` on body `body` follow a cut of it (`node_map` of its [`BladeCut`]; the
/// cut's pieces are added as bodies from index `first_piece` on). A grip on a node the cut
/// did not keep as it was is let go. `bodies` are the bodies after the pieces were added.
pub fn remap_grips<T: BorrowMut<Tool>, B: Borrow<WorldBody>>(
    tools: &mut [T],
    bodies: &[B],
    body: usize,
    node_map: &[(u32, u32)],
    first_piece: usize,
) {
    for t in tools.iter_mut() {
        let t = t.borrow_mut();
        if !t.grips().iter().any(|g| g.body as usize == body) {
            continue;
        }
        let grips = t
            .grips()
            .iter()
            .filter_map(|g| {
                if g.body as usize != body {
                    return Some(*g);
                }
                let &(piece, node) = node_map.get(g.node as usize)?;
                if piece == u32::MAX {
                    return None;
                }
                let index = if piece == 0 {
                    body
                } else {
                    first_piece + piece as usize - 1
                };
                let vertex = bodies
                    .get(index)?
                    .borrow()
                    .mesh
                    .surface()
                    .surface_index(node as usize)?;
                Some(crate::contact::Grip {
                    body: index as u32,
                    node,
                    vertex: vertex as u32,
                    offset: g.offset,
                })
            })
            .collect();
        t.set_grips(grips);
    }
}

/// Whether every edge of `triangles` is in exactly two of them.
pub(super) fn surface_closed(triangles: &[[u32; 3]]) -> bool {
    crate::mesh::cut::manifold(triangles)
}

/// A quarter of the volume of every tetrahedron around each node.
pub(super) fn lumped_volumes(mesh: &TetMesh) -> Vec<f64> {
    let mut out = vec![0.0; mesh.node_count()];
    for (t, v) in mesh.tets().iter().zip(mesh.tet_volumes()) {
        for &i in t {
            out[i as usize] += 0.25 * v.abs();
        }
    }
    out
}

/// The node an origin is, when it is one node of the mesh before as it was.
pub(super) fn single_node(o: &NodeOrigin) -> Option<u32> {
    (o.weights[0] == 1.0).then_some(o.nodes[0])
}

/// The axes a boundary holds at each of `n` nodes.
pub(super) fn held_axes(b: &Boundary, n: usize) -> Vec<[bool; 3]> {
    let mut out = vec![[false; 3]; n];
    for &(node, axes) in &b.fixed {
        if node < n {
            for a in 0..3 {
                out[node][a] |= axes[a];
            }
        }
    }
    out
}

/// The nodes of `n` a carve must not move: fixed (on any axis), anchored, or held at a
/// temperature.
pub(super) fn supports(n: usize, b: &Boundary, heat: Option<&HeatBoundary>) -> Vec<bool> {
    let mut pinned = vec![false; n];
    let nodes = b
        .fixed
        .iter()
        .map(|f| f.0)
        .chain(b.anchors.iter().map(|a| a.0));
    let held = heat.into_iter().flat_map(|h| h.fixed.iter().map(|f| f.0));
    for v in nodes.chain(held) {
        if v < n {
            pinned[v] = true;
        }
    }
    pinned
}

/// The axes held at a new node: those held at every node it was made from.
pub(super) fn fixed_axes(held: &[[bool; 3]], o: &NodeOrigin) -> Option<[bool; 3]> {
    let mut axes = [true; 3];
    for k in 0..4 {
        if o.weights[k] != 0.0 {
            let h = held[o.nodes[k] as usize];
            for a in 0..3 {
                axes[a] &= h[a];
            }
        }
    }
    axes.iter().any(|&a| a).then_some(axes)
}

/// The supports of a piece: fixed axes held by every node a new node was made from, and
/// anchors' stiffness per volume carried by the weights (a soft anchor standing for tissue
/// around the node holds a share of the node's volume).
pub(super) fn carried_boundary(
    b: &Boundary,
    held: &[[bool; 3]],
    origins: &[NodeOrigin],
    nodes: &[u32],
    old_volumes: &[f64],
    new_volumes: &[f64],
) -> Boundary {
    let mut out = Boundary::free();
    let mut anchor = vec![0.0; old_volumes.len()];
    for &(n, k) in &b.anchors {
        if n < anchor.len() && old_volumes[n] > 0.0 {
            anchor[n] += k / old_volumes[n];
        }
    }
    for (local, &n) in nodes.iter().enumerate() {
        let o = &origins[n as usize];
        if let Some(axes) = fixed_axes(held, o) {
            out.fixed.push((local, axes));
        }
        let per_volume: f64 = (0..4)
            .map(|k| o.weights[k] * anchor[o.nodes[k] as usize])
            .sum();
        if per_volume > 0.0 {
            out.anchors.push((local, per_volume * new_volumes[local]));
        }
    }
    out
}

/// The heat field's fixed temperatures of a piece: a new node made only from fixed nodes
/// is fixed at its weighted temperature.
pub(super) fn carried_heat_boundary(
    b: &HeatBoundary,
    origins: &[NodeOrigin],
    nodes: &[u32],
    node_count: usize,
) -> HeatBoundary {
    let mut held = vec![None; node_count];
    for &(n, t) in &b.fixed {
        if n < node_count {
            held[n] = Some(t);
        }
    }
    let mut out = HeatBoundary::default();
    for (local, &n) in nodes.iter().enumerate() {
        let o = &origins[n as usize];
        let mut t = 0.0;
        let mut all = true;
        for k in 0..4 {
            if o.weights[k] == 0.0 {
                continue;
            }
            match held[o.nodes[k] as usize] {
                Some(temp) => t += o.weights[k] * temp,
                None => all = false,
            }
        }
        if all {
            out.fixed.push((local, t));
        }
    }
    out
}
