//! Contact between bodies and between tools and bodies.
//!
//! - **Surfaces.** Each body has a [`SurfaceCollider`]: its boundary triangles, positions
//!   gathered from the body each stage, face normals, angle-weighted vertex normals and edge
//!   pseudo-normals (Baerentzen and Aanaes 2005, so the inside/outside sign is right at edges and
//!   vertices too), and a bounding-volume hierarchy of the triangles (parry3d's `Bvh`, refitted,
//!   not rebuilt, when the body moves). parry works in `f32` on glam 0.33; the conversion is
//!   [`to_parry_aabb`], the only crossing point, which rounds outward so no candidate is lost.
//! - **Broad phase.** Sweep and prune on x over body bounds grown by the search radius
//!   ([`broad_phase`]); tools test their own bounds against each body's.
//! - **Narrow phase.** Vertex against triangle, both ways ([`detect_pair`]): each surface
//!   vertex of one body near the other is projected on the other's nearest triangle (found
//!   through the hierarchy within [`ContactConfig::search_radius`]); its signed distance from
//!   the pseudo-normal decides contact. Tools ([`detect_tool`]) are spheres or capsules: every
//!   triangle near the tool gets its closest point to the tool's core segment.
//! - **Response** is positional (after the solvers move the bodies): penetrating points are
//!   moved out along the contact normal, split between the two sides in proportion to their
//!   inverse masses (so momentum is kept), and the approaching part of the relative normal
//!   velocity is removed (perfectly inelastic, so contact never adds kinetic energy). A body at
//!   the cage level has its cage displaced instead (least-norm cage motion that moves the
//!   points) and is treated as immovable by the other side. The force on a tool is the
//!   tissue's reaction, estimated from the corrections as `m dx / dt^2` (the force that would
//!   have made the correction in one step).

use std::collections::HashMap;

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};
use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::geometry::{closest_on_segment, closest_on_triangle};
use crate::mesh::TetMesh;

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
    /// The body's surface is not a closed 2-manifold, so inside and outside are undefined.
    #[error("body surface edge ({a}, {b}) has {count} triangles (a closed surface has 2)")]
    OpenSurface {
        /// Edge end nodes.
        a: u32,
        /// Edge end nodes.
        b: u32,
        /// Triangles found on it.
        count: usize,
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

fn bounds_of(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    (lo, hi)
}

fn overlaps(a: &(Vec3, Vec3), b: &(Vec3, Vec3), grow: f64) -> bool {
    (0..3).all(|k| a.0[k] - grow <= b.1[k] && b.0[k] - grow <= a.1[k])
}

/// The closest surface point of a body to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    /// Triangle (index into the collider's triangles).
    pub triangle: u32,
    /// Barycentric weights of the closest point in the triangle.
    pub weights: [f64; 3],
    /// The closest point.
    pub point: Vec3,
    /// Signed distance of the query point (negative inside the body).
    pub distance: f64,
    /// Unit outward direction at the contact (from the surface toward a point outside).
    pub normal: Vec3,
}

/// The boundary of one body for contact (see the module docs).
pub struct SurfaceCollider {
    nodes: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    /// Neighbour across edge `k` = (`t[k]`, `t[k + 1]`).
    neighbors: Vec<[u32; 3]>,
    positions: Vec<Vec3>,
    face_normals: Vec<Vec3>,
    vertex_normals: Vec<Vec3>,
    bounds: (Vec3, Vec3),
    bvh: Bvh,
    workspace: BvhWorkspace,
    geometry_fresh: bool,
}

impl std::fmt::Debug for SurfaceCollider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SurfaceCollider")
            .field("vertices", &self.nodes.len())
            .field("triangles", &self.triangles.len())
            .field("bounds", &self.bounds)
            .finish()
    }
}

