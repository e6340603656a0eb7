//! Validation of the FEM solvers against analytic solutions and finite differences.
//!
//! Tolerances: "exact" results (patch tests, uniform stress) are checked to 1e-9 relative, the
//! round-off of a sparse solve on these sizes; finite differences use central differences with
//! step 1e-6 of the body size, whose truncation error is ~1e-10 relative, so 1e-6 leaves
//! room for round-off; discretisation errors (beam bending) are checked for convergence and
//! against the mesh-independent analytic value within a stated margin.

#![allow(clippy::needless_range_loop)] // index loops over parallel node arrays

mod fem_support;

use fem_support::*;
use nalgebra::{Matrix3, Rotation3};
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemModel, element};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::{NodalModel, Vec3};

#[test]
fn patch_test_uniform_strain_is_reproduced_exactly() {
    let mesh = cube(3);
    let (lambda, mu) = element::lame(1000.0, 0.3);
    for model in MODELS {
        // Corotational: the same strain seen through a quarter turn is still reproduced.
        let q = match model {
            FemModel::Linear => Matrix3::identity(),
            FemModel::Corotational | FemModel::CorotationalPrefactored => quarter_turn(),
        };
        let map = |p: &Vec3| q * (Matrix3::identity() + strain()) * p + Vec3::new(0.3, -0.2, 0.1);
        let fixed: Vec<usize> = (0..mesh.positions().len())
            .filter(|&i| on_boundary(&mesh.positions()[i]))
            .collect();
        assert!(
            fixed.len() < mesh.positions().len(),
            "the cube has interior nodes"
        );
        let mut body = FemBody::new(
            &mesh,
            config(model, 1000.0, 0.3),
            &Boundary::fixed_nodes(fixed.iter().copied()),
        )
        .unwrap();
        // Interior forces vanish at the affine state, and the energy is V psi(E).
        let target: Vec<Vec3> = mesh.positions().iter().map(map).collect();
        let mut f = vec![Vec3::zeros(); target.len()];
        let energy = body.forces_and_energy(&target, model, &mut f);
        let expected = element::energy_density(&strain(), lambda, mu);
        assert!(
            (energy - expected).abs() < 1e-9 * expected,
            "{model:?}: energy {energy} vs {expected}"
        );
        let scale = 1000.0 * strain().norm() / 9.0; // stress times a face area of the mesh
        for i in 0..f.len() {
            if !fixed.contains(&i) {
                assert!(
                    f[i].norm() < 1e-9 * scale,
                    "{model:?}: interior node {i} force {}",
                    f[i].norm()
                );
            }
        }
        // Static solve with the boundary held at the affine positions recovers the interior.
        for &i in &fixed {
            body.positions_mut()[i] = target[i];
        }
        body.solve_static(1e-13, 50).unwrap();
        let worst = body
            .positions()
            .iter()
            .zip(&target)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-9,
            "{model:?}: interior off the affine field by {worst}"
        );
    }
}

#[test]
fn rigid_motions_give_zero_elastic_force() {
    let mesh = cube(2);
    let body = FemBody::new(
        &mesh,
        config(FemModel::Corotational, 1000.0, 0.3),
        &Boundary::free(),
    )
    .unwrap();
    let t = Vec3::new(5.0, -3.0, 2.0);
    let mut f = vec![Vec3::zeros(); mesh.positions().len()];
    let scale = 1000.0; // stress of a unit strain
    for model in MODELS {
        let moved: Vec<Vec3> = mesh.positions().iter().map(|p| p + t).collect();
        let e = body.forces_and_energy(&moved, model, &mut f);
        assert!(
            e.abs() < 1e-9 * scale && f.iter().all(|v| v.norm() < 1e-9 * scale),
            "{model:?} translation"
        );
    }
    for angle in [0.3f64, 90f64.to_radians(), 179f64.to_radians()] {
        let r = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vec3::new(-1.0, 0.5, 2.0)),
            angle,
        );
        let moved: Vec<Vec3> = mesh.positions().iter().map(|p| r * p + t).collect();
        let e = body.forces_and_energy(&moved, FemModel::Corotational, &mut f);
        let fmax = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
        assert!(
            e.abs() < 1e-9 * scale && fmax < 1e-9 * scale,
            "corotational, {angle} rad: energy {e}, force {fmax}"
        );
        // Linear elasticity sees a finite rotation as strain: not zero (that is its known flaw).
        let e_lin = body.forces_and_energy(&moved, FemModel::Linear, &mut f);
        assert!(
            e_lin > 1e-3 * scale * (1.0 - angle.cos()),
            "linear, {angle} rad: energy {e_lin}"
        );
    }
}

