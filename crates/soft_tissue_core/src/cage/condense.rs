//! Cage dynamics by static condensation: an opt-in alternative to the Galerkin projection of
//! [`ReducedModel::project`].
//!
//! The Galerkin projection `Kc = J^T K J` gives the cage the energy of the shapes its Green
//! coordinates make. A coarse cage cannot bend a long body the way the body bends (a box cage
//! shears it), so those shapes strain the precise model more than its own bending does and
//! the cage is too stiff: on the paper's cylinder held precise by the RK4 MSD, the box cage's
//! two lowest frequencies are 5.06 and 5.09 rad/s where the MSD's are 1.78 and 1.84 (locking,
//! the Rayleigh-Ritz bound of a poor basis).
//!
//! Condensation takes the stiffness the precise model itself shows through the cage's
//! coordinates. With `P = (J^T M J)^-1 J^T M` the mass-weighted least-squares fit of a nodal
//! displacement to cage coordinates, the cage's compliance is `G = P K^-1 P^T` (the fitted
//! response of the precise model, held at its fixed nodes, to the loads `P^T Q` that do work
//! on the cage coordinates `Q`) and `Kc = G^-1`. The static shapes `Phi = K^-1 P^T Kc` (each
//! a precise displacement whose fit is one unit cage coordinate: `P Phi = I`) give the mass
//! and damping, `Mc = Phi^T M Phi`, `Cc = alpha Mc + beta Kc + gamma Phi^T Phi`. This is
//! Guyan's reduction with the cage coordinates as its masters. On the cylinder's box cage the
//! lowest frequencies become 1.778 and 1.841 rad/s against the MSD's 1.778 and 1.841.
//!
//! What it does not change: forces still reach the cage through the transpose of the
//! linearised Green-coordinate map (`J^T f`), the load of the Galerkin model. The condensed
//! model's own consistent load would be `Phi^T f = Kc P K^-1 f`, a precise solve per step;
//! with `J^T f` a concentrated load (a tool's dent) moves the condensed cage less than the
//! precise model's fit moves.

use super::{Cage, CageError, GreenCoordinates, ReducedModel};
use crate::Vec3;
use faer::linalg::solvers::Solve;
use nalgebra::{DMatrix, Matrix3};

/// What condensation needs of the precise model, at the state the cage was built for.
pub struct CondenseOperators<'a> {
    /// Lumped node masses (one per embedded point).
    pub masses: &'a [f64],
    /// Fixed components per node.
    pub fixed: &'a [[bool; 3]],
    /// `out = K u` (elastic stiffness, anchors included, constraints not applied).
    pub stiffness: &'a mut dyn FnMut(&[Vec3], &mut [Vec3]),
    /// Damping `C = alpha M + beta K + gamma I`: `(alpha, beta, gamma)`.
    pub damping: (f64, f64, f64),
}

/// Most precise nodes a condensation takes (it factors the stiffness densely: 1000 nodes are
/// a matrix of 72 MB).
pub const MAX_NODES: usize = 1000;