impl SurfaceCollider {
    /// Builds the collider of `mesh`'s boundary at its rest positions. Fails when the boundary
    /// is not closed (every edge on exactly two triangles).
    pub fn new(mesh: &TetMesh) -> Result<Self, ContactError> {
        let surface = mesh.surface();
        let nodes = surface.vertices().to_vec();
        let triangles = surface.local_triangles().to_vec();
        let mut edges: HashMap<(u32, u32), Vec<(u32, u8)>> = HashMap::new();
        for (t, tri) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                edges
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push((t as u32, k as u8));
            }
        }
        let mut neighbors = vec![[u32::MAX; 3]; triangles.len()];
        let mut keys: Vec<_> = edges.keys().copied().collect();
        keys.sort_unstable();
        for key in keys {
            let list = &edges[&key];
            if list.len() != 2 {
                return Err(ContactError::OpenSurface {
                    a: nodes[key.0 as usize],
                    b: nodes[key.1 as usize],
                    count: list.len(),
                });
            }
            let (t0, k0) = list[0];
            let (t1, k1) = list[1];
            neighbors[t0 as usize][k0 as usize] = t1;
            neighbors[t1 as usize][k1 as usize] = t0;
        }
        let positions: Vec<Vec3> = nodes
            .iter()
            .map(|&i| mesh.positions()[i as usize])
            .collect();
        let leaves: Vec<ParryAabb> = triangles
            .iter()
            .map(|t| {
                let b = bounds_of(t.iter().map(|&i| positions[i as usize]));
                to_parry_aabb(&b.0, &b.1)
            })
            .collect();
        let bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves);
        let n = positions.len();
        let nt = triangles.len();
        let mut collider = SurfaceCollider {
            bounds: bounds_of(positions.iter().copied()),
            nodes,
            triangles,
            neighbors,
            positions,
            face_normals: vec![Vec3::zeros(); nt],
            vertex_normals: vec![Vec3::zeros(); n],
            bvh,
            workspace: BvhWorkspace::default(),
            geometry_fresh: false,
        };
        collider.refresh();
        Ok(collider)
    }

    /// Mesh node of each surface vertex.
    pub fn nodes(&self) -> &[u32] {
        &self.nodes
    }

    /// Triangles, as indices into [`SurfaceCollider::nodes`].
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Surface positions as last gathered.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Bounds of the surface as last gathered.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Copies the surface positions from the body's node positions and updates the bounds;
    /// normals and the hierarchy are refreshed on the next query.
    pub fn gather(&mut self, node_positions: &[Vec3]) {
        for (p, &i) in self.positions.iter_mut().zip(&self.nodes) {
            *p = node_positions[i as usize];
        }
        self.bounds = bounds_of(self.positions.iter().copied());
        self.geometry_fresh = false;
    }

    /// Normals and hierarchy for the current positions (no-op when up to date).
    pub fn refresh(&mut self) {
        if self.geometry_fresh {
            return;
        }
        self.vertex_normals.fill(Vec3::zeros());
        for (t, tri) in self.triangles.iter().enumerate() {
            let p = tri.map(|i| self.positions[i as usize]);
            let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
            let len = n.norm();
            let unit = if len > 0.0 { n / len } else { Vec3::zeros() };
            self.face_normals[t] = unit;
            for k in 0..3 {
                let e1 = p[(k + 1) % 3] - p[k];
                let e2 = p[(k + 2) % 3] - p[k];
                let denom = e1.norm() * e2.norm();
                if denom > 0.0 {
                    let angle = (e1.dot(&e2) / denom).clamp(-1.0, 1.0).acos();
                    self.vertex_normals[tri[k] as usize] += unit * angle;
                }
            }
            let b = bounds_of(p.into_iter());
            self.bvh
                .insert_or_update_partially(to_parry_aabb(&b.0, &b.1), t as u32, 0.0);
        }
        self.bvh.refit(&mut self.workspace);
        self.geometry_fresh = true;
    }

    /// Closest surface point to `p` within `radius`, with its signed distance (negative
    /// inside) from the pseudo-normal of the closest feature. `None` when no triangle is that
    /// close. Call [`SurfaceCollider::refresh`] after [`SurfaceCollider::gather`] first.
    pub fn closest(&self, p: &Vec3, radius: f64) -> Option<SurfaceHit> {
        let r = Vec3::repeat(radius);
        let query = to_parry_aabb(&(p - r), &(p + r));
        let mut best: Option<(f64, u32, [f64; 3], Vec3)> = None;
        for t in self.bvh.intersect_aabb(&query) {
            let tri = self.triangles[t as usize];
            let [a, b, c] = tri.map(|i| self.positions[i as usize]);
            let w = closest_on_triangle(p, &a, &b, &c);
            let q = a * w[0] + b * w[1] + c * w[2];
            let d2 = (p - q).norm_squared();
            let better = match best {
                None => true,
                Some((bd, bt, _, _)) => d2 < bd || (d2 == bd && t < bt),
            };
            if better {
                best = Some((d2, t, w, q));
            }
        }
        let (d2, t, w, q) = best?;
        let d = d2.sqrt();
        if d > radius {
            return None;
        }
        let pseudo = self.pseudo_normal(t as usize, &w);
        let offset = p - q;
        let sign = if offset.dot(&pseudo) < 0.0 { -1.0 } else { 1.0 };
        let normal = if d > 1e-12 * (1.0 + q.norm()) {
            offset * (sign / d)
        } else {
            pseudo
                .try_normalize(0.0)
                .unwrap_or(self.face_normals[t as usize])
        };
        Some(SurfaceHit {
            triangle: t,
            weights: w,
            point: q,
            distance: sign * d,
            normal,
        })
    }

    fn pseudo_normal(&self, t: usize, w: &[f64; 3]) -> Vec3 {
        let tri = self.triangles[t];
        let zeros = w.iter().filter(|&&x| x == 0.0).count();
        match zeros {
            0 => self.face_normals[t],
            1 => {
                // On the edge opposite the zero weight: edge k = (t[k], t[k+1]) with the zero
                // at k + 2.
                let z = w.iter().position(|&x| x == 0.0).unwrap_or(0);
                let k = (z + 1) % 3;
                let nb = self.neighbors[t][k] as usize;
                self.face_normals[t] + self.face_normals[nb]
            }
            _ => {
                let v = w.iter().position(|&x| x != 0.0).unwrap_or(0);
                self.vertex_normals[tri[v] as usize]
            }
        }
    }
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

