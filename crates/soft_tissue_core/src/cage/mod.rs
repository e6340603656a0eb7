//! The cheap level of precision: a body's points written as 3D Green coordinates of a coarse
//! closed triangle cage (Lipman, Levin and Cohen-Or 2008; paper section III-D, eq. 8), with
//! the cage vertices driven by a small mass-spring-damper.
//!
//! - [`Cage`]: a validated closed, consistently oriented, non-self-intersecting triangle
//!   mesh (outward normals; an inward-oriented input is flipped and reported by
//!   [`Cage::was_flipped`]).
//! - [`green`]: the coordinates in closed form, their exact `f64` evaluation and a packed
//!   `f32` evaluation for the per-step writeback.
//! - [`build`]: the paper's bounding-box cage and a tighter fitted cage built by
//!   shrink-wrapping a box grid onto the body under a vertex budget.
//! - [`CageModel`]: the cage MSD plus the embedded points; contact is mapped onto the cage
//!   vertices through the transpose of the coordinates.

pub mod build;
pub mod condense;
pub mod fit;
pub mod green;
pub mod reduced;

mod body;
mod contact;
use crate::geometry;

pub use body::{CageModel, CageModelConfig, CageSprings, CageStepStats};
pub use build::{FitOptions, box_cage, fitted_cage};
pub use fit::{FitReport, SurfaceFit};
pub use green::GreenCoordinates;
pub use reduced::{CageDynamics, ReducedModel};

use std::collections::HashMap;

use crate::Vec3;
use crate::mesh::io::SurfaceMesh;
use crate::msd::MsdError;

/// Largest magnitude a cage vertex coordinate may have (the Green coordinates take products
/// of coordinates up to the fourth power; beyond this they would overflow `f64`).
pub const MAX_CAGE_COORDINATE: f64 = 1e75;

/// Errors of cage construction, embedding and stepping. Indices name the offending cage
/// vertex, cage triangle or embedded point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CageError {
    /// Fewer than 4 vertices or 4 triangles.
    #[error("a cage needs at least 4 vertices and 4 triangles, found {vertices} and {triangles}")]
    TooSmall {
        /// Vertex count.
        vertices: usize,
        /// Triangle count.
        triangles: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("cage vertex {vertex} is not finite: {position:?}")]
    NonFiniteVertex {
        /// Vertex index.
        vertex: usize,
        /// Its coordinates.
        position: [f64; 3],
    },
    /// A vertex coordinate beyond [`MAX_CAGE_COORDINATE`] in magnitude: the products the
    /// Green coordinates take of it (up to the fourth power) would overflow.
    #[error("cage vertex {vertex} lies beyond {limit:e} of the origin: {position:?}")]
    VertexOutOfRange {
        /// Vertex index.
        vertex: usize,
        /// Its coordinates.
        position: [f64; 3],
        /// [`MAX_CAGE_COORDINATE`].
        limit: f64,
    },
    /// A triangle refers to a vertex that does not exist, or twice to the same vertex.
    #[error("cage triangle {triangle} has bad vertex indices {indices:?} ({vertices} vertices)")]
    BadTriangle {
        /// Triangle index.
        triangle: usize,
        /// Its indices.
        indices: [u32; 3],
        /// Vertex count.
        vertices: usize,
    },
    /// A triangle has (nearly) zero area.
    #[error("cage triangle {triangle} is degenerate (area {area:e})")]
    DegenerateTriangle {
        /// Triangle index.
        triangle: usize,
        /// Its area.
        area: f64,
    },
    /// An edge belongs to one triangle only: the cage has a hole.
    #[error("cage edge ({a}, {b}) belongs to one triangle only: the cage is not closed")]
    OpenEdge {
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
    },
    /// An edge belongs to more than two triangles.
    #[error("cage edge ({a}, {b}) belongs to {count} triangles: the cage is not a manifold")]
    NonManifoldEdge {
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
        /// Number of triangles on it.
        count: usize,
    },
    /// Two triangles traverse a shared edge in the same direction.
    #[error("cage triangles on edge ({a}, {b}) are oriented inconsistently")]
    InconsistentOrientation {
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
    },
    /// A vertex is used by no triangle.
    #[error("cage vertex {vertex} is used by no triangle")]
    UnusedVertex {
        /// Vertex index.
        vertex: usize,
    },
    /// The enclosed volume is (nearly) zero.
    #[error("the cage encloses no volume ({volume:e})")]
    ZeroVolume {
        /// Signed volume.
        volume: f64,
    },
    /// Two non-adjacent triangles intersect (or two adjacent ones fold onto each other).
    #[error("cage triangles {first} and {second} intersect")]
    SelfIntersection {
        /// First triangle.
        first: usize,
        /// Second triangle.
        second: usize,
    },
    /// A point to embed is outside the cage (winding number near 0) or on its boundary.
    #[error(
        "point {point} at ({:.6}, {:.6}, {:.6}) is {} the cage (winding number {winding:.6})",
        position[0], position[1], position[2],
        if *winding < 0.5 { "outside" } else { "on the boundary of" }
    )]
    PointOutside {
        /// Point index.
        point: usize,
        /// Its coordinates.
        position: [f64; 3],
        /// Its winding number with respect to the cage (1 inside, 0 outside).
        winding: f64,
    },
    /// A deformed cage or point list has the wrong length.
    #[error("{what} has {found} entries, expected {expected}")]
    LengthMismatch {
        /// What was passed.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Found length.
        found: usize,
    },
    /// A cage could not be built with the requested options.
    #[error("cage build failed: {0}")]
    Build(String),
    /// An invalid argument (name and reason).
    #[error("invalid {field}: {message}")]
    InvalidArgument {
        /// Argument name.
        field: &'static str,
        /// Why.
        message: String,
    },
    /// The cage MSD refused a step or its configuration.
    #[error("cage MSD: {0}")]
    Msd(#[from] MsdError),
    /// A step produced a non-finite cage vertex or point.
    #[error("the cage step produced a non-finite {what} at index {index}")]
    NonFinite {
        /// "cage vertex" or "point".
        what: &'static str,
        /// Index.
        index: usize,
    },
}

