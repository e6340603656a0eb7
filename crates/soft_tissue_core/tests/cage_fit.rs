//! The least-squares fit of a cage to a surface (`cage::SurfaceFit`) and the face terms'
//! derivatives it uses: derivatives against finite differences of the face terms, the fit
//! against surfaces a cage reproduces exactly, and its optimum against perturbations of the
//! cage evaluated through the Green coordinates alone.

use nalgebra::Matrix3;
use soft_tissue_core::Vec3;
use soft_tissue_core::cage::{Cage, FitOptions, GreenCoordinates, SurfaceFit, fitted_cage};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;

fn asset(name: &str) -> TetMesh {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../../assets/meshes/{name}.vtk"));
    read_tet_mesh(path).unwrap().mesh
}

/// Deterministic pseudo-random numbers in [-1, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        2.0 * ((self.0 >> 11) as f64 / (1u64 << 53) as f64) - 1.0
    }
    fn vec(&mut self) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next())
    }
}

/// The cylinder, its surface nodes and a fitted cage of about `vertices` vertices with the
/// Green coordinates of every node.
fn cylinder_cage(vertices: usize) -> (TetMesh, Vec<u32>, Cage, GreenCoordinates) {
    let mesh = asset("cylinder");
    let surface: Vec<u32> = mesh.surface().vertices().to_vec();
    let cage = fitted_cage(
        mesh.positions(),
        mesh.surface().triangles(),
        &FitOptions::for_points(mesh.positions(), vertices),
    )
    .unwrap();
    let coords = GreenCoordinates::new(&cage, mesh.positions()).unwrap();
    (mesh, surface, cage, coords)
}

/// The cage deformed smoothly: a bend, a twist and a stretch, `amount` of its size.
fn deformed(cage: &Cage, amount: f64, r: &mut Lcg) -> Vec<Vec3> {
    let v = cage.vertices();
    let size = v
        .iter()
        .map(|p| p.norm())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    v.iter()
        .map(|p| {
            let q = p / size;
            let bend = Vec3::new(q.y * q.y, 0.3 * q.x * q.z, -0.2 * q.y * q.x);
            p + bend * (amount * size) + r.vec() * (0.02 * amount * size)
        })
        .collect()
}

#[test]
fn face_term_derivatives_match_finite_differences() {
    let (_, _, cage, coords) = cylinder_cage(64);
    let mut r = Lcg(7);
    let x = deformed(&cage, 0.2, &mut r);
    let nf = coords.face_count();
    let mut terms = vec![Vec3::zeros(); nf];
    let mut jac = vec![[Matrix3::zeros(); 3]; nf];
    coords.face_term_jacobians(&x, &mut terms, &mut jac);
    let mut plain = vec![Vec3::zeros(); nf];
    coords.face_terms(&x, &mut plain);
    assert_eq!(terms, plain, "the same face terms");
    let size = 1.0;
    let eps = 1e-6 * size;
    let (mut plus, mut minus) = (vec![Vec3::zeros(); nf], vec![Vec3::zeros(); nf]);
    let mut worst: f64 = 0.0;
    let mut scale: f64 = 0.0;
    for v in 0..x.len() {
        for a in 0..3 {
            let mut xp = x.clone();
            xp[v][a] += eps;
            coords.face_terms(&xp, &mut plus);
            xp[v][a] -= 2.0 * eps;
            coords.face_terms(&xp, &mut minus);
            for j in 0..nf {
                let fd = (plus[j] - minus[j]) / (2.0 * eps);
                let k = coords
                    .face_vertices(j)
                    .iter()
                    .position(|&w| w as usize == v);
                let exact = k.map_or(Vec3::zeros(), |k| jac[j][k].column(a).into());
                worst = worst.max((fd - exact).norm());
                scale = scale.max(fd.norm());
            }
        }
    }
    assert!(scale > 0.1, "{scale}");
    assert!(
        worst < 1e-7 * scale,
        "largest difference {worst:e} of {scale}"
    );
    // The weighted second derivatives against second differences of the weighted terms.
    let weights: Vec<Vec3> = (0..nf).map(|_| r.vec()).collect();
    let mut curvature = vec![[0.0; 81]; nf];
    coords.face_term_curvatures(&x, &weights, &mut curvature);
    let e = 1e-4;
    let (mut worst, mut scale): (f64, f64) = (0.0, 0.0);
    let weighted = |y: &[Vec3], out: &mut [Vec3]| -> Vec<f64> {
        coords.face_terms(y, out);
        out.iter().zip(&weights).map(|(t, w)| t.dot(w)).collect()
    };
    let mut buf = vec![Vec3::zeros(); nf];
    for j in (0..nf).step_by(7) {
        let fv = coords.face_vertices(j).map(|v| v as usize);
        for row in 0..9 {
            for col in 0..9 {
                let mut g = 0.0;
                for (sr, sc, sign) in [
                    (1.0, 1.0, 1.0),
                    (1.0, -1.0, -1.0),
                    (-1.0, 1.0, -1.0),
                    (-1.0, -1.0, 1.0),
                ] {
                    let mut y = x.clone();
                    y[fv[row / 3]][row % 3] += sr * e;
                    y[fv[col / 3]][col % 3] += sc * e;
                    g += sign * weighted(&y, &mut buf)[j];
                }
                let fd = g / (4.0 * e * e);
                worst = worst.max((fd - curvature[j][row * 9 + col]).abs());
                scale = scale.max(fd.abs());
            }
        }
    }
    assert!(scale > 0.1, "{scale}");
    assert!(
        worst < 1e-5 * scale,
        "largest difference {worst:e} of {scale}"
    );
}

