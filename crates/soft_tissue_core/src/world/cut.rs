//! Cutting a simulated body (see `docs/cutting.md`).
//!
//! The blade cuts the body **where it is now**: the mesh in its current (deformed) shape is
//! cut by [`crate::mesh::cut::recut`], so the wound follows the blade through the tissue as
//! it lies. Every new node is a point of one tetrahedron before (its [`NodeOrigin`]
//! weights); the deformation is linear in each tetrahedron, so the same weights give its
//! rest position, velocity, temperature and damage exactly. The body is then rebuilt on
//! the cut rest mesh: the precise solver (its factor or preconditioner, springs and
//! masses), the heat field, the contact surface and a cage of the new rest shape; it
//! starts at its precise level in the state it was cut in, and drops to its cage once at
//! rest as any body does (held precise until rest: the shape a cut body rests in is not
//! known until it rests, and its cage keeps that shape). Each piece that came loose
//! becomes a body of its own.

use super::*;
use crate::boundary::Boundary;
use crate::mesh::cut::{CutOptions, CutTriangle, NodeOrigin, recut_within};
use crate::mesh::pieces::pieces;

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
    /// Surface triangles (indices into [`SimBody::surface_triangles`]) that are sides of a
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
    /// contact surface, cage) of all its pieces.
    pub mesh_us: f64,
    /// See [`CutRecord::mesh_us`].
    pub build_us: f64,
}

/// What one blade sweep did to one body ([`SimBody::cut_within`]).
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
    pub pieces: Vec<SimBody>,
    /// Where each node of the body before went: `(piece, node)`, piece 0 being the body
    /// itself and `k >= 1` `pieces[k - 1]`; the first copy of a node duplicated by the cut.
    pub node_map: Vec<(u32, u32)>,
    /// The body as it was before the cut.
    pub previous: Box<SimBody>,
}

/// The surface a blade has swept since its cutting turned on. Each step's strip (from the
/// edge's last place to its place now) is kept until a cut that separates something (or a
/// step whose strips cross nothing), and the strips kept bisect what they cross, where the
/// tissue is now: the path the blade took, step by step. While the blade moves in one plane
/// (a straight stroke) the whole stroke, one quadrilateral from where it began to where the
/// edge is now, is where faces on that plane are separated, so a face wider than one step's
/// strip (a strip is far narrower than an element) is cut once the strip that completes it
/// has passed. A turn out of the plane starts a new stroke.
#[derive(Debug, Clone, PartialEq)]
pub struct Incision {
    id: u64,
    start: (Vec3, Vec3),
    last: (Vec3, Vec3),
    /// The strips swept since the last cut that separated something (or crossed nothing),
    /// step by step: the path the blade took, not a straight line.
    pending: Vec<CutTriangle>,
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
            pending: Vec::new(),
        }
    }

    /// The blade edge moved to `edge`: what to cut with now, as `(strips, region)`: the
    /// strips swept step by step since the last cut that separated something (which bisect:
    /// a cut that separates nothing is not kept, so its bisections are made again, where
    /// the tissue is now) and the stroke so far (where faces on the strips' plane are
    /// separated; see [`crate::mesh::cut::recut_within`]).
    pub fn advance(&mut self, edge: (Vec3, Vec3)) -> (Vec<CutTriangle>, Vec<CutTriangle>) {
        let (a0, b0) = self.start;
        let stroke = swept_triangles(a0, b0, self.last.0, self.last.1);
        if !stroke.is_empty() && !self.in_plane(edge) {
            // A new stroke (the pending strips stay: they are the path the blade took).
            self.start = self.last;
        }
        self.pending
            .extend(swept_triangles(self.last.0, self.last.1, edge.0, edge.1));
        let over = self.pending.len().saturating_sub(2 * MAX_PENDING);
        self.pending.drain(..over);
        self.last = edge;
        let (a0, b0) = self.start;
        (
            self.pending.clone(),
            swept_triangles(a0, b0, edge.0, edge.1),
        )
    }

    /// A number no other incision of this process has (what marks the nodes it passed).
    pub fn id(&self) -> u64 {
        self.id
    }

    /// The cut of the last [`Incision::advance`] separated something and was kept, or its
    /// strip crossed nothing: the next strip starts at the edge's place now. (Only a strip
    /// that crossed a body without separating anything stays pending, so the next one
    /// bisects its part again where the tissue then is.)
    pub fn kept(&mut self) {
        self.pending.clear();
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
    pub fn share(&self, body: &SimBody) -> f64 {
        body.mesh.volume() / self.origin_volume
    }
}

