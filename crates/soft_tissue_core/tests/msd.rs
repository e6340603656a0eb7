//! Validation of the mass-spring-damper solvers against the closed-form damped oscillator and
//! finite differences, and of the explicit stability limit.

#![allow(clippy::needless_range_loop)] // index loops over parallel node arrays

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::msd::{
    ExplicitLimit, MsdBody, MsdConfig, MsdError, MsdIntegrator, Spring, SpringSet, SpringStiffness,
    fit_tet_springs,
};
use soft_tissue_core::{NodalModel, Vec3};

fn config(integrator: MsdIntegrator, dt: f64, damping: f64) -> MsdConfig {
    MsdConfig {
        integrator,
        stiffness: 0.0,
        mass: 1.0,
        damping,
        springs: SpringSet::Edges,
        spring_stiffness: SpringStiffness::Constant,
        volume_stiffness: 0.0,
        dt,
        gravity: Vec3::zeros(),
        explicit_limit: ExplicitLimit::Refuse,
        cg_tolerance: 1e-12,
        cg_max_iterations: 100,
        cg_must_converge: false,
    }
}

/// One mass `m` on a spring `k` of rest length 1 from a fixed node, with damping `gamma`,
/// released from a stretch of 0.1. Returns the displacement history.
fn oscillator(
    integrator: MsdIntegrator,
    k: f64,
    m: f64,
    gamma: f64,
    dt: f64,
    steps: usize,
) -> Vec<f64> {
    let spring = Spring {
        a: 0,
        b: 1,
        stiffness: k,
        rest_length: 1.0,
    };
    let mut body = MsdBody::new(
        vec![Vec3::zeros(), Vec3::new(1.1, 0.0, 0.0)],
        vec![1.0, m],
        vec![spring],
        config(integrator, dt, gamma),
        &Boundary::fixed_nodes([0]),
    )
    .unwrap();
    // Damping acts on every node; the fixed node has zero velocity, so only node 1 feels it.
    let mut out = vec![0.1];
    for _ in 0..steps {
        body.step().unwrap();
        out.push(body.positions()[1].x - 1.0);
    }
    out
}

/// Times of the downward zero crossings (linear interpolation) and the positive peaks.
fn crossings_and_peaks(u: &[f64], dt: f64) -> (Vec<f64>, Vec<f64>) {
    let mut crossings = Vec::new();
    let mut peaks = Vec::new();
    for i in 1..u.len() - 1 {
        if u[i] > 0.0 && u[i + 1] <= 0.0 {
            crossings.push((i as f64 + u[i] / (u[i] - u[i + 1])) * dt);
        }
        if u[i] > u[i - 1] && u[i] >= u[i + 1] && u[i] > 0.0 {
            // Parabolic interpolation of the peak value.
            let (a, b, c) = (u[i - 1], u[i], u[i + 1]);
            let d = 0.5 * (a - c) / (a - 2.0 * b + c);
            peaks.push(b - 0.25 * (a - c) * d);
        }
    }
    (crossings, peaks)
}

#[test]
fn rk4_period_and_damping_ratio_match_the_closed_form() {
    let (k, m, gamma): (f64, f64, f64) = (700.0, 2.0, 3.0);
    let omega0 = (k / m).sqrt();
    let zeta = gamma / (2.0 * (k * m).sqrt());
    let omega_d = omega0 * (1.0 - zeta * zeta).sqrt();
    let period = 2.0 * std::f64::consts::PI / omega_d;
    let dt = period / 400.0;
    let u = oscillator(MsdIntegrator::Rk4, k, m, gamma, dt, 4000);
    let (crossings, peaks) = crossings_and_peaks(&u, dt);
    assert!(crossings.len() >= 8 && peaks.len() >= 8);
    let measured = (crossings[crossings.len() - 1] - crossings[0]) / (crossings.len() - 1) as f64;
    // RK4's phase error per step is O((omega h)^5); at 400 steps per period it is ~1e-9
    // relative; the crossing interpolation is the larger error (~1e-6), hence 1e-5.
    assert!(
        (measured - period).abs() < 1e-5 * period,
        "period {measured} vs {period}"
    );
    // Logarithmic decrement: ln(u_n / u_{n+1}) = 2 pi zeta / sqrt(1 - zeta^2).
    let n = peaks.len() - 1;
    let delta = (peaks[0] / peaks[n]).ln() / n as f64;
    let zeta_measured =
        delta / (4.0 * std::f64::consts::PI * std::f64::consts::PI + delta * delta).sqrt();
    assert!(
        (zeta_measured - zeta).abs() < 1e-4 * zeta,
        "damping ratio {zeta_measured} vs {zeta}"
    );
}

