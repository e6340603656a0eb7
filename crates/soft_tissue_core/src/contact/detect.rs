//! Detection: broad phase over body bounds, vertex against triangle between bodies on cached
//! candidates, and body surfaces against rigid shapes (tool parts, obstacles).

use nalgebra::Point3;

use super::rigid::{Pose, RigidShape, ShapeHit};
use super::{ContactConfig, Grip, SurfaceCollider, Tool, overlaps};
use crate::Vec3;
use crate::geometry::{closest_on_segment, closest_on_triangle};

/// A surface point of a body against a tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolContact {
    /// Tool index.
    pub tool: u32,
    /// Part of the tool (0, or 1 for a grasper's second jaw).
    pub part: u8,
    /// Body index.
    pub body: u32,
    /// Surface vertices (collider indices) of the touched triangle.
    pub vertices: [u32; 3],
    /// Weights of the touching point in the triangle.
    pub weights: [f64; 3],
    /// Unit normal of the tool's surface at the point (the way the tool pushes).
    pub normal: Vec3,
    /// Penetration into the tool (negative: within the margin, not touching).
    pub depth: f64,
}

/// A surface vertex of body `a` against a triangle of body `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyContact {
    /// Body of the vertex.
    pub a: u32,
    /// Surface vertex of `a` (collider index).
    pub vertex: u32,
    /// Body of the triangle.
    pub b: u32,
    /// Triangle vertices (collider indices of `b`).
    pub vertices: [u32; 3],
    /// Weights of the closest point in the triangle.
    pub weights: [f64; 3],
    /// Unit outward normal of `b` at the contact (the way the vertex must move).
    pub normal: Vec3,
    /// `thickness - signed distance`: positive when closer than the thickness.
    pub depth: f64,
}

/// Overlapping body pairs by sweep and prune along x over bounds grown by `grow` (pairs
/// `(i, j)` with `i < j`, in a deterministic order).
pub fn broad_phase(
    bounds: &[(Vec3, Vec3)],
    grow: f64,
    order: &mut Vec<u32>,
    out: &mut Vec<(u32, u32)>,
) {
    out.clear();
    order.clear();
    order.extend(0..bounds.len() as u32);
    order.sort_by(|&i, &j| {
        bounds[i as usize]
            .0
            .x
            .total_cmp(&bounds[j as usize].0.x)
            .then(i.cmp(&j))
    });
    for (k, &i) in order.iter().enumerate() {
        let bi = &bounds[i as usize];
        for &j in &order[k + 1..] {
            let bj = &bounds[j as usize];
            if bj.0.x - grow > bi.1.x + grow {
                break;
            }
            if overlaps(bi, bj, grow) {
                out.push((i.min(j), i.max(j)));
            }
        }
    }
    out.sort_unstable();
}

/// The body-body reach of a narrow phase with `margin`: the deepest penetration looked for,
/// or the contact distance when that is larger.
pub fn pair_reach(config: &ContactConfig, margin: f64) -> f64 {
    config.search_radius.max(config.thickness + margin)
}

/// The surface vertices of two bodies that may touch, kept from step to step.
///
/// A vertex of `a` is a candidate when it was within `reach + slack` of `b`'s surface (and
/// the other way round) when the list was built. The unsigned distance between a vertex and a
/// surface changes by at most how far the two moved, so while the two colliders'
/// [`SurfaceCollider::travel`] grew by less than `slack` together, every vertex within
/// `reach` of the other body is in the list: the narrow phase then looks at the candidates
/// only, in detection and again in the response after the solvers. The list is rebuilt when
/// the travel exceeds the slack, or when either body is a different one (identified by
/// [`SurfaceCollider::id`]).
#[derive(Debug, Clone, Default)]
pub struct PairCandidates {
    ids: (u64, u64),
    travel: (f64, f64),
    slack: f64,
    reach: f64,
    valid: bool,
    /// Candidate vertices of `a` (near `b`) and of `b` (near `a`), collider indices.
    near: [Vec<u32>; 2],
    rebuilds: u64,
}

