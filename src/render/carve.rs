//! An app's own visual mesh through a carve: the tissue an electrode vaporized leaves the
//! body's tetrahedra (balls of the rest shape, `soft_tissue_core::mesh::cut::carve`), and the
//! visual mesh keeps its vertices, triangles and attributes (UVs, ...) and shows the crater
//! as a dent.
//!
//! Every visual vertex keeps its rest position (where it was embedded). After a carve:
//!
//! - a vertex outside every removed ball stays where it is and is embedded again in the new
//!   tetrahedra ([`Embedding`]): far from the crater the new elements are the old ones, so it
//!   is drawn where it was;
//! - a vertex inside a removed ball moves along the inward normal of the visual mesh at it
//!   to where that ray leaves the balls (the crater's far, deeper side: the ray through a
//!   ball crosses its sphere once going in), and is embedded there. The carve's wall is a
//!   polyhedron whose vertices lie on the sphere and whose faces are chords inside the ball,
//!   so a point on the sphere lies on the wall or just inside the tissue beyond it (by at
//!   most a chord's sagitta, about 7 % of the radius at the carve's spacing of 0.75 radius),
//!   and the dent the visual mesh shows is the ball's: its depth along the normal is the
//!   crater's.
//!
//! The normal is the area-weighted normal of the triangles around every vertex at the same
//! rest position (the copies of a vertex on a UV seam move together, so the seam does not
//! open in the crater), turned inward by the sign of the volume the mesh encloses (a mesh
//! with inward-facing triangles still dents inward). A vertex with no normal to speak of (a
//! degenerate neighbourhood) moves toward the centre of its ball instead.
//!
//! The other choice, each vertex to the nearest point of the new simulation surface, was
//! rejected: the visual vertices lie on the organ's surface, whose nearest new surface is
//! mostly the crater's rim, so the crater would show as a fold at the rim, not a dent.

use std::collections::HashMap;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::Ball;
use soft_tissue_core::mesh::embed::{EmbedError, Embedding};

use super::EmbeddedVisual;

/// Balls a body keeps for its visual mesh between two drawn frames (more are taken as a
/// change the visual mesh cannot follow).
const MAX_BALLS: usize = 1024;

/// A point counts as inside a ball closer than this fraction of the radius to its sphere
/// (one on the sphere is on the crater's wall already).
const INSIDE: f64 = 1e-9;

/// What changed a body's tetrahedral mesh since its rendered mesh was made (the cut stage
/// notes it, the render stage takes it).
#[derive(Debug, Default, Clone)]
pub(crate) struct MeshChanges {
    /// Balls carved out (rest shape, the coordinates of the body's mesh).
    carved: Vec<Ball>,
    /// A change other than a carve (a blade's cut).
    other: bool,
    /// A reset made the body whole again first: the visual mesh the body was drawn with
    /// is of the mesh before, and the carves since apply to the mesh as it was given.
    reset: bool,
}

impl MeshChanges {
    /// A carve removed `balls`.
    pub(crate) fn carve(&mut self, balls: &[Ball]) {
        if self.other {
            return;
        }
        if self.carved.len() + balls.len() > MAX_BALLS {
            self.cut();
            return;
        }
        self.carved.extend_from_slice(balls);
    }

    /// A blade's cut changed the mesh.
    pub(crate) fn cut(&mut self) {
        self.other = true;
        self.carved = Vec::new();
    }

    /// A reset made the body whole again: what changed before no longer counts.
    pub(crate) fn reset(&mut self) {
        *self = MeshChanges {
            reset: true,
            ..Default::default()
        };
    }

    /// Whether a reset made the body whole again since the rendered mesh was made (the
    /// carves since start from the mesh as it was given, not from the one drawn).
    pub(crate) fn since_reset(&self) -> bool {
        self.reset
    }

    /// The balls carved since the rendered mesh was made (since the last reset), when carves
    /// are all that changed the mesh.
    pub(crate) fn only_carves(&self) -> Option<&[Ball]> {
        (!self.other && !self.carved.is_empty()).then_some(&self.carved[..])
    }
}

/// Unit outward normals at the vertices `rest` of `triangles`: area-weighted over the
/// triangles around every vertex at the same position, turned over when the triangles
/// enclose a negative volume (they face inward). Zero where no triangle has an area.
pub(crate) fn rest_normals(rest: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let key = |p: &Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let mut by_place: HashMap<[u64; 3], Vec3> = HashMap::new();
    let mut volume = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(|i| rest[i as usize]);
        let n = (b - a).cross(&(c - a));
        volume += a.dot(&n) / 6.0;
        for q in [a, b, c] {
            *by_place.entry(key(&q)).or_insert_with(Vec3::zeros) += n;
        }
    }
    let sign = if volume < 0.0 { -1.0 } else { 1.0 };
    rest.iter()
        .map(|p| {
            let n = by_place.get(&key(p)).copied().unwrap_or_else(Vec3::zeros) * sign;
            let len = n.norm();
            if len > 0.0 && len.is_finite() {
                n / len
            } else {
                Vec3::zeros()
            }
        })
        .collect()
}

/// Where the ray from `p` along the unit `dir` leaves the union of `balls`; `None` when `p`
/// is inside none of them. A ray leaves a ball once, so at most one pass per ball.
pub(crate) fn exit_point(p: Vec3, dir: Vec3, balls: &[Ball]) -> Option<Vec3> {
    let inside = |q: &Vec3, b: &Ball| {
        let r = b.radius * (1.0 - INSIDE);
        (q - b.centre).norm_squared() < r * r
    };
    if !balls.iter().any(|b| inside(&p, b)) {
        return None;
    }
    let mut t = 0.0;
    for _ in 0..=balls.len() {
        let q = p + dir * t;
        let mut next = t;
        for b in balls.iter().filter(|b| inside(&q, b)) {
            // |w + s dir| = r, the larger root (the smaller is behind q: it is inside).
            let w = q - b.centre;
            let half = dir.dot(&w);
            let c = w.norm_squared() - b.radius * b.radius;
            next = next.max(t + (-half + (half * half - c).max(0.0).sqrt()));
        }
        if next <= t {
            break;
        }
        t = next;
    }
    Some(p + dir * t)
}

