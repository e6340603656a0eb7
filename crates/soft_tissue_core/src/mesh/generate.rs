//! Tetrahedral meshes generated from signed distance functions, with our own mesher.
//!
//! The mesher is isosurface stuffing on a body-centred-cubic (BCC) lattice after Labelle and
//! Shewchuk (SIGGRAPH 2007): the lattice is laid over the shape, lattice vertices too close to
//! the surface are warped onto it (`alpha_long = 0.24999`, `alpha_short = 0.41189` of the
//! edge length, the paper's values), and each lattice tetrahedron crossed by the surface is
//! cut into the tetrahedra of its inside part. The cut parts are tetrahedra, pyramids and
//! prisms; their quadrilateral faces are split along the shorter diagonal (ties broken by node
//! number), a rule that depends only on the face so neighbours agree; a prism whose three
//! diagonals form a cycle gets a centre node. We do not use the paper's parity stencils, so its
//! angle bound is not inherited: the tests check the minimum dihedral angle we actually get.
//!
//! Shapes ([`Shape`]) are smooth unions of ellipsoids, capsules and capped cylinders. The
//! paper's cylinder and four organ-like bodies (liver, spleen, stomach, pancreas, placed so that
//! they rest touching each other as in the paper's Fig. 4) are predefined ([`Organ`]), at a
//! resolution that reproduces the node/tet/triangle counts of the paper's Table I.

pub use super::coarsen::coarsen_interior;
use super::{MeshError, TetMesh};
use crate::Vec3;
use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// A primitive solid. Angles in degrees, lengths in scene units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Primitive {
    /// Ellipsoid with semi-axes `radii`, rotated by `rotation_deg` (XYZ Euler angles).
    Ellipsoid {
        /// Centre.
        center: [f64; 3],
        /// Semi-axes along the local x, y, z axes.
        radii: [f64; 3],
        /// Rotation (roll, pitch, yaw) in degrees.
        rotation_deg: [f64; 3],
    },
    /// Segment `a`-`b` swept by a sphere whose radius goes linearly from `ra` to `rb`.
    Capsule {
        /// First end.
        a: [f64; 3],
        /// Second end.
        b: [f64; 3],
        /// Radius at `a`.
        ra: f64,
        /// Radius at `b`.
        rb: f64,
    },
    /// Capped cylinder along the z axis.
    Cylinder {
        /// Centre of the axis.
        center: [f64; 3],
        /// Radius.
        radius: f64,
        /// Height.
        height: f64,
    },
}

impl Primitive {
    /// Signed distance (negative inside). Exact for cylinders and capsules, a sign-correct
    /// first-order bound for ellipsoids.
    pub fn eval(&self, p: &Vec3) -> f64 {
        match self {
            Primitive::Ellipsoid {
                center,
                radii,
                rotation_deg,
            } => {
                let rot = rotation(rotation_deg);
                let q = rot.inverse() * (p - Vec3::from(*center));
                let r = Vec3::from(*radii);
                let k0 = q.component_div(&r).norm();
                let k1 = q.component_div(&r.component_mul(&r)).norm();
                if k1 == 0.0 {
                    -r.min()
                } else {
                    k0 * (k0 - 1.0) / k1
                }
            }
            Primitive::Capsule { a, b, ra, rb } => {
                let (a, b) = (Vec3::from(*a), Vec3::from(*b));
                let ab = b - a;
                let t = ((p - a).dot(&ab) / ab.norm_squared().max(1e-300)).clamp(0.0, 1.0);
                (p - (a + ab * t)).norm() - (ra + (rb - ra) * t)
            }
            Primitive::Cylinder {
                center,
                radius,
                height,
            } => {
                let q = p - Vec3::from(*center);
                let dx = (q.x * q.x + q.y * q.y).sqrt() - radius;
                let dz = q.z.abs() - height * 0.5;
                dx.max(dz).min(0.0) + (dx.max(0.0).powi(2) + dz.max(0.0).powi(2)).sqrt()
            }
        }
    }

