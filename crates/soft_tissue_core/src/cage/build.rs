//! Cage builders: the paper's bounding box and a fitted cage.
//!
//! The fitted cage starts from the bounding box (grown by the margin) divided into a grid of
//! about-square cells, as many as the vertex budget allows, and shrink-wraps it: each cage
//! vertex in turn moves inward along its normal (and, alternately, toward the centroid of its
//! neighbours, to keep triangles well shaped) with a step that grows on success and halves on
//! failure. A move is accepted only if
//! - no point of the body changes side (the winding-number change over the moved fan is zero),
//! - the moved triangles cross no triangle of the body's surface (so the whole surface, not
//!   only its vertices, stays inside),
//! - every point stays at least `margin` from the moved triangles,
//! - the moved triangles stay non-degenerate, do not fold, and intersect no other triangle.
//!
//! Every accepted state is therefore a closed, non-self-intersecting cage enclosing every
//! point with the margin; the final cage is validated again by [`Cage::new`] and checked
//! against every point.

// The sweep indexes the per-vertex step alongside the wrap's own vectors.
#![allow(clippy::needless_range_loop)]

use std::collections::HashMap;

use super::{Cage, CageError};
use crate::Vec3;
use crate::geometry::{point_triangle_distance, solid_angle, triangles_cross, triangles_intersect};

fn bounds(points: &[Vec3]) -> Result<(Vec3, Vec3), CageError> {
    let Some(first) = points.first() else {
        return Err(CageError::InvalidArgument {
            field: "points",
            message: "no points to enclose".into(),
        });
    };
    let (mut lo, mut hi) = (*first, *first);
    for (i, p) in points.iter().enumerate() {
        if !p.iter().all(|c| c.is_finite()) {
            return Err(CageError::InvalidArgument {
                field: "points",
                message: format!("point {i} is not finite: {:?}", [p.x, p.y, p.z]),
            });
        }
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    Ok((lo, hi))
}

fn check_margin(margin: f64) -> Result<(), CageError> {
    if margin.is_finite() && margin > 0.0 {
        Ok(())
    } else {
        Err(CageError::InvalidArgument {
            field: "margin",
            message: format!("must be positive and finite, found {margin}"),
        })
    }
}

/// The default margin for a point set: 2 % of its bounding-box diagonal.
pub fn default_margin(points: &[Vec3]) -> f64 {
    match bounds(points) {
        Ok((lo, hi)) => 0.02 * (hi - lo).norm().max(f64::MIN_POSITIVE),
        Err(_) => 0.0,
    }
}

/// A closed grid on the surface of the box `[lo, hi]` with `cells` cells along each axis,
/// triangulated with outward orientation.
fn box_grid(lo: Vec3, hi: Vec3, cells: [usize; 3]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut index: HashMap<[usize; 3], u32> = HashMap::new();
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut vertex = |ijk: [usize; 3], vertices: &mut Vec<Vec3>| -> u32 {
        *index.entry(ijk).or_insert_with(|| {
            let p = Vec3::from_fn(|a, _| lo[a] + (hi[a] - lo[a]) * ijk[a] as f64 / cells[a] as f64);
            vertices.push(p);
            (vertices.len() - 1) as u32
        })
    };
    for a in 0..3 {
        let (u, v) = ((a + 1) % 3, (a + 2) % 3);
        for side in [0, cells[a]] {
            for i in 0..cells[u] {
                for j in 0..cells[v] {
                    let corner = |di: usize, dj: usize| {
                        let mut ijk = [0; 3];
                        ijk[a] = side;
                        ijk[u] = i + di;
                        ijk[v] = j + dj;
                        ijk
                    };
                    let q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)]
                        .map(|c| vertex(c, &mut vertices));
                    // Alternate diagonals so the grid has no preferred direction.
                    let t = if (i + j) % 2 == 0 {
                        [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
                    } else {
                        [[q[0], q[1], q[3]], [q[1], q[2], q[3]]]
                    };
                    for mut tri in t {
                        if side == 0 {
                            tri.swap(1, 2);
                        }
                        triangles.push(tri);
                    }
                }
            }
        }
    }
    (vertices, triangles)
}

/// The paper's cage: the bounding box of `points` grown by `margin` on every side (8
/// vertices, 12 triangles). The margin keeps points off the cage, where Green coordinates are
/// singular.
pub fn box_cage(points: &[Vec3], margin: f64) -> Result<Cage, CageError> {
    check_margin(margin)?;
    let (lo, hi) = bounds(points)?;
    let m = Vec3::repeat(margin);
    let (v, t) = box_grid(lo - m, hi + m, [1, 1, 1]);
    Cage::new(v, t)
}

/// Options of [`fitted_cage`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Most cage vertices (at least 8).
    pub max_vertices: usize,
    /// Smallest distance from any point to the cage.
    pub margin: f64,
    /// Most shrink-wrap sweeps over the vertices.
    pub max_sweeps: usize,
}