impl PairCandidates {
    /// Makes the lists valid for the colliders' current positions, rebuilding them when they
    /// are stale. `reach` is the narrow phase's reach ([`pair_reach`]), `slack` how much the
    /// two bodies may move before the lists are rebuilt.
    pub fn update(&mut self, a: &SurfaceCollider, b: &SurfaceCollider, reach: f64, slack: f64) {
        let moved = (a.travel() - self.travel.0) + (b.travel() - self.travel.1);
        let fresh = self.valid
            && self.ids == (a.id(), b.id())
            && reach <= self.reach
            && moved <= self.slack;
        if fresh {
            return;
        }
        let radius = reach + slack;
        for (list, (x, y)) in self.near.iter_mut().zip([(a, b), (b, a)]) {
            list.clear();
            let (lo, hi) = y.bounds();
            let grow = Vec3::repeat(radius);
            let (lo, hi) = (lo - grow, hi + grow);
            for (v, p) in x.positions().iter().enumerate() {
                if (0..3).any(|k| !(p[k] >= lo[k] && p[k] <= hi[k])) {
                    continue;
                }
                if y.within(p, radius) {
                    list.push(v as u32);
                }
            }
        }
        self.ids = (a.id(), b.id());
        self.travel = (a.travel(), b.travel());
        self.slack = slack;
        self.reach = reach;
        // A body with non-finite positions has infinite travel: never trust a list then.
        self.valid = self.travel.0.is_finite() && self.travel.1.is_finite();
        self.rebuilds += 1;
    }

    /// Marks the lists stale (the next [`PairCandidates::update`] rebuilds them), keeping
    /// their room.
    pub fn invalidate(&mut self) {
        self.valid = false;
    }

    /// Candidate vertices of `a` near `b` (`side` 0) or of `b` near `a` (`side` 1).
    pub fn near(&self, side: usize) -> &[u32] {
        &self.near[side]
    }

    /// How many times the lists were built.
    pub fn rebuilds(&self) -> u64 {
        self.rebuilds
    }
}

/// Candidate vertices `candidates` of `a` against the surface of `b`: appends contacts
/// closer than `thickness + margin` (depth > -margin) found within `reach` (at least
/// [`pair_reach`]; more when the bodies moved far in the step, so a fast vertex deep inside
/// is still found).
#[allow(clippy::too_many_arguments)]
pub fn detect_candidates(
    ia: u32,
    a: &SurfaceCollider,
    candidates: &[u32],
    ib: u32,
    b: &SurfaceCollider,
    config: &ContactConfig,
    margin: f64,
    reach: f64,
    out: &mut Vec<BodyContact>,
) {
    for &v in candidates {
        let p = a.positions()[v as usize];
        out.extend(vertex_contact(ia, a, v, &p, ib, b, config, reach, margin));
    }
}

/// Vertex `v` of body `ia` at `p` against the surface of `b` within `reach`: the contact when
/// it is closer than `thickness + margin`.
#[allow(clippy::too_many_arguments)]
fn vertex_contact(
    ia: u32,
    a: &SurfaceCollider,
    v: u32,
    p: &Vec3,
    ib: u32,
    b: &SurfaceCollider,
    config: &ContactConfig,
    reach: f64,
    margin: f64,
) -> Option<BodyContact> {
    let hit = b.closest(p, reach)?;
    let depth = config.thickness - hit.distance;
    // Two surfaces that face the same way do not press on each other: a vertex on the edge of
    // a face lying in the plane of the other body's side (two blocks side by side, their
    // sides flush) is at distance zero from that side, and its row would ask each body to
    // stay `thickness` beyond the other's side, which no forces can meet (the forces grow
    // without bound). The other rows of the pair (facing surfaces) hold the contact.
    if a.vertex_normal(v as usize).dot(&hit.normal) > SAME_FACING {
        return None;
    }
    (depth > -margin).then(|| BodyContact {
        a: ia,
        vertex: v,
        b: ib,
        vertices: b.triangles()[hit.triangle as usize],
        weights: hit.weights,
        normal: hit.normal,
        depth,
    })
}

/// A vertex whose normal is within 60 degrees of the normal of the surface it is found
/// against faces the same way as that surface (see [`vertex_contact`]).
const SAME_FACING: f64 = 0.5;