    /// A box enclosing the primitive.
    fn bounds(&self) -> (Vec3, Vec3) {
        match self {
            Primitive::Ellipsoid { center, radii, .. } => {
                let r = Vec3::repeat(radii.iter().copied().fold(0.0, f64::max));
                (Vec3::from(*center) - r, Vec3::from(*center) + r)
            }
            Primitive::Capsule { a, b, ra, rb } => {
                let r = Vec3::repeat(ra.max(*rb));
                let (a, b) = (Vec3::from(*a), Vec3::from(*b));
                (a.inf(&b) - r, a.sup(&b) + r)
            }
            Primitive::Cylinder {
                center,
                radius,
                height,
            } => {
                let e = Vec3::new(*radius, *radius, height * 0.5);
                (Vec3::from(*center) - e, Vec3::from(*center) + e)
            }
        }
    }
}

fn rotation(deg: &[f64; 3]) -> Rotation3<f64> {
    Rotation3::from_euler_angles(
        deg[0].to_radians(),
        deg[1].to_radians(),
        deg[2].to_radians(),
    )
}

/// A smooth union of primitives, offset by a translation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shape {
    /// The parts.
    pub parts: Vec<Primitive>,
    /// Blend radius of the smooth union, scene units (0 = sharp union).
    pub blend: f64,
    /// Scale applied to the union along x, y, z (before the translation).
    pub scale: [f64; 3],
    /// Translation applied to the whole shape.
    pub offset: [f64; 3],
}

impl Shape {
    /// Signed distance (negative inside; a bound, not exact, near blends).
    pub fn eval(&self, p: &Vec3) -> f64 {
        let s = Vec3::from(self.scale);
        let q = (p - Vec3::from(self.offset)).component_div(&s);
        let mut d = f64::INFINITY;
        for part in &self.parts {
            let e = part.eval(&q);
            d = if d.is_infinite() {
                e
            } else {
                smooth_min(d, e, self.blend)
            };
        }
        d * s.min()
    }

    /// A box enclosing the shape.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        for part in &self.parts {
            let (a, b) = part.bounds();
            lo = lo.inf(&a);
            hi = hi.sup(&b);
        }
        let o = Vec3::from(self.offset);
        let s = Vec3::from(self.scale);
        (lo.component_mul(&s) + o, hi.component_mul(&s) + o)
    }
}

/// Polynomial smooth minimum (blend radius `k`).
fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

/// Errors from the mesher.
#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    /// The spacing is not positive or the lattice would be too large.
    #[error("invalid lattice spacing {spacing}: {reason}")]
    Spacing {
        /// Requested spacing.
        spacing: f64,
        /// Why it is refused.
        reason: String,
    },
    /// The shape is empty at this resolution.
    #[error("the shape contains no lattice tetrahedron at spacing {0}")]
    Empty(f64),
    /// The produced mesh did not validate (a mesher bug; please report it).
    #[error("generated mesh is invalid: {0}")]
    Invalid(#[from] MeshError),
}

const ALPHA_LONG: f64 = 0.24999;
const ALPHA_SHORT: f64 = 0.41189;
const MAX_LATTICE_VERTICES: usize = 40_000_000;

/// Meshes the inside (`f < 0`) of a shape with lattice spacing `h` (the cube edge).
pub fn stuff(shape: &Shape, h: f64) -> Result<TetMesh, GenerateError> {
    stuff_fn(|p| shape.eval(p), shape.bounds(), h)
}

/// Meshes the inside of any signed function `f` (negative inside) within `bounds`; cut
/// points are bisected 40 times (exact to 1e-12 h).
pub fn stuff_fn(
    f: impl Fn(&Vec3) -> f64 + Sync,
    bounds: (Vec3, Vec3),
    h: f64,
) -> Result<TetMesh, GenerateError> {
    stuff_fn_with(f, bounds, h, 40)
}

/// [`stuff_fn`] with `bisections` steps per cut point (exact to `h` / 2^`bisections`): fewer
/// where `f` is costly and the cut points are moved afterwards anyway (onto a surface). The
/// lattice's values and the cut points are evaluated on the rayon pool.
pub fn stuff_fn_with(
    f: impl Fn(&Vec3) -> f64 + Sync,
    bounds: (Vec3, Vec3),
    h: f64,
    bisections: usize,
) -> Result<TetMesh, GenerateError> {
    stuff_fn_sign(&f, |p| f(p) < 0.0, bounds, h, bisections)
}

