//! Rigid things bodies touch: the shapes of tools and static obstacles (a table, a bone, an
//! instrument port), where they are, and what surface friction they have.
//!
//! Shapes are queried in `f64` in their own frame: spheres and capsules around a core segment,
//! boxes, planes (a half-space) and closed triangle meshes. A mesh is a parry3d `TriMesh`
//! with oriented pseudo-normals, so a point knows whether it is inside (parry works in `f32`:
//! a mesh obstacle answers to `f32` precision, about 1e-7 of its size).

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use parry3d::math::Vector as ParryVector;
use parry3d::query::{PointQuery, PointQueryWithLocation};
use parry3d::shape::{TriMesh, TriMeshFlags};
use serde::{Deserialize, Serialize};

use super::ContactError;
use crate::Vec3;
use crate::geometry::closest_on_segment;

/// How two surfaces' friction coefficients combine (as in Avian and PhysX: when the two
/// rules differ, the one with the higher priority wins, `Max` > `Multiply` > `Min` >
/// `Average`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum FrictionCombine {
    /// The mean of the two (the default).
    #[default]
    Average,
    /// The smaller.
    Min,
    /// The product.
    Multiply,
    /// The larger.
    Max,
}

impl FrictionCombine {
    fn priority(self) -> u8 {
        match self {
            FrictionCombine::Average => 0,
            FrictionCombine::Min => 1,
            FrictionCombine::Multiply => 2,
            FrictionCombine::Max => 3,
        }
    }

    fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            FrictionCombine::Average => 0.5 * (a + b),
            FrictionCombine::Min => a.min(b),
            FrictionCombine::Multiply => a * b,
            FrictionCombine::Max => a.max(b),
        }
    }
}

/// Coulomb friction of a surface (a body, a tool or an obstacle). Dimensionless.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct Friction {
    /// Coefficient while a contact sticks (the largest tangential force per normal force
    /// before it slides). At least the kinetic one.
    pub static_coefficient: f64,
    /// Coefficient while a contact slides.
    pub kinetic_coefficient: f64,
    /// How it combines with the other surface's.
    #[serde(default)]
    pub combine: FrictionCombine,
}

impl Default for Friction {
    /// Wet soft tissue: static 0.2, kinetic 0.15, averaged.
    fn default() -> Self {
        Friction {
            static_coefficient: 0.2,
            kinetic_coefficient: 0.15,
            combine: FrictionCombine::Average,
        }
    }
}

impl Friction {
    /// One coefficient, static and kinetic, averaged with the other surface's.
    pub const fn new(coefficient: f64) -> Self {
        Friction {
            static_coefficient: coefficient,
            kinetic_coefficient: coefficient,
            combine: FrictionCombine::Average,
        }
    }

    /// No friction at all (the contact only pushes); `Min` so it wins against any surface.
    pub const FRICTIONLESS: Friction = Friction {
        static_coefficient: 0.0,
        kinetic_coefficient: 0.0,
        combine: FrictionCombine::Min,
    };

    /// Checks both coefficients are finite and not negative, and the static one is not below
    /// the kinetic one; the error names `owner` and the field.
    pub fn validate(&self, owner: &str) -> Result<(), ContactError> {
        for (field, value) in [
            ("static_coefficient", self.static_coefficient),
            ("kinetic_coefficient", self.kinetic_coefficient),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ContactError::BadFriction {
                    owner: owner.into(),
                    field,
                    value,
                    reason: "must be finite and >= 0",
                });
            }
        }
        if self.static_coefficient < self.kinetic_coefficient {
            return Err(ContactError::BadFriction {
                owner: owner.into(),
                field: "static_coefficient",
                value: self.static_coefficient,
                reason: "must not be below kinetic_coefficient",
            });
        }
        Ok(())
    }

    /// The (static, kinetic) coefficients of a contact between surfaces `a` and `b`.
    pub fn combine(a: &Friction, b: &Friction) -> (f64, f64) {
        let rule = if a.combine.priority() >= b.combine.priority() {
            a.combine
        } else {
            b.combine
        };
        (
            rule.apply(a.static_coefficient, b.static_coefficient),
            rule.apply(a.kinetic_coefficient, b.kinetic_coefficient),
        )
    }
}

/// A closed triangle surface used as a rigid shape (a bone, a rib, an instrument's housing).
#[derive(Clone)]
pub struct MeshShape {
    mesh: TriMesh,
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    lo: Vec3,
    hi: Vec3,
}

impl std::fmt::Debug for MeshShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshShape")
            .field("vertices", &self.vertices.len())
            .field("triangles", &self.triangles.len())
            .finish()
    }
}