#[test]
fn symplectic_and_implicit_euler_oscillate_at_the_right_rate() {
    let (k, m): (f64, f64) = (50.0, 0.5);
    let period = 2.0 * std::f64::consts::PI / (k / m).sqrt();
    let dt = period / 200.0;
    // Symplectic Euler: period error O((omega h)^2) ~ 1e-4 relative at this step.
    let u = oscillator(MsdIntegrator::SymplecticEuler, k, m, 0.0, dt, 2000);
    let (c, peaks) = crossings_and_peaks(&u, dt);
    let measured = (c[c.len() - 1] - c[0]) / (c.len() - 1) as f64;
    assert!(
        (measured - period).abs() < 1e-3 * period,
        "symplectic period {measured} vs {period}"
    );
    // Without damping its amplitude does not drift (bounded to O(omega h)).
    assert!(peaks.iter().all(|p| (p - 0.1).abs() < 0.02), "{peaks:?}");
    // Implicit Euler: same period to O(omega h), and numerical damping only decreases the
    // amplitude.
    let u = oscillator(MsdIntegrator::ImplicitEuler, k, m, 0.0, dt, 2000);
    let (c, peaks) = crossings_and_peaks(&u, dt);
    let measured = (c[c.len() - 1] - c[0]) / (c.len() - 1) as f64;
    assert!(
        (measured - period).abs() < 1e-2 * period,
        "implicit period {measured} vs {period}"
    );
    assert!(
        peaks.windows(2).all(|w| w[1] < w[0]),
        "implicit Euler amplitude must decay"
    );
}

#[test]
fn spring_forces_and_stiffness_match_finite_differences() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [2, 1, 1]).unwrap();
    let mut c = config(MsdIntegrator::Rk4, 0.01, 0.0);
    c.stiffness = 30.0;
    c.springs = SpringSet::EdgesAndBending;
    let mut boundary = Boundary::anchored(mesh.positions().len(), 5.0);
    boundary.anchors.truncate(3);
    let body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
    assert!(
        body.springs().len() > mesh.edges().len(),
        "bending springs added"
    );
    let n = mesh.positions().len();
    let mut s = 7u64;
    let x: Vec<Vec3> = mesh
        .positions()
        .iter()
        .map(|p| {
            let mut r = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            p + 0.3 * Vec3::new(r(), r(), r())
        })
        .collect();
    let energy = |x: &[Vec3], c: MsdConfig| {
        let mut b = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
        b.positions_mut().copy_from_slice(x);
        b.elastic_energy()
    };
    // With the volume term (including inverted states: the jitter flips some elements).
    let mut cv = c;
    cv.volume_stiffness = 80.0;
    let with_volume = MsdBody::from_mesh(&mesh, cv, &boundary).unwrap();
    let mut fv = vec![Vec3::zeros(); n];
    with_volume.spring_forces(&x, &mut fv);
    for j in 0..n {
        for b in 0..3 {
            let mut xp = x.clone();
            xp[j][b] += 1e-6;
            let mut xm = x.clone();
            xm[j][b] -= 1e-6;
            let fd = -(energy(&xp, cv) - energy(&xm, cv)) / 2e-6;
            assert!(
                (fd - fv[j][b]).abs() < 1e-6 * 80.0,
                "volume force {j},{b}: {} vs {fd}",
                fv[j][b]
            );
        }
    }
    let mut f = vec![Vec3::zeros(); n];
    body.spring_forces(&x, &mut f);
    let k = body.stiffness_dense(&x);
    let h = 1e-6;
    let mut fp = vec![Vec3::zeros(); n];
    let mut fm = vec![Vec3::zeros(); n];
    for j in 0..n {
        for b in 0..3 {
            let mut xp = x.clone();
            xp[j][b] += h;
            let mut xm = x.clone();
            xm[j][b] -= h;
            let fd = -(energy(&xp, c) - energy(&xm, c)) / (2.0 * h);
            assert!(
                (fd - f[j][b]).abs() < 1e-6 * 30.0,
                "force {j},{b}: {} vs {fd}",
                f[j][b]
            );
            body.spring_forces(&xp, &mut fp);
            body.spring_forces(&xm, &mut fm);
            for i in 0..n {
                for a in 0..3 {
                    let fd = -(fp[i][a] - fm[i][a]) / (2.0 * h);
                    let kij = k[(3 * i + a) * 3 * n + 3 * j + b];
                    assert!(
                        (fd - kij).abs() < 1e-6 * 30.0,
                        "K[{i}{a},{j}{b}] {kij} vs {fd}"
                    );
                }
            }
        }
    }
}