/// Every vertex of `a` against the surface of `b` (call both ways for a pair). Appends
/// contacts closer than `thickness + margin` (depth > -margin). The reference the cached
/// narrow phase ([`PairCandidates`], [`detect_candidates`]) is checked against.
pub fn detect_pair(
    ia: u32,
    a: &SurfaceCollider,
    ib: u32,
    b: &SurfaceCollider,
    config: &ContactConfig,
    margin: f64,
    out: &mut Vec<BodyContact>,
) {
    let reach = pair_reach(config, margin);
    let (lo, hi) = b.bounds();
    let grow = Vec3::repeat(reach);
    let (lo, hi) = (lo - grow, hi + grow);
    for (v, p) in a.positions().iter().enumerate() {
        if (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]) {
            continue;
        }
        out.extend(vertex_contact(
            ia, a, v as u32, p, ib, b, config, reach, margin,
        ));
    }
}

/// Closest points of a triangle and a segment, by alternating projections (the sets are
/// convex, so this converges; eight rounds are plenty for contact).
pub(crate) fn triangle_segment_closest(
    tri: &[Vec3; 3],
    s0: &Vec3,
    s1: &Vec3,
) -> ([f64; 3], Vec3, Vec3) {
    let centroid = (tri[0] + tri[1] + tri[2]) / 3.0;
    let mut s = s0 + (s1 - s0) * closest_on_segment(&centroid, s0, s1);
    let mut w = closest_on_triangle(&s, &tri[0], &tri[1], &tri[2]);
    let mut q = tri[0] * w[0] + tri[1] * w[1] + tri[2] * w[2];
    if s0 != s1 {
        for _ in 0..8 {
            s = s0 + (s1 - s0) * closest_on_segment(&q, s0, s1);
            w = closest_on_triangle(&s, &tri[0], &tri[1], &tri[2]);
            q = tri[0] * w[0] + tri[1] * w[1] + tri[2] * w[2];
        }
    }
    (w, q, s)
}

/// A surface point against a rigid shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeContact {
    /// Surface vertices (collider indices): a vertex (weights `[1, 0, 0]`) or a triangle.
    pub vertices: [u32; 3],
    /// Weights of the point.
    pub weights: [f64; 3],
    /// Unit outward normal of the shape there (the way the surface is pushed).
    pub normal: Vec3,
    /// Signed distance from the shape (negative: inside).
    pub distance: f64,
}

/// The surface of `body` against a rigid `shape` at `pose`: every surface vertex within
/// `margin` of it (or inside), and for a round shape (sphere, capsule) narrower than a
/// triangle's longest edge, that triangle when its closest point to the shape's core is
/// within the margin and lies on an edge or inside the triangle (a vertex's point is the
/// vertex's own contact): a thin tool pressed between vertices, or into the faces around a
/// vertex it holds, meets the faces. A shape wider than the triangles meets the vertices only
/// (node to rigid surface: the faces between them are the mesh's chords of the surface).
/// `triangles` is a workspace. Appends to `out`.
pub fn detect_shape(
    shape: &RigidShape,
    pose: &Pose,
    body: &SurfaceCollider,
    margin: f64,
    triangles: &mut Vec<u32>,
    out: &mut Vec<ShapeContact>,
) {
    let bounds = super::rigid::world_bounds(shape, pose);
    let g = Vec3::repeat(margin);
    let (lo, hi) = (bounds.0 - g, bounds.1 + g);
    if !overlaps(&(lo, hi), &body.bounds(), 0.0) {
        return;
    }
    let first = out.len();
    let positions = body.positions();
    let query = |p: &Vec3| -> Option<ShapeHit> {
        let local = pose.inverse_transform_point(&Point3::from(*p)).coords;
        shape.query(&local, margin)
    };
    // Vertices: the box of the shape first (cheap), then the shape.
    for (v, p) in positions.iter().enumerate() {
        if (0..3).any(|k| !(p[k] >= lo[k] && p[k] <= hi[k])) {
            continue;
        }
        if let Some(h) = query(p) {
            out.push(ShapeContact {
                vertices: [v as u32; 3],
                weights: [1.0, 0.0, 0.0],
                normal: pose.rotation * h.normal,
                distance: h.distance,
            });
        }
    }
    let Some((a, b, radius)) = shape.core() else {
        return;
    };
    let (s0, s1) = (
        pose.transform_point(&Point3::from(a)).coords,
        pose.transform_point(&Point3::from(b)).coords,
    );
    body.triangles_in(&lo, &hi, triangles);
    let found = first..out.len();
    for &t in triangles.iter() {
        let tri_idx = body.triangles()[t as usize];
        let tri = tri_idx.map(|i| positions[i as usize]);
        // A shape wider than the triangle cannot pass between its vertices: the vertices
        // meet it (node to rigid surface, whose chord between vertices is the mesh's own
        // approximation of the surface). Meeting the faces too would tent them over it.
        let longest = (0..3)
            .map(|k| (tri[(k + 1) % 3] - tri[k]).norm_squared())
            .fold(0.0, f64::max)
            .sqrt();
        if radius >= longest {
            continue;
        }
        let (w, q, s) = triangle_segment_closest(&tri, &s0, &s1);
        // A point at a vertex is the vertex's (found above if it is near).
        if w.iter().any(|&x| x > 1.0 - 1e-9) {
            continue;
        }
        let d = (q - s).norm();
        if d - radius > margin {
            continue;
        }
        let normal = if d > 1e-12 * (1.0 + q.norm()) {
            (q - s) / d
        } else {
            body.face_normal(t as usize)
        };
        out.push(ShapeContact {
            vertices: tri_idx,
            weights: w,
            normal,
            distance: d - radius,
        });
    }
    // Two triangles share an edge point: keep one.
    let tail = &mut out[found.end..];
    tail.sort_unstable_by_key(edge_key);
    let mut keep = found.end;
    for k in found.end..out.len() {
        let key = edge_key(&out[k]);
        let on_edge = key[2] == u32::MAX;
        if !(on_edge && keep > found.end && edge_key(&out[keep - 1]) == key) {
            out[keep] = out[k];
            keep += 1;
        }
    }
    out.truncate(keep);
}

