//! A block stretched by 10 % between its end faces and cut part-way across opens into a gap
//! that grows with the cut's depth. The gap our world gives (the block cut while stretched,
//! then left to come to rest, linear and corotational FEM) is compared with an independent
//! FE solve of the same cut geometry: a static linear-elastic solve written here from the
//! textbook (linear tetrahedra, `K = sum V B^T D B`, conjugate gradients with the end faces
//! displaced), sharing nothing with the core's solvers but the cut mesh.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::ContactConfig;
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::CutTriangle;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, Level, PreciseMethod};
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig};

/// The block: length along x, height along y (cut from the top), width along z; metres.
const L: f64 = 0.1;
const H: f64 = 0.04;
const W: f64 = 0.02;
const CELLS: [usize; 3] = [10, 8, 2];
const STRETCH: f64 = 0.1;
const DT: f64 = 0.01;
const E: f64 = 2.0e4;
const NU: f64 = 0.3;

/// The stretched position of a rest point: uniform along x (the ends are held there).
fn stretched(p: &Vec3) -> Vec3 {
    Vec3::new(p.x * (1.0 + STRETCH), p.y, p.z)
}

fn is_end(p: &Vec3) -> bool {
    !(1e-9..=L - 1e-9).contains(&p.x)
}

/// The mean opening along x, over the width, of the two sides of the cut at its mouth (the
/// top face, mid-length): nodes at the same rest place, pulled apart.
fn mouth_gap(rest: &[Vec3], now: &[Vec3]) -> f64 {
    let at_mouth: Vec<usize> = (0..rest.len())
        .filter(|&i| (rest[i].x - 0.5 * L).abs() < 1e-9 && (rest[i].y - H).abs() < 1e-9)
        .collect();
    let mut gaps = Vec::new();
    for (k, &a) in at_mouth.iter().enumerate() {
        for &b in &at_mouth[k + 1..] {
            if (rest[a] - rest[b]).norm() < 1e-9 {
                gaps.push((now[a].x - now[b].x).abs());
            }
        }
    }
    assert_eq!(
        gaps.len(),
        CELLS[2] + 1,
        "a pair of sides at each node across"
    );
    gaps.iter().sum::<f64>() / gaps.len() as f64
}

