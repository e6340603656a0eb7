//! 3D Green coordinates (Lipman, Levin and Cohen-Or 2008) in closed form.
//!
//! For a point `eta` inside a closed triangle cage with outward unit normals `n_j`, Green's
//! third identity applied to the linear function `f(x) = x` gives
//! `eta = sum_i phi_i(eta) v_i + sum_j psi_j(eta) n_j`, with
//! `phi_i = 1/(4 pi) int Gamma_i(x) (x - eta).n / |x - eta|^3` (the double-layer potential of the
//! hat function of vertex `i`) and `psi_j = 1/(4 pi) int_{t_j} 1 / |x - eta|` (the single-layer
//! potential of face `j`). A deformed cage maps the point to
//! `sum_i phi_i v'_i + sum_j psi_j s_j n'_j` (paper eq. 8), where `s_j` is the stretch factor of
//! face `j`: a similarity of the cage moves the point by the same similarity.
//!
//! Per face the integrals have closed forms (this module's derivation, checked against
//! numerical quadrature in the tests): with `a_k = v_k - eta`, `h = a_0.n`, the signed solid
//! angle `Omega` (Van Oosterom and Strackee), and per edge the in-plane outward normal `m_e`,
//! the line integral `L_e = int_e 1 / |x - eta|` and `t_e = a_e.m_e`,
//! - `int 1/R = sum_e t_e L_e - h Omega` (divergence theorem on `(x - rho) / R` in the plane),
//! - `W = int (x - eta) / R^3 = Omega n - sum_e m_e L_e`, and since
//!   `x - eta = sum_k Gamma_k(x) a_k`, Cramer's rule gives the vertex terms
//!   `phi_k += W.(a_{k+1} x a_{k+2}) / (8 pi A)`, which stays finite when `eta` is in the
//!   face's plane.
//!
//! `L_e` is evaluated in the form that avoids cancellation for every position of `eta` along
//! the edge's line. The winding number `sum Omega / (4 pi)` is 1 inside and 0 outside, so
//! points outside (or on) the cage are detected, never silently mis-weighted.

use std::f64::consts::PI;

use super::{Cage, CageError};
use crate::Vec3;

/// Per-face rest data: unit normal, area, unit edge directions and in-plane outward edge
/// normals (edge `k` runs from corner `k` to corner `k + 1`).
#[derive(Debug, Clone)]
struct Face {
    v: [u32; 3],
    n: Vec3,
    area: f64,
    s: [Vec3; 3],
    m: [Vec3; 3],
}

fn faces_of(cage: &Cage) -> Vec<Face> {
    cage.triangles()
        .iter()
        .map(|t| {
            let p = t.map(|i| cage.vertices()[i as usize]);
            let c = (p[1] - p[0]).cross(&(p[2] - p[0]));
            let area = 0.5 * c.norm();
            let n = c / (2.0 * area);
            let s = [0, 1, 2].map(|k| (p[(k + 1) % 3] - p[k]).normalize());
            let m = s.map(|s| s.cross(&n));
            Face {
                v: *t,
                n,
                area,
                s,
                m,
            }
        })
        .collect()
}

/// `int_e 1 / |x - eta|` over the edge with endpoint offsets `a = va - eta`, `b = vb - eta`
/// and unit direction `s`, without cancellation wherever `eta` projects on the edge's line.
#[inline]
fn edge_log(a: &Vec3, b: &Vec3, s: &Vec3) -> f64 {
    let (ra, rb) = (a.norm(), b.norm());
    let (la, lb) = (a.dot(s), b.dot(s));
    if la >= 0.0 {
        ((rb + lb) / (ra + la)).ln()
    } else if lb <= 0.0 {
        ((ra - la) / (rb - lb)).ln()
    } else {
        let r0 = a.cross(s).norm_squared();
        ((rb + lb) * (ra - la) / r0).ln()
    }
}

