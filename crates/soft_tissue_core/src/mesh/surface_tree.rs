//! A bounding-volume hierarchy over a triangle surface: the closest point by branch and
//! bound, and the generalized winding number summed exactly over the near triangles and by
//! each far cluster's dipole (Barill, Dickson, Schmidt, Levin and Jacobson, "Fast Winding
//! Numbers for Soups and Clouds", 2018: the first-order term of the far-field expansion).

use crate::Vec3;
use crate::geometry::{closest_on_triangle, solid_angle};

/// Triangles per leaf.
const LEAF: usize = 8;

/// A cluster is far from a point, and its dipole used, beyond this many of its radii.
const FAR: f64 = 4.0;

struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Area-weighted centroid of the cluster's triangles.
    centre: Vec3,
    /// Largest distance from `centre` to a vertex of the cluster.
    radius: f64,
    /// Sum of the triangles' area-weighted normals (half the cross products).
    dipole: Vec3,
    /// Children (inner node) or the range of `order` (leaf).
    kind: Kind,
}

enum Kind {
    Inner(u32, u32),
    Leaf(u32, u32),
}

/// The hierarchy over one surface.
pub struct SurfaceTree<'a> {
    positions: &'a [Vec3],
    triangles: &'a [[u32; 3]],
    /// Triangles in leaf order.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl<'a> SurfaceTree<'a> {
    /// Builds the hierarchy (median splits along the longest axis of the centroids).
    pub fn new(positions: &'a [Vec3], triangles: &'a [[u32; 3]]) -> Self {
        let mut tree = SurfaceTree {
            positions,
            triangles,
            order: (0..triangles.len() as u32).collect(),
            nodes: Vec::new(),
        };
        if !triangles.is_empty() {
            let centroids: Vec<Vec3> = triangles
                .iter()
                .map(|t| t.iter().map(|&v| positions[v as usize]).sum::<Vec3>() / 3.0)
                .collect();
            tree.build(0, triangles.len(), &centroids);
        }
        tree
    }

    fn corners(&self, t: u32) -> [Vec3; 3] {
        self.triangles[t as usize].map(|v| self.positions[v as usize])
    }

    fn build(&mut self, start: usize, end: usize, centroids: &[Vec3]) -> u32 {
        let (mut lo, mut hi) = (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY));
        let (mut area_sum, mut weighted, mut dipole) = (0.0, Vec3::zeros(), Vec3::zeros());
        for &t in &self.order[start..end] {
            let [a, b, c] = self.corners(t);
            for p in [a, b, c] {
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
            let n = (b - a).cross(&(c - a)) * 0.5;
            let area = n.norm();
            area_sum += area;
            weighted += centroids[t as usize] * area;
            dipole += n;
        }
        let centre = if area_sum > 0.0 {
            weighted / area_sum
        } else {
            (lo + hi) * 0.5
        };
        let mut radius: f64 = 0.0;
        for &t in &self.order[start..end] {
            for p in self.corners(t) {
                radius = radius.max((p - centre).norm());
            }
        }
        let index = self.nodes.len() as u32;
        self.nodes.push(Node {
            lo,
            hi,
            centre,
            radius,
            dipole,
            kind: Kind::Leaf(start as u32, end as u32),
        });
        if end - start > LEAF {
            let extent = hi - lo;
            let axis = if extent.x >= extent.y && extent.x >= extent.z {
                0
            } else if extent.y >= extent.z {
                1
            } else {
                2
            };
            let mid = (start + end) / 2;
            self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
                centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
            });
            let left = self.build(start, mid, centroids);
            let right = self.build(mid, end, centroids);
            self.nodes[index as usize].kind = Kind::Inner(left, right);
        }
        index
    }

    /// The closest point of the surface to `p` and its distance (`None` without triangles).
    pub fn closest(&self, p: &Vec3) -> Option<(Vec3, f64)> {
        self.closest_triangle(p).map(|(q, d, _)| (q, d))
    }

    /// The closest point of the surface to `p`, its distance and the triangle it lies on
    /// (`None` without triangles).
    pub fn closest_triangle(&self, p: &Vec3) -> Option<(Vec3, f64, usize)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best = (f64::INFINITY, *p, 0usize);
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            // Squared distance from p to the node's box.
            let d = (node.lo - p).sup(&(p - node.hi)).sup(&Vec3::zeros());
            if d.norm_squared() >= best.0 {
                continue;
            }
            match node.kind {
                Kind::Leaf(s, e) => {
                    for &t in &self.order[s as usize..e as usize] {
                        let [a, b, c] = self.corners(t);
                        let w = closest_on_triangle(p, &a, &b, &c);
                        let q = a * w[0] + b * w[1] + c * w[2];
                        let dq = (q - p).norm_squared();
                        if dq < best.0 {
                            best = (dq, q, t as usize);
                        }
                    }
                }
                Kind::Inner(l, r) => {
                    // The nearer child last, so it is searched first.
                    let dist = |k: u32| {
                        let n = &self.nodes[k as usize];
                        (n.lo - p)
                            .sup(&(p - n.hi))
                            .sup(&Vec3::zeros())
                            .norm_squared()
                    };
                    if dist(l) < dist(r) {
                        stack.extend([r, l]);
                    } else {
                        stack.extend([l, r]);
                    }
                }
            }
        }
        Some((best.1, best.0.sqrt(), best.2))
    }

    /// The generalized winding number at `p`: exact over the clusters near `p`, the dipole
    /// of each cluster farther than 4 of its radii.
    pub fn winding_number(&self, p: &Vec3) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let mut sum = 0.0;
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            let r = node.centre - p;
            let d = r.norm();
            if d > FAR * node.radius {
                // Solid angle of a small oriented area A n at distance r: A n . r / |r|^3.
                sum += node.dipole.dot(&r) / (d * d * d);
                continue;
            }
            match node.kind {
                Kind::Leaf(s, e) => {
                    for &t in &self.order[s as usize..e as usize] {
                        let [a, b, c] = self.corners(t).map(|q| q - p);
                        sum += solid_angle(&a, &b, &c);
                    }
                }
                Kind::Inner(l, r) => stack.extend([l, r]),
            }
        }
        sum / (4.0 * std::f64::consts::PI)
    }

    /// The generalized winding number along the segment from `a` to `b`: its value at `a`
    /// and each crossing of a triangle (the parameter along the segment, 0 at `a` and 1 at
    /// `b`, and the whole step of the winding number there: -1 where the segment leaves
    /// through the side the triangle's normal points to, +1 where it enters), sorted.
    /// `None` where that is not the winding number all along: an end is not finite, the
    /// segment touches a triangle's edge or corner, lies in its plane or ends on it (within
    /// a relative 1e-9), or the steps do not lead to the winding number at `b` within a
    /// quarter and on the same side of one half (the surface is not closed there). A bisection along the segment
    /// then asks one list instead of a winding number per step.
    pub fn winding_along(&self, a: &Vec3, b: &Vec3) -> Option<WindingAlong> {
        const EPS: f64 = 1e-9;
        if !(a.iter().chain(b.iter()).all(|c| c.is_finite())) {
            return None;
        }
        let d = b - a;
        let mut steps = Vec::new();
        let (inv, mut stack) = (d.map(|c| 1.0 / c), vec![0u32]);
        while let Some(i) = stack.pop() {
            let node = self.nodes.get(i as usize)?;
            // The slab test, the box grown by a hair for the rounding of its corners.
            let pad = EPS * (1.0 + node.radius);
            let (mut t0, mut t1) = (0.0f64, 1.0f64);
            for k in 0..3 {
                let (lo, hi) = (node.lo[k] - pad - a[k], node.hi[k] + pad - a[k]);
                if d[k] == 0.0 {
                    if lo > 0.0 || hi < 0.0 {
                        t1 = -1.0;
                    }
                    continue;
                }
                let (u, v) = (lo * inv[k], hi * inv[k]);
                t0 = t0.max(u.min(v));
                t1 = t1.min(u.max(v));
            }
            if t0 > t1 {
                continue;
            }
            match node.kind {
                Kind::Inner(l, r) => stack.extend([l, r]),
                Kind::Leaf(s, e) => {
                    for &t in &self.order[s as usize..e as usize] {
                        let [p, q, r] = self.corners(t);
                        let (e1, e2) = (q - p, r - p);
                        let pvec = d.cross(&e2);
                        let det = e1.dot(&pvec);
                        let w = a - p;
                        let scale = e1.norm() * e2.norm() * d.norm();
                        let n = e1.cross(&e2);
                        if n.norm_squared() == 0.0 {
                            // No area: no crossing (nor winding number).
                            continue;
                        }
                        if det.abs() <= EPS * scale {
                            // Parallel: a crossing only where it lies in the plane.
                            if w.dot(&n).abs() <= EPS * scale {
                                return None;
                            }
                            continue;
                        }
                        let u = w.dot(&pvec) / det;
                        let qvec = w.cross(&e1);
                        let v = d.dot(&qvec) / det;
                        let s = e2.dot(&qvec) / det;
                        let outside = |x: f64| !(-EPS..=1.0 + EPS).contains(&x);
                        if outside(u) || outside(v) || outside(u + v) || outside(s) {
                            continue;
                        }
                        let near = |x: f64| !(EPS..=1.0 - EPS).contains(&x);
                        if near(u) || near(v) || near(u + v) || near(s) {
                            return None;
                        }
                        steps.push((s, det.signum()));
                    }
                }
            }
        }
        steps.sort_by(|x, y| x.0.total_cmp(&y.0));
        let start = self.winding_number(a);
        let end = start + steps.iter().map(|s| s.1).sum::<f64>();
        let at_b = self.winding_number(b);
        ((end - at_b).abs() < 0.25 && (end > 0.5) == (at_b > 0.5))
            .then_some(WindingAlong { start, steps })
    }
}

/// The winding number along a segment ([`SurfaceTree::winding_along`]).
#[derive(Debug, Clone)]
pub struct WindingAlong {
    start: f64,
    steps: Vec<(f64, f64)>,
}

impl WindingAlong {
    /// The winding number at parameter `t` along the segment; `None` within 1e-9 of a
    /// crossing (on the surface, where the winding number is about a half and rounding
    /// decides the side).
    pub fn at(&self, t: f64) -> Option<f64> {
        if self.steps.iter().any(|s| (s.0 - t).abs() < 1e-9) {
            return None;
        }
        let before = self.steps.iter().take_while(|s| s.0 < t);
        Some(self.start + before.map(|s| s.1).sum::<f64>())
    }
}
