//! Small geometric predicates shared by the cage and contact code: solid angles, closest
//! points on triangles and segments, point-triangle distance,
//! segment-triangle and triangle-triangle intersection.

use crate::Vec3;

/// Signed solid angle of the triangle `(a, b, c)` (positions relative to the viewpoint),
/// positive when the triangle is counter-clockwise seen from the viewpoint's far side
/// (Van Oosterom and Strackee 1983).
#[inline]
pub(crate) fn solid_angle(a: &Vec3, b: &Vec3, c: &Vec3) -> f64 {
    let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
    let num = a.dot(&b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * num.atan2(den)
}

/// Distance from `p` to the triangle `(a, b, c)`.
pub(crate) fn point_triangle_distance(p: &Vec3, a: &Vec3, b: &Vec3, c: &Vec3) -> f64 {
    let w = closest_on_triangle(p, a, b, c);
    (p - (a * w[0] + b * w[1] + c * w[2])).norm()
}

/// Barycentric weights of the point of triangle `(a, b, c)` closest to `p` (Ericson,
/// Real-Time Collision Detection, 5.1.5: the Voronoi region of `p`). Weights that are zero
/// name the edge or vertex the point lies on.
pub(crate) fn closest_on_triangle(p: &Vec3, a: &Vec3, b: &Vec3, c: &Vec3) -> [f64; 3] {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    [1.0 - v - w, v, w]
}

/// Parameter in [0, 1] of the point of segment `a b` closest to `p`.
pub(crate) fn closest_on_segment(p: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    if len2 <= 0.0 {
        return 0.0;
    }
    ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
}

/// Whether the open segment `p q` crosses the interior of triangle `(a, b, c)`, with a
/// relative tolerance that ignores touching at endpoints and edges.
fn segment_crosses_triangle(p: &Vec3, q: &Vec3, a: &Vec3, b: &Vec3, c: &Vec3) -> bool {
    const EPS: f64 = 1e-9;
    let d = q - p;
    let e1 = b - a;
    let e2 = c - a;
    let h = d.cross(&e2);
    let det = e1.dot(&h);
    let scale = d.norm() * e1.norm() * e2.norm();
    if det.abs() <= 1e-12 * scale {
        return false; // parallel
    }
    let inv = 1.0 / det;
    let s = p - a;
    let u = inv * s.dot(&h);
    if u <= EPS || u >= 1.0 - EPS {
        return false;
    }
    let qv = s.cross(&e1);
    let v = inv * d.dot(&qv);
    if v <= EPS || u + v >= 1.0 - EPS {
        return false;
    }
    let t = inv * e2.dot(&qv);
    t > EPS && t < 1.0 - EPS
}

/// Whether two triangles (vertex indices and positions) intersect other than along what
/// they share. Triangles sharing an edge intersect when they fold onto each other.
pub(crate) fn triangles_intersect(
    ti: &[u32; 3],
    pi: &[Vec3; 3],
    tj: &[u32; 3],
    pj: &[Vec3; 3],
) -> bool {
    let shared = ti.iter().filter(|v| tj.contains(v)).count();
    if shared >= 2 {
        let ni = (pi[1] - pi[0]).cross(&(pi[2] - pi[0])).normalize();
        let nj = (pj[1] - pj[0]).cross(&(pj[2] - pj[0])).normalize();
        return ni.dot(&nj) < -1.0 + 1e-9;
    }
    triangles_cross(pi, pj)
}

/// Whether an edge of either triangle crosses the interior of the other.
pub(crate) fn triangles_cross(pi: &[Vec3; 3], pj: &[Vec3; 3]) -> bool {
    (0..3).any(|k| {
        let (a, b) = (k, (k + 1) % 3);
        segment_crosses_triangle(&pi[a], &pi[b], &pj[0], &pj[1], &pj[2])
            || segment_crosses_triangle(&pj[a], &pj[b], &pi[0], &pi[1], &pi[2])
    })
}

/// The first pair of intersecting triangles, found by a sweep over their x extents.
pub(crate) fn first_self_intersection(v: &[Vec3], t: &[[u32; 3]]) -> Option<(usize, usize)> {
    let pos = |i: usize| t[i].map(|k| v[k as usize]);
    let mut boxes: Vec<(f64, f64, usize)> = (0..t.len())
        .map(|i| {
            let p = pos(i);
            let lo = p[0].x.min(p[1].x).min(p[2].x);
            let hi = p[0].x.max(p[1].x).max(p[2].x);
            (lo, hi, i)
        })
        .collect();
    boxes.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut hits: Vec<(usize, usize)> = Vec::new();
    for (k, &(_, hi, i)) in boxes.iter().enumerate() {
        let pi = pos(i);
        for &(lo2, _, j) in &boxes[k + 1..] {
            if lo2 > hi {
                break;
            }
            let pj = pos(j);
            if triangles_intersect(&t[i], &pi, &t[j], &pj) {
                hits.push((i.min(j), i.max(j)));
            }
        }
    }
    hits.into_iter().min()
}