fn stiff_cube(integrator: MsdIntegrator, dt: f64, policy: ExplicitLimit) -> MsdBody {
    let mesh = block(Vec3::zeros(), Vec3::repeat(1.0), [3, 3, 3]).unwrap();
    let mut c = config(integrator, dt, 0.4);
    c.stiffness = 700.0;
    c.mass = 1.0;
    c.explicit_limit = policy;
    MsdBody::from_mesh(&mesh, c, &Boundary::fixed_below(mesh.positions(), 2, 0.0)).unwrap()
}

/// Peak and final total energy over the initial one, after a kick of the top corner node.
fn perturb_and_run(body: &mut MsdBody, steps: usize) -> Result<(f64, f64), MsdError> {
    let n = body.node_count();
    body.velocities_mut()[n - 1] = Vec3::new(1.0, -2.0, 0.5);
    let e0 = body.kinetic_energy();
    let mut peak: f64 = 0.0;
    for _ in 0..steps {
        body.step()?;
        peak = peak.max(body.kinetic_energy() + body.elastic_energy());
    }
    Ok((
        peak / e0,
        (body.kinetic_energy() + body.elastic_energy()) / e0,
    ))
}

#[test]
fn explicit_step_above_the_limit_is_substepped_or_refused() {
    let probe = stiff_cube(MsdIntegrator::Rk4, 1.0, ExplicitLimit::Refuse);
    let limit = probe.stable_dt();
    assert!(limit.is_finite() && limit > 0.0);
    for integrator in [MsdIntegrator::Rk4, MsdIntegrator::SymplecticEuler] {
        let limit = stiff_cube(integrator, 1.0, ExplicitLimit::Refuse).stable_dt();
        // Just below the limit: stable without substeps; energy never exceeds the input.
        let mut body = stiff_cube(integrator, 0.99 * limit, ExplicitLimit::Refuse);
        // RK4 damps every mode inside its stability region, so the energy never exceeds the
        // input; symplectic Euler conserves a shadow energy, so the true energy oscillates
        // by a bounded factor (1 / (1 - (omega h / 2)^2) for one mode) while damping wins.
        let bound = if integrator == MsdIntegrator::Rk4 {
            1.0 + 1e-6
        } else {
            2.0
        };
        let (peak, last) = perturb_and_run(&mut body, 3000).unwrap();
        assert!(
            peak <= bound && last < 1.0,
            "{integrator:?} at 0.99 of the limit: peak x{peak}, last x{last}"
        );
        // Five times the limit: refused, state untouched.
        let mut body = stiff_cube(integrator, 5.0 * limit, ExplicitLimit::Refuse);
        let before = body.positions().to_vec();
        match body.step() {
            Err(MsdError::TimeStepTooLarge {
                needed, allowed: 0, ..
            }) => assert_eq!(needed, 5),
            other => panic!("{integrator:?}: expected a refusal, got {other:?}"),
        }
        assert_eq!(body.positions(), &before[..]);
        // Substepping policy: split into 5 and stay bounded.
        let mut body = stiff_cube(
            integrator,
            5.0 * limit,
            ExplicitLimit::Substep { max_substeps: 8 },
        );
        let (peak, last) = perturb_and_run(&mut body, 600).unwrap();
        assert_eq!(body.last_step().substeps, 5);
        assert!(
            peak <= bound && last < 1.0,
            "{integrator:?} substepped: peak x{peak}, last x{last}"
        );
        // Not enough substeps allowed: refused with the count needed.
        let mut body = stiff_cube(
            integrator,
            5.0 * limit,
            ExplicitLimit::Substep { max_substeps: 4 },
        );
        assert!(matches!(
            body.step(),
            Err(MsdError::TimeStepTooLarge {
                needed: 5,
                allowed: 4,
                ..
            })
        ));
    }
}

