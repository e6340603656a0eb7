//! Validation of the FEM solvers' time integration: energy, the prefactored model's
//! iterations against the backward-Euler step, BDF2's order on oscillators and a cantilever
//! (and its first order under rotation with the corotational CG model),
//! rest on the static solution.

#![allow(clippy::needless_range_loop)] // index loops over parallel node arrays

mod fem_support;

use fem_support::*;
use nalgebra::{Matrix3, Rotation3};
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemConfig, FemIntegrator, FemModel, MassSpec};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::{NodalModel, Vec3};

#[test]
fn implicit_euler_never_gains_energy() {
    // A free cube released from a 20 % stretch, with and without damping: kinetic plus
    // elastic energy must not increase from one step to the next (backward Euler is
    // dissipative). Tolerance 1e-9 of the initial energy for the CG round-off.
    let mesh = cube(3);
    // Corotational also with the default lagged stiffness update (0.01 rad).
    let cases = [
        (FemModel::Linear, 0.0),
        (FemModel::Corotational, 0.0),
        (FemModel::Corotational, 0.01),
        (FemModel::CorotationalPrefactored, 0.0),
    ];
    for (model, lag) in cases {
        for (alpha, beta) in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.01)] {
            if model == FemModel::CorotationalPrefactored && beta > 0.0 {
                continue; // mass damping only
            }
            let mut c = config(model, 1000.0, 0.3);
            c.mass_damping = alpha;
            c.stiffness_damping = beta;
            c.stiffness_update_angle = lag;
            c.dt = 0.02;
            let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
            let stretch = Matrix3::from_diagonal(&Vec3::new(1.2, 0.9, 1.0));
            for (x, x0) in body.positions_mut().iter_mut().zip(mesh.positions()) {
                *x = stretch * x0;
            }
            let e0 = body.kinetic_energy() + body.elastic_energy();
            let mut prev = e0;
            for s in 0..200 {
                body.step().unwrap();
                let e = body.kinetic_energy() + body.elastic_energy();
                // One quasi-Newton iteration a step (the prefactored model) is not exactly
                // dissipative from one step to the next: allow 1e-4 of the initial energy
                // (about 1e-5 at the first gain measured), never above the start.
                let slack = if model == FemModel::CorotationalPrefactored {
                    1e-4
                } else {
                    1e-9
                };
                assert!(
                    e <= prev + slack * e0 && e <= e0,
                    "{model:?} alpha {alpha} beta {beta}: step {s} energy {prev} -> {e}"
                );
                prev = e;
            }
            assert!(
                prev < 0.9 * e0,
                "{model:?}: energy should decay, {e0} -> {prev}"
            );
        }
    }
}

/// The inertial target `y` of a backward-Euler step and the residual of its optimality
/// condition `c M (x - y) = f(x)` at the body's positions `x` (exact corotated forces with
/// converged rotations, anchors included), over the free components, relative to the largest
/// force. `x0`, `v0`: the state before the step.
fn backward_euler_residual(body: &FemBody, x0: &[Vec3], v0: &[Vec3], c: &FemConfig) -> f64 {
    let h = c.dt;
    let damp = 1.0 + h * c.mass_damping;
    let inertia = damp / (h * h);
    let x = body.positions().to_vec();
    let mut f = vec![Vec3::zeros(); x.len()];
    body.forces_and_energy(&x, FemModel::Corotational, &mut f);
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    for i in 0..x.len() {
        let m = body.masses()[i];
        let y = x0[i] + (h / damp) * v0[i] + c.gravity / inertia;
        let r = inertia * m * (x[i] - y) - f[i];
        worst = worst.max(r.norm());
        scale = scale.max(f[i].norm());
    }
    worst / scale
}

