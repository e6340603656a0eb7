//! What the fit's derivative tests share: a cage to test on and a check of a gradient and a
//! Hessian against central differences.

use crate::Vec3;
use crate::cage::{Cage, FitOptions, GreenCoordinates, fitted_cage};
use crate::mesh::TetMesh;
use crate::mesh::generate::Organ;

/// The generated liver, a fitted cage of about 40 vertices and the Green coordinates of
/// every node.
pub(super) fn liver_cage() -> (TetMesh, Cage, GreenCoordinates) {
    let mesh = Organ::Liver.generate(1.0).unwrap();
    let cage = fitted_cage(
        mesh.positions(),
        mesh.surface().triangles(),
        &FitOptions::for_points(mesh.positions(), 40),
    )
    .unwrap();
    let coords = GreenCoordinates::new(&cage, mesh.positions()).unwrap();
    (mesh, cage, coords)
}

/// Asserts that `grad` and `h` (row-major, `3 x.len()` square) are the gradient and the
/// Hessian at `x` of the function whose value and gradient `eval` gives, to 1e-6 and 1e-5
/// of their largest entries by central differences (step 1e-6), and that neither is
/// negligible.
pub(super) fn assert_derivatives(
    x: &[Vec3],
    grad: &[f64],
    h: &[f64],
    mut eval: impl FnMut(&[Vec3]) -> (f64, Vec<f64>),
) {
    let d = grad.len();
    let eps = 1e-6;
    let (mut worst_g, mut scale_g, mut worst_h, mut scale_h): (f64, f64, f64, f64) =
        (0.0, 0.0, 0.0, 0.0);
    for c in 0..d {
        let mut y = x.to_vec();
        y[c / 3][c % 3] += eps;
        let (fp, gp) = eval(&y);
        y[c / 3][c % 3] -= 2.0 * eps;
        let (fm, gm) = eval(&y);
        let fd = (fp - fm) / (2.0 * eps);
        worst_g = worst_g.max((fd - grad[c]).abs());
        scale_g = scale_g.max(fd.abs());
        for r in 0..d {
            let fd = (gp[r] - gm[r]) / (2.0 * eps);
            worst_h = worst_h.max((fd - h[r * d + c]).abs());
            scale_h = scale_h.max(fd.abs());
        }
    }
    assert!(scale_g > 1e-3 && scale_h > 1e-3, "{scale_g} {scale_h}");
    assert!(
        worst_g < 1e-6 * scale_g,
        "gradient off by {worst_g:e} of {scale_g:e}"
    );
    assert!(
        worst_h < 1e-5 * scale_h,
        "Hessian off by {worst_h:e} of {scale_h:e}"
    );
}

/// Adds each face's `9 x 9` block of `curvature` (as the fit orders them) into `h`.
pub(super) fn add_face_blocks(coords: &GreenCoordinates, curvature: &[[f64; 81]], h: &mut [f64]) {
    let d = (h.len() as f64).sqrt() as usize;
    for (j, o) in curvature.iter().enumerate() {
        let v = coords.face_vertices(j).map(|v| v as usize);
        for r in 0..9 {
            for c in 0..9 {
                h[(3 * v[r / 3] + r % 3) * d + 3 * v[c / 3] + c % 3] += o[r * 9 + c];
            }
        }
    }
}