/// [`stuff_fn_with`] where the bisections ask only whether a point is inside (`inside`,
/// which must agree with `f < 0`): cheaper where the sign costs less than the value (a
/// winding number without the distance).
pub fn stuff_fn_sign(
    f: impl Fn(&Vec3) -> f64 + Sync,
    inside: impl Fn(&Vec3) -> bool + Sync,
    bounds: (Vec3, Vec3),
    h: f64,
    bisections: usize,
) -> Result<TetMesh, GenerateError> {
    stuff_fn_cut(f, |a, b| bisect(a, b, bisections, &inside), bounds, h)
}

/// The point `bisections` halvings of the segment from `a` (inside) to `b` (outside) find
/// where `inside` changes: the midpoint of the last interval.
pub fn bisect(a: &Vec3, b: &Vec3, bisections: usize, inside: impl Fn(&Vec3) -> bool) -> Vec3 {
    let (mut pa, mut pb) = (*a, *b);
    for _ in 0..bisections {
        let m = (pa + pb) * 0.5;
        if inside(&m) { pa = m } else { pb = m }
    }
    (pa + pb) * 0.5
}

/// [`stuff_fn_sign`] with each cut point given by `cut(inside end, outside end)` of a
/// lattice edge whose ends `f` puts on the two sides.
pub fn stuff_fn_cut(
    f: impl Fn(&Vec3) -> f64 + Sync,
    cut_point: impl Fn(&Vec3, &Vec3) -> Vec3 + Sync,
    bounds: (Vec3, Vec3),
    h: f64,
) -> Result<TetMesh, GenerateError> {
    use rayon::prelude::*;
    if !(h.is_finite() && h > 0.0) {
        return Err(GenerateError::Spacing {
            spacing: h,
            reason: "must be positive".into(),
        });
    }
    let lo = bounds.0 - Vec3::repeat(1.5 * h);
    let size = bounds.1 - bounds.0 + Vec3::repeat(3.0 * h);
    // Counted in floating point first: a tiny spacing (a huge resolution) would overflow the
    // integer product.
    let counts = size.map(|s| (s / h).ceil() + 1.0);
    let cells = counts.x * counts.y * counts.z;
    if !(cells.is_finite() && cells < MAX_LATTICE_VERTICES as f64) {
        return Err(GenerateError::Spacing {
            spacing: h,
            reason: format!(
                "the lattice would have {cells:.3e} cells (at most {MAX_LATTICE_VERTICES})"
            ),
        });
    }
    let n = counts.map(|c| c as usize);
    let lat = Lattice { n, lo, h };
    let total = lat.corner_count() + lat.center_count();
    let mut pos: Vec<Vec3> = (0..total).map(|v| lat.position(v)).collect();
    let mut val: Vec<f64> = pos.par_iter().map(&f).collect();

    // Cut points on edges with a sign change (from the inside end: `a` has `f < 0`).
    let cut = |a: usize, b: usize, pos: &[Vec3], _: &[f64]| cut_point(&pos[a], &pos[b]);

    // Warping: a vertex violated by a cut point on one of its edges moves onto the closest one.
    // Cut points are bisected from the inside end and kept: an edge whose two ends are not
    // warped keeps its cut point for the stencils below. Every edge with a sign change is
    // bisected first, on the rayon pool, at the lattice's own positions: the warping below
    // reads cut points only on edges between unwarped vertices (a warped one is zero), so
    // the points are those it would bisect itself, in any order.
    let crossing: Vec<(usize, usize)> = (0..total)
        .into_par_iter()
        .filter(|&v| val[v] != 0.0)
        .flat_map_iter(|v| {
            let val = &val;
            lat.neighbors(v).into_iter().filter_map(move |(w, _)| {
                (w > v && val[w] != 0.0 && (val[w] < 0.0) != (val[v] < 0.0)).then_some((v, w))
            })
        })
        .collect();
    let points: Vec<Vec3> = crossing
        .par_iter()
        .map(|&(v, w)| {
            let (i, o) = if val[v] < 0.0 { (v, w) } else { (w, v) };
            cut(i, o, &pos, &val)
        })
        .collect();
    let mut known_cuts: HashMap<(usize, usize), Vec3> = crossing.into_iter().zip(points).collect();
    for v in 0..total {
        if val[v] == 0.0 {
            continue;
        }
        let mut best: Option<(f64, Vec3)> = None;
        for (w, long) in lat.neighbors(v) {
            if val[w] == 0.0 || (val[w] < 0.0) == (val[v] < 0.0) {
                continue;
            }
            let key = (v.min(w), v.max(w));
            let c = *known_cuts.entry(key).or_insert_with(|| {
                let (i, o) = if val[v] < 0.0 { (v, w) } else { (w, v) };
                cut(i, o, &pos, &val)
            });
            let len = if long { h } else { h * 3f64.sqrt() * 0.5 };
            let alpha = if long { ALPHA_LONG } else { ALPHA_SHORT };
            let d = (c - pos[v]).norm();
            if d < alpha * len && best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, c));
            }
        }
        if let Some((_, c)) = best {
            pos[v] = c;
            val[v] = 0.0;
        }
    }

    let mut b = Builder {
        pos,
        val,
        known_cuts,
        cuts: HashMap::new(),
        tets: Vec::new(),
    };
    for tet in lat.tets() {
        b.stuff_tet(tet, &cut);
    }
    if b.tets.is_empty() {
        return Err(GenerateError::Empty(h));
    }
    // Keep only used nodes, numbered in order of first use (deterministic).
    let mut map = vec![usize::MAX; b.pos.len()];
    let mut positions = Vec::new();
    let mut tets = Vec::with_capacity(b.tets.len());
    for t in &b.tets {
        tets.push(t.map(|v| {
            if map[v] == usize::MAX {
                map[v] = positions.len();
                positions.push(b.pos[v]);
            }
            map[v]
        }));
    }
    Ok(TetMesh::new(positions, tets)?)
}