/// Every embedded point's position in the cage `x` (exact, `f64`).
fn image(coords: &GreenCoordinates, x: &[Vec3]) -> Vec<Vec3> {
    let mut terms = vec![Vec3::zeros(); coords.face_count()];
    coords.face_terms(x, &mut terms);
    let mut out = vec![Vec3::zeros(); coords.point_count()];
    coords.evaluate(x, &terms, &mut out).unwrap();
    out
}

/// The sum of squared distances of the surface points from the cage's image of them.
fn squares(coords: &GreenCoordinates, surface: &[u32], x: &[Vec3], points: &[Vec3]) -> f64 {
    let im = image(coords, x);
    surface
        .iter()
        .map(|&i| (im[i as usize] - points[i as usize]).norm_squared())
        .sum()
}

/// The surface of a smoothly deformed cage (which the cage reproduces exactly) is fitted to
/// 1e-8 of the size from the rest cage, on the 128-vertex fitted cylinder cage; and a motion
/// of that cage's vertices is recovered from the surface velocities to 1e-6.
#[test]
fn a_surface_the_cage_reproduces_is_fitted_exactly() {
    let (mesh, surface, cage, coords) = cylinder_cage(128);
    let mut r = Lcg(11);
    let target = deformed(&cage, 0.1, &mut r);
    let points = image(&coords, &target);
    let mut fit = SurfaceFit::new(&coords, &surface).unwrap();
    let mut x = cage.vertices().to_vec();
    let size = mesh.bbox().smallest_dimension();
    let report = fit.positions(&coords, &points, &mut x, 1e-10 * size, 100);
    assert!(report.converged, "{report:?}");
    let residual = fit.residual(&coords, &x, &points);
    assert!(residual < 1e-8 * size, "residual {residual:e}");
    // Velocities: the cage moving along `u` moves the points by `d image / dt`.
    let u: Vec<Vec3> = (0..x.len()).map(|_| r.vec() * 0.1).collect();
    let h = 1e-6;
    let (mut plus, mut minus) = (x.clone(), x.clone());
    for ((p, m), ui) in plus.iter_mut().zip(minus.iter_mut()).zip(&u) {
        *p += ui * h;
        *m -= ui * h;
    }
    let (ip, im) = (image(&coords, &plus), image(&coords, &minus));
    let v: Vec<Vec3> = ip
        .iter()
        .zip(&im)
        .map(|(a, b)| (a - b) / (2.0 * h))
        .collect();
    let mut fitted = vec![Vec3::zeros(); x.len()];
    let report = fit.velocities(&coords, &x, &v, &mut fitted, 1e-3 * h, 1e-12, 100);
    assert!(report.converged, "{report:?}");
    let speed = v.iter().map(|w| w.norm()).fold(0.0, f64::max);
    let (mut plus, mut minus) = (x.clone(), x.clone());
    for ((p, m), ui) in plus.iter_mut().zip(minus.iter_mut()).zip(&fitted) {
        *p += ui * h;
        *m -= ui * h;
    }
    let (ip, im) = (image(&coords, &plus), image(&coords, &minus));
    let worst = surface
        .iter()
        .map(|&i| {
            let i = i as usize;
            ((ip[i] - im[i]) / (2.0 * h) - v[i]).norm()
        })
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-6 * speed,
        "velocities off by {worst:e} of {speed:e}"
    );
}

