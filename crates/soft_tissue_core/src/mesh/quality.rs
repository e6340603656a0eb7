//! Element quality measures.

use crate::Vec3;
use serde::{Deserialize, Serialize};

/// Quality statistics over all tetrahedra of a mesh.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QualityReport {
    /// Smallest dihedral angle of any tet, degrees (regular tet: 70.53).
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle of any tet, degrees.
    pub max_dihedral_deg: f64,
    /// Largest aspect ratio: longest edge over `2 sqrt(6)` times the inradius (1 for a
    /// regular tet, growing without bound as a tet flattens).
    pub max_aspect_ratio: f64,
    /// Mean aspect ratio.
    pub mean_aspect_ratio: f64,
    /// Smallest radius ratio `3 r_in / r_circ` (1 regular, 0 flat).
    pub min_radius_ratio: f64,
    /// Smallest tet volume.
    pub min_volume: f64,
    /// Largest tet volume.
    pub max_volume: f64,
    /// Index of the tet with the smallest dihedral angle.
    pub worst_tet: usize,
}

impl QualityReport {
    /// Computes the statistics. `tets` must be non-empty and index into `positions`.
    pub fn compute(positions: &[Vec3], tets: &[[u32; 4]]) -> Self {
        let mut r = QualityReport {
            min_dihedral_deg: f64::INFINITY,
            max_dihedral_deg: 0.0,
            max_aspect_ratio: 0.0,
            mean_aspect_ratio: 0.0,
            min_radius_ratio: f64::INFINITY,
            min_volume: f64::INFINITY,
            max_volume: 0.0,
            worst_tet: 0,
        };
        for (i, t) in tets.iter().enumerate() {
            let p = t.map(|n| positions[n as usize]);
            let angles = tet_dihedral_angles(&p);
            let (lo, hi) = angles.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &a| {
                (lo.min(a), hi.max(a))
            });
            if lo < r.min_dihedral_deg {
                r.min_dihedral_deg = lo;
                r.worst_tet = i;
            }
            r.max_dihedral_deg = r.max_dihedral_deg.max(hi);
            let m = tet_measures(&p);
            let aspect = m.longest_edge / (2.0 * 6f64.sqrt() * m.inradius);
            r.max_aspect_ratio = r.max_aspect_ratio.max(aspect);
            r.mean_aspect_ratio += aspect;
            r.min_radius_ratio = r.min_radius_ratio.min(3.0 * m.inradius / m.circumradius);
            r.min_volume = r.min_volume.min(m.volume);
            r.max_volume = r.max_volume.max(m.volume);
        }
        r.mean_aspect_ratio /= tets.len().max(1) as f64;
        r
    }
}

/// Outward unit face normals of a tetrahedron; face i is opposite corner i (a zero normal
/// for a degenerate face).
fn unit_face_normals(p: &[Vec3; 4]) -> [Vec3; 4] {
    super::topology::TET_FACES.map(|f| {
        let [a, b, c] = f.map(|i| p[i]);
        let v = (b - a).cross(&(c - a));
        let len = v.norm();
        if len > 0.0 { v / len } else { v }
    })
}

/// The six dihedral angles of a tetrahedron in degrees, at edges 01, 02, 03, 12, 13, 23.
pub fn tet_dihedral_angles(p: &[Vec3; 4]) -> [f64; 6] {
    let n = unit_face_normals(p);
    // The edge (i, j) is shared by the faces opposite the two other corners k, l; the
    // dihedral angle is pi minus the angle between their outward normals.
    // Edges 01, 02, 03, 12, 13, 23 and the faces opposite their two other corners.
    let others = [(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)];
    others.map(|(k, l)| {
        let c = n[k].dot(&n[l]).clamp(-1.0, 1.0);
        180.0 - c.acos().to_degrees()
    })
}

/// The quality the mesher's bound is checked against, degrees: the smallest of `min(b, 180 - b)`
/// over the dihedral angles `b` of a positive tetrahedron, or -1 for a flat, inverted or
/// non-finite one.
pub(crate) fn tet_quality_deg(p: &[Vec3; 4]) -> f64 {
    // Six acos, as the built-in meshes were generated with: `tet_worst_cos` gives the same
    // angle to rounding, and rounding decides which tetrahedra the generator keeps, so the
    // committed meshes stay reproducible byte for byte.
    let volume = super::tet_signed_volume(p);
    if volume.is_nan() || volume <= 0.0 {
        return -1.0;
    }
    let mut q = f64::INFINITY;
    for b in tet_dihedral_angles(p) {
        if !b.is_finite() {
            return -1.0;
        }
        q = q.min(b.min(180.0 - b));
    }
    q
}

