//! Contact between bodies and between tools and bodies.
//!
//! - **Surfaces.** Each body has a [`SurfaceCollider`]: its boundary triangles, positions
//!   gathered from the body, the inside/outside test by pseudo-normals (Baerentzen and Aanaes
//!   2005) made right at non-manifold edges and vertices too (triangles paired through the
//!   tetrahedra around each edge, one vertex normal per sheet; see [`surface`]'s docs),
//!   normals computed only where a query lands, and a bounding-volume hierarchy of the
//!   triangles (parry3d's `Bvh`) whose leaf boxes are grown by a slack so that a move updates
//!   only the leaves of vertices that left them. parry works in `f32` on glam 0.33; the
//!   conversion is [`to_parry_aabb`], the only crossing point, which rounds outward so no
//!   candidate is lost.
//! - **Broad phase.** Sweep and prune on x over body bounds grown by the search radius
//!   ([`broad_phase`]); tools test their own bounds against each body's. Pairs whose bounds
//!   do not overlap cost nothing further.
//! - **Narrow phase.** Vertex against triangle, both ways: each surface vertex of one body
//!   near the other is projected on the other's nearest triangle (a pruned descent of the
//!   hierarchy within [`ContactConfig::search_radius`]); its signed distance from the
//!   pseudo-normal decides contact. Only the [`PairCandidates`] of a pair are projected: the
//!   vertices that were within the reach plus a slack when the list was built, kept while
//!   the two bodies have moved less than the slack since ([`SurfaceCollider::travel`]).
//!   [`detect_pair`] projects every vertex (the reference). Tools ([`detect_tool`]) are
//!   spheres or capsules: every triangle near the tool gets its closest point to the tool's
//!   core segment.
//! - **Response** is positional (after the solvers move the bodies, on the same candidates):
//!   penetrating points are moved out along the contact normal, split between the two sides
//!   in proportion to their inverse masses (so momentum is kept), and the approaching part of
//!   the relative normal velocity is removed (perfectly inelastic, so contact never adds
//!   kinetic energy). A body at the cage level takes the correction as forces on its cage
//!   (through the transpose of its coordinates) and is treated as immovable by the other side.
//!   The force on a tool is the tissue's reaction, estimated from the corrections as
//!   `m dx / dt^2` (the force that would have made the correction in one step).

pub mod surface;

pub use surface::{SurfaceCollider, SurfaceHit};

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::geometry::{closest_on_segment, closest_on_triangle};

/// Contact settings, in scene units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactConfig {
    /// Bodies are kept this far apart (a skin that absorbs round-off and the f32 rendering).
    pub thickness: f64,
    /// Deepest penetration the narrow phase looks for.
    pub search_radius: f64,
    /// A tool this close to a body counts as touching it (raises it early); 0 for contact only.
    pub tool_margin: f64,
    /// Bodies this close count as touching for the switch (before they overlap).
    pub body_margin: f64,
}

impl ContactConfig {
    /// Defaults for a scene whose bodies are about `scale` across: thickness 0.2 %, search
    /// radius 5 %, tool and body margins 0.5 %.
    pub fn for_scale(scale: f64) -> Self {
        ContactConfig {
            thickness: 0.002 * scale,
            search_radius: 0.05 * scale,
            tool_margin: 0.005 * scale,
            body_margin: 0.005 * scale,
        }
    }

    /// Checks every field is finite and not negative, the search radius positive.
    pub fn validate(&self) -> Result<(), ContactError> {
        let fields = [
            ("thickness", self.thickness),
            ("search_radius", self.search_radius),
            ("tool_margin", self.tool_margin),
            ("body_margin", self.body_margin),
        ];
        for (field, value) in fields {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ContactError::BadParameter { field, value });
            }
        }
        if self.search_radius <= 0.0 {
            return Err(ContactError::BadParameter {
                field: "search_radius",
                value: self.search_radius,
            });
        }
        Ok(())
    }
}