/// A surface no cage reproduces (the cylinder bent and twisted by 5 % of its size) on the
/// 128-vertex fitted cage, where the fixed point is not a contraction: the first fit falls
/// back to Newton steps (it spends more iterations than the fixed point was given), later
/// fits go on from there and converge; and the result is a least-squares minimum: no small
/// move of the cage lowers the sum of squares, evaluated through the Green coordinates alone
/// (once more fitted from itself, so the pull toward the start vanishes at the optimum).
#[test]
fn where_the_fixed_point_fails_newton_steps_reach_a_least_squares_minimum() {
    let (mesh, surface, cage, coords) = cylinder_cage(128);
    let size = mesh.bbox().smallest_dimension();
    let points: Vec<Vec3> = mesh
        .positions()
        .iter()
        .map(|p| p + Vec3::new(0.05 * p.y * p.y, 0.0, 0.03 * p.x * p.y))
        .collect();
    let mut fit = SurfaceFit::new(&coords, &surface).unwrap();
    let mut x = cage.vertices().to_vec();
    let first = fit.positions(&coords, &points, &mut x, 1e-10 * size, 100);
    assert!(first.iterations > 100, "the fixed point failed: {first:?}");
    let mut fits = 1;
    let mut report = first;
    while !report.converged && fits < 10 {
        report = fit.positions(&coords, &points, &mut x, 1e-10 * size, 100);
        fits += 1;
    }
    assert!(report.converged, "{fits} fits: {report:?}");
    let report = fit.positions(&coords, &points, &mut x, 1e-10 * size, 100);
    assert!(report.converged, "{report:?}");
    let f = squares(&coords, &surface, &x, &points);
    assert!(f > 1e-8, "a residual is left: {f:e}");
    let mut r = Lcg(5);
    for _ in 0..20 {
        let d: Vec<Vec3> = (0..x.len()).map(|_| r.vec()).collect();
        for eps in [1e-4 * size, 1e-3 * size] {
            for sign in [1.0, -1.0] {
                let y: Vec<Vec3> = x
                    .iter()
                    .zip(&d)
                    .map(|(a, b)| a + b * (sign * eps))
                    .collect();
                let g = squares(&coords, &surface, &y, &points);
                assert!(
                    g >= f * (1.0 - 1e-9),
                    "a move of {eps:e} lowers the sum of squares {f:e} to {g:e}"
                );
            }
        }
    }
}

/// The signed area ratio of every cage face of `x` against the rest cage (the rest normal,
/// the body not turned): below zero a face has turned over.
fn area_ratios(cage: &Cage, x: &[Vec3]) -> Vec<f64> {
    let v = cage.vertices();
    cage.triangles()
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| i as usize);
            let rest = (v[b] - v[a]).cross(&(v[c] - v[a]));
            let now = (x[b] - x[a]).cross(&(x[c] - x[a]));
            rest.dot(&now) / rest.norm_squared()
        })
        .collect()
}

/// A dent narrower than a cage cell pressed a fifth of the size into the 128-vertex fitted
/// cylinder cage's surface, deepened over ten fits as a tool's would be: the unguarded
/// least-squares fit follows such a dent by turning cage faces over, where the face terms
/// jump and no Newton step converges (measured on the poke of Fig. 5: 439 of 500 fits
/// missed). Every depth's fit converges here in one fit of at most 100 Newton steps (as
/// `LeveledModel::fit_cage_now` fits), and no face of the fitted cage falls below half the
/// fold guard's margin of a fifth of its rest area, let alone turns over.
#[test]
fn a_deep_narrow_dent_is_fitted_without_folding_the_cage() {
    let (mesh, surface, cage, coords) = cylinder_cage(128);
    let size = mesh.bbox().smallest_dimension();
    // The dent's centre: the surface node farthest along x, pressed toward -x.
    let centre = *surface
        .iter()
        .map(|&i| &mesh.positions()[i as usize])
        .max_by(|a, b| a.x.total_cmp(&b.x))
        .unwrap();
    let radius = 0.25 * size;
    let mut fit = SurfaceFit::new(&coords, &surface).unwrap();
    // As `fit_cage_now` fits: up to 100 Newton steps a fit.
    fit.set_newton_steps(100);
    let mut x = cage.vertices().to_vec();
    let mut worst: f64 = 1.0;
    for k in 1..=10 {
        let depth = 0.2 * size * k as f64 / 10.0;
        let points: Vec<Vec3> = mesh
            .positions()
            .iter()
            .map(|p| {
                let r = (p - centre).norm() / radius;
                let fall = if r < 1.0 { (1.0 - r * r).powi(2) } else { 0.0 };
                p - Vec3::x() * (depth * fall)
            })
            .collect();
        let report = fit.positions(&coords, &points, &mut x, 1e-10 * size, 100);
        if k == 1 {
            // The fixed point failed (its 100 iterations spent) and Newton steps took over.
            assert!(report.iterations > 100, "{report:?}");
        }
        assert!(report.converged, "depth {k}/10: {report:?}");
        eprintln!("depth {k}/10: {} iterations", report.iterations);
        let smallest = area_ratios(&cage, &x).into_iter().fold(1.0, f64::min);
        worst = worst.min(smallest);
        // The fit follows the dent: no surface point is off by half its depth.
        let residual = fit.residual(&coords, &x, &points);
        assert!(residual < 0.5 * depth, "depth {k}: residual {residual:e}");
    }
    eprintln!("smallest face area ratio over the fits: {worst:.4}");
    assert!(worst >= 0.1, "a face fell to {worst} of its rest area");
}