impl FitOptions {
    /// `max_vertices` vertices, the [`default_margin`] of `points`, 80 sweeps.
    pub fn for_points(points: &[Vec3], max_vertices: usize) -> Self {
        FitOptions {
            max_vertices,
            margin: default_margin(points),
            max_sweeps: 80,
        }
    }
}

/// Cells per axis with at most `budget` grid vertices (`2 (ab + bc + ca) + 2`), as close to
/// cubic cells as possible, then as many vertices as possible.
fn grid_cells(extent: Vec3, budget: usize) -> [usize; 3] {
    let mut best = ([1, 1, 1], f64::INFINITY, 8);
    for a in 1..=24usize {
        for b in 1..=24usize {
            for c in 1..=24usize {
                let v = 2 * (a * b + b * c + c * a) + 2;
                if v > budget {
                    continue;
                }
                let size = [
                    extent.x / a as f64,
                    extent.y / b as f64,
                    extent.z / c as f64,
                ];
                let worst = size.iter().cloned().fold(0.0, f64::max);
                if worst < best.1 * (1.0 - 1e-9) || (worst <= best.1 * (1.0 + 1e-9) && v > best.2) {
                    best = ([a, b, c], worst, v);
                }
            }
        }
    }
    best.0
}

struct Wrap<'a> {
    points: &'a [Vec3],
    margin: f64,
    v: Vec<Vec3>,
    t: Vec<[u32; 3]>,
    incident: Vec<Vec<usize>>,
    ring: Vec<Vec<u32>>,
    /// Body surface triangles (positions) with their bounding boxes.
    body: Vec<([Vec3; 3], Vec3, Vec3)>,
}

impl Wrap<'_> {
    fn tri(&self, f: usize, moved: usize, to: &Vec3) -> [Vec3; 3] {
        self.t[f].map(|i| {
            if i as usize == moved {
                *to
            } else {
                self.v[i as usize]
            }
        })
    }

    fn normal(&self, i: usize) -> Vec3 {
        let mut n = Vec3::zeros();
        for &f in &self.incident[i] {
            let p = self.t[f].map(|k| self.v[k as usize]);
            n += (p[1] - p[0]).cross(&(p[2] - p[0]));
        }
        n.try_normalize(0.0).unwrap_or_else(Vec3::zeros)
    }

    /// Whether moving vertex `i` to `to` keeps every invariant (see the module docs).
    fn valid(&self, i: usize, to: &Vec3) -> bool {
        let from = self.v[i];
        // Shape of the moved fan.
        for &f in &self.incident[i] {
            let old = self.t[f].map(|k| self.v[k as usize]);
            let new = self.tri(f, i, to);
            let n_old = (old[1] - old[0]).cross(&(old[2] - old[0]));
            let n_new = (new[1] - new[0]).cross(&(new[2] - new[0]));
            if n_new.norm() < 1e-3 * n_old.norm() || n_new.normalize().dot(&n_old.normalize()) < 0.3
            {
                return false;
            }
        }
        // Points near the moved fan: no side change, margin kept.
        let mut lo = from.inf(to);
        let mut hi = from.sup(to);
        for &k in &self.ring[i] {
            lo = lo.inf(&self.v[k as usize]);
            hi = hi.sup(&self.v[k as usize]);
        }
        let m = Vec3::repeat(self.margin);
        let (lo, hi) = (lo - m, hi + m);
        for p in self.points {
            if (0..3).any(|a| p[a] < lo[a] || p[a] > hi[a]) {
                continue;
            }
            let mut change = 0.0;
            for &f in &self.incident[i] {
                let old = self.t[f].map(|k| self.v[k as usize] - p);
                let new = self.tri(f, i, to).map(|q| q - p);
                change +=
                    solid_angle(&new[0], &new[1], &new[2]) - solid_angle(&old[0], &old[1], &old[2]);
                if point_triangle_distance(p, &(new[0] + p), &(new[1] + p), &(new[2] + p))
                    < self.margin
                {
                    return false;
                }
            }
            if change.abs() > std::f64::consts::PI {
                return false;
            }
        }
        // No intersection of the moved fan with any cage or body triangle.
        for &f in &self.incident[i] {
            let pf = self.tri(f, i, to);
            let flo = pf[0].inf(&pf[1]).inf(&pf[2]);
            let fhi = pf[0].sup(&pf[1]).sup(&pf[2]);
            for (pb, blo, bhi) in &self.body {
                if (0..3).any(|a| blo[a] > fhi[a] || bhi[a] < flo[a]) {
                    continue;
                }
                if triangles_cross(&pf, pb) {
                    return false;
                }
            }
            for g in 0..self.t.len() {
                if g == f {
                    continue;
                }
                let pg = self.tri(g, i, to);
                let glo = pg[0].inf(&pg[1]).inf(&pg[2]);
                let ghi = pg[0].sup(&pg[1]).sup(&pg[2]);
                if (0..3).any(|a| glo[a] > fhi[a] || ghi[a] < flo[a]) {
                    continue;
                }
                if triangles_intersect(&self.t[f], &pf, &self.t[g], &pg) {
                    return false;
                }
            }
        }
        true
    }
}

