//! The per-element part of a corotational step (deformation gradient, rotation update, elastic
//! forces) for eight elements at a time.
//!
//! Elements are grouped in packs of [`LANES`] with their shape-function gradients stored
//! lane by lane, so every quantity of the element loop is an array of eight numbers and the
//! loops over lanes compile to vector instructions (AVX-512 or AVX2 chosen at run time). The
//! arithmetic is that of [`super::element`] and [`super::rotation`]: `F = sum_a x_a b_a^T`,
//! one first-order quaternion update per iteration of the rotation extraction (lanes whose
//! correction is large, or whose `F` is not finite, go through the scalar
//! [`rotation::extract_rotation`] from their previous rotation, exactly as before), and
//! `f_a = -V R sigma(sym(R^T F) - I) b_a`. Forces are written per element corner and summed
//! per node through a fixed list of corners, so there are no conflicting writes and the sum
//! has a fixed order.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion};
use rayon::prelude::*;

use super::rotation;
use crate::Vec3;
use crate::linalg::madd;

/// Elements per pack.
pub(super) const LANES: usize = 8;

/// Packs per parallel part of the element loop (a fixed partition: the parts' results are
/// put together in part order, so the thread count never changes a result).
const CHUNK_PACKS: usize = 32;

/// Nodes per parallel part of the corner sums.
const CHUNK_NODES: usize = 1024;

type Lanes = [f64; LANES];

/// Eight elements: their node indices, shape-function gradients (`grads[a][j]` is component
/// `j` of the gradient of node `a`) and volumes (zero in the padding lanes of the last pack).
#[derive(Debug, Clone)]
pub(super) struct Pack {
    nodes: [[u32; LANES]; 4],
    grads: [[Lanes; 3]; 4],
    volume: Lanes,
    /// Number of real elements (the rest are padding copies of element 0 of the pack).
    count: usize,
}

/// The packed elements and the corner-to-node summation lists.
#[derive(Debug, Clone)]
pub(super) struct PackedElements {
    packs: Vec<Pack>,
    /// Force of every corner, at `(pack * 4 + a) * LANES + lane`.
    corner_force: Vec<Vec3>,
    /// For node `i`, its corners are `corners[corner_start[i] .. corner_start[i + 1]]`.
    corner_start: Vec<u32>,
    corners: Vec<u32>,
    /// Per part of a parallel element loop: its stale elements and its statistics.
    chunk_stale: Vec<Vec<u32>>,
    chunk_stats: Vec<LoopStats>,
}

/// What the element loop reports.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LoopStats {
    /// Largest number of rotation updates of any element.
    pub worst_iterations: u32,
    /// Whether some element turned by more than the update angle since the last assembly
    /// (they are listed in [`RotationState::stale`]).
    pub stale: bool,
}

/// The mutable per-element rotation state.
pub(super) struct RotationState<'a> {
    pub quats: &'a mut [UnitQuaternion<f64>],
    pub rots: &'a mut [Matrix3<f64>],
    pub assembled: &'a [UnitQuaternion<f64>],
    /// Filled with the elements that turned by more than the update angle since their last
    /// assembly, in increasing order (cleared first).
    pub stale: &'a mut Vec<u32>,
}

