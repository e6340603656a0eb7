//! Numerical stability on hard cases: 10,000 steps each on the paper's cylinder (bottom 10 %
//! fixed, gravity off), for both FEM models and the MSD integrators, through
//! `soft_tissue_core::stability` (the cases `soft-tissue report` tabulates). Every step must
//! succeed (no NaN, no error), the energy must stay bounded once the disturbance is over, and
//! the body must come back to rest (largest node distance from rest below 1e-3 of the body's
//! width).

use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::msd::MsdIntegrator;
use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD};
use soft_tissue_core::stability::{
    CaseMethod, CaseReport, Disturbance, HardCase, Outcome, run_case,
};

const STEPS: usize = 10_000;

fn cylinder() -> TetMesh {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../assets/meshes/cylinder.vtk"
    );
    read_tet_mesh(std::path::Path::new(path)).unwrap().mesh
}

fn run(case: &HardCase) -> CaseReport {
    run_case(
        &cylinder(),
        case,
        (&CYLINDER_FEM.params, CYLINDER_FEM.dt),
        (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
        STEPS,
    )
    .unwrap()
}

/// The cases matching `name` and `method`.
fn cases(name: &str, method: impl Fn(CaseMethod) -> bool) -> Vec<HardCase> {
    let v: Vec<HardCase> = HardCase::all()
        .into_iter()
        .filter(|c| c.name == name && method(c.method))
        .collect();
    assert!(!v.is_empty(), "no case `{name}`");
    v
}

/// Checks a case that must run every step and come back to rest; `bound` is the allowed
/// energy growth factor after the disturbance.
fn check_returns_to_rest(case: &HardCase, bound: f64) {
    let r = run(case);
    let name = format!("{} ({})", case.name, case.method_name());
    assert!(
        matches!(r.outcome, Outcome::Stable | Outcome::Substepped(_)),
        "{name}: {:?}",
        r.outcome
    );
    assert_eq!(r.steps, STEPS, "{name}");
    match case.disturbance {
        Disturbance::Fold => assert!(r.inverted > 0, "{name}: the fold must invert elements"),
        Disturbance::Squash => assert!(r.flat > 0, "{name}: the squash must flatten elements"),
        _ => {}
    }
    assert!(
        r.peak_energy <= bound * r.end_energy + 1e-12,
        "{name}: energy grew from {} to {}",
        r.end_energy,
        r.peak_energy
    );
    assert!(
        r.final_distance < 1e-3,
        "{name}: did not return to rest (distance {} of the width)",
        r.final_distance
    );
}

fn is_fem(m: CaseMethod) -> bool {
    matches!(m, CaseMethod::Fem(_) | CaseMethod::FemBdf2(_))
}

// FEM: bounded means the energy after the disturbance never exceeds what it was when it
// ended by more than 1 % (inexact CG solves and the linearised rotations may add round-off,
// never growth).

#[test]
fn fem_near_incompressible() {
    for c in cases("Poisson 0.49", is_fem) {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn fem_young_times_1000_at_the_paper_step() {
    for c in cases("Young x1000", is_fem) {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn fem_ten_times_the_paper_step() {
    for c in cases("dt x10", is_fem) {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn fem_initially_inverted_elements() {
    for c in cases("initially inverted", is_fem) {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn fem_initially_flat_elements() {
    for c in cases("initially flat", is_fem) {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn fem_tool_force_100_times_the_weight_then_released() {
    let v = cases("tool force 100x weight", is_fem);
    assert_eq!(v.len(), 5);
    for c in v {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn every_case_is_listed_once_per_solver() {
    let all = HardCase::all();
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            assert!(
                !(a.name == b.name && a.method == b.method),
                "{} ({}) twice",
                a.name,
                a.method_name()
            );
        }
    }
}

#[test]
fn msd_stiff_springs_implicit() {
    let v = cases("stiffness x1000", |m| {
        m == CaseMethod::Msd(MsdIntegrator::ImplicitEuler)
            || m == CaseMethod::Msd(MsdIntegrator::ImplicitBdf2)
    });
    assert_eq!(v.len(), 2);
    for c in v {
        check_returns_to_rest(&c, 1.01);
    }
}

#[test]
fn msd_tool_force_100_times_the_weight_then_released() {
    // The paper's MSD (edge springs only): a force of 100 body weights on one node drags it
    // several body widths away and pulls neighbours through each other; edge springs cannot
    // undo an inversion (a tetrahedron and its mirror image have the same edge lengths), so
    // the body comes to rest partly tangled rather than exactly at rest (the FEM cases above
    // do come back). Checked: every step succeeds, the energy stays bounded after release,
    // the body stops, and it ends far closer to rest than at the peak of the pull.
    let v = cases("tool force 100x weight", |m| !is_fem(m));
    assert_eq!(v.len(), 3);
    for c in v {
        let r = run(&c);
        let name = c.method_name();
        assert!(
            matches!(r.outcome, Outcome::Stable | Outcome::Substepped(_)),
            "{name}: {:?}",
            r.outcome
        );
        assert!(
            r.peak_energy <= 1.01 * r.end_energy,
            "{name}: energy grew from {} to {}",
            r.end_energy,
            r.peak_energy
        );
        assert!(
            r.final_speed < 1e-6,
            "{name}: still moving at {}",
            r.final_speed
        );
        assert!(
            r.disturbed_distance > 1.0 && r.final_distance < 0.2 * r.disturbed_distance,
            "{name}: distance from rest {}, at the peak {}",
            r.final_distance,
            r.disturbed_distance
        );
    }
}

#[test]
fn msd_squashed_and_folded() {
    // Symplectic Euler is not among the cases; RK4, implicit Euler and BDF2 dissipate.
    for name in ["initially flat", "initially inverted"] {
        let v = cases(name, |m| !is_fem(m));
        assert_eq!(v.len(), 3, "{name}");
        for c in v {
            check_returns_to_rest(&c, 1.01);
        }
    }
}

#[test]
fn msd_rk4_above_its_limit_is_substepped_or_refused() {
    let rk4 = |m| m == CaseMethod::Msd(MsdIntegrator::Rk4);
    // Substepped: stable for 10,000 steps and back at rest, three substeps per step.
    let [c] = cases("dt 3x its limit, substep", rk4)[..] else {
        panic!("one substep case expected")
    };
    check_returns_to_rest(&c, 1.01);
    assert_eq!(run(&c).outcome, Outcome::Substepped(3));
    // Refused: a clear error on the first step.
    let [c] = cases("dt 3x its limit, refuse", rk4)[..] else {
        panic!("one refuse case expected")
    };
    let r = run(&c);
    match &r.outcome {
        Outcome::Refused(message) => assert!(message.contains("stability limit"), "{message}"),
        other => panic!("expected a refusal, got {other:?}"),
    }
    assert_eq!(r.steps, 0);
}