/// A deterministic pseudo-random displacement field.
fn jitter(mesh: &TetMesh, amplitude: f64, seed: u64) -> Vec<Vec3> {
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    mesh.positions()
        .iter()
        .map(|p| p + amplitude * Vec3::new(next(), next(), next()))
        .collect()
}

#[test]
fn forces_and_stiffness_match_finite_differences_of_the_energy() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [2, 1, 1]).unwrap();
    let body = FemBody::new(
        &mesh,
        config(FemModel::Corotational, 100.0, 0.35),
        &Boundary::free(),
    )
    .unwrap();
    let n = mesh.positions().len();
    let rot = Rotation3::from_euler_angles(0.4, -0.9, 1.3);
    let states = [
        ("strained", jitter(&mesh, 0.15, 1)),
        (
            "rotated and strained",
            jitter(&mesh, 0.15, 2)
                .iter()
                .map(|p| rot * p)
                .collect::<Vec<_>>(),
        ),
    ];
    let h = 1e-6;
    let mut f = vec![Vec3::zeros(); n];
    let mut fp = vec![Vec3::zeros(); n];
    let mut fm = vec![Vec3::zeros(); n];
    for model in MODELS {
        for (name, x) in &states {
            body.forces_and_energy(x, model, &mut f);
            let fscale = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
            for i in 0..n {
                for a in 0..3 {
                    let mut xp = x.clone();
                    xp[i][a] += h;
                    let mut xm = x.clone();
                    xm[i][a] -= h;
                    let ep = body.forces_and_energy(&xp, model, &mut fp);
                    let em = body.forces_and_energy(&xm, model, &mut fm);
                    let fd = -(ep - em) / (2.0 * h);
                    assert!(
                        (fd - f[i][a]).abs() < 1e-6 * fscale,
                        "{model:?} {name}: node {i} axis {a}: force {} vs -dE/dx {fd}",
                        f[i][a]
                    );
                }
            }
        }
    }
    // Stiffness: exact Hessian for linear FEM everywhere, and for corotational FEM at a rotated
    // stress-free state (elsewhere the warped stiffness drops the derivative of R by design).
    let rotated: Vec<Vec3> = mesh.positions().iter().map(|p| rot * p).collect();
    for (model, x) in [
        (FemModel::Linear, states[0].1.clone()),
        (FemModel::Corotational, rotated),
    ] {
        let k = body.stiffness_at(&x, model);
        let mut col = vec![Vec3::zeros(); n];
        let kscale = k.blocks().iter().map(|b| b.abs().max()).fold(0.0, f64::max);
        for j in 0..n {
            for b in 0..3 {
                let mut xp = x.clone();
                xp[j][b] += h;
                let mut xm = x.clone();
                xm[j][b] -= h;
                body.forces_and_energy(&xp, model, &mut fp);
                body.forces_and_energy(&xm, model, &mut fm);
                let mut e = vec![Vec3::zeros(); n];
                e[j][b] = 1.0;
                k.mul(&e, &mut col);
                for i in 0..n {
                    let fd = -(fp[i] - fm[i]) / (2.0 * h);
                    let err = (fd - col[i]).abs().max();
                    assert!(
                        err < 1e-6 * kscale,
                        "{model:?}: K[{i},{j}] column {b} off by {err} (scale {kscale})"
                    );
                }
            }
        }
        assert!(k.asymmetry() < 1e-12 * kscale);
    }
}

