//! Numerical stability on hard cases: 10,000 steps each on the paper's cylinder (bottom 10 %
//! fixed, gravity off), for both FEM models and the MSD integrators. Every step must succeed
//! (no NaN, no error), the energy must stay bounded once the disturbance is over, and the body
//! must come back to rest (largest node distance from rest below 1e-3 of the body's width).

#![allow(clippy::needless_range_loop)] // index loops over parallel node arrays

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemConfig, FemModel, element};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::msd::{ExplicitLimit, MsdBody, MsdConfig, MsdError, MsdIntegrator};
use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD};
use soft_tissue_core::{NodalBody, Vec3};

const STEPS: usize = 10_000;

fn cylinder() -> TetMesh {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../assets/meshes/cylinder.vtk"
    );
    read_tet_mesh(std::path::Path::new(path)).unwrap().mesh
}

fn width(mesh: &TetMesh) -> f64 {
    let b = mesh.bbox();
    (b.max.x - b.min.x).min(b.max.z - b.min.z)
}

fn top_nodes(mesh: &TetMesh, fraction: f64) -> Vec<usize> {
    let b = mesh.bbox();
    let cut = b.max.y - fraction * (b.max.y - b.min.y);
    (0..mesh.positions().len())
        .filter(|&i| mesh.positions()[i].y >= cut)
        .collect()
}

/// How a case disturbs the body.
enum Disturbance {
    /// Horizontal velocity on the top 20 % of the nodes.
    Kick(f64),
    /// Fold the top 25 % of the body down through the plane below it (inverts elements).
    Fold,
    /// Flatten elements (degenerate: zero volume).
    Squash,
    /// A force of this many body weights on one top node for 1 s, then released.
    ToolForce(f64),
}

fn disturb_positions(mesh: &TetMesh, d: &Disturbance, x: &mut [Vec3]) {
    let b = mesh.bbox();
    let h = b.max.y - b.min.y;
    match d {
        Disturbance::Fold => {
            let cut = b.max.y - 0.25 * h;
            for p in x.iter_mut() {
                if p.y > cut {
                    p.y = 2.0 * cut - p.y;
                }
            }
        }
        Disturbance::Squash => {
            // Flatten every 25th element by moving its last node onto the plane of the other
            // three (later moves may partly undo earlier ones; the count is checked).
            // Nodes of the fixed bottom are left alone.
            let floor = b.min.y + 0.15 * h;
            for tet in mesh.tets().iter().step_by(25) {
                let [a, b, c, d] = tet.map(|i| i as usize);
                if mesh.positions()[d].y < floor {
                    continue;
                }
                let n = (x[b] - x[a]).cross(&(x[c] - x[a])).normalize();
                let off = (x[d] - x[a]).dot(&n);
                x[d] -= off * n;
            }
        }
        _ => {}
    }
}

/// Counts inverted and (nearly) flat elements of positions `x`.
fn inverted_and_flat(mesh: &TetMesh, x: &[Vec3]) -> (usize, usize) {
    let (mut inv, mut flat) = (0, 0);
    for (t, vol0) in mesh.tets().iter().zip(mesh.tet_volumes()) {
        let p = t.map(|i| x[i as usize]);
        let v = element::shape_gradients(&p).map(|(_, v)| v).unwrap_or(0.0);
        if v.abs() <= 1e-9 * vol0 {
            flat += 1;
        } else if v < 0.0 {
            inv += 1;
        }
    }
    (inv, flat)
}

/// A body under test, FEM or MSD.
trait Body: NodalBody {
    fn step(&mut self) -> Result<(), String>;
    fn energy(&self) -> f64;
}

impl Body for FemBody {
    fn step(&mut self) -> Result<(), String> {
        FemBody::step(self).map(|_| ()).map_err(|e| e.to_string())
    }
    fn energy(&self) -> f64 {
        self.kinetic_energy() + self.elastic_energy()
    }
}

impl Body for MsdBody {
    fn step(&mut self) -> Result<(), String> {
        MsdBody::step(self).map(|_| ()).map_err(|e| e.to_string())
    }
    fn energy(&self) -> f64 {
        self.kinetic_energy() + self.elastic_energy()
    }
}