impl PartialEq for MeshShape {
    fn eq(&self, other: &Self) -> bool {
        self.vertices == other.vertices && self.triangles == other.triangles
    }
}

impl MeshShape {
    /// A rigid shape from a closed, outward-oriented triangle surface (its own frame). An
    /// empty surface, a bad index or a non-finite vertex is refused, naming it.
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<Self, ContactError> {
        let bad = |reason: String| ContactError::BadShape {
            shape: "mesh".into(),
            reason,
        };
        if triangles.is_empty() {
            return Err(bad("no triangles".into()));
        }
        if let Some(v) = vertices
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(bad(format!("vertex {v} is not finite")));
        }
        if let Some(t) = triangles
            .iter()
            .position(|t| t.iter().any(|&i| i as usize >= vertices.len()))
        {
            return Err(bad(format!(
                "triangle {t} names a vertex beyond the {} given",
                vertices.len()
            )));
        }
        let pv: Vec<ParryVector> = vertices
            .iter()
            .map(|p| ParryVector::new(p.x as f32, p.y as f32, p.z as f32))
            .collect();
        let mesh = TriMesh::with_flags(pv, triangles.clone(), TriMeshFlags::ORIENTED)
            .map_err(|e| bad(format!("parry refused it: {e:?}")))?;
        let (lo, hi) = vertices.iter().fold(
            (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        );
        Ok(MeshShape {
            mesh,
            vertices,
            triangles,
            lo,
            hi,
        })
    }

    /// Vertices (own frame).
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// Triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

/// A rigid shape in its own frame.
#[derive(Debug, Clone, PartialEq)]
pub enum RigidShape {
    /// A ball of `radius` about the origin.
    Sphere {
        /// Radius.
        radius: f64,
    },
    /// The points within `radius` of the segment from the origin to `length` along +y.
    Capsule {
        /// Radius.
        radius: f64,
        /// Segment length.
        length: f64,
    },
    /// A box centred on the origin.
    Box {
        /// Half extents along x, y, z.
        half_extents: Vec3,
    },
    /// The half-space below the plane y = 0 (its surface normal is +y).
    Plane,
    /// A closed triangle surface.
    Mesh(Arc<MeshShape>),
}

/// A point against a shape: how far outside it is (negative inside), the unit normal of the
/// shape's surface there (pointing out of the shape) and the closest surface point, all in
/// the shape's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeHit {
    /// Signed distance (negative inside).
    pub distance: f64,
    /// Outward unit normal.
    pub normal: Vec3,
    /// Closest point of the surface.
    pub point: Vec3,
}