/// Adds the coordinates of `eta` to `phi` (one per cage vertex) and writes `psi` (one per
/// face); returns the winding number.
fn coordinates_into(
    vertices: &[Vec3],
    faces: &[Face],
    eta: &Vec3,
    phi: &mut [f64],
    psi: &mut [f64],
) -> f64 {
    let mut winding = 0.0;
    for (j, f) in faces.iter().enumerate() {
        let a = f.v.map(|i| vertices[i as usize] - eta);
        let omega = crate::geometry::solid_angle(&a[0], &a[1], &a[2]);
        let h = a[0].dot(&f.n);
        let mut w = f.n * omega;
        let mut single = -h * omega;
        for k in 0..3 {
            let l = edge_log(&a[k], &a[(k + 1) % 3], &f.s[k]);
            w -= f.m[k] * l;
            single += a[k].dot(&f.m[k]) * l;
        }
        psi[j] = single / (4.0 * PI);
        let scale = 1.0 / (8.0 * PI * f.area);
        for k in 0..3 {
            let c = a[(k + 1) % 3].cross(&a[(k + 2) % 3]);
            phi[f.v[k] as usize] += w.dot(&c) * scale;
        }
        winding += omega;
    }
    winding / (4.0 * PI)
}

/// Green coordinates of one point in a cage: `(phi, psi, winding number)`. For checks and
/// one-off queries; [`GreenCoordinates`] precomputes many points.
pub fn coordinates_at(cage: &Cage, eta: &Vec3) -> (Vec<f64>, Vec<f64>, f64) {
    let faces = faces_of(cage);
    let mut phi = vec![0.0; cage.vertices().len()];
    let mut psi = vec![0.0; faces.len()];
    let w = coordinates_into(cage.vertices(), &faces, eta, &mut phi, &mut psi);
    (phi, psi, w)
}

/// Points whose winding number is within this of 1 count as inside.
const INSIDE_TOLERANCE: f64 = 1e-6;

/// Points per SIMD block of the packed single-precision coefficients.
const LANES: usize = 16;

/// One column of a block: the coefficients of 16 points, aligned to a cache line so every
/// vector load is a single line.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
struct Lane([f32; LANES]);

/// The Green coordinates of a set of points in a cage, precomputed once.
///
/// [`GreenCoordinates::evaluate`] maps them through a deformed cage in `f64` (exact up to
/// rounding); [`GreenCoordinates::evaluate_fast`] computes the displacement from the rest
/// position with packed `f32` coefficients (blocks of 32 points, one column per cage vertex
/// and face) and runtime-selected AVX-512 / AVX2 kernels, for the per-step writeback. Its
/// error is about `1e-7` of the displacement, not of the position.
#[derive(Debug, Clone)]
pub struct GreenCoordinates {
    nv: usize,
    faces: Vec<Face>,
    rest_vertices: Vec<Vec3>,
    points: Vec<Vec3>,
    phi: Vec<f64>,
    psi: Vec<f64>,
    packed: Vec<Lane>,
}

/// Work buffers of [`GreenCoordinates::evaluate_fast`] (one per caller, no allocation per
/// call).
#[derive(Debug, Clone, Default)]
pub struct FastScratch {
    q: [Vec<f32>; 3],
}

impl GreenCoordinates {
    /// Coordinates of `points` in `cage`. A point outside the cage or on its boundary is an
    /// error naming it.
    pub fn new(cage: &Cage, points: &[Vec3]) -> Result<Self, CageError> {
        let faces = faces_of(cage);
        let nv = cage.vertices().len();
        let nf = faces.len();
        let mut phi = vec![0.0; points.len() * nv];
        let mut psi = vec![0.0; points.len() * nf];
        for (p, eta) in points.iter().enumerate() {
            if !eta.iter().all(|c| c.is_finite()) {
                return Err(CageError::PointOutside {
                    point: p,
                    position: [eta.x, eta.y, eta.z],
                    winding: f64::NAN,
                });
            }
            let w = coordinates_into(
                cage.vertices(),
                &faces,
                eta,
                &mut phi[p * nv..(p + 1) * nv],
                &mut psi[p * nf..(p + 1) * nf],
            );
            let finite = phi[p * nv..(p + 1) * nv]
                .iter()
                .chain(&psi[p * nf..(p + 1) * nf])
                .all(|v| v.is_finite());
            if !((w - 1.0).abs() < INSIDE_TOLERANCE && finite) {
                return Err(CageError::PointOutside {
                    point: p,
                    position: [eta.x, eta.y, eta.z],
                    winding: w,
                });
            }
        }
        let k = nv + nf;
        // Blocks of 32 points: per column, the 16-lane halves side by side.
        let blocks = points.len().div_ceil(2 * LANES);
        let mut packed = vec![Lane::default(); blocks * k * 2];
        for p in 0..points.len() {
            let (b, half, lane) = (p / (2 * LANES), (p / LANES) % 2, p % LANES);
            for c in 0..k {
                let v = if c < nv {
                    phi[p * nv + c]
                } else {
                    psi[p * nf + c - nv]
                };
                packed[(b * k + c) * 2 + half].0[lane] = v as f32;
            }
        }
        Ok(GreenCoordinates {
            nv,
            faces,
            rest_vertices: cage.vertices().to_vec(),
            points: points.to_vec(),
            phi,
            psi,
            packed,
        })
    }