/// A failure of the contact code.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContactError {
    /// A parameter is negative, zero where it must not be, or not finite.
    #[error("contact parameter `{field}` = {value} is out of range")]
    BadParameter {
        /// Field name.
        field: &'static str,
        /// Value given.
        value: f64,
    },
    /// A boundary triangle has no partner across one of its edges (a mesh that passed
    /// validation always has one; this names the triangle if it does not).
    #[error("surface triangle {triangle}: {reason}")]
    BadSurface {
        /// Triangle index (surface order).
        triangle: usize,
        /// What is wrong.
        reason: String,
    },
    /// A tool pose or setting is not finite or out of range.
    #[error("tool `{tool}`: {what} is invalid ({value})")]
    BadTool {
        /// Tool name.
        tool: String,
        /// What is wrong.
        what: &'static str,
        /// Offending value (a norm for vectors).
        value: f64,
    },
}

/// Converts bounds to parry's `f32` boxes, rounding outward. The one place where parry's
/// glam 0.33 types meet the `f64` nalgebra types of the core.
pub fn to_parry_aabb(min: &Vec3, max: &Vec3) -> ParryAabb {
    let down = |x: f64| {
        let f = x as f32;
        if (f as f64) > x { f.next_down() } else { f }
    };
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x { f.next_up() } else { f }
    };
    ParryAabb::new(
        ParryVector::new(down(min.x), down(min.y), down(min.z)),
        ParryVector::new(up(max.x), up(max.y), up(max.z)),
    )
}

fn overlaps(a: &(Vec3, Vec3), b: &(Vec3, Vec3), grow: f64) -> bool {
    (0..3).all(|k| a.0[k] - grow <= b.1[k] && b.0[k] - grow <= a.1[k])
}

/// Shape of a tool's tip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ToolShape {
    /// A ball of `radius` centred at the tool position.
    Sphere {
        /// Radius, scene units.
        radius: f64,
    },
    /// A capsule of `radius` around the segment from the tool position along the tool axis
    /// for `length` (the shaft behind the tip).
    Capsule {
        /// Radius, scene units.
        radius: f64,
        /// Segment length, scene units.
        length: f64,
    },
}

impl ToolShape {
    /// Radius of the tip.
    pub fn radius(&self) -> f64 {
        match *self {
            ToolShape::Sphere { radius } | ToolShape::Capsule { radius, .. } => radius,
        }
    }
}

/// A surface node held by a pick tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grip {
    /// Body index.
    pub body: u32,
    /// Node of that body.
    pub node: u32,
    /// Node position minus tool position when grabbed.
    pub offset: Vec3,
}

/// A kinematic tool: pokes (always), picks (after [`Tool::grab`]) and cauterizes (with power
/// set). The caller sets its pose each step; the step returns the reaction force on it.
#[derive(Debug, Clone)]
pub struct Tool {
    name: String,
    shape: ToolShape,
    position: Vec3,
    axis: Vec3,
    last_position: Option<Vec3>,
    velocity: Vec3,
    cautery_watts: f64,
    grab_requested: bool,
    grips: Vec<Grip>,
    reaction: Vec3,
    contacts: u32,
}

impl Tool {
    /// A tool at the origin pointing along +y (shaft upward), idle.
    pub fn new(name: impl Into<String>, shape: ToolShape) -> Result<Self, ContactError> {
        let name = name.into();
        let (radius, length) = match shape {
            ToolShape::Sphere { radius } => (radius, 0.0),
            ToolShape::Capsule { radius, length } => (radius, length),
        };
        if !(radius.is_finite() && radius > 0.0) {
            return Err(ContactError::BadTool {
                tool: name,
                what: "radius (must be > 0)",
                value: radius,
            });
        }
        if !(length.is_finite() && length >= 0.0) {
            return Err(ContactError::BadTool {
                tool: name,
                what: "capsule length (must be >= 0)",
                value: length,
            });
        }
        Ok(Tool {
            name,
            shape,
            position: Vec3::zeros(),
            axis: Vec3::y(),
            last_position: None,
            velocity: Vec3::zeros(),
            cautery_watts: 0.0,
            grab_requested: false,
            grips: Vec::new(),
            reaction: Vec3::zeros(),
            contacts: 0,
        })
    }

    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Shape.
    pub fn shape(&self) -> ToolShape {
        self.shape
    }

    /// Tip position.
    pub fn position(&self) -> Vec3 {
        self.position
    }