#[test]
fn the_limit_is_safe_and_not_far_from_the_true_one() {
    // True largest angular frequency from the dense eigenproblem of M^-1/2 K M^-1/2 on the
    // free components; RK4 on the undamped system is stable for omega h < 2 sqrt(2).
    let body = stiff_cube(MsdIntegrator::Rk4, 1.0, ExplicitLimit::Refuse);
    let n = body.node_count();
    let k = body.stiffness_dense(body.positions());
    let free: Vec<usize> = (0..3 * n)
        .filter(|&d| body.positions()[d / 3].z > 1e-12)
        .collect();
    let m = body.masses();
    let a = nalgebra::DMatrix::from_fn(free.len(), free.len(), |r, c| {
        let (i, j) = (free[r], free[c]);
        k[i * 3 * n + j] / (m[i / 3] * m[j / 3]).sqrt()
    });
    let omega_max = a.symmetric_eigenvalues().max().sqrt();
    let gamma_rate = 0.4 / m.iter().copied().fold(f64::INFINITY, f64::min);
    let true_limit = 2.0 * 2f64.sqrt() / (omega_max + gamma_rate);
    let estimate = body.stable_dt();
    assert!(
        estimate < true_limit,
        "estimate {estimate} above the true limit {true_limit}"
    );
    assert!(
        estimate > 0.25 * true_limit,
        "estimate {estimate} far below the true limit {true_limit}"
    );
}

#[test]
fn implicit_euler_never_gains_energy_with_stiff_springs() {
    for k_scale in [1.0, 1000.0] {
        let mesh = block(Vec3::zeros(), Vec3::repeat(1.0), [3, 3, 3]).unwrap();
        let mut c = config(MsdIntegrator::ImplicitEuler, 0.02, 0.4);
        c.stiffness = 700.0 * k_scale;
        c.mass = 1.0;
        let mut body = MsdBody::from_mesh(&mesh, c, &Boundary::free()).unwrap();
        for (x, x0) in body.positions_mut().iter_mut().zip(mesh.positions()) {
            *x = Vec3::new(1.2 * x0.x, 0.9 * x0.y, x0.z);
        }
        let e0 = body.kinetic_energy() + body.elastic_energy();
        let mut prev = e0;
        for s in 0..300 {
            body.step().unwrap();
            let e = body.kinetic_energy() + body.elastic_energy();
            assert!(
                e <= prev + 1e-9 * e0,
                "k x{k_scale}: step {s}: {prev} -> {e}"
            );
            prev = e;
        }
        assert!(prev < 0.5 * e0);
    }
}

/// Against the closed form of the damped oscillator `m u'' + gamma u' + k u = 0` (from
/// `u = 0.1`, at rest): the largest error over `t` in [0, 2] of implicit Euler halves when the step halves
/// (first order) and BDF2's falls by four (second order), far below implicit Euler's at the
/// same step. The motion stays on the spring's axis, where the spring is linear.
#[test]
fn bdf2_is_second_order_and_implicit_euler_first() {
    let (k, m): (f64, f64) = (40.0, 1.0);
    for gamma in [0.0, 1.5] {
        let omega0 = (k / m).sqrt();
        let zeta_w = gamma / (2.0 * m);
        let wd = (omega0 * omega0 - zeta_w * zeta_w).sqrt();
        let exact =
            |t: f64| 0.1 * (-zeta_w * t).exp() * ((wd * t).cos() + zeta_w / wd * (wd * t).sin());
        let error = |integrator, dt: f64| {
            let steps = (2.0 / dt).round() as usize;
            let u = oscillator(integrator, k, m, gamma, dt, steps);
            u.iter()
                .enumerate()
                .map(|(i, u)| (u - exact(i as f64 * dt)).abs() / 0.1)
                .fold(0.0, f64::max)
        };
        let dts = [0.004, 0.002, 0.001];
        let be = dts.map(|dt| error(MsdIntegrator::ImplicitEuler, dt));
        let bdf2 = dts.map(|dt| error(MsdIntegrator::ImplicitBdf2, dt));
        println!("gamma {gamma}: implicit Euler {be:?}, BDF2 {bdf2:?}");
        for w in be.windows(2) {
            let r = w[0] / w[1];
            assert!((1.8..2.2).contains(&r), "implicit Euler ratio {r}: {be:?}");
        }
        for w in bdf2.windows(2) {
            let r = w[0] / w[1];
            assert!((3.6..4.4).contains(&r), "BDF2 ratio {r}: {bdf2:?}");
        }
        assert!(bdf2[0] < 0.1 * be[0], "{be:?} {bdf2:?}");
    }
}