    /// These coordinates for their cage and points moved rigidly by `m` (a teleport): the
    /// coordinates themselves are the same (Green coordinates do not change under a rigid
    /// motion of the cage and the point together); the rest cage, its face frames and the
    /// points move.
    pub(crate) fn moved(&self, m: &nalgebra::Isometry3<f64>) -> Self {
        let at = |p: &Vec3| m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin();
        let r = m.rotation;
        let mut out = self.clone();
        for f in &mut out.faces {
            f.n = r * f.n;
            f.s = f.s.map(|s| r * s);
            f.m = f.m.map(|v| r * v);
        }
        for p in out.rest_vertices.iter_mut().chain(out.points.iter_mut()) {
            *p = at(p);
        }
        out
    }

    /// Number of embedded points.
    pub fn point_count(&self) -> usize {
        self.points.len()
    }

    /// Number of cage vertices.
    pub fn vertex_count(&self) -> usize {
        self.nv
    }

    /// Number of cage faces.
    pub fn face_count(&self) -> usize {
        self.faces.len()
    }

    /// Rest positions of the embedded points.
    pub fn rest_points(&self) -> &[Vec3] {
        &self.points
    }

    /// Vertex coordinates `phi` of point `p` (one per cage vertex).
    pub fn phi(&self, p: usize) -> &[f64] {
        &self.phi[p * self.nv..(p + 1) * self.nv]
    }

    /// Face coordinates `psi` of point `p` (one per cage face).
    pub fn psi(&self, p: usize) -> &[f64] {
        let nf = self.faces.len();
        &self.psi[p * nf..(p + 1) * nf]
    }

    /// The face terms `s_j n'_j` of a deformed cage: unit normal times the stretch factor
    /// `s_j = sqrt(|u'|^2 |v|^2 - 2 (u'.v')(u.v) + |v'|^2 |u|^2) / (sqrt(8) area_j)` of Lipman
    /// et al. (`u`, `v` two rest edges of the face, primes deformed).
    pub fn face_terms(&self, deformed: &[Vec3], out: &mut [Vec3]) {
        for (f, o) in self.faces.iter().zip(out.iter_mut()) {
            let [i0, i1, i2] = f.v.map(|i| i as usize);
            let (u, v) = (
                self.rest_vertices[i1] - self.rest_vertices[i0],
                self.rest_vertices[i2] - self.rest_vertices[i0],
            );
            let (du, dv) = (deformed[i1] - deformed[i0], deformed[i2] - deformed[i0]);
            let c = du.cross(&dv);
            let len = c.norm();
            let s2 = du.norm_squared() * v.norm_squared() - 2.0 * du.dot(&dv) * u.dot(&v)
                + dv.norm_squared() * u.norm_squared();
            let s = s2.max(0.0).sqrt() / (8f64.sqrt() * f.area);
            *o = if len > 0.0 {
                c * (s / len)
            } else {
                Vec3::zeros()
            };
        }
    }

    fn check_lengths(
        &self,
        deformed: &[Vec3],
        face_terms: &[Vec3],
        out: &[Vec3],
    ) -> Result<(), CageError> {
        let check = |what, expected: usize, found: usize| {
            if expected == found {
                Ok(())
            } else {
                Err(CageError::LengthMismatch {
                    what,
                    expected,
                    found,
                })
            }
        };
        check("deformed cage", self.nv, deformed.len())?;
        check("face terms", self.faces.len(), face_terms.len())?;
        check("output points", self.points.len(), out.len())
    }