impl RigidShape {
    /// Checks the dimensions are finite and positive; the error names `owner` and the field.
    pub fn validate(&self, owner: &str) -> Result<(), ContactError> {
        let bad = |what: &'static str, value: f64| ContactError::BadTool {
            tool: owner.into(),
            what,
            value,
        };
        match self {
            RigidShape::Sphere { radius } if !(radius.is_finite() && *radius > 0.0) => {
                Err(bad("radius (must be > 0)", *radius))
            }
            RigidShape::Capsule { radius, length } => {
                if !(radius.is_finite() && *radius > 0.0) {
                    Err(bad("radius (must be > 0)", *radius))
                } else if !(length.is_finite() && *length >= 0.0) {
                    Err(bad("capsule length (must be >= 0)", *length))
                } else {
                    Ok(())
                }
            }
            RigidShape::Box { half_extents } => {
                match half_extents.iter().find(|h| !(h.is_finite() && **h > 0.0)) {
                    Some(h) => Err(bad("box half extent (must be > 0)", *h)),
                    None => Ok(()),
                }
            }
            _ => Ok(()),
        }
    }

    /// The core segment and radius of a round shape (sphere, capsule).
    pub fn core(&self) -> Option<(Vec3, Vec3, f64)> {
        match *self {
            RigidShape::Sphere { radius } => Some((Vec3::zeros(), Vec3::zeros(), radius)),
            RigidShape::Capsule { radius, length } => {
                Some((Vec3::zeros(), Vec3::new(0.0, length, 0.0), radius))
            }
            _ => None,
        }
    }

    /// Bounds in the shape's frame (`None` for the unbounded plane).
    pub fn local_bounds(&self) -> Option<(Vec3, Vec3)> {
        match self {
            RigidShape::Sphere { radius } => Some((Vec3::repeat(-radius), Vec3::repeat(*radius))),
            RigidShape::Capsule { radius, length } => Some((
                Vec3::repeat(-radius),
                Vec3::new(*radius, length + radius, *radius),
            )),
            RigidShape::Box { half_extents } => Some((-half_extents, *half_extents)),
            RigidShape::Plane => None,
            RigidShape::Mesh(m) => Some((m.lo, m.hi)),
        }
    }

    /// The point `p` (shape frame) against the shape, if it is within `reach` of its surface
    /// (inside counts at any depth for the solid shapes; a mesh is searched within `reach`).
    pub fn query(&self, p: &Vec3, reach: f64) -> Option<ShapeHit> {
        let hit = match self {
            RigidShape::Sphere { .. } | RigidShape::Capsule { .. } => {
                let (a, b, r) = self.core().expect("round");
                let s = a + (b - a) * closest_on_segment(p, &a, &b);
                let off = p - s;
                let d = off.norm();
                let normal = if d > 0.0 { off / d } else { Vec3::x() };
                ShapeHit {
                    distance: d - r,
                    normal,
                    point: s + normal * r,
                }
            }
            RigidShape::Plane => ShapeHit {
                distance: p.y,
                normal: Vec3::y(),
                point: Vec3::new(p.x, 0.0, p.z),
            },
            RigidShape::Box { half_extents } => box_query(half_extents, p),
            RigidShape::Mesh(m) => {
                let q = ParryVector::new(p.x as f32, p.y as f32, p.z as f32);
                // Inside at any depth counts (a vertex that went deep in one step).
                let limit = if m.mesh.contains_local_point(q) {
                    f32::MAX
                } else {
                    (reach.max(0.0) as f32).max(f32::MIN_POSITIVE)
                };
                let (proj, (tri, _)) = m
                    .mesh
                    .project_local_point_and_get_location_with_max_dist(q, false, limit)?;
                let point = Vec3::new(
                    proj.point.x as f64,
                    proj.point.y as f64,
                    proj.point.z as f64,
                );
                let off = p - point;
                let d = off.norm();
                let face = {
                    let t = m.triangles[tri as usize].map(|i| m.vertices[i as usize]);
                    (t[1] - t[0]).cross(&(t[2] - t[0])).normalize()
                };
                let sign = if proj.is_inside { -1.0 } else { 1.0 };
                let normal = if d > 1e-6 * (1.0 + point.norm()) {
                    off / d * sign
                } else {
                    face
                };
                ShapeHit {
                    distance: sign * d,
                    normal,
                    point,
                }
            }
        };
        (hit.distance <= reach).then_some(hit)
    }
}

/// Signed distance, outward normal and closest surface point of a box.
fn box_query(h: &Vec3, p: &Vec3) -> ShapeHit {
    let q = p.abs() - h;
    if q.max() <= 0.0 {
        // Inside: out through the nearest face.
        let k = q.imax();
        let mut normal = Vec3::zeros();
        normal[k] = if p[k] >= 0.0 { 1.0 } else { -1.0 };
        let mut point = *p;
        point[k] = normal[k] * h[k];
        ShapeHit {
            distance: q[k],
            normal,
            point,
        }
    } else {
        let point = p.zip_map(h, |x, e| x.clamp(-e, e));
        let off = p - point;
        let d = off.norm();
        ShapeHit {
            distance: d,
            normal: off / d,
            point,
        }
    }
}

/// A pose: where a shape's frame is, as `f64` position and rotation.
pub type Pose = Isometry3<f64>;

/// The pose at `position` whose +y axis is `axis` (the shortest turn from +y; any length but
/// zero).
pub fn pose_along(position: Vec3, axis: Vec3) -> Pose {
    let rotation = UnitQuaternion::rotation_between(&Vec3::y(), &axis).unwrap_or_else(|| {
        // Opposite to +y: half a turn about x.
        UnitQuaternion::from_axis_angle(&Vec3::x_axis(), std::f64::consts::PI)
    });
    Isometry3::from_parts(Translation3::from(position), rotation)
}

/// A static rigid obstacle: a shape where it stands, and its friction.
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    name: String,
    shape: RigidShape,
    pose: Pose,
    friction: Friction,
    bounds: (Vec3, Vec3),
}

impl Obstacle {
    /// An obstacle; a bad shape, pose or friction is refused, naming it.
    pub fn new(
        name: impl Into<String>,
        shape: RigidShape,
        pose: Pose,
        friction: Friction,
    ) -> Result<Self, ContactError> {
        let name = name.into();
        shape.validate(&name)?;
        friction.validate(&name)?;
        let finite = pose.translation.vector.iter().all(|c| c.is_finite())
            && pose.rotation.coords.iter().all(|c| c.is_finite());
        if !finite {
            return Err(ContactError::BadShape {
                shape: name,
                reason: "pose is not finite".into(),
            });
        }
        let bounds = world_bounds(&shape, &pose);
        Ok(Obstacle {
            name,
            shape,
            pose,
            friction,
            bounds,
        })
    }

    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Shape (own frame).
    pub fn shape(&self) -> &RigidShape {
        &self.shape
    }