/// Tip deflection of a cantilever (length 10, square section 1, clamped at x = 0) under its
/// own weight, as a fraction of the Euler-Bernoulli value q L^4 / (8 E I).
fn cantilever_ratio(model: FemModel, cells: [usize; 3], young: f64, gravity: f64) -> f64 {
    let (len, a) = (10.0, 1.0);
    let mesh = block(Vec3::zeros(), Vec3::new(len, a, a), cells).unwrap();
    let mut c = config(model, young, 0.0);
    c.gravity = Vec3::new(0.0, 0.0, -gravity);
    let boundary = Boundary::fixed_below(mesh.positions(), 0, 0.0);
    let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
    body.solve_static(1e-12, 200).unwrap();
    let tip: Vec<usize> = (0..mesh.positions().len())
        .filter(|&i| (mesh.positions()[i].x - len).abs() < 1e-9)
        .collect();
    let deflection = -tip
        .iter()
        .map(|&i| body.positions()[i].z - mesh.positions()[i].z)
        .sum::<f64>()
        / tip.len() as f64;
    let q = 1.0 * gravity * a * a; // density 1
    let inertia = a.powi(4) / 12.0;
    deflection / (q * len.powi(4) / (8.0 * young * inertia))
}

#[test]
fn cantilever_converges_to_euler_bernoulli() {
    // Linear tetrahedra are too stiff in bending on coarse meshes (locking); the error must
    // fall with refinement. With nu = 0 and L / a = 10, shear adds 0.8 % to the beam-theory
    // deflection (Timoshenko), so the finest mesh is checked within 5 % of Euler-Bernoulli.
    let mut errors = Vec::new();
    for cells in [[10, 1, 1], [20, 2, 2], [40, 4, 4], [80, 8, 8]] {
        let ratio = cantilever_ratio(FemModel::Linear, cells, 1e5, 1.0);
        println!("cells {cells:?}: tip / Euler-Bernoulli = {ratio:.4}");
        errors.push((1.0 - ratio).abs());
    }
    assert!(
        errors.windows(2).all(|w| w[1] < w[0]),
        "error must fall with refinement: {errors:?}"
    );
    assert!(errors[errors.len() - 1] < 0.05, "finest error {errors:?}");
}

#[test]
fn linear_and_corotational_agree_at_small_strain() {
    let lin = cantilever_ratio(FemModel::Linear, [20, 2, 2], 1e7, 1.0);
    let cor = cantilever_ratio(FemModel::Corotational, [20, 2, 2], 1e7, 1.0);
    // Tip deflection / length ~ 1.5e-5: the models differ by second-order terms only.
    assert!(
        (lin - cor).abs() < 1e-3 * lin,
        "linear {lin} vs corotational {cor}"
    );
}

#[test]
fn poisson_contraction_of_a_bar_under_tension() {
    let (len, a, young, nu, sigma) = (4.0, 1.0, 500.0, 0.3, 2.0);
    let mesh = block(Vec3::zeros(), Vec3::new(len, a, a), [8, 2, 2]).unwrap();
    let p = mesh.positions();
    // Rollers on x = 0, the origin pinned, and (0, a, 0) held in z: no rigid motion, no
    // restraint of the lateral contraction.
    let mut boundary = Boundary::free();
    for i in 0..p.len() {
        if p[i].x.abs() < 1e-12 {
            let mut mask = [true, false, false];
            if p[i].norm() < 1e-12 {
                mask = [true; 3];
            } else if (p[i] - Vec3::new(0.0, a, 0.0)).norm() < 1e-12 {
                mask = [true, false, true];
            }
            boundary.fixed.push((i, mask));
        }
    }
    for model in MODELS {
        let mut body = FemBody::new(&mesh, config(model, young, nu), &boundary).unwrap();
        // Uniform traction on x = len: a third of each triangle's force to each corner.
        for tri in mesh.surface().triangles() {
            let q = tri.map(|i| p[i as usize]);
            if q.iter().all(|v| (v.x - len).abs() < 1e-12) {
                let area = 0.5 * (q[1] - q[0]).cross(&(q[2] - q[0])).norm();
                for &i in tri {
                    body.external_forces_mut()[i as usize].x += sigma * area / 3.0;
                }
            }
        }
        body.solve_static(1e-13, 100).unwrap();
        let eps = sigma / young;
        for (i, (x, x0)) in body.positions().iter().zip(p).enumerate() {
            let expected = Vec3::new(x0.x * eps, -nu * eps * x0.y, -nu * eps * x0.z);
            let err = (x - x0 - expected).norm();
            assert!(
                err < 1e-9 * len,
                "{model:?}: node {i} off the uniaxial solution by {err}"
            );
        }
    }
}