    /// Unit shaft axis (from the tip backward).
    pub fn axis(&self) -> Vec3 {
        self.axis
    }

    /// Velocity over the last step.
    pub fn velocity(&self) -> Vec3 {
        self.velocity
    }

    /// Sets the pose for the next step: tip position and shaft axis (any length but zero).
    pub fn set_pose(&mut self, position: Vec3, axis: Vec3) -> Result<(), ContactError> {
        if !position.iter().all(|x| x.is_finite()) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "position (not finite)",
                value: position.norm(),
            });
        }
        let len = axis.norm();
        if !(len.is_finite() && len > 0.0) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "axis (zero or not finite)",
                value: len,
            });
        }
        self.position = position;
        self.axis = axis / len;
        Ok(())
    }

    /// Moves the tip keeping the axis.
    pub fn set_position(&mut self, position: Vec3) -> Result<(), ContactError> {
        self.set_pose(position, self.axis)
    }

    /// Electrocautery power delivered while touching, W (0 turns it off).
    pub fn set_cautery(&mut self, watts: f64) -> Result<(), ContactError> {
        if !(watts.is_finite() && watts >= 0.0) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "cautery power (must be >= 0)",
                value: watts,
            });
        }
        self.cautery_watts = watts;
        Ok(())
    }

    /// Cautery power, W.
    pub fn cautery_watts(&self) -> f64 {
        self.cautery_watts
    }

    /// Grabs the surface under the tip at the next contact stage (nodes within the tip
    /// radius plus the tool margin of the nearest body).
    pub fn grab(&mut self) {
        self.grab_requested = true;
    }

    /// Lets go of whatever is held.
    pub fn release(&mut self) {
        self.grab_requested = false;
        self.grips.clear();
    }

    /// Whether a grab is waiting for the next contact stage.
    pub fn grab_requested(&self) -> bool {
        self.grab_requested
    }

    /// Nodes held.
    pub fn grips(&self) -> &[Grip] {
        &self.grips
    }

    /// Force of the tissue on the tool over the last step.
    pub fn reaction_force(&self) -> Vec3 {
        self.reaction
    }

    /// Triangles touched in the last step.
    pub fn contact_count(&self) -> u32 {
        self.contacts
    }

    /// Core segment (tip, back end).
    pub fn core(&self) -> (Vec3, Vec3) {
        match self.shape {
            ToolShape::Sphere { .. } => (self.position, self.position),
            ToolShape::Capsule { length, .. } => {
                (self.position, self.position + self.axis * length)
            }
        }
    }

    /// Bounds of the tool grown by `grow`.
    pub fn bounds(&self, grow: f64) -> (Vec3, Vec3) {
        let (a, b) = self.core();
        let r = Vec3::repeat(self.shape.radius() + grow);
        (a.inf(&b) - r, a.sup(&b) + r)
    }

    /// Start of a step of `dt`: the velocity from the pose change, the reaction cleared.
    pub fn begin_step(&mut self, dt: f64) {
        self.velocity = match self.last_position {
            Some(last) if dt > 0.0 => (self.position - last) / dt,
            _ => Vec3::zeros(),
        };
        self.last_position = Some(self.position);
        self.reaction = Vec3::zeros();
        self.contacts = 0;
    }

    /// Sets the grips (the contact stage's answer to a grab).
    pub fn take_grips(&mut self, grips: Vec<Grip>) {
        self.grab_requested = false;
        self.grips = grips;
    }

    /// Adds to the reaction force of this step.
    pub fn add_reaction(&mut self, force: Vec3) {
        self.reaction += force;
    }

    /// Drops the reaction force summed so far this step (a failed contact stage).
    pub fn clear_reaction(&mut self) {
        self.reaction = Vec3::zeros();
    }

    /// Counts touched triangles.
    pub fn add_contacts(&mut self, n: u32) {
        self.contacts += n;
    }

    /// Back to idle at the origin (no grips, no cautery).
    pub fn reset(&mut self) {
        self.position = Vec3::zeros();
        self.axis = Vec3::y();
        self.last_position = None;
        self.velocity = Vec3::zeros();
        self.cautery_watts = 0.0;
        self.grab_requested = false;
        self.grips.clear();
        self.reaction = Vec3::zeros();
        self.contacts = 0;
    }
}

