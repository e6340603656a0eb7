//! Assembly of the FEM systems: the rest stiffness and the element blocks warped by their
//! rotations, scattered into the upper triangle of the block-sparse matrix.

use super::*;

/// `(1 + h alpha) M + (h beta + h^2) K + h^2 Ka` at rest, into `out` (same pattern as `k`).
pub(super) fn fill_rest_system(
    out: &mut BlockSparse,
    k: &BlockSparse,
    mass: &[f64],
    anchor_k: &[f64],
    config: &FemConfig,
) {
    let h = config.system_dt();
    let c = config.stiffness_damping * h + h * h;
    out.copy_values_from(k);
    for b in out.blocks_mut() {
        *b *= c;
    }
    for i in 0..mass.len() {
        let d = out.diag_index(i);
        out.blocks_mut()[d] +=
            Matrix3::identity() * ((1.0 + h * config.mass_damping) * mass[i] + h * h * anchor_k[i]);
    }
}

/// Adds `scale * R K^e R^T` of every element into the upper triangle of `k` (diagonal
/// included) through the upper scatter map; call [`BlockSparse::mirror_upper`] after. Blocks
/// `K_ab = V (lambda c_a c_b^T + mu c_b c_a^T + mu (b_a . b_b) I)` with `c = R b`, written out
/// by hand (this is the hot loop of a corotational step); checked against
/// [`element::stiffness_block`] by a unit test.
#[allow(clippy::too_many_arguments)]
pub(super) fn add_warped_upper(
    k: &mut BlockSparse,
    upper: &[[u32; 10]],
    grads: &[[Vec3; 4]],
    volumes: &[f64],
    rotation: impl Fn(usize) -> Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) {
    let blocks = k.blocks_mut();
    for t in 0..grads.len() {
        let r = rotation(t);
        add_element_upper(
            blocks, &upper[t], &grads[t], volumes[t], &r, lambda, mu, scale,
        );
    }
}

/// `scale (K(new) - K(old))` for the ten upper blocks `(a, b)`, `a <= b` in the order of
/// [`PAIRS`], of one element's warped stiffness `R K_e R^T` (see [`add_element_upper`]; the
/// rotation-free `mu (b_a . b_b) I` part cancels), each column-major (entry `(i, j)` at
/// `3 j + i`), oriented as the element's node pair (not yet transposed for storage).
pub(super) fn element_upper_change(
    b: &[Vec3; 4],
    volume: f64,
    old: &Matrix3<f64>,
    new: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) -> [[f64; 9]; 10] {
    let co = [old * b[0], old * b[1], old * b[2], old * b[3]];
    let cn = [new * b[0], new * b[1], new * b[2], new * b[3]];
    let (vl, vm) = (volume * scale * lambda, volume * scale * mu);
    std::array::from_fn(|p| {
        let (a, bb) = PAIRS[p];
        let mut k = [0.0; 9];
        for j in 0..3 {
            for i in 0..3 {
                let outer = cn[a][i] * cn[bb][j] - co[a][i] * co[bb][j];
                let transposed = cn[bb][i] * cn[a][j] - co[bb][i] * co[a][j];
                k[3 * j + i] = vl * outer + vm * transposed;
            }
        }
        k
    })
}

/// Adds element block changes (as [`element_upper_change`] gives them) into the
/// upper-triangle storage through the element's scatter map.
pub(super) fn scatter_upper(
    blocks: &mut [Matrix3<f64>],
    upper: &[u32; 10],
    element: &[[f64; 9]; 10],
) {
    for (&target, e) in upper.iter().zip(element) {
        let k = blocks[(target & !TRANSPOSED) as usize].as_mut_slice();
        if target & TRANSPOSED == 0 {
            for (dst, src) in k.iter_mut().zip(e) {
                *dst += src;
            }
        } else {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * i + j] += e[3 * j + i];
                }
            }
        }
    }
}

/// Adds `scale` times the warped stiffness `R K_e R^T` of one element (shape gradients `b`,
/// volume, rotation `r`) into the upper-triangle blocks its scatter map names.
#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) fn add_element_upper(
    blocks: &mut [Matrix3<f64>],
    upper: &[u32; 10],
    b: &[Vec3; 4],
    volume: f64,
    r: &Matrix3<f64>,
    lambda: f64,
    mu: f64,
    scale: f64,
) {
    let cr = [r * b[0], r * b[1], r * b[2], r * b[3]];
    let (vl, vm) = (volume * scale * lambda, volume * scale * mu);
    for (&(a, bb), &target) in PAIRS.iter().zip(upper) {
        let ca = [cr[a].x, cr[a].y, cr[a].z];
        let cb = [cr[bb].x, cr[bb].y, cr[bb].z];
        let d = vm * b[a].dot(&b[bb]);
        let k = blocks[(target & !TRANSPOSED) as usize].as_mut_slice();
        // Column-major storage: entry (i, j) at 3 j + i. Transposed: (j, i).
        if target & TRANSPOSED == 0 {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * j + i] += vl * ca[i] * cb[j] + vm * cb[i] * ca[j];
                }
                k[4 * j] += d;
            }
        } else {
            for j in 0..3 {
                for i in 0..3 {
                    k[3 * i + j] += vl * ca[i] * cb[j] + vm * cb[i] * ca[j];
                }
                k[4 * j] += d;
            }
        }
    }
}
