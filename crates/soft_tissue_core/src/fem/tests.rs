//! Unit tests of the FEM body.

use super::*;
use crate::mesh::generate::block;
use nalgebra::Rotation3;

/// The hand-written upper-triangle assembly (used by steps, `stiffness_at` and the static
/// solve) equals a plain assembly of [`element::stiffness_block`] over all 16 blocks.
#[test]
fn fast_assembly_matches_the_element_kernel() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [3, 2, 2]).unwrap();
    let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
    c.stiffness_damping = 0.003;
    let mut boundary = Boundary::fixed_nodes([0, 1]);
    boundary.anchors.push((5, 40.0));
    let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
    let rot = Rotation3::from_euler_angles(0.5, -0.3, 1.1);
    for (i, x) in body.positions_mut().iter_mut().enumerate() {
        *x = rot * (*x * (1.0 + 0.01 * (i % 5) as f64));
    }
    body.sync_rotations();
    // Converged rotations (the hand-over sync stops at 1e-6 rad).
    for t in 0..body.tets.len() {
        let p = body.tets[t].map(|i| body.nodes.x[i as usize]);
        let f = element::deformation_gradient(&p, &body.grads[t]);
        rotation::extract_rotation(&f, &mut body.quats[t], &mut body.rots[t], 100, 1e-15);
    }
    // Reference: K_R plus anchors, from the element kernel.
    let mut reference = body.k_rest.clone();
    reference.set_zero();
    for (t, tet) in body.tets.iter().enumerate() {
        let b = &body.grads[t];
        let r = body.rots[t];
        for a in 0..4 {
            for bb in 0..4 {
                let blk = element::stiffness_block(
                    &(r * b[a]),
                    &(r * b[bb]),
                    b[a].dot(&b[bb]),
                    body.volumes[t],
                    body.lambda,
                    body.mu,
                );
                let k = reference
                    .block_index(tet[a] as usize, tet[bb] as usize)
                    .unwrap();
                reference.blocks_mut()[k] += blk;
            }
        }
    }
    for i in 0..body.node_count() {
        let d = reference.diag_index(i);
        reference.blocks_mut()[d] += Matrix3::identity() * body.nodes.anchor_k[i];
    }
    let size = reference
        .blocks()
        .iter()
        .map(|b| b.abs().max())
        .fold(0.0, f64::max);
    let at = body.stiffness_at(body.positions(), FemModel::Corotational);
    let worst = at
        .blocks()
        .iter()
        .zip(reference.blocks())
        .map(|(a, b)| (a - b).abs().max())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-12 * size,
        "stiffness_at differs by {worst} (scale {size})"
    );
    // The step's system matrix: (1 + h alpha) M + c K_R + h^2 Ka, updated element by
    // element from the rest system, at most a quarter of the elements (at least 64) a
    // step: every element has turned here, so it takes two element loops.
    for round in 0..2 {
        body.rhs.fill(Vec3::zeros());
        body.corotational_forces_and_matrix();
        let pending = body
            .quats
            .iter()
            .zip(&body.quats_assembled)
            .filter(|(q, a)| q.angle_to(a) > 1e-12)
            .count();
        let expected = [body.tets.len() - 64, 0][round];
        assert_eq!(pending, expected, "round {round}");
    }
    let h = c.dt;
    let scale = c.stiffness_damping * h + h * h;
    let mut worst: f64 = 0.0;
    for i in 0..body.node_count() {
        let (cols, range) = reference.row(i);
        for (&j, k) in cols.iter().zip(range) {
            let mut expected = reference.blocks()[k] * scale;
            if j as usize == i {
                expected += Matrix3::identity()
                    * ((1.0 + h * c.mass_damping) * body.nodes.mass[i]
                        + (h * h - scale) * body.nodes.anchor_k[i]);
            }
            worst = worst.max((body.system.matrix.blocks()[k] - expected).abs().max());
        }
    }
    assert!(worst < 1e-12 * size, "system matrix differs by {worst}");
    assert!(body.system.matrix.asymmetry() < 1e-15 * size);
}

