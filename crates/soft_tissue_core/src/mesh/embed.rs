//! Embedding of points (a visual mesh finer than the simulation mesh) in a tetrahedral mesh.
//!
//! Every point is given the tetrahedron of the rest mesh that contains it, or, for a point
//! outside the mesh (a visual surface that bulges slightly past the simulation surface), the
//! nearest tetrahedron; its weights are the barycentric coordinates in that tetrahedron
//! (negative outside it, so the point follows the tetrahedron's affine motion). A deformed
//! point is the weighted sum of its tetrahedron's four deformed nodes: exact for any affine
//! deformation of the tetrahedron, continuous across shared faces for points inside.
//!
//! Location uses a uniform grid of the tetrahedra's bounding boxes; the nearest tetrahedron
//! of an outside point is exact (the search widens ring by ring until no closer cell can
//! exist). Points farther than a limit from the mesh are an error naming them: they belong
//! to another model, another scale or another placement.

use super::TetMesh;
use super::tet_grid::{TetGrid, grid_cells};
use crate::Vec3;
use crate::geometry::point_triangle_distance;
use nalgebra::Matrix3;
use thiserror::Error;

/// Why points could not be embedded or an embedding could not be applied.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EmbedError {
    /// A point has a NaN or infinite coordinate.
    #[error("point {point} has a non-finite coordinate")]
    NotFinite {
        /// Index of the point.
        point: usize,
    },
    /// A point lies farther from the mesh than the limit.
    #[error(
        "point {point} lies {distance} from the simulation mesh, farther than the limit {limit}: \
         the visual mesh does not match the body (other model, scale or placement?)"
    )]
    TooFar {
        /// Index of the point.
        point: usize,
        /// Its distance from the nearest tetrahedron.
        distance: f64,
        /// The limit it exceeds.
        limit: f64,
    },
    /// The limit is negative or not finite.
    #[error("the distance limit {0} must be finite and non-negative")]
    BadLimit(f64),
    /// The node positions handed to [`Embedding::apply`] are fewer than the mesh's nodes.
    #[error("the embedding needs {needed} node positions, got {got}")]
    TooFewNodes {
        /// Nodes the embedding refers to (highest index + 1).
        needed: usize,
        /// Positions given.
        got: usize,
    },
    /// The output slice does not hold one entry per embedded point.
    #[error("the output holds {got} entries, the embedding has {points} points")]
    WrongOutputLength {
        /// Embedded points.
        points: usize,
        /// Output length.
        got: usize,
    },
}

/// Points embedded in a tetrahedral mesh: per point four node indices and four weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Embedding {
    corners: Vec<[u32; 4]>,
    weights: Vec<[f64; 4]>,
    needed: usize,
    outside: usize,
    max_distance: f64,
}

/// Barycentric coordinates of `p` in tetrahedron `t` (`inv` maps `p - x0` to `b1..b3`).
fn barycentric(inv: &Matrix3<f64>, x0: &Vec3, p: &Vec3) -> [f64; 4] {
    let b = inv * (p - x0);
    [1.0 - b.x - b.y - b.z, b.x, b.y, b.z]
}

/// Distance from `p` to tetrahedron `p4` whose barycentric coordinates of `p` are `b`.
fn tet_distance(p4: &[Vec3; 4], b: &[f64; 4], p: &Vec3) -> f64 {
    if b.iter().all(|&w| w >= 0.0) {
        return 0.0;
    }
    // Outside: the nearest point is on a face opposite a negative coordinate.
    let faces = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
    let mut best = f64::INFINITY;
    for (opposite, f) in faces.iter().enumerate() {
        if b[opposite] < 0.0 {
            best = best.min(point_triangle_distance(p, &p4[f[0]], &p4[f[1]], &p4[f[2]]));
        }
    }
    best
}