    /// The embedded points in the deformed cage, in `f64`: `sum phi_i v'_i + sum psi_j t_j`
    /// with `t_j` from [`GreenCoordinates::face_terms`].
    pub fn evaluate(
        &self,
        deformed: &[Vec3],
        face_terms: &[Vec3],
        out: &mut [Vec3],
    ) -> Result<(), CageError> {
        self.check_lengths(deformed, face_terms, out)?;
        let nf = self.faces.len();
        for (p, o) in out.iter_mut().enumerate() {
            let mut acc = Vec3::zeros();
            for (c, v) in self.phi[p * self.nv..(p + 1) * self.nv]
                .iter()
                .zip(deformed)
            {
                acc += v * *c;
            }
            for (c, t) in self.psi[p * nf..(p + 1) * nf].iter().zip(face_terms) {
                acc += t * *c;
            }
            *o = acc;
        }
        Ok(())
    }

    /// A scratch buffer for [`GreenCoordinates::evaluate_fast`].
    pub fn scratch(&self) -> FastScratch {
        let k = self.nv + self.faces.len();
        FastScratch {
            q: [vec![0.0; k], vec![0.0; k], vec![0.0; k]],
        }
    }

    /// Like [`GreenCoordinates::evaluate`], as rest position plus an `f32` displacement
    /// `sum phi_i (v'_i - v_i) + sum psi_j (t_j - n_j)`. No allocation.
    pub fn evaluate_fast(
        &self,
        deformed: &[Vec3],
        face_terms: &[Vec3],
        scratch: &mut FastScratch,
        out: &mut [Vec3],
    ) -> Result<(), CageError> {
        self.check_lengths(deformed, face_terms, out)?;
        let k = self.nv + self.faces.len();
        if scratch.q.iter().any(|q| q.len() != k) {
            *scratch = self.scratch();
        }
        let d = deformed
            .iter()
            .zip(&self.rest_vertices)
            .map(|(a, b)| a - b)
            .chain(face_terms.iter().zip(&self.faces).map(|(t, f)| t - f.n));
        for (c, v) in d.enumerate() {
            for a in 0..3 {
                scratch.q[a][c] = v[a] as f32;
            }
        }
        let [qx, qy, qz] = &scratch.q;
        kernel_dispatch(&self.packed, k, [qx, qy, qz], &self.points, out);
        Ok(())
    }
}