/// A surface point of a body against a tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolContact {
    /// Tool index.
    pub tool: u32,
    /// Body index.
    pub body: u32,
    /// Surface vertices (collider indices) of the touched triangle.
    pub vertices: [u32; 3],
    /// Weights of the touching point in the triangle.
    pub weights: [f64; 3],
    /// Unit direction from the tool core to the point (the way the tool pushes).
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
/// closer than `thickness + margin` (depth > -margin) found within `reach` ([`pair_reach`]).
#[allow(clippy::too_many_arguments)]
pub fn detect_candidates(
    ia: u32,
    a: &SurfaceCollider,
    candidates: &[u32],
    ib: u32,
    b: &SurfaceCollider,
    config: &ContactConfig,
    margin: f64,
    out: &mut Vec<BodyContact>,
) {
    let reach = pair_reach(config, margin);
    for &v in candidates {
        let p = a.positions()[v as usize];
        out.extend(vertex_contact(ia, v, &p, ib, b, config, reach, margin));
    }
}

/// Vertex `v` of body `ia` at `p` against the surface of `b` within `reach`: the contact when
/// it is closer than `thickness + margin`.
#[allow(clippy::too_many_arguments)]
fn vertex_contact(
    ia: u32,
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
            ia, v as u32, p, ib, b, config, reach, margin,
        ));
    }
}

/// Closest points of a triangle and a segment, by alternating projections (the sets are
/// convex, so this converges; eight rounds are plenty for contact).
fn triangle_segment_closest(tri: &[Vec3; 3], s0: &Vec3, s1: &Vec3) -> ([f64; 3], Vec3, Vec3) {
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

/// Triangles of `body` within the tool's radius plus `margin`; `triangles` is a workspace.
pub fn detect_tool(
    it: u32,
    tool: &Tool,
    ib: u32,
    body: &SurfaceCollider,
    margin: f64,
    triangles: &mut Vec<u32>,
    out: &mut Vec<ToolContact>,
) {
    let (lo, hi) = tool.bounds(margin);
    if !overlaps(&(lo, hi), &body.bounds(), 0.0) {
        return;
    }
    let (s0, s1) = tool.core();
    let radius = tool.shape.radius();
    body.triangles_in(&lo, &hi, triangles);
    for &t in triangles.iter() {
        let tri_idx = body.triangles()[t as usize];
        let tri = tri_idx.map(|i| body.positions()[i as usize]);
        let (w, q, s) = triangle_segment_closest(&tri, &s0, &s1);
        let d = (q - s).norm();
        let depth = radius - d;
        if depth > -margin {
            let normal = if d > 1e-12 * (1.0 + q.norm()) {
                (q - s) / d
            } else {
                body.face_normal(t as usize)
            };
            out.push(ToolContact {
                tool: it,
                body: ib,
                vertices: tri_idx,
                weights: w,
                normal,
                depth,
            });
        }
    }
}

/// Surface vertices of `body` a pick tool grabs: those within the tip radius plus `margin`
/// of its core, with their offsets from the tool position.
pub fn grab_vertices(tool: &Tool, ib: u32, body: &SurfaceCollider, margin: f64) -> Vec<Grip> {
    let (s0, s1) = tool.core();
    let reach = tool.shape.radius() + margin;
    body.positions()
        .iter()
        .enumerate()
        .filter_map(|(v, p)| {
            let s = s0 + (s1 - s0) * closest_on_segment(p, &s0, &s1);
            ((p - s).norm() <= reach).then(|| Grip {
                body: ib,
                node: body.nodes()[v],
                offset: p - tool.position,
            })
        })
        .collect()
}

/// Distance from `p` to the tool's surface (negative inside), and the unit direction from the
/// core to `p`.
pub fn tool_distance(tool: &Tool, p: &Vec3) -> (f64, Vec3) {
    let (s0, s1) = tool.core();
    let s = s0 + (s1 - s0) * closest_on_segment(p, &s0, &s1);
    let off = p - s;
    let d = off.norm();
    let n = if d > 0.0 { off / d } else { -tool.axis };
    (d - tool.shape.radius(), n)
}
