//! The rapier3d adapter: bad input is refused by name, and the material, masses, pins and
//! load reach rapier3d in its units (a cantilever under its own weight bends by the
//! Euler-Bernoulli amount, within what a coarse linear-tetrahedron bar can do; a bar pulled
//! along its axis by its own weight stretches by the closed form the report's comparison
//! measures against).

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_peers::{PeerError, PeerSetup, rapier_fem};

/// A bar along y, `n` cells long and 2 x 2 cells across, cell size `h`, six tetrahedra per
/// cell.
fn bar(n: usize, h: f64) -> TetMesh {
    let idx = |i: usize, j: usize, k: usize| (j * 3 + k) * 3 + i;
    let mut p = Vec::new();
    for j in 0..=n {
        for k in 0..3 {
            for i in 0..3 {
                p.push(Vec3::new(i as f64 * h, j as f64 * h, k as f64 * h));
            }
        }
    }
    let mut t = Vec::new();
    for j in 0..n {
        for k in 0..2 {
            for i in 0..2 {
                let c = |di: usize, dj: usize, dk: usize| idx(i + di, j + dj, k + dk);
                let (v0, v6) = (c(0, 0, 0), c(1, 1, 1));
                let ring = [
                    c(1, 0, 0),
                    c(1, 1, 0),
                    c(0, 1, 0),
                    c(0, 1, 1),
                    c(0, 0, 1),
                    c(1, 0, 1),
                ];
                for s in 0..6 {
                    t.push([v0, ring[s], ring[(s + 1) % 6], v6]);
                }
            }
        }
    }
    // Orient every tetrahedron positively.
    for tet in &mut t {
        let [a, b, c, d] = tet.map(|i| p[i]);
        if (b - a).cross(&(c - a)).dot(&(d - a)) < 0.0 {
            tet.swap(1, 2);
        }
    }
    TetMesh::new(p, t).unwrap()
}

fn setup(mesh: &TetMesh, young: f64, gravity: f64) -> PeerSetup {
    let n = mesh.node_count();
    PeerSetup {
        young_modulus: young,
        poisson_ratio: 0.0,
        damping_ratio: 1.0,
        masses: vec![1.0 / n as f64; n],
        fixed: (0..n).filter(|&i| mesh.positions()[i].y == 0.0).collect(),
        gravity: Vec3::new(gravity, 0.0, 0.0),
        dt: 0.01,
    }
}

#[test]
fn bad_input_is_refused_by_name() {
    let mesh = bar(2, 0.1);
    let mut s = setup(&mesh, 1e5, 1.0);
    s.masses.pop();
    assert!(matches!(
        rapier_fem(&mesh, &s, 1),
        Err(PeerError::Masses { .. })
    ));
    let mut s = setup(&mesh, 1e5, 1.0);
    s.fixed.push(10_000);
    assert!(matches!(
        rapier_fem(&mesh, &s, 1),
        Err(PeerError::FixedNode { node: 10_000, .. })
    ));
    for (name, edit) in [
        (
            "young_modulus",
            (|s: &mut PeerSetup| s.young_modulus = -1.0) as fn(&mut PeerSetup),
        ),
        ("poisson_ratio", |s| s.poisson_ratio = 0.5),
        ("dt", |s| s.dt = f64::NAN),
    ] {
        let mut s = setup(&mesh, 1e5, 1.0);
        edit(&mut s);
        match rapier_fem(&mesh, &s, 1) {
            Err(e @ PeerError::Setting { .. }) => assert!(e.to_string().contains(name), "{e}"),
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn a_cantilever_bends_by_its_own_weight_as_euler_bernoulli_says() {
    // L = 1, square section 0.1 x 0.1 (I = h^4 / 12), total mass 1 (q = m g / L per length):
    // tip deflection q L^4 / (8 E I). E chosen for a 5 % deflection.
    let (n, h) = (20, 0.05);
    let mesh = bar(n, h);
    let (length, side, g) = (n as f64 * h, 2.0 * h, 1.0);
    let inertia = side.powi(4) / 12.0;
    let young = g * length.powi(3) / (8.0 * 0.05 * length * inertia);
    let expected = g * length.powi(3) / (8.0 * young * inertia);
    let run = rapier_fem(&mesh, &setup(&mesh, young, g), 600).unwrap();
    let top: Vec<usize> = (0..mesh.node_count())
        .filter(|&i| (mesh.positions()[i].y - length).abs() < 1e-9)
        .collect();
    let tip = top
        .iter()
        .map(|&i| run.positions[i].x - mesh.positions()[i].x)
        .sum::<f64>()
        / top.len() as f64;
    // Measured: 1.074 times the Euler-Bernoulli deflection (0.05368 against 0.05; the bar is
    // 10 sections long, so shear adds about 1 % (Timoshenko), equal node masses put more of
    // the load on the surface nodes, and the body still sways a little after 6 s: rapier
    // damps with a damping ratio, not a mass-proportional term). Allowed: that value plus or
    // minus 5 % of the analytic deflection.
    assert!(
        tip > 1.024 * expected && tip < 1.124 * expected,
        "tip {tip}, Euler-Bernoulli {expected}"
    );
    eprintln!("tip {tip} expected {expected} speed {}", run.max_speed);
    assert_eq!(run.step_us.len(), 600);
}

#[test]
fn an_axial_bar_stretches_by_its_own_weight_as_the_closed_form_says() {
    // The peer report's reference: a prismatic bar clamped at y = 0, Poisson ratio 0, a
    // uniform body force g along +y. Linear elasticity: u(y) = (rho g / E) (L y - y^2 / 2),
    // nothing across; at the free end rho g L^2 / (2 E). E chosen for 1 % of L there.
    let (n, h) = (20, 0.05);
    let mesh = bar(n, h);
    let (length, side, g) = (n as f64 * h, 2.0 * h, 1.0);
    let rho = 1.0 / (length * side * side);
    let young = rho * g * length * length / (2.0 * 0.01 * length);
    let expected = rho * g * length * length / (2.0 * young);
    let mut s = setup(&mesh, young, 0.0);
    s.gravity = Vec3::new(0.0, g, 0.0);
    // Masses lumped by volume (a quarter of each tetrahedron's mass on each corner), so the
    // nodal loads are those of a uniform body force.
    s.masses = vec![0.0; mesh.node_count()];
    for (tet, v) in mesh.tets().iter().zip(mesh.tet_volumes()) {
        for &i in tet {
            s.masses[i as usize] += rho * v / 4.0;
        }
    }
    let run = rapier_fem(&mesh, &s, 600).unwrap();
    let top: Vec<usize> = (0..mesh.node_count())
        .filter(|&i| (mesh.positions()[i].y - length).abs() < 1e-9)
        .collect();
    let tip = top
        .iter()
        .map(|&i| run.positions[i].y - mesh.positions()[i].y)
        .sum::<f64>()
        / top.len() as f64;
    eprintln!(
        "axial: tip {tip}, closed form {expected}, speed {}",
        run.max_speed
    );
    // The free end's mean axial displacement: 0.10 % from the closed form measured; 0.5 %
    // allowed. (Node by node this mesh cannot follow the closed form: every cell is split
    // along the same diagonal, and the static linear-FEM solution on it moves the free end
    // sideways by 12 % of the axial displacement; the report states that floor per mesh.)
    assert!(
        (tip - expected).abs() < 0.005 * expected,
        "tip {tip}, closed form {expected}"
    );
}
