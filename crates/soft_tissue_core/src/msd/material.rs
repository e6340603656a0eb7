//! Spring stiffnesses from a material: each tetrahedron's six edge springs are fitted to its
//! linear FEM stiffness matrix.
//!
//! For one tetrahedron with volume `V`, shape-function gradients `g_i` and Lamé parameters
//! `λ, μ`, the linear FEM element stiffness is the 12 x 12 matrix with 3 x 3 blocks
//! `K_ij = V (λ g_i g_jᵀ + μ g_j g_iᵀ + μ (g_i · g_j) I)`. An edge spring of stiffness `k`
//! between nodes `a` and `b` along the unit direction `d`, linearized at rest, contributes
//! `k (s sᵀ) ⊗ (d dᵀ)` with `s` the edge's incidence vector (`-1` at `a`, `+1` at `b`). The six
//! stiffnesses are the non-negative least-squares fit of `Σ k_e K_e` to `K` in the Frobenius
//! norm. The normal equations need only inner products:
//!
//! - `<K_e, K_f> = (s_e · s_f)² (d_e · d_f)²`, where `(s_e · s_f)²` is 4 for the same edge, 1 for
//!   edges sharing a node and 0 for opposite edges;
//! - `<K_e, K> = V ((λ + μ) ((g_b - g_a) · d)² + μ |g_b - g_a|²)`.
//!
//! With six unknowns the exact non-negative solution is found by trying every set of free
//! stiffnesses. A spring of the mesh gets the sum over the tetrahedra that share its edge.
//!
//! For a regular tetrahedron with Poisson ratio 1/4 the fit is `k = 2 √2 E l / 25` on every
//! edge, the closed form of Lloyd, Székely and Harders (2007, "Identification of spring
//! parameters for deformable object simulation", IEEE TVCG 13(5)), who show that ratio is the
//! only one a regular tetrahedron's springs can match. Other ratios and shapes get the nearest
//! spring network; springs stay isotropic in no case (a spring network has a Poisson ratio of
//! its own), so this narrows the gap to FEM without closing it.

use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::fem::element::{lame, shape_gradients};

/// Where an MSD's spring stiffnesses come from (mesh constructor only).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum SpringStiffness {
    /// Every spring gets [`MsdConfig::stiffness`](super::MsdConfig::stiffness) (the paper).
    #[default]
    Constant,
    /// Fitted to the linear FEM stiffness of this material, tetrahedron by tetrahedron (see
    /// the module documentation). Springs that are no tetrahedron's edge (bending springs)
    /// keep [`MsdConfig::stiffness`](super::MsdConfig::stiffness).
    Material {
        /// Young's modulus, force / length².
        young_modulus: f64,
        /// Poisson ratio, in (-1, 0.5).
        poisson_ratio: f64,
    },
}

impl SpringStiffness {
    /// Checks the material's ranges; the message names the field.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if let SpringStiffness::Material {
            young_modulus,
            poisson_ratio,
        } = *self
        {
            if !(young_modulus.is_finite() && young_modulus > 0.0) {
                return Err((
                    "spring_stiffness.young_modulus",
                    format!("must be positive, found {young_modulus}"),
                ));
            }
            if !(poisson_ratio > -1.0 && poisson_ratio < 0.5) {
                return Err((
                    "spring_stiffness.poisson_ratio",
                    format!("must be in (-1, 0.5), found {poisson_ratio}"),
                ));
            }
        }
        Ok(())
    }
}

/// The local node pairs of a tetrahedron's six edges.
const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// The non-negative least-squares stiffnesses of one tetrahedron's six edge springs (in the
/// order `01, 02, 03, 12, 13, 23`) against its linear FEM stiffness. A degenerate
/// tetrahedron (no volume, or a zero-length edge) gets zeros.
pub fn fit_tet_springs(p: [Vec3; 4], young_modulus: f64, poisson_ratio: f64) -> [f64; 6] {
    let (lambda, mu) = lame(young_modulus, poisson_ratio);
    let Some((g, signed_volume)) = shape_gradients(&p) else {
        return [0.0; 6];
    };
    let volume = signed_volume.abs();
    let mut dir = [Vec3::zeros(); 6];
    let mut rhs = [0.0; 6];
    for (k, &[a, b]) in EDGES.iter().enumerate() {
        let edge = p[b] - p[a];
        let len = edge.norm();
        if !(len > 0.0 && len.is_finite()) {
            return [0.0; 6];
        }
        dir[k] = edge / len;
        let dg = g[b] - g[a];
        rhs[k] = volume * ((lambda + mu) * dg.dot(&dir[k]).powi(2) + mu * dg.norm_squared());
    }
    let mut gram = [[0.0; 6]; 6];
    for (i, ei) in EDGES.iter().enumerate() {
        for (j, ej) in EDGES.iter().enumerate() {
            let shared = ei.iter().filter(|n| ej.contains(n)).count();
            let ss = match shared {
                2 => 4.0,
                1 => 1.0,
                _ => 0.0,
            };
            gram[i][j] = ss * dir[i].dot(&dir[j]).powi(2);
        }
    }
    nnls6(&gram, &rhs)
}

/// Exact non-negative least squares `min kᵀ G k - 2 kᵀ b, k >= 0` for six unknowns: the best
/// of the unconstrained solutions on every subset of free variables that come out
/// non-negative (at the optimum the objective is `-k_Sᵀ b_S`).
fn nnls6(gram: &[[f64; 6]; 6], rhs: &[f64; 6]) -> [f64; 6] {
    let mut best = [0.0; 6];
    let mut best_gain = 0.0;
    for mask in 1u32..64 {
        let free: Vec<usize> = (0..6).filter(|i| mask & (1 << i) != 0).collect();
        let m = free.len();
        let a = nalgebra::DMatrix::from_fn(m, m, |i, j| gram[free[i]][free[j]]);
        let b = nalgebra::DVector::from_fn(m, |i, _| rhs[free[i]]);
        let Some(chol) = a.cholesky() else {
            continue;
        };
        let k = chol.solve(&b);
        if k.iter().any(|&v| v.is_nan() || v < 0.0) {
            continue;
        }
        let gain = k.dot(&b);
        if gain > best_gain {
            best_gain = gain;
            best = [0.0; 6];
            for (i, &f) in free.iter().enumerate() {
                best[f] = k[i];
            }
        }
    }
    best
}

/// Per-spring stiffnesses for `pairs` (node pairs, either order) on the mesh's tetrahedra:
/// the sum of the fitted stiffnesses of the tetrahedra sharing each edge. A pair that is no
/// tetrahedron's edge gets `None`.
pub fn material_stiffnesses(
    positions: &[Vec3],
    tets: &[[u32; 4]],
    pairs: &[[u32; 2]],
    young_modulus: f64,
    poisson_ratio: f64,
) -> Vec<Option<f64>> {
    let key = |a: u32, b: u32| [a.min(b), a.max(b)];
    let index: std::collections::HashMap<[u32; 2], usize> = pairs
        .iter()
        .enumerate()
        .map(|(i, &[a, b])| (key(a, b), i))
        .collect();
    let mut out = vec![None; pairs.len()];
    for t in tets {
        let p = t.map(|i| positions[i as usize]);
        let k = fit_tet_springs(p, young_modulus, poisson_ratio);
        for (e, &[a, b]) in EDGES.iter().enumerate() {
            if let Some(&s) = index.get(&key(t[a], t[b])) {
                *out[s].get_or_insert(0.0) += k[e];
            }
        }
    }
    out
}