/// The cosine of [`tet_quality_deg`] without the acos, for searches that only compare: the
/// largest |cos| between two faces' normals (`min(b, 180 - b)` over the six angles `b` is
/// its acos, since b is 180 degrees less the angle between the outward normals), or
/// infinity for a flat, inverted or non-finite tetrahedron. Smaller is better.
pub(crate) fn tet_worst_cos(p: &[Vec3; 4]) -> f64 {
    let volume = super::tet_signed_volume(p);
    if volume.is_nan() || volume <= 0.0 {
        return f64::INFINITY;
    }
    let n = unit_face_normals(p);
    let mut worst: f64 = 0.0;
    for (k, l) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] {
        let c = n[k].dot(&n[l]).abs();
        if !c.is_finite() {
            return f64::INFINITY;
        }
        worst = worst.max(c);
    }
    worst.min(1.0)
}

/// Radius ratio `3 r_in / r_circ` of a tetrahedron (1 regular, 0 flat).
pub fn tet_radius_ratio(p: &[Vec3; 4]) -> f64 {
    let m = tet_measures(p);
    3.0 * m.inradius / m.circumradius
}

struct TetMeasures {
    volume: f64,
    inradius: f64,
    circumradius: f64,
    longest_edge: f64,
}

fn tet_measures(p: &[Vec3; 4]) -> TetMeasures {
    let volume = super::tet_signed_volume(p).abs();
    let area: f64 = super::topology::TET_FACES
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| p[i]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum();
    let inradius = if area > 0.0 { 3.0 * volume / area } else { 0.0 };
    // Circumradius: |a|^2 (b x c) + |b|^2 (c x a) + |c|^2 (a x b) over 12 V, relative to p0.
    let (a, b, c) = (p[1] - p[0], p[2] - p[0], p[3] - p[0]);
    let num = b.cross(&c) * a.norm_squared()
        + c.cross(&a) * b.norm_squared()
        + a.cross(&b) * c.norm_squared();
    let circumradius = if volume > 0.0 {
        num.norm() / (12.0 * volume)
    } else {
        f64::INFINITY
    };
    let mut longest_edge: f64 = 0.0;
    for i in 0..4 {
        for j in i + 1..4 {
            longest_edge = longest_edge.max((p[i] - p[j]).norm());
        }
    }
    TetMeasures {
        volume,
        inradius,
        circumradius,
        longest_edge,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn regular() -> [Vec3; 4] {
        [
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, -1.0, -1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, -1.0, 1.0),
        ]
    }

    #[test]
    fn regular_tet_measures_match_closed_form() {
        let p = regular();
        let expected = (1.0f64 / 3.0).acos().to_degrees(); // 70.5288 degrees
        for a in tet_dihedral_angles(&p) {
            assert!((a - expected).abs() < 1e-10, "{a}");
        }
        assert!((tet_radius_ratio(&p) - 1.0).abs() < 1e-12);
        let q = QualityReport::compute(&p, &[[0, 1, 2, 3]]);
        assert!((q.max_aspect_ratio - 1.0).abs() < 1e-12);
    }

    #[test]
    fn corner_tet_has_right_and_acute_angles() {
        // Unit corner tet: three right dihedral angles at the edges through the origin, and
        // acos(1/sqrt 3) = 54.7356 degrees at the edges of the slanted face.
        let p = [
            Vec3::zeros(),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let a = tet_dihedral_angles(&p);
        let slanted = (1.0f64 / 3f64.sqrt()).acos().to_degrees();
        for k in 0..3 {
            assert!((a[k] - 90.0).abs() < 1e-10);
            assert!((a[k + 3] - slanted).abs() < 1e-10);
        }
        // The bound's quality is the smallest of the three right angles' and the slanted
        // ones' distance from flat: acos(1/sqrt 3) itself.
        assert!((tet_quality_deg(&p) - slanted).abs() < 1e-10);
    }

    /// The bound's quality is the smallest `min(b, 180 - b)` over the six angles, and the
    /// search's (one acos of the largest |cos| between face normals) agrees with it, from
    /// flat slivers to needles; -1 and infinity for an inverted or flat tetrahedron.
    #[test]
    fn quality_is_the_smallest_angle_from_flat() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut checked = 0;
        for k in 0..2000 {
            let scale = 10f64.powi(k % 7 - 3);
            let p: [Vec3; 4] =
                std::array::from_fn(|_| Vec3::new(next(), next(), next() * scale) * 2.0);
            let volume = crate::mesh::tet_signed_volume(&p);
            if volume <= 0.0 {
                assert_eq!(tet_quality_deg(&p), -1.0);
                assert_eq!(tet_worst_cos(&p), f64::INFINITY);
                continue;
            }
            let expected = tet_dihedral_angles(&p)
                .iter()
                .map(|b| b.min(180.0 - b))
                .fold(f64::INFINITY, f64::min);
            assert!((tet_quality_deg(&p) - expected).abs() < 1e-12, "{p:?}");
            let fast = tet_worst_cos(&p).acos().to_degrees();
            assert!((fast - expected).abs() < 1e-6, "{p:?}");
            checked += 1;
        }
        assert!(checked > 500);
        let flat = [
            Vec3::zeros(),
            Vec3::x(),
            Vec3::y(),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        assert_eq!(tet_quality_deg(&flat), -1.0);
        assert_eq!(tet_worst_cos(&flat), f64::INFINITY);
    }
}