struct Lattice {
    n: Vector3<usize>,
    lo: Vec3,
    h: f64,
}

impl Lattice {
    fn corner_count(&self) -> usize {
        self.n.x * self.n.y * self.n.z
    }
    fn center_count(&self) -> usize {
        (self.n.x - 1) * (self.n.y - 1) * (self.n.z - 1)
    }
    fn corner(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.n.x * (j + self.n.y * k)
    }
    fn center(&self, i: usize, j: usize, k: usize) -> usize {
        self.corner_count() + i + (self.n.x - 1) * (j + (self.n.y - 1) * k)
    }
    fn coords(&self, v: usize) -> (bool, [usize; 3]) {
        if v < self.corner_count() {
            let (nx, ny) = (self.n.x, self.n.y);
            (false, [v % nx, (v / nx) % ny, v / (nx * ny)])
        } else {
            let c = v - self.corner_count();
            let (nx, ny) = (self.n.x - 1, self.n.y - 1);
            (true, [c % nx, (c / nx) % ny, c / (nx * ny)])
        }
    }
    fn position(&self, v: usize) -> Vec3 {
        let (is_center, [i, j, k]) = self.coords(v);
        let o = if is_center { 0.5 } else { 0.0 };
        self.lo + Vec3::new(i as f64 + o, j as f64 + o, k as f64 + o) * self.h
    }