    /// Where it stands.
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// Moves it (kinematically, between steps).
    pub fn set_pose(&mut self, pose: Pose) -> Result<(), ContactError> {
        *self = Obstacle::new(self.name.clone(), self.shape.clone(), pose, self.friction)?;
        Ok(())
    }

    /// Friction.
    pub fn friction(&self) -> &Friction {
        &self.friction
    }

    /// Changes the friction (refused when invalid).
    pub fn set_friction(&mut self, friction: Friction) -> Result<(), ContactError> {
        friction.validate(&self.name)?;
        self.friction = friction;
        Ok(())
    }

    /// World bounds (infinite for a plane).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// A world point against the obstacle within `reach`: the hit in world coordinates.
    pub fn query(&self, p: &Vec3, reach: f64) -> Option<ShapeHit> {
        let local = self.pose.inverse_transform_point(&Point3::from(*p)).coords;
        self.shape.query(&local, reach).map(|h| ShapeHit {
            distance: h.distance,
            normal: self.pose.rotation * h.normal,
            point: self.pose.transform_point(&Point3::from(h.point)).coords,
        })
    }
}

/// World bounds of a shape at a pose (infinite for a plane).
pub fn world_bounds(shape: &RigidShape, pose: &Pose) -> (Vec3, Vec3) {
    let Some((lo, hi)) = shape.local_bounds() else {
        return (Vec3::repeat(f64::NEG_INFINITY), Vec3::repeat(f64::INFINITY));
    };
    let mut out = (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY));
    for k in 0..8 {
        let c = Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let w = pose.transform_point(&Point3::from(c)).coords;
        out = (out.0.inf(&w), out.1.sup(&w));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed distances and normals of the closed-form shapes at a few points.
    #[test]
    fn shapes_answer_their_closed_forms() {
        let b = RigidShape::Box {
            half_extents: Vec3::new(1.0, 2.0, 3.0),
        };
        let h = b.query(&Vec3::new(0.5, 1.9, 0.0), 1.0).unwrap();
        assert!((h.distance + 0.1).abs() < 1e-12 && h.normal == Vec3::y());
        let h = b.query(&Vec3::new(2.0, 0.0, 0.0), 2.0).unwrap();
        assert!((h.distance - 1.0).abs() < 1e-12 && h.normal == Vec3::x());
        assert!(b.query(&Vec3::new(5.0, 0.0, 0.0), 1.0).is_none());
        let h = RigidShape::Plane
            .query(&Vec3::new(3.0, -0.25, 1.0), 0.1)
            .unwrap();
        assert_eq!((h.distance, h.normal), (-0.25, Vec3::y()));
        let c = RigidShape::Capsule {
            radius: 0.5,
            length: 2.0,
        };
        let h = c.query(&Vec3::new(0.0, 3.0, 0.0), 1.0).unwrap();
        assert!((h.distance - 0.5).abs() < 1e-12 && h.normal == Vec3::y());
    }

    /// A mesh obstacle (a closed octahedron) knows inside from outside.
    #[test]
    fn a_mesh_shape_tells_inside_from_outside() {
        let v = vec![
            Vec3::x(),
            -Vec3::x(),
            Vec3::y(),
            -Vec3::y(),
            Vec3::z(),
            -Vec3::z(),
        ];
        let t = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        let m = RigidShape::Mesh(Arc::new(MeshShape::new(v, t).unwrap()));
        let inside = m.query(&Vec3::new(0.1, 0.1, 0.1), 2.0).unwrap();
        assert!(inside.distance < 0.0, "{inside:?}");
        let outside = m.query(&Vec3::new(1.0, 1.0, 1.0), 2.0).unwrap();
        let expected = (3.0f64.sqrt() - 1.0 / 3.0f64.sqrt()).abs();
        assert!((outside.distance - expected).abs() < 1e-5, "{outside:?}");
        assert!((outside.normal - Vec3::repeat(1.0).normalize()).norm() < 1e-5);
    }

    /// Friction combines by the higher-priority rule and refuses bad values by name.
    #[test]
    fn friction_combines_and_validates() {
        let a = Friction::new(0.4);
        let b = Friction::new(0.1);
        assert!((Friction::combine(&a, &b).0 - 0.25).abs() < 1e-15);
        assert_eq!(Friction::combine(&a, &Friction::FRICTIONLESS), (0.0, 0.0));
        let mut bad = Friction::new(0.3);
        bad.static_coefficient = 0.2;
        let e = bad.validate("jaw").unwrap_err().to_string();
        assert!(e.contains("jaw") && e.contains("static_coefficient"), "{e}");
        assert!(Friction::new(f64::NAN).validate("t").is_err());
    }
}