impl PackedElements {
    /// Packs `tets` (with gradients `grads` and volumes) for a mesh of `nodes` nodes.
    pub(super) fn new(
        tets: &[[u32; 4]],
        grads: &[[Vec3; 4]],
        volumes: &[f64],
        nodes: usize,
    ) -> Self {
        let mut packs = Vec::with_capacity(tets.len().div_ceil(LANES));
        for (p, chunk) in tets.chunks(LANES).enumerate() {
            let mut pack = Pack {
                nodes: [[chunk[0][0]; LANES]; 4],
                grads: [[[0.0; LANES]; 3]; 4],
                volume: [0.0; LANES],
                count: chunk.len(),
            };
            for l in 0..LANES {
                // Padding lanes repeat the first element with zero volume: finite, no force.
                let (t, real) = if l < chunk.len() {
                    (p * LANES + l, true)
                } else {
                    (p * LANES, false)
                };
                for a in 0..4 {
                    pack.nodes[a][l] = tets[t][a];
                    for j in 0..3 {
                        pack.grads[a][j][l] = grads[t][a][j];
                    }
                }
                pack.volume[l] = if real { volumes[t] } else { 0.0 };
            }
            packs.push(pack);
        }
        // Corner lists per node (counting sort, corners in increasing order).
        let mut count = vec![0u32; nodes + 1];
        for pack in &packs {
            for a in 0..4 {
                for l in 0..pack.count {
                    count[pack.nodes[a][l] as usize + 1] += 1;
                }
            }
        }
        for i in 0..nodes {
            count[i + 1] += count[i];
        }
        let corner_start = count.clone();
        let mut fill = count;
        let mut corners = vec![0u32; corner_start[nodes] as usize];
        for (p, pack) in packs.iter().enumerate() {
            for a in 0..4 {
                for l in 0..pack.count {
                    let i = pack.nodes[a][l] as usize;
                    corners[fill[i] as usize] = ((p * 4 + a) * LANES + l) as u32;
                    fill[i] += 1;
                }
            }
        }
        let chunks = packs.len().div_ceil(CHUNK_PACKS);
        PackedElements {
            corner_force: vec![Vec3::zeros(); packs.len() * 4 * LANES],
            chunk_stale: (0..chunks)
                .map(|_| Vec::with_capacity(CHUNK_PACKS * LANES))
                .collect(),
            chunk_stats: vec![LoopStats::default(); chunks],
            packs,
            corner_start,
            corners,
        }
    }

    /// Updates every element's rotation from the positions `x` (at most `max_iterations`
    /// updates, stopping below `tolerance` radians), adds the elastic forces to `rhs`, and
    /// reports whether some rotation moved more than `cos_half` (cosine of half the update
    /// angle) away from the assembled one.
    #[allow(unsafe_code, clippy::too_many_arguments)]
    pub(super) fn forces(
        &mut self,
        x: &[Vec3],
        state: RotationState,
        lambda: f64,
        mu: f64,
        max_iterations: u32,
        tolerance: f64,
        cos_half: f64,
        rhs: &mut [Vec3],
    ) -> LoopStats {
        let args = Args {
            x,
            lambda,
            mu,
            max_iterations,
            tolerance,
            cos_half,
        };
        let mut stats = LoopStats::default();
        self.dispatch::<true>(&args, state, &mut stats);
        self.sum_corners(rhs);
        stats
    }

    /// Adds every node's corner forces to `rhs`, in the fixed corner order (node ranges in
    /// parallel inside a pool, the same sums).
    fn sum_corners(&self, rhs: &mut [Vec3]) {
        if crate::parallel::in_pool() && rhs.len() >= 2 * CHUNK_NODES {
            rhs.par_chunks_mut(CHUNK_NODES)
                .enumerate()
                .for_each(|(k, part)| self.sum_corners_from(k * CHUNK_NODES, part));
        } else {
            self.sum_corners_from(0, rhs);
        }
    }

    /// [`PackedElements::sum_corners`] for the nodes `first..first + rhs.len()`.
    fn sum_corners_from(&self, first: usize, rhs: &mut [Vec3]) {
        for (k, r) in rhs.iter_mut().enumerate() {
            let i = first + k;
            let (s, e) = (
                self.corner_start[i] as usize,
                self.corner_start[i + 1] as usize,
            );
            let mut f = *r;
            for &c in &self.corners[s..e] {
                f += self.corner_force[c as usize];
            }
            *r = f;
        }
    }

    /// Brings every element's rotation to the rotation of its deformation gradient at `x`,
    /// from the held rotations, to `tolerance` radians (at most `max_iterations` updates;
    /// elements that need a large correction or end in a saddle get the scalar extraction).
    /// No forces. For handing a state over from elsewhere.
    pub(super) fn sync(
        &mut self,
        x: &[Vec3],
        state: RotationState,
        max_iterations: u32,
        tolerance: f64,
    ) -> LoopStats {
        let args = Args {
            x,
            lambda: 0.0,
            mu: 0.0,
            max_iterations,
            tolerance,
            cos_half: -1.0,
        };
        let mut stats = LoopStats::default();
        self.dispatch::<false>(&args, state, &mut stats);
        stats
    }