    /// Lattice neighbours of a vertex, with whether the edge is long (axis-aligned).
    fn neighbors(&self, v: usize) -> Vec<(usize, bool)> {
        let (is_center, c) = self.coords(v);
        let mut out = Vec::with_capacity(14);
        let (lim, idx): (Vector3<usize>, &dyn Fn(usize, usize, usize) -> usize) = if is_center {
            (self.n.map(|x| x - 1), &|i, j, k| self.center(i, j, k))
        } else {
            (self.n, &|i, j, k| self.corner(i, j, k))
        };
        for axis in 0..3 {
            for s in [-1i64, 1] {
                let mut q = c.map(|x| x as i64);
                q[axis] += s;
                if q[axis] >= 0 && (q[axis] as usize) < lim[axis] {
                    out.push((idx(q[0] as usize, q[1] as usize, q[2] as usize), true));
                }
            }
        }
        for d in 0..8usize {
            let off = [d & 1, (d >> 1) & 1, (d >> 2) & 1];
            if is_center {
                out.push((
                    self.corner(c[0] + off[0], c[1] + off[1], c[2] + off[2]),
                    false,
                ));
            } else {
                let q: Vec<i64> = (0..3).map(|a| c[a] as i64 + off[a] as i64 - 1).collect();
                if q.iter()
                    .zip(0..3)
                    .all(|(&x, a)| x >= 0 && (x as usize) < self.n[a] - 1)
                {
                    out.push((
                        self.center(q[0] as usize, q[1] as usize, q[2] as usize),
                        false,
                    ));
                }
            }
        }
        out
    }

    /// All BCC tetrahedra: for every pair of face-adjacent cells, the two centres and each
    /// edge of the shared face.
    fn tets(&self) -> impl Iterator<Item = [usize; 4]> + '_ {
        let cn = self.n.map(|x| x - 1);
        (0..3).flat_map(move |axis| {
            let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut out = Vec::new();
            for k in 0..cn.z {
                for j in 0..cn.y {
                    for i in 0..cn.x {
                        let c = [i, j, k];
                        if c[axis] + 1 >= cn[axis] {
                            continue;
                        }
                        let mut d = c;
                        d[axis] += 1;
                        let c1 = self.center(c[0], c[1], c[2]);
                        let c2 = self.center(d[0], d[1], d[2]);
                        // Face corners in cyclic order.
                        let mut q = [[0usize; 3]; 4];
                        for (m, (du, dw)) in
                            [(0, 0), (1, 0), (1, 1), (0, 1)].into_iter().enumerate()
                        {
                            let mut p = d;
                            p[u] += du;
                            p[w] += dw;
                            q[m] = p;
                        }
                        for m in 0..4 {
                            let a = q[m];
                            let b = q[(m + 1) % 4];
                            out.push([
                                c1,
                                c2,
                                self.corner(a[0], a[1], a[2]),
                                self.corner(b[0], b[1], b[2]),
                            ]);
                        }
                    }
                }
            }
            out
        })
    }
}

struct Builder {
    pos: Vec<Vec3>,
    val: Vec<f64>,
    /// Cut points already bisected during warping, by edge.
    known_cuts: HashMap<(usize, usize), Vec3>,
    cuts: HashMap<(usize, usize), usize>,
    tets: Vec<[usize; 4]>,
}

impl Builder {
    fn sign(&self, v: usize) -> i8 {
        let f = self.val[v];
        if f < 0.0 {
            -1
        } else if f > 0.0 {
            1
        } else {
            0
        }
    }

    fn cut_node(
        &mut self,
        a: usize,
        b: usize,
        cut: &impl Fn(usize, usize, &[Vec3], &[f64]) -> Vec3,
    ) -> usize {
        let key = (a.min(b), a.max(b));
        if let Some(&n) = self.cuts.get(&key) {
            return n;
        }
        // Always bisect from the inside end so both orders give the same point.
        let p = match self.known_cuts.get(&key) {
            Some(&p) => p,
            None => {
                let (i, o) = if self.val[a] < 0.0 { (a, b) } else { (b, a) };
                cut(i, o, &self.pos, &self.val)
            }
        };
        let n = self.pos.len();
        self.pos.push(p);
        self.val.push(0.0);
        self.cuts.insert(key, n);
        n
    }

    fn emit(&mut self, t: [usize; 4]) {
        let p = t.map(|v| self.pos[v]);
        let vol = super::tet_signed_volume(&p);
        if vol == 0.0 {
            return;
        }
        let mut t = t;
        if vol < 0.0 {
            t.swap(1, 2);
        }
        self.tets.push(t);
    }

    /// Diagonal of the cyclic quad `q`: `true` for q0-q2, `false` for q1-q3.
    fn diagonal(&self, q: [usize; 4]) -> bool {
        let d02 = (self.pos[q[0]] - self.pos[q[2]]).norm_squared();
        let d13 = (self.pos[q[1]] - self.pos[q[3]]).norm_squared();
        if d02 != d13 {
            d02 < d13
        } else {
            q[0].min(q[2]) < q[1].min(q[3])
        }
    }