/// The element loop, its force sums and the warped-stiffness update give the same bits
/// on one thread and in pools of two and three (they split into parts only in a pool):
/// rotations, forces, stale lists and the system matrix, on a turned, deformed block of
/// 3000 elements whose every element is stale.
#[test]
fn element_loop_and_assembly_are_the_same_on_any_thread_count() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [10, 10, 5]).unwrap();
    let run = |threads: usize| {
        let c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
        let mut body = FemBody::new(&mesh, c, &Boundary::fixed_nodes([0])).unwrap();
        let rot = Rotation3::from_euler_angles(0.4, -0.2, 0.9);
        for (i, x) in body.nodes.x.iter_mut().enumerate() {
            let s = i as f64;
            *x = rot * (*x + 0.02 * Vec3::new(s.sin(), (1.3 * s).cos(), (0.4 * s).sin()));
        }
        let pool = crate::parallel::Threads::new(threads).unwrap();
        let mut stale = 0;
        pool.run(|| {
            for _ in 0..3 {
                body.rhs.fill(Vec3::zeros());
                body.corotational_forces_and_matrix();
                stale = stale.max(body.stale.len());
            }
        });
        (body, stale)
    };
    let (one, stale) = run(1);
    assert!(stale >= 2 * PARALLEL_ELEMENTS, "{stale} stale elements");
    for threads in [2, 3] {
        let (other, _) = run(threads);
        assert_eq!(one.rhs, other.rhs, "{threads} threads: forces");
        assert_eq!(one.quats, other.quats, "{threads} threads: rotations");
        assert_eq!(one.stale, other.stale, "{threads} threads: stale list");
        assert_eq!(
            one.system.matrix.blocks(),
            other.system.matrix.blocks(),
            "{threads} threads: system matrix"
        );
    }
}

/// The linear step without a product with `K` (used when the fixed components sit at rest)
/// gives the `dv` of the step with the product, on a body with fixed nodes, an anchor,
/// stiffness damping, a deformed state, velocities and external forces.
#[test]
fn linear_step_without_the_stiffness_product_is_the_same_step() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [4, 2, 2]).unwrap();
    for beta in [0.0, 0.004] {
        let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
        c.model = FemModel::Linear;
        c.stiffness_damping = beta;
        c.mass_damping = 0.3;
        c.gravity = Vec3::new(0.0, -9.81, 0.0);
        let mut boundary = Boundary::fixed_nodes([0, 1, 2]);
        boundary.anchors.push((7, 40.0));
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        for (i, (x, v)) in body
            .nodes
            .x
            .iter_mut()
            .zip(body.nodes.v.iter_mut())
            .enumerate()
        {
            if i > 2 {
                let s = i as f64;
                *x += Vec3::new(0.01 * s.sin(), 0.02 * s.cos(), -0.015 * (0.7 * s).sin());
                *v = Vec3::new(0.3 * (1.3 * s).cos(), -0.2 * s.sin(), 0.1);
            }
        }
        body.nodes.f_ext[9] = Vec3::new(3.0, -1.0, 2.0);
        assert!(body.fixed_at_rest());
        body.fill_common_rhs();
        body.linear_dv(true).unwrap();
        let with = body.dv.clone();
        body.fill_common_rhs();
        body.linear_dv(false).unwrap();
        let scale = with.iter().map(|d| d.norm()).fold(0.0, f64::max);
        assert!(scale > 1e-3, "the state moves");
        for (i, (a, b)) in with.iter().zip(&body.dv).enumerate() {
            assert!(
                (a - b).norm() <= 1e-10 * scale,
                "beta {beta}, node {i}: {a:?} vs {b:?}"
            );
        }
    }
}