/// The linear FEM stiffness of one tetrahedron assembled the textbook way, `V Bᵀ D B` with
/// Voigt strains, independently of the inner products the fit uses.
fn fem_element_stiffness(p: [Vec3; 4], e: f64, nu: f64) -> nalgebra::DMatrix<f64> {
    let m = nalgebra::Matrix4::from_fn(|i, j| if j == 0 { 1.0 } else { p[i][j - 1] });
    let volume = m.determinant().abs() / 6.0;
    let c = m.try_inverse().unwrap();
    let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mu = e / (2.0 * (1.0 + nu));
    let mut b = nalgebra::DMatrix::<f64>::zeros(6, 12);
    for i in 0..4 {
        let (gx, gy, gz) = (c[(1, i)], c[(2, i)], c[(3, i)]);
        let rows = [
            [gx, 0.0, 0.0],
            [0.0, gy, 0.0],
            [0.0, 0.0, gz],
            [gy, gx, 0.0],
            [0.0, gz, gy],
            [gz, 0.0, gx],
        ];
        for (r, row) in rows.iter().enumerate() {
            for (k, v) in row.iter().enumerate() {
                b[(r, 3 * i + k)] = *v;
            }
        }
    }
    let mut d = nalgebra::DMatrix::<f64>::zeros(6, 6);
    for i in 0..3 {
        for j in 0..3 {
            d[(i, j)] = lambda;
        }
        d[(i, i)] += 2.0 * mu;
        d[(i + 3, i + 3)] = mu;
    }
    b.transpose() * d * b * volume
}

/// The rest-state stiffness of the six edge springs with stiffnesses `k`.
fn spring_stiffness_matrix(p: [Vec3; 4], k: [f64; 6]) -> nalgebra::DMatrix<f64> {
    let edges = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];
    let mut out = nalgebra::DMatrix::<f64>::zeros(12, 12);
    for (e, &[a, b]) in edges.iter().enumerate() {
        let d = (p[b] - p[a]).normalize();
        let dd = d * d.transpose() * k[e];
        for (i, si) in [(a, -1.0), (b, 1.0)] {
            for (j, sj) in [(a, -1.0), (b, 1.0)] {
                for r in 0..3 {
                    for c in 0..3 {
                        out[(3 * i + r, 3 * j + c)] += si * sj * dd[(r, c)];
                    }
                }
            }
        }
    }
    out
}

/// Lloyd, Székely and Harders (2007): a regular tetrahedron of edge `l` with Poisson ratio 1/4
/// is matched by springs of stiffness `2 √2 E l / 25`.
#[test]
fn material_springs_match_lloyds_closed_form_on_a_regular_tetrahedron() {
    for (e, scale) in [(1.0, 1.0), (140.0, 0.3), (5e3, 2.5)] {
        let p = [
            Vec3::new(1.0, 1.0, 1.0) * scale,
            Vec3::new(1.0, -1.0, -1.0) * scale,
            Vec3::new(-1.0, 1.0, -1.0) * scale,
            Vec3::new(-1.0, -1.0, 1.0) * scale,
        ];
        let l = 8f64.sqrt() * scale;
        let expected = 2.0 * 2f64.sqrt() / 25.0 * e * l;
        for k in fit_tet_springs(p, e, 0.25) {
            assert!(
                (k - expected).abs() < 1e-12 * expected,
                "E {e}, l {l}: {k} against {expected}"
            );
        }
    }
}