    fn pyramid(&mut self, apex: usize, q: [usize; 4], diag02: bool) {
        if diag02 {
            self.emit([apex, q[0], q[1], q[2]]);
            self.emit([apex, q[0], q[2], q[3]]);
        } else {
            self.emit([apex, q[1], q[2], q[3]]);
            self.emit([apex, q[1], q[3], q[0]]);
        }
    }

    /// Prism with triangles `a` and `b` (`a[i]`-`b[i]` lateral edges). `free` marks a quad
    /// (index i: a[i], a[i+1], b[i+1], b[i]) whose diagonal may be chosen freely.
    fn prism(&mut self, a: [usize; 3], b: [usize; 3], free: Option<usize>) {
        let quad = |i: usize| [a[i], a[(i + 1) % 3], b[(i + 1) % 3], b[i]];
        // diag[i] = true: a[i]-b[i+1]; false: a[i+1]-b[i].
        let mut diag = [0, 1, 2].map(|i| self.diagonal(quad(i)));
        let cyclic = |d: &[bool; 3]| d[0] == d[1] && d[1] == d[2];
        if let Some(i) = free
            && cyclic(&diag)
        {
            diag[i] = !diag[i];
        }
        if cyclic(&diag) {
            // Three diagonals in a cycle: no 3-tet split exists; add a centre node.
            let all = [a[0], a[1], a[2], b[0], b[1], b[2]];
            let c = all.iter().fold(Vec3::zeros(), |s, &v| s + self.pos[v]) / 6.0;
            let cn = self.pos.len();
            self.pos.push(c);
            self.val.push(-1.0);
            self.emit([cn, a[0], a[1], a[2]]);
            self.emit([cn, b[0], b[1], b[2]]);
            for (i, &d) in diag.iter().enumerate() {
                self.pyramid(cn, quad(i), d);
            }
            return;
        }
        // A vertex where two diagonals meet takes the opposite triangle; the rest is a pyramid
        // over the third quad.
        for i in 0..3 {
            let prev = (i + 2) % 3;
            if diag[i] && !diag[prev] {
                // a[i] is on diagonals of quads i and prev.
                self.emit([a[i], b[0], b[1], b[2]]);
                let k = (i + 1) % 3;
                self.pyramid(a[i], quad(k), diag[k]);
                return;
            }
            if !diag[i] && diag[prev] {
                // b[i] is on diagonals of quads i (a[i+1]-b[i]) and prev (a[prev]-b[i]).
                self.emit([b[i], a[0], a[1], a[2]]);
                let k = (i + 1) % 3;
                self.pyramid(b[i], quad(k), diag[k]);
                return;
            }
        }
    }

    fn stuff_tet(&mut self, t: [usize; 4], cut: &impl Fn(usize, usize, &[Vec3], &[f64]) -> Vec3) {
        let s = t.map(|v| self.sign(v));
        let neg: Vec<usize> = (0..4).filter(|&i| s[i] < 0).map(|i| t[i]).collect();
        let zero: Vec<usize> = (0..4).filter(|&i| s[i] == 0).map(|i| t[i]).collect();
        let pos: Vec<usize> = (0..4).filter(|&i| s[i] > 0).map(|i| t[i]).collect();
        if pos.is_empty() {
            if !neg.is_empty() {
                self.emit(t);
            }
            return;
        }
        match (neg.len(), zero.len(), pos.len()) {
            (0, _, _) => {}
            (1, _, _) => {
                let mut v = vec![neg[0]];
                v.extend(&zero);
                for &p in &pos {
                    v.push(self.cut_node(neg[0], p, cut));
                }
                self.emit([v[0], v[1], v[2], v[3]]);
            }
            (2, 1, 1) => {
                let (a, b, z, p) = (neg[0], neg[1], zero[0], pos[0]);
                let ap = self.cut_node(a, p, cut);
                let bp = self.cut_node(b, p, cut);
                let q = [a, b, bp, ap];
                let d = self.diagonal(q);
                self.pyramid(z, q, d);
            }
            (2, 0, 2) => {
                let (a, b, c, d) = (neg[0], neg[1], pos[0], pos[1]);
                let ac = self.cut_node(a, c, cut);
                let ad = self.cut_node(a, d, cut);
                let bc = self.cut_node(b, c, cut);
                let bd = self.cut_node(b, d, cut);
                // Triangles (a, ac, ad) and (b, bc, bd); quad 1 (ac, ad, bd, bc) is the cut
                // surface, free to choose.
                self.prism([a, ac, ad], [b, bc, bd], Some(1));
            }
            (3, 0, 1) => {
                let p = pos[0];
                let cuts = [0, 1, 2].map(|i| self.cut_node(neg[i], p, cut));
                self.prism([neg[0], neg[1], neg[2]], cuts, None);
            }
            _ => {}
        }
    }
}