/// Runs a case; returns (peak energy after the disturbance, energy when it ended, final
/// distance from rest / width).
fn run(
    name: &str,
    mesh: &TetMesh,
    body: &mut dyn Body,
    d: Disturbance,
    dt: f64,
) -> (f64, f64, f64) {
    let top = top_nodes(mesh, 0.2);
    let mut active_steps = 0;
    match &d {
        Disturbance::Kick(speed) => {
            for &i in &top {
                body.velocities_mut()[i] = Vec3::new(*speed, 0.0, 0.5 * speed);
            }
        }
        Disturbance::Fold | Disturbance::Squash => {
            disturb_positions(mesh, &d, body.positions_mut());
            let (inv, flat) = inverted_and_flat(mesh, body.positions());
            match d {
                Disturbance::Fold => assert!(inv > 0, "{name}: the fold must invert elements"),
                _ => assert!(flat > 0, "{name}: the squash must flatten elements"),
            }
        }
        Disturbance::ToolForce(_) => active_steps = (1.0 / dt).round() as usize,
    }
    let node = top[0];
    let weight = body.masses().iter().sum::<f64>() * 9.81;
    let mut end_energy = body.energy();
    let mut peak: f64 = end_energy;
    for s in 0..STEPS {
        if let Disturbance::ToolForce(times) = d
            && s < active_steps
        {
            body.add_force(node, Vec3::new(times * weight, 0.0, 0.0));
        }
        body.step()
            .unwrap_or_else(|e| panic!("{name}: step {s} failed: {e}"));
        let e = body.energy();
        assert!(e.is_finite(), "{name}: step {s}: energy {e}");
        if s + 1 == active_steps {
            end_energy = e;
            peak = e;
        }
        if s >= active_steps {
            peak = peak.max(e);
        }
    }
    let dist = body
        .positions()
        .iter()
        .zip(mesh.positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    (peak, end_energy, dist / width(mesh))
}

fn fem_case(
    name: &str,
    model: FemModel,
    young_scale: f64,
    poisson: f64,
    dt_scale: f64,
    d: Disturbance,
) {
    let mesh = cylinder();
    let mut c = FemConfig::paper(&CYLINDER_FEM.params, CYLINDER_FEM.dt * dt_scale);
    c.model = model;
    c.young_modulus *= young_scale;
    c.poisson_ratio = poisson;
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
    let name = format!("{name} ({model:?})");
    let (peak, end, dist) = run(&name, &mesh, &mut body, d, c.dt);
    // Bounded: after the disturbance the energy never exceeds what it was when it ended by more
    // than 1 % (inexact CG solves and the linearised rotations may add round-off, never growth).
    assert!(
        peak <= 1.01 * end + 1e-12,
        "{name}: energy grew from {end} to {peak}"
    );
    assert!(
        dist < 1e-3,
        "{name}: did not return to rest (distance {dist} of the width)"
    );
}

const MODELS: [FemModel; 2] = [FemModel::Linear, FemModel::Corotational];

#[test]
fn fem_near_incompressible() {
    for m in MODELS {
        fem_case("Poisson 0.49", m, 1.0, 0.49, 1.0, Disturbance::Kick(2.0));
    }
}

#[test]
fn fem_young_times_1000_at_the_paper_step() {
    for m in MODELS {
        fem_case(
            "Young x1000",
            m,
            1000.0,
            CYLINDER_FEM.params.poisson_ratio,
            1.0,
            Disturbance::Kick(2.0),
        );
    }
}

#[test]
fn fem_ten_times_the_paper_step() {
    for m in MODELS {
        fem_case(
            "dt x10",
            m,
            1.0,
            CYLINDER_FEM.params.poisson_ratio,
            10.0,
            Disturbance::Kick(2.0),
        );
    }
}

#[test]
fn fem_initially_inverted_elements() {
    for m in MODELS {
        fem_case("folded", m, 1.0, 0.3, 1.0, Disturbance::Fold);
    }
}

#[test]
fn fem_initially_flat_elements() {
    for m in MODELS {
        fem_case("squashed", m, 1.0, 0.3, 1.0, Disturbance::Squash);
    }
}

#[test]
fn fem_tool_force_100_times_the_weight_then_released() {
    for m in MODELS {
        fem_case(
            "tool force",
            m,
            1.0,
            CYLINDER_FEM.params.poisson_ratio,
            1.0,
            Disturbance::ToolForce(100.0),
        );
    }
}

/// Volume stiffness used where elements get inverted: edge springs alone cannot tell a
/// tetrahedron from its mirror image, so without it a folded MSD body stays folded.
const VOLUME_STIFFNESS: f64 = 2000.0;

fn msd_case(
    name: &str,
    integrator: MsdIntegrator,
    stiffness_scale: f64,
    volume: f64,
    d: Disturbance,
) {
    let mesh = cylinder();
    let mut c = MsdConfig::paper(&CYLINDER_MSD.params, CYLINDER_MSD.dt);
    c.integrator = integrator;
    c.stiffness *= stiffness_scale;
    c.volume_stiffness = volume;
    c.explicit_limit = ExplicitLimit::Substep { max_substeps: 1000 };
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let mut body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
    let name = format!("{name} ({integrator:?})");
    let (peak, end, dist) = run(&name, &mesh, &mut body, d, c.dt);
    // Symplectic Euler's energy oscillates around its shadow energy: allow a factor 2 there.
    let bound = if integrator == MsdIntegrator::SymplecticEuler {
        2.0
    } else {
        1.01
    };
    assert!(
        peak <= bound * end + 1e-12,
        "{name}: energy grew from {end} to {peak}"
    );
    assert!(
        dist < 1e-3,
        "{name}: did not return to rest (distance {dist} of the width)"
    );
}

#[test]
fn msd_stiff_springs_implicit() {
    msd_case(
        "stiffness x1000",
        MsdIntegrator::ImplicitEuler,
        1000.0,
        0.0,
        Disturbance::Kick(2.0),
    );
}

#[test]
fn msd_tool_force_100_times_the_weight_then_released() {
    // The paper's MSD (edge springs only): a force of 100 body weights on one node drags it
    // several body widths away and pulls neighbours through each other; edge springs cannot
    // undo an inversion (a tetrahedron and its mirror image have the same edge lengths), so
    // the body comes to rest partly tangled rather than exactly at rest (the FEM cases above
    // do come back). Checked: every step succeeds, the energy stays bounded after release,
    // the body stops, and it ends far closer to rest than at the peak of the pull.
    for integrator in [MsdIntegrator::Rk4, MsdIntegrator::ImplicitEuler] {
        let mesh = cylinder();
        let mut c = MsdConfig::paper(&CYLINDER_MSD.params, CYLINDER_MSD.dt);
        c.integrator = integrator;
        c.explicit_limit = ExplicitLimit::Substep { max_substeps: 1000 };
        let mut body =
            MsdBody::from_mesh(&mesh, c, &Boundary::fixed_below(mesh.positions(), 1, 0.1)).unwrap();
        let node = top_nodes(&mesh, 0.05)[0];
        let weight = body.masses().iter().sum::<f64>() * 9.81;
        let (mut peak_dist, mut end_energy, mut peak_energy) = (0.0f64, 0.0, 0.0f64);
        let pull = (1.0 / c.dt).round() as usize;
        let distance = |b: &MsdBody| {
            b.positions()
                .iter()
                .zip(mesh.positions())
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max)
        };
        for s in 0..STEPS {
            if s < pull {
                body.add_force(node, Vec3::new(100.0 * weight, 0.0, 0.0));
            }
            body.step()
                .unwrap_or_else(|e| panic!("{integrator:?} tool force: step {s}: {e}"));
            let e = body.kinetic_energy() + body.elastic_energy();
            if s + 1 == pull {
                end_energy = e;
                peak_dist = distance(&body);
            }
            if s >= pull {
                peak_energy = peak_energy.max(e);
            }
        }
        let dist = distance(&body);
        assert!(
            peak_energy <= 1.01 * end_energy,
            "{integrator:?}: energy grew from {end_energy} to {peak_energy}"
        );
        assert!(
            body.max_speed() < 1e-6 * width(&mesh),
            "{integrator:?}: still moving at {}",
            body.max_speed()
        );
        assert!(
            dist < 0.2 * peak_dist,
            "{integrator:?}: distance from rest {dist}, at the peak {peak_dist}"
        );
    }
}