/// A twisted, stretched, moving free cube: one step of the prefactored model with enough
/// iterations solves the backward-Euler step of the corotated energy (its optimality
/// condition, with the finite-difference-checked forces of `forces_and_energy`, holds to
/// round-off). With fewer iterations it is an approximation of that step, whose distance
/// falls as iterations are added.
#[test]
fn prefactored_iterations_converge_to_the_backward_euler_step() {
    let mesh = cube(3);
    let twist = Rotation3::from_euler_angles(0.4, -0.8, 1.1);
    let stretch = Matrix3::from_diagonal(&Vec3::new(1.15, 0.92, 1.05));
    let run = |iterations: u32| {
        let mut c = config(FemModel::CorotationalPrefactored, 1000.0, 0.3);
        c.mass_damping = 0.5;
        c.dt = 0.02;
        c.gravity = Vec3::new(0.0, -9.81, 0.0);
        c.rotation_iterations = 1;
        c.prefactored_iterations = iterations;
        let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
        for (i, (x, x0)) in body
            .positions_mut()
            .iter_mut()
            .zip(mesh.positions())
            .enumerate()
        {
            let s = i as f64;
            *x = twist
                * (stretch * x0 + 0.02 * Vec3::new(s.sin(), (1.3 * s).cos(), (0.7 * s).sin()));
        }
        for (i, v) in body.velocities_mut().iter_mut().enumerate() {
            let s = i as f64;
            *v = Vec3::new(0.3 * (0.9 * s).cos(), -0.2, 0.1 * s.sin());
        }
        body.sync_rotations();
        let (x0, v0) = (body.positions().to_vec(), body.velocities().to_vec());
        body.step().unwrap();
        let r = backward_euler_residual(&body, &x0, &v0, &c);
        let moved = body
            .positions()
            .iter()
            .zip(&x0)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        (body.positions().to_vec(), r, moved)
    };
    let (exact, residual, moved) = run(400);
    println!("400 iterations: relative residual {residual:.3e}, step moved {moved:.3e}");
    assert!(residual < 1e-8, "converged residual {residual:e}");
    let mut distances = Vec::new();
    for iterations in [1, 2, 4, 16] {
        let (x, _, _) = run(iterations);
        let d = x
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        println!("{iterations} iterations: {:.3e} of the step", d / moved);
        distances.push(d / moved);
    }
    assert!(distances.windows(2).all(|w| w[1] < w[0]), "{distances:?}");
    // Here (a stiff cube, h^2 k / m far above 1, released from a 15 % stretch) one iteration
    // falls short of the converged step by a good part of the step's motion: an
    // approximation, whose effect on whole runs the report's speed-against-error table
    // measures. It must still move the body most of the right way.
    assert!(distances[0] < 0.7, "{distances:?}");
}

/// A cantilever bending far under its own weight (tip deflection about half its length) and
/// damped by mass: the prefactored model's steps come to rest on the static equilibrium of
/// the corotated energy (the Newton static solve): its fixed point is exact.
#[test]
fn prefactored_comes_to_rest_on_the_corotational_static_equilibrium() {
    let (len, a) = (4.0, 0.5);
    let mesh = block(Vec3::zeros(), Vec3::new(len, a, a), [16, 2, 2]).unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 0, 0.0);
    let mut c = config(FemModel::Corotational, 3000.0, 0.35);
    c.gravity = Vec3::new(0.0, 0.0, -9.81);
    let mut reference = FemBody::new(&mesh, c, &boundary).unwrap();
    reference.solve_static(1e-12, 200).unwrap();
    let tip = (0..mesh.positions().len())
        .max_by(|&i, &j| mesh.positions()[i].x.total_cmp(&mesh.positions()[j].x))
        .unwrap();
    let deflection = (reference.positions()[tip] - mesh.positions()[tip]).norm();
    assert!(deflection > 0.05 * len, "a visible bend: {deflection}");
    c.model = FemModel::CorotationalPrefactored;
    c.mass_damping = 1.0;
    // Eight iterations a step: with one, this slender beam (large rotations along it, which
    // the rotation-invariant matrix penalises) falls many times slower than backward Euler
    // (numerical damping, measured: half the deflection still to go after 5 s); the fixed
    // point is the same.
    c.prefactored_iterations = 8;
    c.rotation_iterations = 1;
    let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
    for _ in 0..3000 {
        body.step().unwrap();
    }
    assert!(
        body.max_speed() < 1e-6 * len,
        "at rest: {}",
        body.max_speed()
    );
    let worst = body
        .positions()
        .iter()
        .zip(reference.positions())
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max);
    println!("prefactored rest vs static: {worst:.3e} (deflection {deflection:.3})");
    assert!(
        worst < 1e-6 * deflection,
        "off the static solution by {worst}"
    );
}