/// The predefined bodies: the paper's cylinder and the four organs of its Fig. 4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Organ {
    /// The paper's cylinder (diameter 1.24, height 1.72), centred at the origin, axis z.
    Cylinder,
    /// Liver: a wedge-like blend of three ellipsoids.
    Liver,
    /// Spleen: a curved, flattened bean.
    Spleen,
    /// Stomach: a J-shaped bag.
    Stomach,
    /// Pancreas: a long tapered body.
    Pancreas,
}

impl Organ {
    /// The four organs of the organs scene.
    pub const ORGANS: [Organ; 4] = [Organ::Liver, Organ::Spleen, Organ::Stomach, Organ::Pancreas];

    /// Lower-case name (`liver`, ...), also the asset file stem.
    pub fn name(self) -> &'static str {
        match self {
            Organ::Cylinder => "cylinder",
            Organ::Liver => "liver",
            Organ::Spleen => "spleen",
            Organ::Stomach => "stomach",
            Organ::Pancreas => "pancreas",
        }
    }

    /// The shape in scene coordinates (organs are placed as in the organs scene).
    pub fn shape(self) -> Shape {
        use Primitive::*;
        let e = |c: [f64; 3], r: [f64; 3], rot: [f64; 3]| Ellipsoid {
            center: c,
            radii: r,
            rotation_deg: rot,
        };
        match self {
            Organ::Cylinder => Shape {
                parts: vec![Cylinder {
                    center: [0.0; 3],
                    radius: 0.62,
                    height: 1.72,
                }],
                blend: 0.0,
                scale: [1.0; 3],
                offset: [0.0; 3],
            },
            Organ::Liver => Shape {
                parts: vec![
                    e([0.0, 0.0, 0.0], [1.15, 0.75, 0.42], [0.0, 0.0, -10.0]),
                    e([-0.95, 0.15, 0.05], [0.75, 0.5, 0.25], [0.0, 10.0, 15.0]),
                ],
                blend: 0.25,
                scale: [1.0, 1.0, 1.0],
                offset: [1.1, 0.9, 0.0],
            },
            Organ::Spleen => Shape {
                parts: vec![
                    e([0.0, 0.3, 0.0], [0.28, 0.5, 0.22], [0.0, 0.0, 20.0]),
                    e([0.08, -0.25, 0.0], [0.25, 0.42, 0.2], [0.0, 0.0, -20.0]),
                ],
                blend: 0.15,
                scale: [1.0, 1.0, 1.0],
                offset: [-1.674646, 0.5, -0.05],
            },
            Organ::Stomach => Shape {
                parts: vec![
                    Capsule {
                        a: [-0.35, 0.45, 0.0],
                        b: [-0.1, -0.35, 0.0],
                        ra: 0.42,
                        rb: 0.36,
                    },
                    Capsule {
                        a: [-0.1, -0.35, 0.0],
                        b: [0.55, -0.45, 0.0],
                        ra: 0.36,
                        rb: 0.2,
                    },
                ],
                blend: 0.15,
                scale: [1.0, 1.0, 1.0],
                offset: [-0.622765, 0.35, 0.1],
            },
            Organ::Pancreas => Shape {
                parts: vec![
                    Capsule {
                        a: [-0.9, 0.1, 0.0],
                        b: [0.2, -0.05, 0.0],
                        ra: 0.14,
                        rb: 0.2,
                    },
                    e([0.45, -0.1, 0.0], [0.35, 0.28, 0.2], [0.0, 0.0, 0.0]),
                ],
                blend: 0.12,
                scale: [1.0, 1.0, 1.0],
                offset: [-0.55, -0.349659, -0.35],
            },
        }
    }

    /// Lattice spacing at resolution 1, chosen so the counts match the paper's Table I (and
    /// its cylinder) within 15 % (see the generator tests).
    pub fn base_spacing(self) -> f64 {
        match self {
            Organ::Cylinder => 0.3,
            Organ::Liver => 0.1925,
            Organ::Spleen => 0.145,
            Organ::Stomach => 0.1825,
            Organ::Pancreas => 0.14,
        }
    }

    /// Minimum dihedral angle kept when interior nodes are removed by
    /// [`coarsen_interior`] (degrees), or `None` for no coarsening. The paper's organ meshes
    /// (TetGen, no Steiner points) have almost every node on the surface; coarsening the
    /// interior gives the same proportions. The paper's cylinder keeps interior nodes.
    pub fn coarsening(self) -> Option<f64> {
        match self {
            Organ::Cylinder => None,
            _ => Some(18.0),
        }
    }

    /// The paper's counts (nodes, tets, surface triangles); for the cylinder, section IV-A.
    pub fn paper_counts(self) -> (usize, usize, usize) {
        match self {
            Organ::Cylinder => (252, 939, 336),
            Organ::Liver => (504, 1578, 1004),
            Organ::Spleen => (218, 661, 432),
            Organ::Stomach => (291, 890, 578),
            Organ::Pancreas => (229, 657, 454),
        }
    }

    /// Meshes the body. `resolution` 1 gives the paper's size; 2 halves the lattice spacing
    /// (about 8 times the tetrahedra), and so on.
    pub fn generate(self, resolution: f64) -> Result<TetMesh, GenerateError> {
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(GenerateError::Spacing {
                spacing: f64::NAN,
                reason: format!("resolution must be positive, found {resolution}"),
            });
        }
        let mesh = stuff(&self.shape(), self.base_spacing() / resolution)?;
        match self.coarsening() {
            Some(angle) => Ok(coarsen_interior(&mesh, angle)?),
            None => Ok(mesh),
        }
    }
}