/// Our world: the block held stretched, cut `depth` (a fraction of its height) from the
/// top at mid-length, then left to come to rest. Returns the gap and the cut rest mesh.
fn ours(method: PreciseMethod, depth: f64) -> (f64, TetMesh) {
    let mesh = block(Vec3::zeros(), Vec3::new(L, H, W), CELLS).unwrap();
    let fem = FemParams {
        young_modulus: E,
        poisson_ratio: NU,
        mass: 1000.0 * mesh.volume(),
        damping: 60.0,
    };
    let msd = MsdParams {
        stiffness: 1.0,
        mass: 1000.0 * mesh.volume(),
        damping: 1.0,
    };
    let mut s = BodySettings::new(fem, msd, DT);
    s.precise = method;
    s.boundary =
        Boundary::fixed_nodes((0..mesh.node_count()).filter(|&i| is_end(&mesh.positions()[i])));
    let body = WorldBody::new("block", Arc::new(mesh), s, None).unwrap();
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt: DT,
        contact: ContactConfig::for_scale(0.1),
    })
    .unwrap();
    w.add_body(body).unwrap();
    let b = &mut w.bodies_mut()[0];
    b.model_mut().pin(Some(Level::Precise)).unwrap();
    // Held stretched by its supports (a fixed node keeps the position it is given).
    let precise = b.model_mut().precise_mut();
    let rest = precise.rest_positions().to_vec();
    for (p, r) in precise.positions_mut().iter_mut().zip(&rest) {
        *p = stretched(r);
    }
    for _ in 0..300 {
        w.step_fixed().unwrap();
    }
    // The blade: the plane through mid-length, from above the top down to the node layer at
    // `depth` of the height (its lower edge a tenth of a layer below where that layer is
    // now), past both sides.
    let now = w.bodies()[0].model().node_positions();
    let rest = w.bodies()[0].mesh().positions();
    let layer = H * (1.0 - depth);
    let on_layer: Vec<f64> = (0..rest.len())
        .filter(|&i| (rest[i].x - 0.5 * L).abs() < 1e-9 && (rest[i].y - layer).abs() < 1e-9)
        .map(|i| now[i].y)
        .collect();
    let bottom = on_layer.iter().sum::<f64>() / on_layer.len() as f64 - 0.1 * H / CELLS[1] as f64;
    let x = 0.5 * L * (1.0 + STRETCH);
    let c = |y: f64, z: f64| Vec3::new(x, y, z);
    let (top, z0, z1) = (2.0 * H, -W, 2.0 * W);
    let blade = [
        CutTriangle {
            corners: [c(bottom, z0), c(top, z0), c(top, z1)],
        },
        CutTriangle {
            corners: [c(bottom, z0), c(top, z1), c(bottom, z1)],
        },
    ];
    let made = w.cut_body(0, &blade).unwrap();
    assert!(made.is_empty(), "a cut part-way across leaves one piece");
    for _ in 0..500 {
        w.step_fixed().unwrap();
    }
    let b = &w.bodies()[0];
    // The crack is where it was meant to be: its two sides, down to the layer at `depth`,
    // across the whole width (at rest).
    let r = b.cut_record().unwrap();
    let area = 2.0 * depth * H * W;
    assert!(
        r.closed && (r.area - area).abs() < 1e-9 * area,
        "cut area {} of {area}",
        r.area
    );
    // The supports held the ends where they were when it was cut: stretched.
    for (i, r) in b.mesh().positions().iter().enumerate() {
        if is_end(r) {
            let p = b.model().node_positions()[i];
            assert!(
                (p - stretched(r)).norm() < 1e-12,
                "support {i} moved to {p:?}"
            );
        }
    }
    (
        mouth_gap(b.mesh().positions(), b.model().node_positions()),
        (**b.mesh()).clone(),
    )
}

type M3 = [[f64; 3]; 3];

fn det3(m: &M3) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

fn inv3(m: &M3) -> M3 {
    let det = det3(m);
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            let (r1, r2) = ((c + 1) % 3, (c + 2) % 3);
            let (c1, c2) = ((r + 1) % 3, (r + 2) % 3);
            *v = (m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1]) / det;
        }
    }
    out
}

fn mul3(a: &M3, b: &M3) -> M3 {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

fn transpose3(a: &M3) -> M3 {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = a[j][i];
        }
    }
    out
}

/// The rotation of the polar decomposition of `f` (det > 0), by the iteration
/// `R <- (R + R^-T) / 2` from `f`.
fn polar_rotation(f: &M3) -> M3 {
    let mut r = *f;
    for _ in 0..100 {
        let it = transpose3(&inv3(&r));
        let mut next = [[0.0; 3]; 3];
        let mut change = 0.0f64;
        for i in 0..3 {
            for j in 0..3 {
                next[i][j] = 0.5 * (r[i][j] + it[i][j]);
                change = change.max((next[i][j] - r[i][j]).abs());
            }
        }
        r = next;
        if change < 1e-15 {
            break;
        }
    }
    r
}

/// The columns `X1 - X0, X2 - X0, X3 - X0` of an element at `x`.
fn edges(x: &[[f64; 3]], t: &[usize; 4]) -> M3 {
    let d = |k: usize, a: usize| x[t[k]][a] - x[t[0]][a];
    [
        [d(1, 0), d(2, 0), d(3, 0)],
        [d(1, 1), d(2, 1), d(3, 1)],
        [d(1, 2), d(2, 2), d(3, 2)],
    ]
}