/// Vertices of `a` against the surface of `b` (call both ways for a pair). Appends contacts
/// closer than `thickness + margin` (depth > -margin). Both colliders must be refreshed.
pub fn detect_pair(
    ia: u32,
    a: &SurfaceCollider,
    ib: u32,
    b: &SurfaceCollider,
    config: &ContactConfig,
    margin: f64,
    out: &mut Vec<BodyContact>,
) {
    let reach = config.search_radius.max(config.thickness + margin);
    let (lo, hi) = b.bounds;
    let grow = Vec3::repeat(reach);
    let (lo, hi) = (lo - grow, hi + grow);
    for (v, p) in a.positions.iter().enumerate() {
        if (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]) {
            continue;
        }
        let Some(hit) = b.closest(p, reach) else {
            continue;
        };
        let depth = config.thickness - hit.distance;
        if depth > -margin {
            out.push(BodyContact {
                a: ia,
                vertex: v as u32,
                b: ib,
                vertices: b.triangles[hit.triangle as usize],
                weights: hit.weights,
                normal: hit.normal,
                depth,
            });
        }
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

/// Triangles of `body` within the tool's radius plus `margin`. The collider must be refreshed.
pub fn detect_tool(
    it: u32,
    tool: &Tool,
    ib: u32,
    body: &SurfaceCollider,
    margin: f64,
    out: &mut Vec<ToolContact>,
) {
    let (lo, hi) = tool.bounds(margin);
    if !overlaps(&(lo, hi), &body.bounds, 0.0) {
        return;
    }
    let (s0, s1) = tool.core();
    let radius = tool.shape.radius();
    let query = to_parry_aabb(&lo, &hi);
    let mut found: Vec<u32> = body.bvh.intersect_aabb(&query).collect();
    found.sort_unstable();
    for t in found {
        let tri_idx = body.triangles[t as usize];
        let tri = tri_idx.map(|i| body.positions[i as usize]);
        let (w, q, s) = triangle_segment_closest(&tri, &s0, &s1);
        let d = (q - s).norm();
        let depth = radius - d;
        if depth > -margin {
            let normal = if d > 1e-12 * (1.0 + q.norm()) {
                (q - s) / d
            } else {
                body.face_normals[t as usize]
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
    body.positions
        .iter()
        .enumerate()
        .filter_map(|(v, p)| {
            let s = s0 + (s1 - s0) * closest_on_segment(p, &s0, &s1);
            ((p - s).norm() <= reach).then(|| Grip {
                body: ib,
                node: body.nodes[v],
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