/// On irregular tetrahedra the fitted stiffnesses are the constrained least-squares optimum
/// against the textbook element matrix: the residual's gradient vanishes along every
/// positive stiffness and points outward (>= 0) along every zero one (the KKT conditions),
/// and no random non-negative alternative fits better.
#[test]
fn material_springs_are_the_least_squares_fit_to_the_fem_element() {
    let mut seed = 7u64;
    let mut rand = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let mut zero_seen = false;
    for case in 0..40 {
        let p = [0; 4].map(|_| Vec3::new(rand(), rand(), rand()));
        let nu = [0.0, 0.23, 0.3, 0.45, -0.3][case % 5];
        let k = fit_tet_springs(p, 10.0, nu);
        let target = fem_element_stiffness(p, 10.0, nu);
        let residual = |k: [f64; 6]| (spring_stiffness_matrix(p, k) - &target).norm_squared();
        let r0 = residual(k);
        let scale = target.norm_squared();
        for e in 0..6 {
            let h = 1e-6 * (1.0 + k[e]);
            let mut up = k;
            up[e] += h;
            let grad = (residual(up) - r0) / h;
            if k[e] > 0.0 {
                let mut down = k;
                down[e] -= h;
                let central = (residual(up) - residual(down)) / (2.0 * h);
                assert!(
                    central.abs() < 1e-5 * scale,
                    "case {case} edge {e}: {central}"
                );
            } else {
                zero_seen = true;
                assert!(grad > -1e-5 * scale, "case {case} edge {e}: {grad} < 0");
            }
        }
        for _ in 0..20 {
            let other = k.map(|v| (v * (1.0 + 0.3 * rand())).max(0.0));
            assert!(residual(other) >= r0 * (1.0 - 1e-12), "case {case}");
        }
    }
    assert!(zero_seen, "no case exercised the non-negativity bound");
}

/// A material MSD gets the mesh's springs from the fit, summed over the tetrahedra sharing
/// an edge; the stiffness scales with Young's modulus, and a bad material is refused.
#[test]
fn material_msd_sums_the_fit_over_tetrahedra() {
    let mesh = block(Vec3::zeros(), Vec3::new(1.0, 0.5, 0.5), [2, 1, 1]).unwrap();
    let mut c = config(MsdIntegrator::ImplicitEuler, 0.01, 0.1);
    c.spring_stiffness = SpringStiffness::Material {
        young_modulus: 100.0,
        poisson_ratio: 0.3,
    };
    let body = MsdBody::from_mesh(&mesh, c, &Boundary::free()).unwrap();
    let x = mesh.positions();
    for s in body.springs() {
        let mut expected = 0.0;
        for t in mesh.tets() {
            let local: Vec<usize> = [s.a, s.b]
                .iter()
                .filter_map(|n| t.iter().position(|m| m == n))
                .collect();
            if local.len() == 2 {
                let edges = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];
                let pair = [local[0].min(local[1]), local[0].max(local[1])];
                let e = edges.iter().position(|&q| q == pair).unwrap();
                expected += fit_tet_springs(t.map(|i| x[i as usize]), 100.0, 0.3)[e];
            }
        }
        assert!((s.stiffness - expected).abs() <= 1e-12 * expected.max(1.0));
    }
    c.spring_stiffness = SpringStiffness::Material {
        young_modulus: 200.0,
        poisson_ratio: 0.3,
    };
    let stiffer = MsdBody::from_mesh(&mesh, c, &Boundary::free()).unwrap();
    for (a, b) in body.springs().iter().zip(stiffer.springs()) {
        assert!((2.0 * a.stiffness - b.stiffness).abs() <= 1e-12 * b.stiffness.max(1.0));
    }
    for bad in [(-1.0, 0.3), (100.0, 0.5), (f64::NAN, 0.3)] {
        c.spring_stiffness = SpringStiffness::Material {
            young_modulus: bad.0,
            poisson_ratio: bad.1,
        };
        let err = MsdBody::from_mesh(&mesh, c, &Boundary::free()).unwrap_err();
        assert!(err.to_string().contains("spring_stiffness"), "{err}");
    }
}