/// The rest positions of the visual vertices `rest` of `triangles` after `balls` were
/// carved out (see the module docs), and how many moved.
pub(crate) fn onto_crater(
    rest: &[Vec3],
    triangles: &[[u32; 3]],
    balls: &[Ball],
) -> (Vec<Vec3>, usize) {
    let normals = rest_normals(rest, triangles);
    let mut moved = 0;
    let points = rest
        .iter()
        .zip(&normals)
        .map(|(&p, n)| {
            let dir = if n.norm_squared() > 0.0 {
                -n
            } else {
                // No normal: toward the centre of the (first) ball it is in.
                balls
                    .iter()
                    .find(|b| (p - b.centre).norm() < b.radius)
                    .map(|b| b.centre - p)
                    .filter(|d| d.norm() > 0.0)
                    .map_or(-Vec3::y(), |d| d.normalize())
            };
            match exit_point(p, dir, balls) {
                Some(q) => {
                    moved += 1;
                    q
                }
                None => p,
            }
        })
        .collect();
    (points, moved)
}

/// `visual` fitted to `mesh`, the body's tetrahedra after `balls` were carved out of them:
/// the same vertices and triangles, those inside a ball moved onto the crater's wall, all
/// embedded again (with the limit they were embedded with first).
pub(crate) fn refit(
    visual: &EmbeddedVisual,
    balls: &[Ball],
    mesh: &TetMesh,
) -> Result<EmbeddedVisual, EmbedError> {
    let (rest, _) = onto_crater(&visual.rest, &visual.triangles, balls);
    let embedding = Embedding::new(mesh, &rest, visual.limit)?;
    let mut carved = visual.carved.clone();
    carved.extend_from_slice(balls);
    Ok(EmbeddedVisual {
        embedding,
        triangles: visual.triangles.clone(),
        rest,
        limit: visual.limit,
        carved,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ball(x: f64, y: f64, z: f64, radius: f64) -> Ball {
        Ball {
            centre: Vec3::new(x, y, z),
            radius,
        }
    }

    #[test]
    fn a_ray_leaves_the_union_of_balls_on_their_far_side() {
        let down = -Vec3::y();
        // One ball centred on the point: its radius below.
        let one = [ball(0.0, 0.0, 0.0, 1.0)];
        let q = exit_point(Vec3::zeros(), down, &one).unwrap();
        assert!((q - Vec3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        // Two overlapping balls along the ray: out of both.
        let two = [ball(0.0, 0.0, 0.0, 1.0), ball(0.0, -1.5, 0.0, 1.0)];
        let q = exit_point(Vec3::new(0.0, 0.5, 0.0), down, &two).unwrap();
        assert!((q - Vec3::new(0.0, -2.5, 0.0)).norm() < 1e-12, "{q}");
        // Outside, and on a sphere: not moved.
        assert_eq!(exit_point(Vec3::new(0.0, 3.0, 0.0), down, &two), None);
        assert_eq!(exit_point(Vec3::new(1.0, 0.0, 0.0), down, &one), None);
    }

    #[test]
    fn normals_point_out_whatever_way_the_triangles_face_and_seams_share_them() {
        // A unit cube's six faces, each face's corners its own copies (a UV-seamed mesh).
        let mut rest = Vec::new();
        let mut triangles = Vec::new();
        for axis in 0..3 {
            for side in [0.0, 1.0] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let base = rest.len() as u32;
                for (a, b) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                    let mut p = Vec3::zeros();
                    p[axis] = side;
                    p[u] = a;
                    p[v] = b;
                    rest.push(p);
                }
                let quad = if side == 1.0 {
                    [[0, 1, 2], [0, 2, 3]]
                } else {
                    [[0, 2, 1], [0, 3, 2]]
                };
                triangles.extend(quad.map(|t| t.map(|i| base + i)));
            }
        }
        let centre = Vec3::repeat(0.5);
        for flip in [false, true] {
            let t: Vec<[u32; 3]> = triangles
                .iter()
                .map(|&[a, b, c]| if flip { [a, c, b] } else { [a, b, c] })
                .collect();
            let n = rest_normals(&rest, &t);
            for (k, (p, m)) in rest.iter().zip(&n).enumerate() {
                // Outward, the same for the three copies of a corner; along the diagonal
                // where the corner's triangles are alike on its three faces.
                let out = (p - centre).normalize();
                assert!(m.dot(&out) > 0.5, "{p} {m} flip {flip}");
                for (q, o) in rest.iter().zip(&n).skip(k + 1) {
                    if q == p {
                        assert_eq!(m, o);
                    }
                }
                if p == &Vec3::zeros() || p == &Vec3::repeat(1.0) {
                    assert!((m - out).norm() < 1e-12, "{p} {m} flip {flip}");
                }
            }
        }
        // A ball at a corner dents it inward, onto the sphere.
        let b = [ball(1.0, 1.0, 1.0, 0.5)];
        let (moved, count) = onto_crater(&rest, &triangles, &b);
        assert_eq!(count, 3);
        for (p, q) in rest.iter().zip(&moved) {
            if p == &Vec3::repeat(1.0) {
                assert!((q - Vec3::repeat(1.0 - 0.5 / 3f64.sqrt())).norm() < 1e-12);
            } else {
                assert_eq!(p, q);
            }
        }
    }
}