/// The static equilibrium of `mesh` with its end faces displaced by the stretch, linear
/// (`corotational` false: `K u = 0` on the free nodes) or corotational (each element's
/// stiffness turned by the rotation of its deformation, `sum R K (R^T x - X) = 0`, by the
/// fixed point of the warped-stiffness solve: rotations from the last positions, the
/// linear system for new ones, until the positions change by less than 1e-12 of the
/// length). Conjugate gradients (Jacobi preconditioned) to a relative residual of 1e-12.
/// Returns the positions.
fn reference(mesh: &TetMesh, corotational: bool) -> Vec<Vec3> {
    let rest: Vec<[f64; 3]> = mesh.positions().iter().map(|p| [p.x, p.y, p.z]).collect();
    let n = rest.len();
    let tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let (lambda, mu) = (
        E * NU / ((1.0 + NU) * (1.0 - 2.0 * NU)),
        E / (2.0 * (1.0 + NU)),
    );
    // Each element's rest edges, shape-function gradients and volume.
    let elements: Vec<(M3, [[f64; 3]; 4], f64)> = tets
        .iter()
        .map(|t| {
            let m = edges(&rest, t);
            let det = det3(&m);
            assert!(det > 0.0, "an element of the cut mesh is inverted");
            let inv = inv3(&m);
            let mut g = [[0.0; 3]; 4];
            for k in 1..4 {
                for a in 0..3 {
                    g[k][a] = inv[k - 1][a];
                    g[0][a] -= g[k][a];
                }
            }
            (inv, g, det / 6.0)
        })
        .collect();
    let fixed: Vec<bool> = mesh.positions().iter().map(is_end).collect();
    // Start from the uniform stretch (exact on the ends, which never change).
    let mut x: Vec<[f64; 3]> = rest
        .iter()
        .map(|p| [p[0] * (1.0 + STRETCH), p[1], p[2]])
        .collect();
    for _round in 0..if corotational { 200 } else { 1 } {
        // Rows of 3x3 blocks R K_ab R^T, and the right-hand side sum R K_ab X_b.
        let mut rows: Vec<Vec<(usize, M3)>> = vec![Vec::new(); n];
        let mut rhs = vec![[0.0; 3]; n];
        for (t, (inv, g, volume)) in tets.iter().zip(&elements) {
            let r = if corotational {
                polar_rotation(&mul3(&edges(&x, t), inv))
            } else {
                [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            };
            let rt = transpose3(&r);
            for (ka, &a) in t.iter().enumerate() {
                for (kb, &b) in t.iter().enumerate() {
                    let (ga, gb) = (g[ka], g[kb]);
                    let dot = ga[0] * gb[0] + ga[1] * gb[1] + ga[2] * gb[2];
                    // K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I).
                    let mut k = [[0.0; 3]; 3];
                    for i in 0..3 {
                        for j in 0..3 {
                            k[i][j] = volume
                                * (lambda * ga[i] * gb[j]
                                    + mu * ga[j] * gb[i]
                                    + if i == j { mu * dot } else { 0.0 });
                        }
                    }
                    let rk = mul3(&r, &k);
                    for i in 0..3 {
                        rhs[a][i] += (0..3).map(|j| rk[i][j] * rest[b][j]).sum::<f64>();
                    }
                    let block = mul3(&rk, &rt);
                    match rows[a].iter_mut().find(|(c, _)| *c == b) {
                        Some((_, sum)) => {
                            for i in 0..3 {
                                for j in 0..3 {
                                    sum[i][j] += block[i][j];
                                }
                            }
                        }
                        None => rows[a].push((b, block)),
                    }
                }
            }
        }
        let before = x.clone();
        solve(&rows, &rhs, &fixed, &mut x);
        let change = x
            .iter()
            .zip(&before)
            .map(|(p, q)| (0..3).map(|i| (p[i] - q[i]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        if change < 1e-12 * L {
            break;
        }
        assert!(_round < 199, "the corotational reference converged");
    }
    x.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect()
}

/// `rows x = rhs` on the nodes not `fixed` (those keep their `x`), by conjugate gradients
/// from `x`, Jacobi preconditioned, to a relative residual of 1e-12.
fn solve(rows: &[Vec<(usize, M3)>], rhs: &[[f64; 3]], fixed: &[bool], x: &mut [[f64; 3]]) {
    let n = x.len();
    let mul = |u: &[[f64; 3]], out: &mut [[f64; 3]]| {
        for (a, row) in rows.iter().enumerate() {
            let mut s = [0.0; 3];
            for (b, k) in row {
                for i in 0..3 {
                    for j in 0..3 {
                        s[i] += k[i][j] * u[*b][j];
                    }
                }
            }
            out[a] = if fixed[a] { [0.0; 3] } else { s };
        }
    };
    let dot = |p: &[[f64; 3]], q: &[[f64; 3]]| -> f64 {
        p.iter()
            .zip(q)
            .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .sum()
    };
    let diag: Vec<[f64; 3]> = rows
        .iter()
        .enumerate()
        .map(|(a, row)| {
            let k = row.iter().find(|(b, _)| *b == a).unwrap().1;
            [k[0][0], k[1][1], k[2][2]]
        })
        .collect();
    let mut r = vec![[0.0; 3]; n];
    mul(x, &mut r);
    for a in 0..n {
        for i in 0..3 {
            r[a][i] = if fixed[a] { 0.0 } else { rhs[a][i] - r[a][i] };
        }
    }
    let precondition = |r: &[[f64; 3]]| -> Vec<[f64; 3]> {
        r.iter()
            .zip(&diag)
            .map(|(r, d)| [r[0] / d[0], r[1] / d[1], r[2] / d[2]])
            .collect()
    };
    let scale = dot(rhs, rhs).sqrt().max(dot(&r, &r).sqrt());
    let mut z = precondition(&r);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let mut q = vec![[0.0; 3]; n];
    for _ in 0..20 * 3 * n {
        if dot(&r, &r).sqrt() <= 1e-12 * scale {
            return;
        }
        mul(&p, &mut q);
        let alpha = rz / dot(&p, &q);
        for a in 0..n {
            for i in 0..3 {
                x[a][i] += alpha * p[a][i];
                r[a][i] -= alpha * q[a][i];
            }
        }
        z = precondition(&r);
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        for a in 0..n {
            for i in 0..3 {
                p[a][i] = z[a][i] + beta * p[a][i];
            }
        }
    }
    panic!("the reference's conjugate gradients did not converge");
}

#[test]
fn a_stretched_block_cut_part_way_opens_as_an_independent_fe_solve_says() {
    let mut last = 0.0;
    for depth in [0.25, 0.5, 0.75] {
        let (linear, mesh) = ours(PreciseMethod::LinearFem, depth);
        let (corotational, _) = ours(PreciseMethod::CorotationalFem, depth);
        let peer_linear = mouth_gap(mesh.positions(), &reference(&mesh, false));
        let peer_corotational = mouth_gap(mesh.positions(), &reference(&mesh, true));
        let off = |g: f64, peer: f64| 100.0 * (g - peer) / peer;
        println!(
            "cut {:.0} % deep: gap, independent solve / ours: linear {:.4} / {:.4} mm ({:+.1e} %), corotational {:.4} / {:.4} mm ({:+.1e} %)",
            100.0 * depth,
            peer_linear * 1e3,
            linear * 1e3,
            off(linear, peer_linear),
            peer_corotational * 1e3,
            corotational * 1e3,
            off(corotational, peer_corotational),
        );
        assert!(
            off(linear, peer_linear).abs() < 10.0
                && off(corotational, peer_corotational).abs() < 10.0,
            "cut {depth}: our gaps {linear} and {corotational} against the independent solves' {peer_linear} and {peer_corotational}"
        );
        // Our solvers at rest are the static solution of their model: far tighter than the
        // issue's 10 %.
        assert!(off(linear, peer_linear).abs() < 0.1, "linear");
        assert!(
            off(corotational, peer_corotational).abs() < 1.0,
            "corotational"
        );
        assert!(
            corotational > 1.2 * last,
            "the gap grows with the cut: {corotational} after {last}"
        );
        last = corotational;
    }
}