/// A free body, no damping, no gravity: the prefactored step conserves linear momentum (the
/// Laplacian's rows and every element's forces sum to zero), and a body turning rigidly
/// keeps its shape (no elastic energy appears from the rotation alone).
#[test]
fn prefactored_conserves_momentum_and_turns_rigidly() {
    let mesh = cube(3);
    let c = config(FemModel::CorotationalPrefactored, 1000.0, 0.3);
    let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
    let centre = Vec3::repeat(0.5);
    let omega = Vec3::new(0.0, 0.0, 3.0);
    for (v, x) in body.velocities_mut().iter_mut().zip(mesh.positions()) {
        *v = Vec3::new(0.2, -0.1, 0.05) + omega.cross(&(x - centre));
    }
    let momentum = |b: &FemBody| -> Vec3 {
        b.velocities()
            .iter()
            .zip(b.masses())
            .map(|(v, m)| v * *m)
            .sum()
    };
    let p0 = momentum(&body);
    let e0 = body.kinetic_energy();
    for _ in 0..100 {
        body.step().unwrap();
    }
    let p1 = momentum(&body);
    assert!((p1 - p0).norm() < 1e-9 * p0.norm(), "{p0:?} -> {p1:?}");
    // A second of turning at 3 rad/s (about half a turn): the shape stays that of the rest
    // state (elastic energy tiny against the kinetic energy).
    let elastic = body.elastic_energy();
    println!("elastic energy after half a turn: {elastic:.3e} (kinetic {e0:.3e})");
    assert!(elastic < 1e-2 * e0, "elastic {elastic} vs kinetic {e0}");
}

/// The prefactored model refuses stiffness damping with an error naming the field, at build time
/// and when switched to at run time (the body keeps its model).
#[test]
fn prefactored_refuses_stiffness_damping() {
    let mesh = cube(2);
    let mut c = config(FemModel::CorotationalPrefactored, 1000.0, 0.3);
    c.stiffness_damping = 0.01;
    let e = FemBody::new(&mesh, c, &Boundary::free()).unwrap_err();
    assert!(e.to_string().contains("stiffness_damping"), "{e}");
    c.model = FemModel::Corotational;
    let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
    let e = body
        .set_model(FemModel::CorotationalPrefactored)
        .unwrap_err();
    assert!(e.to_string().contains("stiffness_damping"), "{e}");
    assert_eq!(body.model(), FemModel::Corotational);
}