#[test]
fn corotational_is_right_under_a_large_rotation_and_linear_is_not() {
    // Clamp one end of a beam and turn the clamp by 90 degrees about the beam's cross axis,
    // with no load: the exact answer is the beam turned rigidly.
    let len = 4.0;
    let mesh = block(
        Vec3::new(0.0, -0.5, -0.5),
        Vec3::new(len, 0.5, 0.5),
        [8, 2, 2],
    )
    .unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 0, 0.0);
    let turn = Rotation3::from_axis_angle(&Vec3::y_axis(), std::f64::consts::FRAC_PI_2);
    let exact: Vec<Vec3> = mesh.positions().iter().map(|p| turn * p).collect();
    let mut errors = Vec::new();
    for model in MODELS {
        let mut body = FemBody::new(&mesh, config(model, 1000.0, 0.3), &boundary).unwrap();
        for &(i, _) in &boundary.fixed {
            body.positions_mut()[i] = exact[i];
        }
        body.solve_static(1e-12, 500).unwrap();
        let err = body
            .positions()
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        errors.push(err / len);
    }
    assert!(
        errors[1] < 1e-8,
        "corotational off the rigid rotation by {} of the length",
        errors[1]
    );
    assert!(
        errors[0] > 0.1,
        "linear FEM should distort under a 90-degree turn, off by {}",
        errors[0]
    );
}

/// The P1 gradients and volume of a tetrahedron, from its corners (here, not the library's
/// kernels): `grad N_k` for k = 1..3 are the rows of the inverse of the edge matrix
/// `[x1 - x0, x2 - x0, x3 - x0]`, and `grad N_0` is minus their sum.
fn p1_gradients(p: [Vec3; 4]) -> ([Vec3; 4], f64) {
    let d = Matrix3::from_columns(&[p[1] - p[0], p[2] - p[0], p[3] - p[0]]);
    let inv = d.try_inverse().unwrap();
    let g: [Vec3; 3] = [0, 1, 2].map(|k| inv.row(k).transpose());
    (
        [-(g[0] + g[1] + g[2]), g[0], g[1], g[2]],
        d.determinant().abs() / 6.0,
    )
}

/// `L u` for `L = sum_e V G_e^T G_e` (the rest mesh's scalar stiffness, the same for each
/// axis), from the definition.
fn laplacian_times(mesh: &TetMesh, u: &[Vec3]) -> Vec<Vec3> {
    let mut out = vec![Vec3::zeros(); u.len()];
    for t in mesh.tets() {
        let (g, v) = p1_gradients(t.map(|i| mesh.positions()[i as usize]));
        for a in 0..4 {
            for b in 0..4 {
                out[t[a] as usize] += v * g[a].dot(&g[b]) * u[t[b] as usize];
            }
        }
    }
    out
}

/// The prefactored model in the patch test: the boundary of a cube held on an affine map
/// (a uniform strain seen through a quarter turn), one step long enough to be quasi-static
/// (dt 1000: the inertia weighs 1e-6 of the stiffness) with the iterations run to
/// convergence puts every interior node on the affine map: its own forces (the eight-lane
/// element loop) and its constant matrix reproduce a uniform strain exactly.
#[test]
fn prefactored_steps_reproduce_a_uniform_strain_exactly() {
    let mesh = cube(3);
    let map = |p: &Vec3| {
        quarter_turn() * (Matrix3::identity() + strain()) * p + Vec3::new(0.3, -0.2, 0.1)
    };
    let fixed: Vec<usize> = (0..mesh.positions().len())
        .filter(|&i| on_boundary(&mesh.positions()[i]))
        .collect();
    let mut c = config(FemModel::CorotationalPrefactored, 1000.0, 0.3);
    c.dt = 1000.0;
    c.prefactored_iterations = 400;
    let mut body = FemBody::new(&mesh, c, &Boundary::fixed_nodes(fixed.iter().copied())).unwrap();
    let target: Vec<Vec3> = mesh.positions().iter().map(map).collect();
    for &i in &fixed {
        body.positions_mut()[i] = target[i];
    }
    body.step().unwrap();
    let worst = body
        .positions()
        .iter()
        .zip(&target)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-9, "interior off the affine field by {worst}");
}