/// A cage fitted to `points` (all the body's nodes, so that every one is enclosed) and to
/// the body's surface triangles `surface` (indices into `points`; may be empty for a point
/// cloud), with at most `options.max_vertices` vertices, by shrink-wrapping a box grid (see
/// the module docs).
pub fn fitted_cage(
    points: &[Vec3],
    surface: &[[u32; 3]],
    options: &FitOptions,
) -> Result<Cage, CageError> {
    check_margin(options.margin)?;
    if options.max_vertices < 8 {
        return Err(CageError::InvalidArgument {
            field: "max_vertices",
            message: format!("must be at least 8, found {}", options.max_vertices),
        });
    }
    let (lo, hi) = bounds(points)?;
    let mut body = Vec::with_capacity(surface.len());
    for (k, t) in surface.iter().enumerate() {
        if t.iter().any(|&i| i as usize >= points.len()) {
            return Err(CageError::InvalidArgument {
                field: "surface",
                message: format!("triangle {k} {t:?} refers past the {} points", points.len()),
            });
        }
        let p = t.map(|i| points[i as usize]);
        body.push((p, p[0].inf(&p[1]).inf(&p[2]), p[0].sup(&p[1]).sup(&p[2])));
    }
    let m = Vec3::repeat(options.margin * 1.01);
    let (lo, hi) = (lo - m, hi + m);
    let extent = hi - lo;
    let (v, t) = box_grid(lo, hi, grid_cells(extent, options.max_vertices));
    let mut incident = vec![Vec::new(); v.len()];
    let mut ring: Vec<Vec<u32>> = vec![Vec::new(); v.len()];
    for (f, tri) in t.iter().enumerate() {
        for k in 0..3 {
            incident[tri[k] as usize].push(f);
            for d in [1, 2] {
                let o = tri[(k + d) % 3];
                if !ring[tri[k] as usize].contains(&o) {
                    ring[tri[k] as usize].push(o);
                }
            }
        }
    }
    let mut w = Wrap {
        points,
        margin: options.margin,
        v,
        t,
        incident,
        ring,
        body,
    };
    let smallest = extent.min();
    let mut step = vec![0.25 * smallest; w.v.len()];
    let min_step = 0.05 * options.margin;
    for sweep in 0..options.max_sweeps {
        let mut moved = false;
        for i in 0..w.v.len() {
            if step[i] < min_step {
                continue;
            }
            // Inward along the normal, else toward the nearest point of the body.
            let n = w.normal(i);
            let nearest = points
                .iter()
                .min_by(|a, b| {
                    (*a - w.v[i])
                        .norm_squared()
                        .total_cmp(&(*b - w.v[i]).norm_squared())
                })
                .map(|p| (p - w.v[i]).normalize())
                .unwrap_or_else(Vec3::zeros);
            // The nearest-point direction with one axis removed lets a vertex slide along a
            // flat side of the starting box without tilting the triangles above a flat part
            // of the body (a cylinder's cap).
            let slide = |a: usize| {
                let mut d = nearest;
                d[a] = 0.0;
                d.try_normalize(1e-12).unwrap_or_else(Vec3::zeros)
            };
            let accepted = [-n, nearest, slide(0), slide(1), slide(2)]
                .into_iter()
                .filter(|d| d.norm_squared() > 0.0)
                .map(|d| w.v[i] + d * step[i])
                .find(|to| w.valid(i, to));
            if let Some(to) = accepted {
                w.v[i] = to;
                step[i] = (step[i] * 1.5).min(0.25 * smallest);
                moved = true;
            } else {
                step[i] *= 0.5;
            }
        }
        // Tangential relaxation every other sweep: toward the ring centroid, in the tangent
        // plane, half way.
        if sweep % 2 == 1 {
            for i in 0..w.v.len() {
                let n = w.normal(i);
                let c = w.ring[i].iter().map(|&k| w.v[k as usize]).sum::<Vec3>()
                    / w.ring[i].len() as f64;
                let d = c - w.v[i];
                let d = (d - n * n.dot(&d)) * 0.5;
                if d.norm() > min_step {
                    let to = w.v[i] + d;
                    if w.valid(i, &to) {
                        w.v[i] = to;
                    }
                }
            }
        }
        if !moved {
            break;
        }
    }
    let cage = Cage::new(w.v, w.t)
        .map_err(|e| CageError::Build(format!("the shrink-wrapped cage is invalid: {e}")))?;
    for (i, p) in points.iter().enumerate() {
        let wn = cage.winding_number(p);
        if (wn - 1.0).abs() > 1e-6 {
            return Err(CageError::Build(format!(
                "point {i} ended outside the fitted cage (winding number {wn})"
            )));
        }
    }
    Ok(cage)
}