/// One tetrahedron with three corners clamped: the free corner is a three-degree-of-freedom
/// linear oscillator `m u'' + alpha m u' + K u = 0` (linear model, `K` the free corner's
/// stiffness block, `m` its lumped mass). Returns the body and the closed-form displacement
/// at time `t` from `u(0) = u0`, `u'(0) = 0`, by modes of `K / m`.
fn oscillator(
    integrator: FemIntegrator,
    model: FemModel,
    dt: f64,
    alpha: f64,
) -> (FemBody, Box<dyn Fn(f64, Vec3) -> Vec3>) {
    let mesh = TetMesh::new(
        vec![
            Vec3::zeros(),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.3, 0.4, 1.0),
        ],
        vec![[0, 1, 2, 3]],
    )
    .unwrap();
    let mut c = config(model, 10.0, 0.3);
    c.dt = dt;
    c.mass_damping = alpha;
    c.integrator = integrator;
    let body = FemBody::new(&mesh, c, &Boundary::fixed_nodes([0, 1, 2])).unwrap();
    let k = body.stiffness_at(mesh.positions(), FemModel::Linear);
    let km = k.blocks()[k.block_index(3, 3).unwrap()] / body.masses()[3];
    let eig = km.symmetric_eigen();
    let exact = move |t: f64, u0: Vec3| {
        let q0 = eig.eigenvectors.transpose() * u0;
        let q = Vec3::from_fn(|j, _| {
            let w2 = eig.eigenvalues[j];
            let wd = (w2 - 0.25 * alpha * alpha).sqrt();
            let decay = (-0.5 * alpha * t).exp();
            q0[j] * decay * ((wd * t).cos() + 0.5 * alpha / wd * (wd * t).sin())
        });
        eig.eigenvectors * q
    };
    (body, Box::new(exact))
}

/// Largest error over `t` in [0, 2] of the oscillator released from a small displacement,
/// relative to it.
fn oscillator_error(integrator: FemIntegrator, model: FemModel, dt: f64, alpha: f64) -> f64 {
    let (mut body, exact) = oscillator(integrator, model, dt, alpha);
    let u0 = Vec3::new(0.01, -0.02, 0.015);
    let rest = body.positions()[3];
    body.positions_mut()[3] = rest + u0;
    let steps = (2.0 / dt).round() as usize;
    let mut worst = 0.0f64;
    for k in 1..=steps {
        body.step().unwrap();
        let e = (body.positions()[3] - rest - exact(k as f64 * dt, u0)).norm();
        worst = worst.max(e / u0.norm());
    }
    worst
}

/// Against the closed form (linear model; the corotational one differs from it by the
/// strain): backward Euler's error halves when the step halves (first order), BDF2's falls by
/// four (second order) and is far smaller at the same step. Ratios checked within [1.8, 2.2]
/// and [3.6, 4.4].
#[test]
fn bdf2_is_second_order_and_backward_euler_first_on_an_oscillator() {
    let model = FemModel::Linear;
    for alpha in [0.0, 0.8] {
        let errors = |integrator| {
            [0.004, 0.002, 0.001].map(|dt| oscillator_error(integrator, model, dt, alpha))
        };
        let be = errors(FemIntegrator::BackwardEuler);
        let bdf2 = errors(FemIntegrator::Bdf2);
        println!("alpha {alpha}: backward Euler {be:?}, BDF2 {bdf2:?}");
        for w in be.windows(2) {
            let r = w[0] / w[1];
            assert!((1.8..2.2).contains(&r), "BE ratio {r}: {be:?}");
        }
        for w in bdf2.windows(2) {
            let r = w[0] / w[1];
            assert!((3.6..4.4).contains(&r), "BDF2 ratio {r}: {bdf2:?}");
        }
        assert!(bdf2[0] < 0.1 * be[0], "{be:?} {bdf2:?}");
    }
}