/// `model` (the Galerkin-projected dynamics of `cage`, whose coordinates `coords` embed the
/// precise nodes) with its mass, stiffness and damping replaced by the condensed ones (see
/// the module docs). The precise stiffness must be positive definite on the free nodes (a
/// body held by fixed nodes or anchors); otherwise an error says so, as it does for a body
/// of more than [`MAX_NODES`] nodes.
pub fn condensed_model(
    cage: &Cage,
    coords: &GreenCoordinates,
    model: &ReducedModel,
    ops: CondenseOperators<'_>,
) -> Result<ReducedModel, CageError> {
    let n = coords.point_count();
    let nv = cage.vertices().len();
    let dim = 3 * nv;
    if ops.masses.len() != n || ops.fixed.len() != n {
        return Err(CageError::LengthMismatch {
            what: "precise masses / fixed flags (one per embedded point)",
            expected: n,
            found: ops.masses.len().min(ops.fixed.len()),
        });
    }
    if model.dim() != dim {
        return Err(CageError::LengthMismatch {
            what: "reduced model coordinates (3 per cage vertex)",
            expected: dim,
            found: model.dim(),
        });
    }
    let invalid = |message: String| CageError::InvalidArgument {
        field: "condensed cage",
        message,
    };
    // J at the rest cage (3n x dim), exact: phi per axis plus psi through the face terms'
    // derivatives.
    let nf = coords.face_count();
    let mut terms = vec![Vec3::zeros(); nf];
    let mut jac = vec![[Matrix3::zeros(); 3]; nf];
    coords.face_term_jacobians(cage.vertices(), &mut terms, &mut jac);
    let mut j = DMatrix::<f64>::zeros(3 * n, dim);
    for p in 0..n {
        for (v, &w) in coords.phi(p).iter().enumerate() {
            for a in 0..3 {
                j[(3 * p + a, 3 * v + a)] += w;
            }
        }
        for (f, &w) in coords.psi(p).iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            for (k, v) in coords.face_vertices(f).into_iter().enumerate() {
                for a in 0..3 {
                    for b in 0..3 {
                        j[(3 * p + a, 3 * v as usize + b)] += w * jac[f][k][(a, b)];
                    }
                }
            }
        }
    }
    // The mass-weighted fit P = (J^T M J)^-1 J^T M (dim x 3n).
    let mut jtm = j.transpose();
    for (c, mut col) in jtm.column_iter_mut().enumerate() {
        col *= ops.masses[c / 3];
    }
    let jtmj = &jtm * &j;
    let p = jtmj
        .cholesky()
        .ok_or_else(|| {
            invalid("the nodes' masses do not determine the cage (J^T M J singular)".into())
        })?
        .solve(&jtm);
    // Z = K^-1 P^T on the free components (fixed ones held at zero): K built densely from
    // its products with unit vectors, factored once.
    if n > MAX_NODES {
        return Err(invalid(format!(
            "condensation factors the precise stiffness densely: at most {MAX_NODES} nodes, \
             this body has {n}"
        )));
    }
    let free: Vec<usize> = (0..3 * n).filter(|&r| !ops.fixed[r / 3][r % 3]).collect();
    let nfree = free.len();
    let mut kff = faer::Mat::<f64>::zeros(nfree, nfree);
    let (mut unit, mut out) = (vec![Vec3::zeros(); n], vec![Vec3::zeros(); n]);
    for (c, &col) in free.iter().enumerate() {
        unit[col / 3][col % 3] = 1.0;
        (ops.stiffness)(&unit, &mut out);
        unit[col / 3][col % 3] = 0.0;
        for (r, &row) in free.iter().enumerate() {
            kff[(r, c)] = out[row / 3][row % 3];
        }
    }
    let kff = faer::Mat::<f64>::from_fn(nfree, nfree, |r, c| 0.5 * (kff[(r, c)] + kff[(c, r)]));
    let llt = kff.llt(faer::Side::Lower).map_err(|_| {
        invalid(
            "the precise stiffness is not positive definite on the free nodes (is the body \
             held by fixed nodes or anchors?)"
                .into(),
        )
    })?;
    let mut zf = faer::Mat::<f64>::from_fn(nfree, dim, |r, c| p[(c, free[r])]);
    llt.solve_in_place(zf.as_mut());
    let mut z = DMatrix::<f64>::zeros(3 * n, dim);
    for (r, &row) in free.iter().enumerate() {
        for c in 0..dim {
            z[(row, c)] = zf[(r, c)];
        }
    }
    // Kc = (P Z)^-1, symmetrised.
    let g = &p * &z;
    let g = (&g + g.transpose()) * 0.5;
    let kc = g
        .cholesky()
        .ok_or_else(|| invalid("the cage's compliance P K^-1 P^T is not positive definite".into()))?
        .inverse();
    let kc = (&kc + kc.transpose()) * 0.5;
    let phi = &z * &kc;
    let mut m_phi = phi.clone();
    for (r, mut row) in m_phi.row_iter_mut().enumerate() {
        row *= ops.masses[r / 3];
    }
    let mut mc = phi.transpose() * &m_phi;
    let ptp = phi.transpose() * &phi;
    // As in the projection: directions that move no massive node get a mass of 1e-6 of the
    // mean diagonal.
    let floor = 1e-6 * mc.trace() / dim as f64;
    for i in 0..dim {
        mc[(i, i)] += floor.max(f64::MIN_POSITIVE);
    }
    let (alpha, beta, gamma) = ops.damping;
    let row_major = |m: &DMatrix<f64>| -> Vec<f64> {
        (0..dim * dim)
            .map(|i| {
                let (r, c) = (i / dim, i % dim);
                0.5 * (m[(r, c)] + m[(c, r)])
            })
            .collect()
    };
    let cc = &mc * alpha + &kc * beta + ptp * gamma;
    model.with_matrices(row_major(&mc), row_major(&kc), row_major(&cc))
}