/// The packed (eight-lane) element loop gives the rotations, iteration counts and forces
/// of the scalar element code ([`rotation::extract_rotation`], `-V R sigma b`): on a mesh
/// whose element count is not a multiple of eight, for a small deformation (first-order
/// updates), a half-turn-scale rotation (the large-correction fallback) and one inverted
/// element, with one and with three rotation iterations. Both round differently (the
/// vector code orders the quaternion arithmetic its own way); the iteration amplifies that
/// for an element a half turn from its start (5e-10 measured, elsewhere 1e-13), so the
/// bound is 1e-9, far below the 1e-4 rad stopping tolerance the test uses.
#[test]
fn packed_element_loop_matches_the_scalar_element_code() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [3, 2, 1]).unwrap();
    assert_ne!(mesh.tets().len() % packed::LANES, 0);
    for (angle, iterations) in [(0.02, 1), (0.02, 3), (1.3, 1), (1.3, 3)] {
        let mut c = FemConfig::paper(&crate::scenario::ORGAN_FEM.params, 0.01);
        c.rotation_iterations = iterations;
        // A coarse stopping tolerance, so both codes stop on the same iteration (at the
        // default, rounding near the threshold could stop them one update apart).
        c.rotation_tolerance = 1e-4;
        let mut body = FemBody::new(&mesh, c, &Boundary::fixed_nodes([0])).unwrap();
        let rot = Rotation3::from_euler_angles(angle, -0.5 * angle, 0.7 * angle);
        for (i, x) in body.nodes.x.iter_mut().enumerate() {
            let s = i as f64;
            *x = rot * (*x + 0.03 * Vec3::new(s.sin(), (1.7 * s).cos(), (0.3 * s).sin()));
        }
        // Invert one element by pushing a corner through its opposite face.
        let t0 = body.tets[3];
        let (p0, p1, p2, p3) = (
            body.nodes.x[t0[0] as usize],
            body.nodes.x[t0[1] as usize],
            body.nodes.x[t0[2] as usize],
            body.nodes.x[t0[3] as usize],
        );
        body.nodes.x[t0[0] as usize] = p0 + 1.6 * ((p1 + p2 + p3) / 3.0 - p0);
        let (quats0, rots0) = (body.quats.clone(), body.rots.clone());
        body.rhs.fill(Vec3::zeros());
        let (worst, ..) = body.corotational_forces_and_matrix();
        // Scalar reference.
        let mut expected = vec![Vec3::zeros(); body.node_count()];
        let mut expected_worst = 0;
        for (t, tet) in body.tets.iter().enumerate() {
            let p = tet.map(|i| body.nodes.x[i as usize]);
            let f = element::deformation_gradient(&p, &body.grads[t]);
            let (mut q, mut r) = (quats0[t], rots0[t]);
            let it =
                rotation::extract_rotation(&f, &mut q, &mut r, iterations, c.rotation_tolerance);
            expected_worst = expected_worst.max(it);
            assert!(
                (q.coords - body.quats[t].coords).abs().max() < 1e-9,
                "angle {angle}, element {t}: {q:?} vs {:?}",
                body.quats[t]
            );

            assert!((r - body.rots[t]).abs().max() < 1e-9);
            let s = r.transpose() * f;
            let eps = (s + s.transpose()) * 0.5 - Matrix3::identity();
            let pm = r * element::stress(&eps, body.lambda, body.mu) * (-body.volumes[t]);
            for a in 0..4 {
                expected[tet[a] as usize] += pm * body.grads[t][a];
            }
        }
        assert_eq!(worst, expected_worst, "angle {angle}");
        let scale = expected.iter().map(|f| f.norm()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        for (i, (a, b)) in body.rhs.iter().zip(&expected).enumerate() {
            assert!(
                (a - b).norm() <= 1e-9 * scale,
                "angle {angle}, node {i}: {a:?} vs {b:?}"
            );
        }
    }
}