#[test]
fn msd_squashed_and_folded() {
    for i in [MsdIntegrator::Rk4, MsdIntegrator::ImplicitEuler] {
        msd_case("squashed", i, 1.0, 0.0, Disturbance::Squash);
        msd_case("folded", i, 1.0, VOLUME_STIFFNESS, Disturbance::Fold);
    }
}

#[test]
fn msd_rk4_above_its_limit_is_substepped_or_refused() {
    let mesh = cylinder();
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let mut c = MsdConfig::paper(&CYLINDER_MSD.params, CYLINDER_MSD.dt);
    let probe = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
    c.dt = 3.0 * probe.stable_dt();
    // Substepped: stable for 10,000 steps and back at rest.
    c.explicit_limit = ExplicitLimit::Substep { max_substeps: 16 };
    let mut body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
    let (peak, end, dist) = run(
        "rk4 above limit",
        &mesh,
        &mut body,
        Disturbance::Kick(2.0),
        c.dt,
    );
    assert_eq!(body.last_step().substeps, 3);
    assert!(
        peak <= 1.01 * end && dist < 1e-3,
        "peak {peak} end {end} dist {dist}"
    );
    // Refused: a clear error, state untouched.
    c.explicit_limit = ExplicitLimit::Refuse;
    let mut body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
    let err = body.step().unwrap_err();
    assert!(
        matches!(err, MsdError::TimeStepTooLarge { needed: 3, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("stability limit"));
}