// Lane loops index several fixed-size arrays in step; written for the vectorizer.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn kernel<const FMA: bool>(
    packed: &[Lane],
    k: usize,
    q: [&[f32]; 3],
    rest: &[Vec3],
    out: &mut [Vec3],
) {
    /// Accumulators of one 32-point block: [half][coordinate][lane].
    type Acc = [[[f32; LANES]; 3]; 2];
    #[inline(always)]
    fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
        if FMA { a.mul_add(b, c) } else { a * b + c }
    }
    #[inline(always)]
    fn column<const FMA: bool>(acc: &mut Acc, col: &[Lane], x: f32, y: f32, z: f32) {
        for (acc, col) in acc.iter_mut().zip(col) {
            for l in 0..LANES {
                acc[0][l] = madd::<FMA>(col.0[l], x, acc[0][l]);
                acc[1][l] = madd::<FMA>(col.0[l], y, acc[1][l]);
                acc[2][l] = madd::<FMA>(col.0[l], z, acc[2][l]);
            }
        }
    }
    // Two 16-lane halves share each broadcast of the control values (fewer loads per FMA);
    // two accumulator sets per half hide the FMA latency; iterators (no indexing) keep the
    // accumulators in registers.
    const U: usize = 2;
    let [qx, qy, qz] = q;
    let (qx, qy, qz) = (&qx[..k], &qy[..k], &qz[..k]);
    let main = k / U * U;
    for (b, chunk) in packed.chunks_exact(2 * k).enumerate() {
        let mut acc: [Acc; U] = [[[[0.0f32; LANES]; 3]; 2]; U];
        let (head, tail) = chunk.split_at(2 * main);
        let qs = qx[..main]
            .chunks_exact(U)
            .zip(qy[..main].chunks_exact(U))
            .zip(qz[..main].chunks_exact(U));
        for (cols, ((x, y), z)) in head.chunks_exact(2 * U).zip(qs) {
            for (u, (acc, col)) in acc.iter_mut().zip(cols.chunks_exact(2)).enumerate() {
                column::<FMA>(acc, col, x[u], y[u], z[u]);
            }
        }
        let qs = qx[main..].iter().zip(&qy[main..]).zip(&qz[main..]);
        for (col, ((x, y), z)) in tail.chunks_exact(2).zip(qs) {
            column::<FMA>(&mut acc[0], col, *x, *y, *z);
        }
        let mut d: Acc = [[[0.0f32; LANES]; 3]; 2];
        for a in acc {
            for h in 0..2 {
                for c in 0..3 {
                    for l in 0..LANES {
                        d[h][c][l] += a[h][c][l];
                    }
                }
            }
        }
        let start = b * 2 * LANES;
        let end = (start + 2 * LANES).min(out.len());
        for (i, (o, r)) in out[start..end]
            .iter_mut()
            .zip(&rest[start..end])
            .enumerate()
        {
            let (h, l) = (i / LANES, i % LANES);
            *o = r + Vec3::new(d[h][0][l] as f64, d[h][1][l] as f64, d[h][2][l] as f64);
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn kernel_avx512(packed: &[Lane], k: usize, q: [&[f32]; 3], rest: &[Vec3], out: &mut [Vec3]) {
    kernel::<true>(packed, k, q, rest, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn kernel_avx2(packed: &[Lane], k: usize, q: [&[f32]; 3], rest: &[Vec3], out: &mut [Vec3]) {
    kernel::<true>(packed, k, q, rest, out)
}

/// Runs the widest kernel the CPU supports (the portable one when
/// [`crate::linalg::set_portable_kernels`] forced it).
#[allow(unsafe_code)]
fn kernel_dispatch(packed: &[Lane], k: usize, q: [&[f32]; 3], rest: &[Vec3], out: &mut [Vec3]) {
    use crate::linalg::KernelVariant;
    match crate::linalg::kernel_variant() {
        // SAFETY: `kernel_variant` saw the features `kernel_avx512` is compiled for.
        #[cfg(target_arch = "x86_64")]
        KernelVariant::Avx512 => unsafe { kernel_avx512(packed, k, q, rest, out) },
        // SAFETY: `kernel_variant` saw the features `kernel_avx2` is compiled for.
        #[cfg(target_arch = "x86_64")]
        KernelVariant::Avx2 => unsafe { kernel_avx2(packed, k, q, rest, out) },
        KernelVariant::Portable => kernel::<false>(packed, k, q, rest, out),
    }
}

/// One face's term `s n'` and its derivatives by the face's three deformed vertices `p`
/// (see [`GreenCoordinates::face_term_jacobians`]).
fn face_jacobian(f: &Face, rest: &[Vec3], p: [Vec3; 3]) -> (Vec3, [nalgebra::Matrix3<f64>; 3]) {
    use nalgebra::Matrix3;
    let [i0, i1, i2] = f.v.map(|i| i as usize);
    let (u, v) = (rest[i1] - rest[i0], rest[i2] - rest[i0]);
    let (du, dv) = (p[1] - p[0], p[2] - p[0]);
    let c = du.cross(&dv);
    let len = c.norm();
    let (uu, vv, uv) = (u.norm_squared(), v.norm_squared(), u.dot(&v));
    let q = du.norm_squared() * vv - 2.0 * du.dot(&dv) * uv + dv.norm_squared() * uu;
    let root = q.max(0.0).sqrt();
    let k = 8f64.sqrt() * f.area;
    let s = root / k;
    if !(len > 0.0 && root > 0.0) {
        let t = if len > 0.0 {
            c * (s / len)
        } else {
            Vec3::zeros()
        };
        return (t, [Matrix3::zeros(); 3]);
    }
    let n = c / len;
    let ds_du = (du * vv - dv * uv) / (root * k);
    let ds_dv = (dv * uu - du * uv) / (root * k);
    let proj = (Matrix3::identity() - n * n.transpose()) / len;
    let j_du = n * ds_du.transpose() - proj * dv.cross_matrix() * s;
    let j_dv = n * ds_dv.transpose() + proj * du.cross_matrix() * s;
    (c * (s / len), [-(j_du + j_dv), j_du, j_dv])
}

/// The face terms' derivatives, for fits that move the cage by Gauss-Newton steps.
impl GreenCoordinates {
    /// The cage vertices of face `j`, in the order [`GreenCoordinates::face_term_jacobians`]
    /// gives their derivatives.
    pub fn face_vertices(&self, j: usize) -> [u32; 3] {
        self.faces[j].v
    }

    /// The rest cage's vertices, as the coordinates were computed in.
    pub fn rest_cage_vertices(&self) -> &[Vec3] {
        &self.rest_vertices
    }

    /// The face terms `t_j = s_j n'_j` of a deformed cage (as
    /// [`GreenCoordinates::face_terms`]) and their exact derivatives: `jac[j][k]` is
    /// `d t_j / d v'` for the `k`-th vertex of face `j` (row: component of `t_j`, column:
    /// component of the vertex). With `u'`, `v'` the deformed edges from the first vertex,
    /// `c = u' x v'`, `n' = c / |c|` and `s_j = sqrt(q) / (sqrt(8) A)`, `q = |u'|^2 |v|^2 - 2
    /// (u'.v')(u.v) + |v'|^2 |u|^2`: `dt = n' ds + s dn'`, `ds / du' = (|v|^2 u' - (u.v) v') /
    /// (sqrt(q) sqrt(8) A)` (and `u`, `v` swapped for `v'`), `dn' = (I - n' n'^T) dc / |c|`
    /// with `dc = -[v']x du' + [u']x dv'`; the first vertex takes minus the sum of the other
    /// two. A degenerate deformed face (zero area or stretch) gets zero derivatives.
    pub fn face_term_jacobians(
        &self,
        deformed: &[Vec3],
        terms: &mut [Vec3],
        jac: &mut [[nalgebra::Matrix3<f64>; 3]],
    ) {
        for ((f, o), jf) in self.faces.iter().zip(terms.iter_mut()).zip(jac.iter_mut()) {
            let p = f.v.map(|i| deformed[i as usize]);
            (*o, *jf) = face_jacobian(f, &self.rest_vertices, p);
        }
    }

    /// The second derivatives of the face terms weighted per face: `out[j]` is the `9 x 9`
    /// matrix (row-major; index `3 k + a` for axis `a` of the face's `k`-th vertex) of
    /// `sum_c weights[j]_c d^2 t_jc / dx dx'`, by central differences of the exact first
    /// derivatives (step 1e-6 of the face's longest deformed edge), symmetrised. With
    /// `weights` the face rows of `Psi^T r` it is the part of a least-squares fit's Hessian
    /// that Gauss-Newton leaves out.
    pub fn face_term_curvatures(&self, deformed: &[Vec3], weights: &[Vec3], out: &mut [[f64; 81]]) {
        for ((f, w), o) in self.faces.iter().zip(weights).zip(out.iter_mut()) {
            let p = f.v.map(|i| deformed[i as usize]);
            let size = [
                (p[1] - p[0]).norm(),
                (p[2] - p[1]).norm(),
                (p[0] - p[2]).norm(),
            ]
            .into_iter()
            .fold(0.0, f64::max);
            let eps = 1e-6 * size.max(f64::MIN_POSITIVE);
            for col in 0..9 {
                let (k, b) = (col / 3, col % 3);
                let (mut plus, mut minus) = (p, p);
                plus[k][b] += eps;
                minus[k][b] -= eps;
                let (_, jp) = face_jacobian(f, &self.rest_vertices, plus);
                let (_, jm) = face_jacobian(f, &self.rest_vertices, minus);
                for row in 0..9 {
                    let (k2, a) = (row / 3, row % 3);
                    let d = jp[k2].column(a) - jm[k2].column(a);
                    o[row * 9 + col] = w.dot(&d) / (2.0 * eps);
                }
            }
            for r in 0..9 {
                for c in r + 1..9 {
                    let m = 0.5 * (o[r * 9 + c] + o[c * 9 + r]);
                    o[r * 9 + c] = m;
                    o[c * 9 + r] = m;
                }
            }
        }
    }
}