/// A triangle contact's identity: the vertices with a weight, sorted (`u32::MAX` after
/// them: a point on an edge has two).
fn edge_key(c: &ShapeContact) -> [u32; 3] {
    let mut key = [u32::MAX; 3];
    let mut n = 0;
    for k in 0..3 {
        if c.weights[k] > 1e-9 {
            key[n] = c.vertices[k];
            n += 1;
        }
    }
    key[..n].sort_unstable();
    key
}

/// The surface of `body` against every part of tool `it` within the tool's radius plus
/// `margin`: for the start-of-step detection (who is touched, cautery, the haptic contact
/// model). `triangles` and `scratch` are workspaces. Appends to `out`.
#[allow(clippy::too_many_arguments)]
pub fn detect_tool(
    it: u32,
    tool: &Tool,
    ib: u32,
    body: &SurfaceCollider,
    margin: f64,
    triangles: &mut Vec<u32>,
    scratch: &mut Vec<ShapeContact>,
    out: &mut Vec<ToolContact>,
) {
    for k in 0..tool.shape().parts() {
        scratch.clear();
        detect_shape(
            &tool.part_shape(k),
            &tool.part_pose(k),
            body,
            margin,
            triangles,
            scratch,
        );
        out.extend(scratch.iter().map(|c| ToolContact {
            tool: it,
            part: k as u8,
            body: ib,
            vertices: c.vertices,
            weights: c.weights,
            normal: c.normal,
            depth: -c.distance,
        }));
    }
}

/// Surface vertices of `body` a pick tool grabs: those within `margin` of the tool (any
/// part), with their offsets from the tool position in the tool's frame.
pub fn grab_vertices(tool: &Tool, ib: u32, body: &SurfaceCollider, margin: f64) -> Vec<Grip> {
    let inverse = tool.rotation().inverse();
    body.positions()
        .iter()
        .enumerate()
        .filter(|(_, p)| tool_distance(tool, p).0 <= margin)
        .map(|(v, p)| Grip {
            body: ib,
            node: body.nodes()[v],
            vertex: v as u32,
            offset: inverse * (p - tool.position()),
        })
        .collect()
}

/// Distance from `p` to the tool's surface (negative inside, the nearest part), and the
/// unit outward normal there.
pub fn tool_distance(tool: &Tool, p: &Vec3) -> (f64, Vec3) {
    let mut best = (f64::INFINITY, -tool.axis());
    for k in 0..tool.shape().parts() {
        let pose = tool.part_pose(k);
        let local = pose.inverse_transform_point(&Point3::from(*p)).coords;
        if let Some(h) = tool.part_shape(k).query(&local, f64::INFINITY)
            && h.distance < best.0
        {
            best = (h.distance, pose.rotation * h.normal);
        }
    }
    best
}