impl SimBody {
    /// The cuts this body came from, if any.
    pub fn cut_record(&self) -> Option<&CutRecord> {
        self.cut.as_ref()
    }

    /// Cuts the body along `blade` (triangles in scene coordinates, where the body is now).
    /// Returns `None` when nothing was separated (the body is unchanged). Otherwise the body
    /// becomes the piece holding most of its fixed nodes (the largest when none is fixed),
    /// each other piece is returned as a new body named `NAME.k`, and every piece is at its
    /// precise level in the state the body was cut in (see the module docs). A refused cut
    /// leaves the body as it was.
    pub fn cut(
        &mut self,
        blade: &[CutTriangle],
        options: &CutOptions,
    ) -> Result<Option<BladeCut>, WorldError> {
        Ok(match self.cut_within(blade, &[], 0, options)? {
            BladeOutcome::Cut(c) => Some(*c),
            _ => None,
        })
    }

    /// [`SimBody::cut`] by the pending strips `blade` of incision `incision` ([`Incision::id`])
    /// whose stroke so far is `region` (see [`crate::mesh::cut::recut_within`]).
    pub fn cut_within(
        &mut self,
        blade: &[CutTriangle],
        region: &[CutTriangle],
        incision: u64,
        options: &CutOptions,
    ) -> Result<BladeOutcome, WorldError> {
        let err = |b: &SimBody, reason: String| WorldError::Cut {
            body: b.label(),
            reason,
        };
        crate::mesh::cut::check_blade(blade)
            .and_then(|_| crate::mesh::cut::check_blade(region))
            .map_err(|e| err(self, e.to_string()))?;
        if blade.is_empty() || !self.blade_reaches(blade) {
            return Ok(BladeOutcome::Missed);
        }
        // From here a failure is the shape's, not the blade's: the body is passed by this
        // step, as it is (a warning names why).
        let skip = |b: &SimBody, why: String| {
            log::warn!("body `{}`: not cut this step: {why}", b.name);
            Ok(BladeOutcome::Missed)
        };
        let started = std::time::Instant::now();
        let (x, v) = self.body.node_state().map_err(|e| self.precision_err(e))?;
        let tets: Vec<[usize; 4]> = self
            .mesh
            .tets()
            .iter()
            .map(|t| t.map(|i| i as usize))
            .collect();
        let now = match TetMesh::new(x.clone(), tets) {
            Ok(m) => m,
            Err(e) => return skip(self, format!("its shape now: {e}")),
        };
        if now
            .warnings()
            .iter()
            .any(|w| matches!(w, crate::mesh::MeshWarning::Reoriented { .. }))
        {
            // Where its elements are turned inside out the body has no shape to cut along.
            return skip(
                self,
                "some tetrahedra are inverted in the shape it is in".into(),
            );
        }
        let history = self.cut.as_ref().map(|c| &c.history);
        let cut = match recut_within(&now, history, blade, region, incision, options) {
            Ok(c) => c,
            Err(e) => return skip(self, e.to_string()),
        };
        if cut.separated == 0 {
            return Ok(if cut.bisected > 0 {
                BladeOutcome::Crossed
            } else {
                BladeOutcome::Missed
            });
        }
        // Every field of the body before, carried to the new nodes.
        let origins = &cut.node_origin;
        let carry = |field: &[Vec3]| -> Vec<Vec3> {
            origins.iter().map(|o| o.interpolate(field)).collect()
        };
        let rest_all = carry(self.mesh.positions());
        let v_all = carry(&v);
        let x_all = cut.mesh.positions().to_vec();
        let heat_all = self.heat.as_ref().map(|h| {
            let t: Vec<f64> = origins
                .iter()
                .map(|o| o.interpolate(h.temperatures()))
                .collect();
            let d: Vec<f64> = origins.iter().map(|o| o.interpolate(h.damage())).collect();
            (t, d)
        });
        let parts = match pieces(&cut.mesh) {
            Ok(p) => p,
            Err(e) => return skip(self, format!("its pieces: {e}")),
        };
        let mut build_us = 0.0;
        let settings = self.body.settings().clone();
        let old_volumes = lumped_volumes(&self.mesh);
        let held = held_axes(&settings.boundary, self.mesh.node_count());
        let origin = self.cut.as_ref().map_or_else(
            || (self.name.clone(), self.mesh.volume(), 0),
            |c| (c.origin.clone(), c.origin_volume, c.cuts),
        );
        // The body keeps the piece with most fixed nodes, then the largest.
        let fixed_count = |p: &crate::mesh::pieces::Piece| {
            p.nodes
                .iter()
                .filter(|&&n| fixed_axes(&held, &origins[n as usize]).is_some())
                .count()
        };
        let keep = (0..parts.len())
            .max_by(|&a, &b| {
                (fixed_count(&parts[a]), parts[a].mesh.volume())
                    .partial_cmp(&(fixed_count(&parts[b]), parts[b].mesh.volume()))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .unwrap_or(0);
        let mut order: Vec<usize> = vec![keep];
        order.extend((0..parts.len()).filter(|&k| k != keep));
        let mut built = Vec::with_capacity(parts.len());
        let mut node_map = vec![(u32::MAX, u32::MAX); self.mesh.node_count()];
        for (slot, &k) in order.iter().enumerate() {
            let part = &parts[k];
            let rest: Vec<Vec3> = part.nodes.iter().map(|&n| rest_all[n as usize]).collect();
            let corners: Vec<[usize; 4]> = part
                .mesh
                .tets()
                .iter()
                .map(|t| t.map(|i| i as usize))
                .collect();
            let mesh = match TetMesh::new(rest, corners) {
                Ok(m) => m,
                Err(e) => return skip(self, format!("a piece's rest shape: {e}")),
            };
            if mesh
                .warnings()
                .iter()
                .any(|w| matches!(w, crate::mesh::MeshWarning::Reoriented { .. }))
            {
                return skip(self, "a piece's rest tetrahedron would be inverted".into());
            }
            let new_volumes = lumped_volumes(&mesh);
            let mut piece_settings = settings.clone();
            // Masses are given per body: each piece takes its share by volume.
            let share = mesh.volume() / self.mesh.volume();
            piece_settings.fem.mass *= share;
            piece_settings.msd.mass *= share;
            piece_settings.cage_msd.mass *= share;
            // The MSD's damping is per node: the same damping rate on nodes of the piece's
            // mass (its share of the mass over its nodes, against the body's per node).
            let per_node = share * self.mesh.node_count() as f64 / mesh.node_count() as f64;
            piece_settings.msd.damping *= per_node;
            piece_settings.cage_msd.damping *= share;
            piece_settings.boundary = carried_boundary(
                &settings.boundary,
                &held,
                origins,
                &part.nodes,
                &old_volumes,
                &new_volumes,
            );
            let heat = self.heat.as_ref().map(|h| {
                let fixed = carried_heat_boundary(
                    &self.heat_boundary,
                    origins,
                    &part.nodes,
                    self.mesh.node_count(),
                );
                (*h.params(), fixed)
            });
            let name = if slot == 0 {
                self.name.clone()
            } else {
                format!("{}.{}", self.name, self.pieces_made + slot)
            };
            let building = std::time::Instant::now();
            let mut body = match SimBody::build(name, Arc::new(mesh), piece_settings, heat, false) {
                Ok(b) => b,
                Err(e) => return skip(self, format!("building a piece: {e}")),
            };
            build_us += building.elapsed().as_secs_f64() * 1e6;
            let xp: Vec<Vec3> = part.nodes.iter().map(|&n| x_all[n as usize]).collect();
            let vp: Vec<Vec3> = part.nodes.iter().map(|&n| v_all[n as usize]).collect();
            body.body
                .pin(self.body.pinned())
                .map_err(|e| body.precision_err(e))?;
            body.body
                .start_precise(&xp, &vp)
                .map_err(|e| body.precision_err(e))?;
            if let (Some(h), Some((t, d))) = (body.heat.as_mut(), heat_all.as_ref()) {
                let nodes = &part.nodes;
                let r = h
                    .set_temperatures(|i| t[nodes[i] as usize])
                    .and_then(|_| h.set_damage(|i| d[nodes[i] as usize]));
                r.map_err(|source| WorldError::Heat {
                    body: body.label(),
                    source,
                })?;
            }
            body.friction = self.friction;
            // What was set at run time beyond the settings.
            body.body
                .set_precise_cg_must_converge(self.body.cg_must_converge());
            if self.body.has_shadow() {
                body.set_shadow(true)?;
            }
            let history = crate::mesh::cut::CutHistory {
                sides: part
                    .tets
                    .iter()
                    .map(|&t| cut.history.sides[t as usize])
                    .collect(),
                on_blade: part
                    .nodes
                    .iter()
                    .map(|&n| cut.history.on_blade[n as usize])
                    .collect(),
            };
            body.cut = Some(CutRecord {
                origin: origin.0.clone(),
                origin_volume: origin.1,
                cuts: origin.2 + 1,
                ..CutRecord::default()
            });
            body.finish_cut_record(history);
            body.collider.gather(body.body.node_positions());
            body.start.copy_from_slice(body.collider.positions());
            body.write_surface()?;
            for (local, &n) in part.nodes.iter().enumerate() {
                if let Some(o) = single_node(&origins[n as usize]) {
                    let slot_map = &mut node_map[o as usize];
                    if slot_map.0 == u32::MAX {
                        *slot_map = (slot as u32, local as u32);
                    }
                }
            }
            built.push(body);
        }
        let whole_us = started.elapsed().as_secs_f64() * 1e6;
        for b in &mut built {
            if let Some(r) = b.cut.as_mut() {
                r.mesh_us = whole_us - build_us;
                r.build_us = build_us;
            }
        }
        let mut built = built.into_iter();
        let kept = built.next().expect("a cut leaves at least one piece");
        let made = self.pieces_made + order.len() - 1;
        let loose = self.loose;
        let previous = Box::new(std::mem::replace(self, kept));
        self.pieces_made = made;
        self.loose = loose;
        let mut pieces: Vec<SimBody> = built.collect();
        for p in &mut pieces {
            p.loose = true;
        }
        Ok(BladeOutcome::Cut(Box::new(BladeCut {
            separated: cut.separated,
            bisected: cut.bisected,
            pieces,
            node_map,
            previous,
        })))
    }

    /// Whether the blade's bounds meet the body's (a cheap test before the cut).
    fn blade_reaches(&self, blade: &[CutTriangle]) -> bool {
        let Some(b) = crate::mesh::Aabb::from_points(self.body.node_positions()) else {
            return false;
        };
        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        for t in blade {
            for c in &t.corners {
                lo = lo.inf(c);
                hi = hi.sup(c);
            }
        }
        (0..3).all(|a| lo[a] <= b.max[a] && hi[a] >= b.min[a])
    }

    /// Fills the record's per-face and per-body figures from `sides`.
    fn finish_cut_record(&mut self, history: crate::mesh::cut::CutHistory) {
        let sides = &history.sides;
        let surface = self.mesh.surface();
        let p = self.mesh.positions();
        let mut faces = Vec::new();
        let mut area = 0.0;
        for (k, &(t, corner)) in surface.triangle_tets().iter().enumerate() {
            if sides[t as usize][corner as usize] {
                faces.push(k as u32);
                let [a, b, c] = surface.triangles()[k].map(|i| p[i as usize]);
                area += 0.5 * (b - a).cross(&(c - a)).norm();
            }
        }
        let mut smallest = f64::INFINITY;
        for tet in self.mesh.tets() {
            let corners = tet.map(|i| p[i as usize]);
            for a in crate::mesh::tet_dihedral_angles(&corners) {
                smallest = smallest.min(a);
            }
        }
        let closed = surface_closed(surface.triangles());
        if let Some(r) = self.cut.as_mut() {
            r.history = history;
            r.surface_faces = faces;
            r.area = area;
            r.smallest_dihedral_deg = smallest;
            r.closed = closed;
        }
    }
}

/// Grips of `tools` on body `body` follow a cut of it (`node_map` of its [`BladeCut`]; the
/// cut's pieces are added as bodies from index `first_piece` on). A grip on a node the cut
/// did not keep as it was is let go. `bodies` are the bodies after the pieces were added.
pub fn remap_grips<T: BorrowMut<Tool>, B: Borrow<SimBody>>(
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
fn surface_closed(triangles: &[[u32; 3]]) -> bool {
    let mut edges: Vec<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        if j - i != 2 {
            return false;
        }
        i = j;
    }
    true
}

/// A quarter of the volume of every tetrahedron around each node.
fn lumped_volumes(mesh: &TetMesh) -> Vec<f64> {
    let mut out = vec![0.0; mesh.node_count()];
    for (t, v) in mesh.tets().iter().zip(mesh.tet_volumes()) {
        for &i in t {
            out[i as usize] += 0.25 * v.abs();
        }
    }
    out
}

/// The node an origin is, when it is one node of the mesh before as it was.
fn single_node(o: &NodeOrigin) -> Option<u32> {
    (o.weights[0] == 1.0).then_some(o.nodes[0])
}

/// The axes a boundary holds at each of `n` nodes.
fn held_axes(b: &Boundary, n: usize) -> Vec<[bool; 3]> {
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

/// The axes held at a new node: those held at every node it was made from.
fn fixed_axes(held: &[[bool; 3]], o: &NodeOrigin) -> Option<[bool; 3]> {
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
fn carried_boundary(
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
fn carried_heat_boundary(
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