/// The prefactored model against finite differences of the corotated energy: one iteration
/// of its step from rest (no gravity, a free body, so the inertial target is the start `x`)
/// moves the body by `dx` with `A dx = -grad E(x)`, `A = c M + (2 mu + 3 lambda) L` (its
/// module's definition, rebuilt here from the mesh), `grad E` by central differences of
/// the energy (step 1e-6), at a strained and at a rotated and strained state. And that
/// matrix bounds the energy's Hessian from above (what keeps the model from gaining energy
/// at any step): `d^T H d <= (2 mu + 3 lambda) d^T L d` along random directions, `H d` by
/// central differences of the forces.
#[test]
fn prefactored_step_matches_finite_differences_of_the_energy() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [2, 1, 1]).unwrap();
    let (young, nu) = (100.0, 0.35);
    let (lambda, mu) = element::lame(young, nu);
    let kappa = 2.0 * mu + 3.0 * lambda;
    let n = mesh.positions().len();
    let rot = Rotation3::from_euler_angles(0.4, -0.9, 1.3);
    let states = [
        ("strained", jitter(&mesh, 0.15, 1)),
        (
            "rotated and strained",
            jitter(&mesh, 0.15, 2)
                .iter()
                .map(|p| rot * p)
                .collect::<Vec<_>>(),
        ),
    ];
    let h = 1e-6;
    for (name, x) in &states {
        let mut c = config(FemModel::CorotationalPrefactored, young, nu);
        c.dt = 0.05;
        c.prefactored_iterations = 1;
        let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
        body.positions_mut().copy_from_slice(x);
        body.sync_rotations();
        body.step().unwrap();
        let dx: Vec<Vec3> = body.positions().iter().zip(x).map(|(a, b)| a - b).collect();
        let lap = laplacian_times(&mesh, &dx);
        let inertia = 1.0 / (c.dt * c.dt);
        let mut f = vec![Vec3::zeros(); n];
        let mut scale: f64 = 0.0;
        let mut worst: f64 = 0.0;
        for i in 0..n {
            for a in 0..3 {
                let mut xp = x.clone();
                xp[i][a] += h;
                let mut xm = x.clone();
                xm[i][a] -= h;
                let ep = body.forces_and_energy(&xp, FemModel::Corotational, &mut f);
                let em = body.forces_and_energy(&xm, FemModel::Corotational, &mut f);
                let force = -(ep - em) / (2.0 * h);
                let a_dx = inertia * body.masses()[i] * dx[i][a] + kappa * lap[i][a];
                scale = scale.max(force.abs());
                worst = worst.max((a_dx - force).abs());
            }
        }
        assert!(
            worst < 1e-6 * scale,
            "{name}: A dx off -dE/dx by {worst} (forces up to {scale})"
        );
        // The bound on the Hessian, along seeded directions.
        let (mut fp, mut fm) = (vec![Vec3::zeros(); n], vec![Vec3::zeros(); n]);
        for seed in 10..16 {
            let d: Vec<Vec3> = jitter(&mesh, 1.0, seed)
                .iter()
                .zip(mesh.positions())
                .map(|(a, b)| a - b)
                .collect();
            let xp: Vec<Vec3> = x.iter().zip(&d).map(|(p, q)| p + h * q).collect();
            let xm: Vec<Vec3> = x.iter().zip(&d).map(|(p, q)| p - h * q).collect();
            body.forces_and_energy(&xp, FemModel::Corotational, &mut fp);
            body.forces_and_energy(&xm, FemModel::Corotational, &mut fm);
            let hessian: f64 = (0..n)
                .map(|i| -d[i].dot(&(fp[i] - fm[i])) / (2.0 * h))
                .sum();
            let bound: f64 = kappa
                * laplacian_times(&mesh, &d)
                    .iter()
                    .zip(&d)
                    .map(|(l, q)| l.dot(q))
                    .sum::<f64>();
            assert!(
                hessian <= bound * (1.0 + 1e-6),
                "{name}, direction {seed}: d^T H d {hessian} above the matrix's {bound}"
            );
        }
    }
}