impl Embedding {
    /// Embeds `points` (in the coordinates of the rest mesh) in `mesh`. A point farther than
    /// `limit` from every tetrahedron is an error naming it.
    pub fn new(mesh: &TetMesh, points: &[Vec3], limit: f64) -> Result<Self, EmbedError> {
        if !(limit.is_finite() && limit >= 0.0) {
            return Err(EmbedError::BadLimit(limit));
        }
        let x = mesh.positions();
        let inverses: Vec<Matrix3<f64>> = mesh
            .tets()
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|i| x[i as usize]);
                Matrix3::from_columns(&[b - a, c - a, d - a])
                    .try_inverse()
                    .unwrap_or_else(Matrix3::zeros)
            })
            .collect();
        let grid = TetGrid::new(mesh);
        let corners_of = |t: u32| mesh.tets()[t as usize];
        let mut e = Embedding {
            corners: Vec::with_capacity(points.len()),
            weights: Vec::with_capacity(points.len()),
            needed: 0,
            outside: 0,
            max_distance: 0.0,
        };
        for (k, p) in points.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(EmbedError::NotFinite { point: k });
            }
            let home = [0, 1, 2].map(|a| grid.index(p[a], a));
            let eval = |t: u32| {
                let c = corners_of(t);
                let p4 = c.map(|i| x[i as usize]);
                let b = barycentric(&inverses[t as usize], &p4[0], p);
                (b, tet_distance(&p4, &b, p))
            };
            // Nearest tetrahedron, ring by ring; ties go to the lowest index so the result
            // does not depend on the order cells are visited.
            let mut best: Option<(f64, u32, [f64; 4])> = None;
            let max_ring = grid.dims.iter().copied().max().unwrap_or(1);
            for ring in 0..=max_ring {
                if let Some((d, _, _)) = best
                    && (ring as f64 - 1.0) * grid.cell > d
                {
                    break;
                }
                let r = [0, 1, 2].map(|a| {
                    [
                        home[a].saturating_sub(ring),
                        (home[a] + ring).min(grid.dims[a] - 1),
                    ]
                });
                grid_cells(grid.dims, &r, |c| {
                    // Only the cells on the ring's shell (the inside was visited before).
                    let i = c % grid.dims[0];
                    let j = (c / grid.dims[0]) % grid.dims[1];
                    let kk = c / (grid.dims[0] * grid.dims[1]);
                    let cheb = [i, j, kk]
                        .iter()
                        .zip(&home)
                        .map(|(&v, &h)| v.abs_diff(h))
                        .max()
                        .unwrap_or(0);
                    if cheb != ring {
                        return;
                    }
                    for &t in grid.cell_items(c) {
                        let (b, d) = eval(t);
                        let better = match best {
                            None => true,
                            Some((bd, bt, _)) => d < bd || (d == bd && t < bt),
                        };
                        if better {
                            best = Some((d, t, b));
                        }
                    }
                });
            }
            let Some((distance, t, b)) = best else {
                return Err(EmbedError::TooFar {
                    point: k,
                    distance: f64::INFINITY,
                    limit,
                });
            };
            if distance > limit {
                return Err(EmbedError::TooFar {
                    point: k,
                    distance,
                    limit,
                });
            }
            if distance > 0.0 {
                e.outside += 1;
            }
            e.max_distance = e.max_distance.max(distance);
            let c = corners_of(t);
            e.needed = e
                .needed
                .max(c.iter().map(|&i| i as usize + 1).max().unwrap_or(0));
            e.corners.push(c);
            e.weights.push(b);
        }
        Ok(e)
    }

    /// Number of embedded points.
    pub fn len(&self) -> usize {
        self.corners.len()
    }

    /// Whether no point is embedded.
    pub fn is_empty(&self) -> bool {
        self.corners.is_empty()
    }

    /// The four nodes each point follows.
    pub fn corners(&self) -> &[[u32; 4]] {
        &self.corners
    }

    /// The four weights of each point (they sum to one; negative for points outside).
    pub fn weights(&self) -> &[[f64; 4]] {
        &self.weights
    }

    /// Points that lie outside the mesh (embedded in their nearest tetrahedron).
    pub fn outside_count(&self) -> usize {
        self.outside
    }

    /// Largest distance of a point from the mesh.
    pub fn max_distance(&self) -> f64 {
        self.max_distance
    }

    /// Writes the points deformed by the node positions `nodes` into `out`.
    pub fn apply(&self, nodes: &[Vec3], out: &mut [[f32; 3]]) -> Result<(), EmbedError> {
        self.check(nodes.len(), out.len())?;
        for ((o, c), w) in out.iter_mut().zip(&self.corners).zip(&self.weights) {
            let p = nodes[c[0] as usize] * w[0]
                + nodes[c[1] as usize] * w[1]
                + nodes[c[2] as usize] * w[2]
                + nodes[c[3] as usize] * w[3];
            *o = [p.x as f32, p.y as f32, p.z as f32];
        }
        Ok(())
    }

    /// Interpolates a per-node scalar (a temperature, a damage fraction) at the points.
    pub fn interpolate(&self, values: &[f64], out: &mut [f32]) -> Result<(), EmbedError> {
        self.check(values.len(), out.len())?;
        for ((o, c), w) in out.iter_mut().zip(&self.corners).zip(&self.weights) {
            let v: f64 = (0..4).map(|i| values[c[i] as usize] * w[i]).sum();
            *o = v as f32;
        }
        Ok(())
    }

    fn check(&self, nodes: usize, out: usize) -> Result<(), EmbedError> {
        if nodes < self.needed {
            return Err(EmbedError::TooFewNodes {
                needed: self.needed,
                got: nodes,
            });
        }
        if out != self.corners.len() {
            return Err(EmbedError::WrongOutputLength {
                points: self.corners.len(),
                got: out,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate;

    fn cylinder() -> TetMesh {
        generate::Organ::Cylinder.generate(1.0).expect("cylinder")
    }

    /// Deterministic pseudo-random numbers in [0, 1).
    fn rng(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn nodes_embed_to_themselves_and_affine_motion_is_reproduced() {
        let mesh = cylinder();
        let bbox = mesh.bbox();
        // Random points in (and slightly around) the bounding box, kept if near the mesh.
        let mut seed = 7;
        let mut points: Vec<Vec3> = mesh.positions().to_vec();
        for _ in 0..400 {
            let t = Vec3::new(rng(&mut seed), rng(&mut seed), rng(&mut seed));
            points.push(bbox.min + bbox.extent().component_mul(&t));
        }
        let e = Embedding::new(&mesh, &points, bbox.diagonal()).expect("embedding");
        assert_eq!(e.len(), points.len());
        for w in e.weights() {
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
        // The rest shape gives the points back.
        let mut out = vec![[0.0f32; 3]; points.len()];
        e.apply(mesh.positions(), &mut out).unwrap();
        for (o, p) in out.iter().zip(&points) {
            let err = (Vec3::new(o[0] as f64, o[1] as f64, o[2] as f64) - p).norm();
            assert!(err < 1e-5 * bbox.diagonal(), "rest error {err}");
        }
        // Any affine map of the nodes moves every point by the same map (f32 output).
        let a = Matrix3::new(1.2, 0.3, -0.1, 0.05, 0.8, 0.2, -0.2, 0.1, 1.1);
        let shift = Vec3::new(0.5, -2.0, 1.0);
        let moved: Vec<Vec3> = mesh.positions().iter().map(|p| a * p + shift).collect();
        e.apply(&moved, &mut out).unwrap();
        for (o, p) in out.iter().zip(&points) {
            let want = a * p + shift;
            let err = (Vec3::new(o[0] as f64, o[1] as f64, o[2] as f64) - want).norm();
            assert!(err < 1e-5 * bbox.diagonal(), "affine error {err}");
        }
    }

    #[test]
    fn inside_points_get_nonnegative_weights_and_outside_points_their_distance() {
        let mesh = cylinder();
        // Tetrahedron centroids are inside: non-negative weights, distance zero.
        let centroids: Vec<Vec3> = mesh
            .tets()
            .iter()
            .map(|t| {
                t.iter()
                    .map(|&i| mesh.positions()[i as usize])
                    .sum::<Vec3>()
                    / 4.0
            })
            .collect();
        let e = Embedding::new(&mesh, &centroids, 0.0).expect("inside points");
        assert_eq!(e.outside_count(), 0);
        assert!(e.weights().iter().flatten().all(|&w| w >= -1e-12));
        // A point pushed out along a surface triangle's normal is at exactly that distance.
        let s = mesh.surface();
        let [a, b, c] = s.triangles()[0].map(|i| mesh.positions()[i as usize]);
        let n = (b - a).cross(&(c - a)).normalize();
        let centre = (a + b + c) / 3.0;
        let d = 0.01 * mesh.bbox().smallest_dimension();
        let e = Embedding::new(&mesh, &[centre + n * d], 1.0).expect("near point");
        assert_eq!(e.outside_count(), 1);
        assert!(
            (e.max_distance() - d).abs() < 1e-9 * (1.0 + d),
            "{}",
            e.max_distance()
        );
        assert!(e.weights()[0].iter().any(|&w| w < 0.0));
    }

    #[test]
    fn the_nearest_tetrahedron_matches_a_brute_force_search() {
        let mesh = generate::Organ::Liver.generate(1.0).expect("liver");
        let bbox = mesh.bbox();
        let grow = bbox.extent() * 0.2;
        let mut seed = 11;
        let points: Vec<Vec3> = (0..300)
            .map(|_| {
                let t = Vec3::new(rng(&mut seed), rng(&mut seed), rng(&mut seed));
                bbox.min - grow + (bbox.extent() + 2.0 * grow).component_mul(&t)
            })
            .collect();
        let e = Embedding::new(&mesh, &points, bbox.diagonal()).expect("embedding");
        let x = mesh.positions();
        let distance = |t: &[u32; 4], p: &Vec3| {
            let p4 = t.map(|i| x[i as usize]);
            let inv = Matrix3::from_columns(&[p4[1] - p4[0], p4[2] - p4[0], p4[3] - p4[0]])
                .try_inverse()
                .unwrap();
            tet_distance(&p4, &barycentric(&inv, &p4[0], p), p)
        };
        for (k, p) in points.iter().enumerate() {
            let brute = mesh
                .tets()
                .iter()
                .map(|t| distance(t, p))
                .fold(f64::INFINITY, f64::min);
            let got = distance(&e.corners()[k], p);
            assert!(
                (got - brute).abs() <= 1e-12 * bbox.diagonal(),
                "point {k}: {got} vs {brute}"
            );
        }
        assert!(e.outside_count() > 0 && e.outside_count() < points.len());
    }

    #[test]
    fn bad_points_and_sizes_are_named() {
        let mesh = cylinder();
        let far = mesh.bbox().max + Vec3::repeat(10.0 * mesh.bbox().diagonal());
        let points = [mesh.positions()[0], far];
        match Embedding::new(&mesh, &points, 0.1) {
            Err(EmbedError::TooFar { point: 1, .. }) => {}
            other => panic!("{other:?}"),
        }
        let nan = [Vec3::new(f64::NAN, 0.0, 0.0)];
        assert_eq!(
            Embedding::new(&mesh, &nan, 1.0),
            Err(EmbedError::NotFinite { point: 0 })
        );
        assert_eq!(
            Embedding::new(&mesh, &[], -1.0),
            Err(EmbedError::BadLimit(-1.0))
        );
        let e = Embedding::new(&mesh, mesh.positions(), 0.0).unwrap();
        let mut out = vec![[0.0f32; 3]; 2];
        assert!(matches!(
            e.apply(mesh.positions(), &mut out),
            Err(EmbedError::WrongOutputLength { .. })
        ));
        let mut out = vec![[0.0f32; 3]; e.len()];
        assert!(matches!(
            e.apply(&mesh.positions()[..3], &mut out),
            Err(EmbedError::TooFewNodes { .. })
        ));
        // Interpolating a linear field reproduces it.
        let field: Vec<f64> = mesh.positions().iter().map(|p| 2.0 * p.x - p.z).collect();
        let mut vals = vec![0.0f32; e.len()];
        e.interpolate(&field, &mut vals).unwrap();
        for (v, f) in vals.iter().zip(&field) {
            assert!((*v as f64 - f).abs() < 1e-4 * (1.0 + f.abs()));
        }
    }
}