    /// Runs the element loop: in parallel parts of [`CHUNK_PACKS`] packs inside a pool (when
    /// there are at least two), otherwise in one pass; the same per-element arithmetic and
    /// the stale list in element order either way.
    fn dispatch<const FORCES: bool>(
        &mut self,
        args: &Args,
        state: RotationState,
        stats: &mut LoopStats,
    ) {
        state.stale.clear();
        if !(crate::parallel::in_pool() && self.packs.len() >= 2 * CHUNK_PACKS) {
            kernel::<FORCES>(&self.packs, args, state, &mut self.corner_force, stats, 0);
            return;
        }
        let RotationState {
            quats,
            rots,
            assembled,
            stale,
        } = state;
        let elements = CHUNK_PACKS * LANES;
        self.packs
            .par_chunks(CHUNK_PACKS)
            .zip(self.corner_force.par_chunks_mut(CHUNK_PACKS * 4 * LANES))
            .zip(quats.par_chunks_mut(elements))
            .zip(rots.par_chunks_mut(elements))
            .zip(assembled.par_chunks(elements))
            .zip(self.chunk_stale.par_iter_mut())
            .zip(self.chunk_stats.par_iter_mut())
            .enumerate()
            .for_each(|(k, ((((((packs, out), q), r), a), st), ss))| {
                st.clear();
                *ss = LoopStats::default();
                let part = RotationState {
                    quats: q,
                    rots: r,
                    assembled: a,
                    stale: st,
                };
                kernel::<FORCES>(packs, args, part, out, ss, (k * elements) as u32);
            });
        for (st, ss) in self.chunk_stale.iter().zip(&self.chunk_stats) {
            stale.extend_from_slice(st);
            stats.worst_iterations = stats.worst_iterations.max(ss.worst_iterations);
            stats.stale |= ss.stale;
        }
    }
}

/// The element loop over `packs` with the widest kernel this CPU has; stale elements are
/// listed with `offset` added (the index of the first element of `packs`).
#[allow(unsafe_code)]
fn kernel<const FORCES: bool>(
    packs: &[Pack],
    args: &Args,
    state: RotationState,
    out: &mut [Vec3],
    stats: &mut LoopStats,
    offset: u32,
) {
    use crate::linalg::KernelVariant;
    match crate::linalg::kernel_variant() {
        // SAFETY: `kernel_variant` saw the features `packs_avx512` is compiled for.
        #[cfg(target_arch = "x86_64")]
        KernelVariant::Avx512 => unsafe {
            packs_avx512::<FORCES>(packs, args, state, out, stats, offset)
        },
        // SAFETY: `kernel_variant` saw the features `packs_avx2` is compiled for.
        #[cfg(target_arch = "x86_64")]
        KernelVariant::Avx2 => unsafe {
            packs_avx2::<FORCES>(packs, args, state, out, stats, offset)
        },
        KernelVariant::Portable => {
            packs_loop::<false, FORCES>(packs, args, state, out, stats, offset)
        }
    }
}