/// A cube turning and vibrating (nonlinear corotated forces), corotational CG model (the
/// prefactored one refuses BDF2), against BDF2 at a step 16 times finer. The CG model
/// linearizes each step once, at its start, with the warped stiffness, which leaves out the
/// derivative of the rotations: under rotation of a deformed body that error (proportional
/// to the strain) makes BDF2 first order here, measured 2.6e-2, 1.2e-2, 5.4e-3 at dt 0.01,
/// 0.005, 0.0025 (ratios 2.08 and 2.30) against backward Euler's 1.6e-2, 9.9e-3, 6.0e-3.
/// Linearizing at the predicted positions `x + h v` made it second order (ratios 4.1 and
/// 4.2) but blew up in the ten-times-the-step hard case, so it is not used. Checked: each
/// halving of the step divides the error by 1.8 to 3 (first order; second order would
/// divide it by 4, and would fail this test until it is renamed).
#[test]
fn bdf2_is_first_order_for_corotational_fem_under_rotation() {
    let mesh = cube(2);
    let run = |model: FemModel, integrator: FemIntegrator, dt: f64| {
        let mut c = config(model, 20.0, 0.3);
        c.dt = dt;
        c.integrator = integrator;
        c.prefactored_iterations = 30;
        c.cg_tolerance = 1e-12;
        let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
        let centre = Vec3::repeat(0.5);
        let omega = Vec3::new(0.5, 1.0, 2.0);
        for (i, x0) in mesh.positions().iter().enumerate() {
            body.positions_mut()[i] = x0 + 0.05 * Vec3::new(x0.y, -x0.z, x0.x * x0.y);
            body.velocities_mut()[i] = omega.cross(&(x0 - centre));
        }
        let steps = (1.0 / dt).round() as usize;
        for _ in 0..steps {
            body.step().unwrap();
        }
        body.positions().to_vec()
    };
    {
        let model = FemModel::Corotational;
        let reference = run(model, FemIntegrator::Bdf2, 0.01 / 16.0);
        let errors = |integrator| {
            [0.01, 0.005, 0.0025].map(|dt| {
                run(model, integrator, dt)
                    .iter()
                    .zip(&reference)
                    .map(|(a, b)| (a - b).norm())
                    .fold(0.0, f64::max)
            })
        };
        let (bdf2, be) = (
            errors(FemIntegrator::Bdf2),
            errors(FemIntegrator::BackwardEuler),
        );
        println!("{model:?} errors: BDF2 {bdf2:?}, backward Euler {be:?}");
        // First order: the error halves with the step (on the linear part of the motion,
        // the oscillator test, it is second order).
        for w in bdf2.windows(2) {
            let r = w[0] / w[1];
            assert!(
                (1.8..3.0).contains(&r),
                "{model:?} BDF2 ratio {r}: {bdf2:?}"
            );
        }
    }
}

/// A cantilever under its own weight, damped by mass, stepped with the default corotational
/// settings (one rotation update a step, the lagged stiffness, a loose CG) comes to rest
/// within 1e-8 (relative to the tip deflection) of the static solve, with either
/// integrator: the rotation tolerance no longer leaves it short.
#[test]
fn corotational_steps_come_to_rest_on_the_static_solution() {
    let (len, a) = (4.0, 0.5);
    let mesh = block(Vec3::zeros(), Vec3::new(len, a, a), [16, 2, 2]).unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 0, 0.0);
    let mut c = FemConfig::paper(&soft_tissue_core::scenario::ORGAN_FEM.params, 0.01);
    c.young_modulus = 3000.0;
    c.poisson_ratio = 0.35;
    c.mass = MassSpec::Density(1.0);
    c.mass_damping = 4.0;
    c.gravity = Vec3::new(0.0, 0.0, -9.81);
    let mut reference = FemBody::new(&mesh, c, &boundary).unwrap();
    reference.solve_static(1e-13, 200).unwrap();
    let tip = (0..mesh.positions().len())
        .max_by(|&i, &j| mesh.positions()[i].x.total_cmp(&mesh.positions()[j].x))
        .unwrap();
    let deflection = (reference.positions()[tip] - mesh.positions()[tip]).norm();
    assert!(deflection > 0.05 * len, "a visible bend: {deflection}");
    for (integrator, tolerance) in [
        (FemIntegrator::BackwardEuler, c.rotation_tolerance),
        (FemIntegrator::Bdf2, c.rotation_tolerance),
        (FemIntegrator::BackwardEuler, 1e-4),
    ] {
        let mut c = c;
        c.integrator = integrator;
        c.rotation_tolerance = tolerance;
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        for _ in 0..2000 {
            body.step().unwrap();
        }
        let worst = body
            .positions()
            .iter()
            .zip(reference.positions())
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
            / deflection;
        println!("{integrator:?}, rotation tolerance {tolerance:e}: {worst:.3e} off");
        if tolerance == c.rotation_tolerance && tolerance < 1e-8 {
            assert!(
                worst < 1e-8,
                "{integrator:?}: off the static solution by {worst}"
            );
        } else {
            // The former fixed tolerance, 1e-4 rad, left it measurably short (2.9e-5).
            assert!(worst > 1e-6, "{integrator:?} at {tolerance:e}: {worst}");
        }
    }
}