impl std::str::FromStr for Organ {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [Organ::Cylinder]
            .into_iter()
            .chain(Organ::ORGANS)
            .find(|o| o.name() == s)
            .ok_or_else(|| {
                format!("unknown body '{s}': expected cylinder, liver, spleen, stomach or pancreas")
            })
    }
}

/// A structured box mesh from `min` to `max` with `cells` cubes along each axis, each split
/// into six tetrahedra around its main diagonal (Kuhn subdivision; conforming because every
/// cube is split the same way). For beams, patch tests and convergence studies.
pub fn block(min: Vec3, max: Vec3, cells: [usize; 3]) -> Result<TetMesh, MeshError> {
    let [nx, ny, nz] = cells.map(|c| c.max(1));
    let idx = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
    let mut positions = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                let t = Vec3::new(
                    i as f64 / nx as f64,
                    j as f64 / ny as f64,
                    k as f64 / nz as f64,
                );
                positions.push(min + (max - min).component_mul(&t));
            }
        }
    }
    const PERMS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for p in PERMS {
                    let mut c = [i, j, k];
                    let mut tet = [idx(i, j, k), 0, 0, idx(i + 1, j + 1, k + 1)];
                    for (s, &axis) in p.iter().take(2).enumerate() {
                        c[axis] += 1;
                        tet[s + 1] = idx(c[0], c[1], c[2]);
                    }
                    let v = super::tet_signed_volume(&[
                        positions[tet[0]],
                        positions[tet[1]],
                        positions[tet[2]],
                        positions[tet[3]],
                    ]);
                    if v < 0.0 {
                        tet.swap(1, 2);
                    }
                    tets.push(tet);
                }
            }
        }
    }
    TetMesh::new(positions, tets)
}