/// A closed, consistently outward-oriented, non-self-intersecting triangle cage.
#[derive(Debug, Clone, PartialEq)]
pub struct Cage {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    flipped: bool,
}

impl Cage {
    /// Validates and builds a cage. Triangles may be oriented either way as long as they
    /// agree; an inward-oriented cage is flipped (see [`Cage::was_flipped`]).
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<Self, CageError> {
        let nv = vertices.len();
        if nv < 4 || triangles.len() < 4 {
            return Err(CageError::TooSmall {
                vertices: nv,
                triangles: triangles.len(),
            });
        }
        for (i, v) in vertices.iter().enumerate() {
            if !v.iter().all(|c| c.is_finite()) {
                return Err(CageError::NonFiniteVertex {
                    vertex: i,
                    position: [v.x, v.y, v.z],
                });
            }
            if v.amax() > MAX_CAGE_COORDINATE {
                return Err(CageError::VertexOutOfRange {
                    vertex: i,
                    position: [v.x, v.y, v.z],
                    limit: MAX_CAGE_COORDINATE,
                });
            }
        }
        let mut lo = vertices[0];
        let mut hi = vertices[0];
        for v in &vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
        let scale = (hi - lo).norm();
        let mut used = vec![false; nv];
        for (t, tri) in triangles.iter().enumerate() {
            let bad = tri.iter().any(|&i| i as usize >= nv)
                || tri[0] == tri[1]
                || tri[1] == tri[2]
                || tri[0] == tri[2];
            if bad {
                return Err(CageError::BadTriangle {
                    triangle: t,
                    indices: *tri,
                    vertices: nv,
                });
            }
            let p = tri.map(|i| vertices[i as usize]);
            let area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
            if area.is_nan() || area <= 1e-12 * scale * scale {
                return Err(CageError::DegenerateTriangle { triangle: t, area });
            }
            for &i in tri {
                used[i as usize] = true;
            }
        }
        if let Some(vertex) = used.iter().position(|u| !u) {
            return Err(CageError::UnusedVertex { vertex });
        }
        // Every undirected edge: exactly two triangles, traversing it in opposite directions.
        let mut edges: HashMap<(u32, u32), (usize, usize)> = HashMap::new();
        for tri in &triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let e = edges.entry((a.min(b), a.max(b))).or_insert((0, 0));
                if a < b {
                    e.0 += 1;
                } else {
                    e.1 += 1;
                }
            }
        }
        let mut sorted: Vec<_> = edges.into_iter().collect();
        sorted.sort_unstable_by_key(|(k, _)| *k);
        for ((a, b), (fwd, back)) in sorted {
            match fwd + back {
                1 => return Err(CageError::OpenEdge { a, b }),
                2 if fwd == 1 => {}
                2 => return Err(CageError::InconsistentOrientation { a, b }),
                count => return Err(CageError::NonManifoldEdge { a, b, count }),
            }
        }
        let mut cage = Cage {
            vertices,
            triangles,
            flipped: false,
        };
        let volume = cage.volume();
        if volume.abs() <= 1e-12 * scale * scale * scale {
            return Err(CageError::ZeroVolume { volume });
        }
        if volume < 0.0 {
            for t in &mut cage.triangles {
                t.swap(1, 2);
            }
            cage.flipped = true;
        }
        if let Some((first, second)) =
            geometry::first_self_intersection(&cage.vertices, &cage.triangles)
        {
            return Err(CageError::SelfIntersection { first, second });
        }
        Ok(cage)
    }

    /// A cage from an OBJ-style triangle surface.
    pub fn from_surface(surface: &SurfaceMesh) -> Result<Self, CageError> {
        Cage::new(surface.positions.clone(), surface.triangles.clone())
    }

    /// The cage as a triangle surface (for writing OBJ).
    pub fn to_surface(&self) -> SurfaceMesh {
        SurfaceMesh {
            positions: self.vertices.clone(),
            triangles: self.triangles.clone(),
        }
    }

    /// Rest vertex positions.
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// Triangles, counter-clockwise seen from outside.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Whether [`Cage::new`] reversed the input's orientation.
    pub fn was_flipped(&self) -> bool {
        self.flipped
    }

    /// Unique undirected edges `(a, b)` with `a < b`, sorted.
    pub fn edges(&self) -> Vec<[u32; 2]> {
        let mut e: Vec<[u32; 2]> = self
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| [t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3])]))
            .collect();
        e.sort_unstable();
        e.dedup();
        e
    }

    /// Enclosed volume (positive for outward orientation).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let p = t.map(|i| self.vertices[i as usize]);
                p[0].dot(&p[1].cross(&p[2])) / 6.0
            })
            .sum()
    }

    /// Generalized winding number of `p` (1 inside, 0 outside, 1/2 on a face).
    pub fn winding_number(&self, p: &Vec3) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let q = t.map(|i| self.vertices[i as usize] - p);
                geometry::solid_angle(&q[0], &q[1], &q[2])
            })
            .sum::<f64>()
            / (4.0 * std::f64::consts::PI)
    }
}