/// BDF2 on the free stretched cube of `implicit_euler_never_gains_energy`: not monotone
/// from step to step in general (a two-step method), but the energy stays bounded by its
/// start (1e-6 slack) and decays under damping. (That it damps less than backward Euler at
/// frequencies the step resolves is what the oscillator tests show; this cube's modes are
/// far above `1 / dt`, where both damp them out.)
#[test]
fn bdf2_energy_stays_bounded_and_decays() {
    let mesh = cube(3);
    for model in [FemModel::Linear, FemModel::Corotational] {
        for alpha in [0.0, 0.5] {
            let mut c = config(model, 1000.0, 0.3);
            c.mass_damping = alpha;
            c.stiffness_update_angle = 0.01;
            c.dt = 0.02;
            c.integrator = FemIntegrator::Bdf2;
            let mut be = c;
            be.integrator = FemIntegrator::BackwardEuler;
            let energy_after = |c: FemConfig| {
                let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
                let stretch = Matrix3::from_diagonal(&Vec3::new(1.2, 0.9, 1.0));
                for (x, x0) in body.positions_mut().iter_mut().zip(mesh.positions()) {
                    *x = stretch * x0;
                }
                let e0 = body.kinetic_energy() + body.elastic_energy();
                let mut e = e0;
                for s in 0..200 {
                    body.step().unwrap();
                    e = body.kinetic_energy() + body.elastic_energy();
                    assert!(
                        e <= e0 * (1.0 + 1e-6),
                        "{model:?} alpha {alpha}: step {s} {e0} -> {e}"
                    );
                }
                e / e0
            };
            let (kept_bdf2, kept_be) = (energy_after(c), energy_after(be));
            println!("{model:?} alpha {alpha}: energy kept BDF2 {kept_bdf2:.3}, BE {kept_be:.3}");
            if alpha > 0.0 {
                assert!(kept_bdf2 < 0.9, "{model:?}: should decay, kept {kept_bdf2}");
            }
        }
    }
}

/// The prefactored model takes backward Euler only: BDF2 is refused with an error naming the
/// field, at build time and at run time (the body keeps its integrator).
#[test]
fn prefactored_refuses_bdf2() {
    let mesh = cube(1);
    let mut c = config(FemModel::CorotationalPrefactored, 1000.0, 0.3);
    c.integrator = FemIntegrator::Bdf2;
    let err = FemBody::new(&mesh, c, &Boundary::free()).unwrap_err();
    assert!(err.to_string().contains("`integrator`"), "{err}");
    c.integrator = FemIntegrator::BackwardEuler;
    let mut body = FemBody::new(&mesh, c, &Boundary::free()).unwrap();
    assert!(body.set_integrator(FemIntegrator::Bdf2).is_err());
    assert_eq!(body.integrator(), FemIntegrator::BackwardEuler);
    body.step().unwrap();
}