struct Args<'a> {
    x: &'a [Vec3],
    lambda: f64,
    mu: f64,
    max_iterations: u32,
    tolerance: f64,
    cos_half: f64,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn packs_avx512<const FORCES: bool>(
    packs: &[Pack],
    args: &Args,
    state: RotationState,
    out: &mut [Vec3],
    stats: &mut LoopStats,
    offset: u32,
) {
    packs_loop::<true, FORCES>(packs, args, state, out, stats, offset)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn packs_avx2<const FORCES: bool>(
    packs: &[Pack],
    args: &Args,
    state: RotationState,
    out: &mut [Vec3],
    stats: &mut LoopStats,
    offset: u32,
) {
    packs_loop::<true, FORCES>(packs, args, state, out, stats, offset)
}

/// Rotation matrix (`r[i][j]`, row `i`, column `j`) of the unit quaternion `(w, x, y, z)`.
#[inline(always)]
fn quat_matrix(w: f64, x: f64, y: f64, z: f64) -> [[f64; 3]; 3] {
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, xz, yz) = (x * y, x * z, y * z);
    let (wx, wy, wz) = (w * x, w * y, w * z);
    [
        [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
        [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
        [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
    ]
}

#[inline(always)]
fn packs_loop<const FMA: bool, const FORCES: bool>(
    packs: &[Pack],
    args: &Args,
    state: RotationState,
    out: &mut [Vec3],
    stats: &mut LoopStats,
    offset: u32,
) {
    let RotationState {
        quats,
        rots,
        assembled,
        stale,
    } = state;
    let x = args.x;
    let tol2 = args.tolerance * args.tolerance;
    for (p, pack) in packs.iter().enumerate() {
        let base = p * LANES;
        // Gather the corner positions.
        let mut pos = [[[0.0; LANES]; 3]; 4];
        for a in 0..4 {
            for l in 0..LANES {
                let xi = x[pack.nodes[a][l] as usize];
                pos[a][0][l] = xi.x;
                pos[a][1][l] = xi.y;
                pos[a][2][l] = xi.z;
            }
        }
        // F[i][j] = sum_a x_a[i] b_a[j]
        let mut f = [[[0.0; LANES]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                for l in 0..LANES {
                    let mut s = pos[0][i][l] * pack.grads[0][j][l];
                    for a in 1..4 {
                        s = madd::<FMA>(pos[a][i][l], pack.grads[a][j][l], s);
                    }
                    f[i][j][l] = s;
                }
            }
        }
        // Rotation state of the lanes.
        let mut q = [[0.0; LANES]; 4]; // w, x, y, z
        let mut r = [[[0.0; LANES]; 3]; 3];
        let mut finite = [true; LANES];
        for l in 0..pack.count {
            let c = quats[base + l].coords; // (x, y, z, w)
            q[0][l] = c[3];
            q[1][l] = c[0];
            q[2][l] = c[1];
            q[3][l] = c[2];
            let m = &rots[base + l];
            for i in 0..3 {
                for j in 0..3 {
                    r[i][j][l] = m[(i, j)];
                }
            }
            finite[l] = (0..3).all(|i| (0..3).all(|j| f[i][j][l].is_finite()));
        }
        for l in pack.count..LANES {
            q[0][l] = 1.0;
            for i in 0..3 {
                r[i][i][l] = 1.0;
            }
        }
        let mut iterations = [0u32; LANES];
        let mut active = finite;
        let mut large = [false; LANES];
        for _ in 0..args.max_iterations {
            // omega = sum_c r_c x f_c / (|sum_c r_c . f_c| + eps), columns c.
            let mut omega = [[0.0; LANES]; 3];
            let mut w2 = [0.0; LANES];
            for l in 0..LANES {
                let mut num = [0.0; 3];
                let mut den = 0.0;
                for c in 0..3 {
                    let (rx, ry, rz) = (r[0][c][l], r[1][c][l], r[2][c][l]);
                    let (fx, fy, fz) = (f[0][c][l], f[1][c][l], f[2][c][l]);
                    num[0] += ry * fz - rz * fy;
                    num[1] += rz * fx - rx * fz;
                    num[2] += rx * fy - ry * fx;
                    den += rx * fx + ry * fy + rz * fz;
                }
                let inv = 1.0 / (den.abs() + 1e-9);
                for k in 0..3 {
                    omega[k][l] = num[k] * inv;
                }
                w2[l] = omega[0][l] * omega[0][l]
                    + omega[1][l] * omega[1][l]
                    + omega[2][l] * omega[2][l];
            }
            let mut any = false;
            for l in 0..LANES {
                // A lane stops at its tolerance; non-finite ones never start.
                active[l] = active[l] && w2[l] >= tol2;
                if active[l] && w2[l] >= 0.01 {
                    large[l] = true;
                }
                any |= active[l];
            }
            if !any {
                break;
            }
            // First-order update q <- normalize((1, omega / 2) q) on the active lanes.
            for l in 0..LANES {
                let (hx, hy, hz) = (0.5 * omega[0][l], 0.5 * omega[1][l], 0.5 * omega[2][l]);
                let (w, qx, qy, qz) = (q[0][l], q[1][l], q[2][l], q[3][l]);
                let nw = w - (hx * qx + hy * qy + hz * qz);
                let nx = qx + w * hx + (hy * qz - hz * qy);
                let ny = qy + w * hy + (hz * qx - hx * qz);
                let nz = qz + w * hz + (hx * qy - hy * qx);
                let inv = 1.0 / (nw * nw + nx * nx + ny * ny + nz * nz).sqrt();
                let on = active[l];
                q[0][l] = if on { nw * inv } else { w };
                q[1][l] = if on { nx * inv } else { qx };
                q[2][l] = if on { ny * inv } else { qy };
                q[3][l] = if on { nz * inv } else { qz };
                iterations[l] += on as u32;
                let m = quat_matrix(q[0][l], q[1][l], q[2][l], q[3][l]);
                for i in 0..3 {
                    for j in 0..3 {
                        r[i][j][l] = m[i][j];
                    }
                }
            }
        }
        // Store the rotations; large corrections redo the scalar extraction from the start.
        for l in 0..pack.count {
            let t = base + l;
            if large[l] {
                let fm = Matrix3::from_fn(|i, j| f[i][j][l]);
                let mut qq = quats[t];
                let mut rr = rots[t];
                iterations[l] = rotation::extract_rotation(
                    &fm,
                    &mut qq,
                    &mut rr,
                    args.max_iterations,
                    args.tolerance,
                );
                quats[t] = qq;
                rots[t] = rr;
                let c = qq.coords;
                q[0][l] = c[3];
                q[1][l] = c[0];
                q[2][l] = c[1];
                q[3][l] = c[2];
                for i in 0..3 {
                    for j in 0..3 {
                        r[i][j][l] = rr[(i, j)];
                    }
                }
            } else if iterations[l] > 0 {
                quats[t] = UnitQuaternion::new_unchecked(Quaternion::new(
                    q[0][l], q[1][l], q[2][l], q[3][l],
                ));
                rots[t] = Matrix3::from_fn(|i, j| r[i][j][l]);
            }
            stats.worst_iterations = stats.worst_iterations.max(iterations[l]);
            if FORCES {
                let a = assembled[t].coords;
                let d = a[3] * q[0][l] + a[0] * q[1][l] + a[1] * q[2][l] + a[2] * q[3][l];
                if d.abs() < args.cos_half {
                    stats.stale = true;
                    stale.push(offset + t as u32);
                }
            } else {
                // A hand-over: a rotation in a saddle (a half turn away from the best one)
                // gets the cold, saddle-proof search.
                let rr = &rots[t];
                let mut trace = 0.0;
                for i in 0..3 {
                    for j in 0..3 {
                        trace += rr[(j, i)] * f[j][i][l];
                    }
                }
                if trace <= 0.0 && finite[l] {
                    let fm = Matrix3::from_fn(|i, j| f[i][j][l]);
                    let cold = rotation::rotation_of(&fm);
                    rots[t] = cold;
                    quats[t] = UnitQuaternion::from_rotation_matrix(
                        &nalgebra::Rotation3::from_matrix_unchecked(cold),
                    );
                }
            }
        }
        if !FORCES {
            continue;
        }
        // Forces: S = R^T F, eps = sym(S) - I, sigma = 2 mu eps + lambda tr(eps) I,
        // P = -V R sigma, f_a = P b_a.
        let (lambda, mu) = (args.lambda, args.mu);
        let mut pm = [[[0.0; LANES]; 3]; 3];
        for l in 0..LANES {
            let mut s = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    let mut acc = r[0][i][l] * f[0][j][l];
                    acc = madd::<FMA>(r[1][i][l], f[1][j][l], acc);
                    acc = madd::<FMA>(r[2][i][l], f[2][j][l], acc);
                    s[i][j] = acc;
                }
            }
            let tr = s[0][0] + s[1][1] + s[2][2] - 3.0;
            let mut sigma = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    let eps = 0.5 * (s[i][j] + s[j][i]) - if i == j { 1.0 } else { 0.0 };
                    sigma[i][j] = 2.0 * mu * eps + if i == j { lambda * tr } else { 0.0 };
                }
            }
            let nv = -pack.volume[l];
            for i in 0..3 {
                for j in 0..3 {
                    let mut acc = r[i][0][l] * sigma[0][j];
                    acc = madd::<FMA>(r[i][1][l], sigma[1][j], acc);
                    acc = madd::<FMA>(r[i][2][l], sigma[2][j], acc);
                    pm[i][j][l] = nv * acc;
                }
            }
        }
        for a in 0..4 {
            let dst = &mut out[(p * 4 + a) * LANES..(p * 4 + a + 1) * LANES];
            let g = &pack.grads[a];
            for l in 0..LANES {
                let mut fa = [0.0; 3];
                for i in 0..3 {
                    let mut acc = pm[i][0][l] * g[0][l];
                    acc = madd::<FMA>(pm[i][1][l], g[1][l], acc);
                    acc = madd::<FMA>(pm[i][2][l], g[2][l], acc);
                    fa[i] = acc;
                }
                dst[l] = Vec3::new(fa[0], fa[1], fa[2]);
            }
        }
    }
}