/// A cantilever (10 x 1 x 1, clamped at x = 0, linear model, first bending period about 2 s)
/// released from rest in the shape of its first Euler-Bernoulli bending mode, followed for
/// 1 s: its tip deflection against BDF2 at a step 32 times finer. Backward Euler's largest
/// error halves when the step halves (first order: measured 1.91, 1.96), BDF2's falls by
/// about four (second order: 3.83, 3.94) and is 15-60 times smaller at the same step.
///
/// Where second order needs care: the released shape is not exactly a mode of the mesh,
/// and its fast modes (shear, axial) are faster than the steps. BDF2 damps those as backward
/// Euler does (it is L-stable), the fine reference does not; without physical damping they
/// set a floor under BDF2's error (measured 2.6, 2.3, 2.1 % at the three steps; from rest
/// under gravity switched on at once, 0.62, 0.21, 0.11 %: ratios 2.9 and 2.0). Stiffness-
/// proportional damping removes
/// them from every run alike, so the test measures the order on what the steps resolve.
#[test]
fn bdf2_is_second_order_on_a_fem_cantilever_against_a_fine_step() {
    let (len, a) = (10.0, 1.0);
    let mesh = block(Vec3::zeros(), Vec3::new(len, a, a), [20, 2, 2]).unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 0, 0.0);
    let tip: Vec<usize> = (0..mesh.positions().len())
        .filter(|&i| (mesh.positions()[i].x - len).abs() < 1e-9)
        .collect();
    let duration = 1.0;
    // Tip deflection at every 0.04 s.
    let run = |integrator: FemIntegrator, dt: f64| -> Vec<f64> {
        let mut c = config(FemModel::Linear, 1e5, 0.0);
        // Stiffness-proportional damping: 0.016 /s on the first mode, above 200 /s on the
        // modes faster than 200 rad/s, which the steps checked do not resolve.
        c.stiffness_damping = 1e-2;
        c.dt = dt;
        c.integrator = integrator;
        c.cg_tolerance = 1e-12;
        c.cg_max_iterations = 500;
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        // The first mode of an Euler-Bernoulli cantilever: beta L = 1.8751.
        let beta = 1.875_104_07 / len;
        let bl = beta * len;
        let sigma = (bl.cosh() + bl.cos()) / (bl.sinh() + bl.sin());
        let mode = |x: f64| {
            let b = beta * x;
            b.cosh() - b.cos() - sigma * (b.sinh() - b.sin())
        };
        for (i, x0) in mesh.positions().iter().enumerate() {
            body.positions_mut()[i].z = x0.z + 0.05 * mode(x0.x);
        }
        let every = (0.04 / dt).round() as usize;
        let steps = (duration / dt).round() as usize;
        let mut out = Vec::new();
        for k in 1..=steps {
            body.step().unwrap();
            if k % every == 0 {
                let z: f64 = tip
                    .iter()
                    .map(|&i| body.positions()[i].z - mesh.positions()[i].z)
                    .sum::<f64>()
                    / tip.len() as f64;
                out.push(z);
            }
        }
        out
    };
    let reference = run(FemIntegrator::Bdf2, 0.01 / 32.0);
    let scale = reference.iter().fold(0.0f64, |m, z| m.max(z.abs()));
    let error = |integrator, dt| {
        run(integrator, dt)
            .iter()
            .zip(&reference)
            .map(|(z, r)| (z - r).abs())
            .fold(0.0f64, f64::max)
            / scale
    };
    let steps = [0.02, 0.01, 0.005];
    let be = steps.map(|dt| error(FemIntegrator::BackwardEuler, dt));
    let bdf2 = steps.map(|dt| error(FemIntegrator::Bdf2, dt));
    println!("tip error / largest deflection: backward Euler {be:?}, BDF2 {bdf2:?}");
    for w in be.windows(2) {
        let r = w[0] / w[1];
        assert!((1.6..2.4).contains(&r), "BE ratio {r}: {be:?}");
    }
    for w in bdf2.windows(2) {
        let r = w[0] / w[1];
        assert!((3.2..4.8).contains(&r), "BDF2 ratio {r}: {bdf2:?}");
    }
    assert!(bdf2[1] < 0.2 * be[1], "{be:?} {bdf2:?}");
}
