//! Bad input to the solvers gives a typed error naming what and where, never a panic, and a
//! refused step leaves the state as it was.

use soft_tissue_core::boundary::{Boundary, BoundaryError};
use soft_tissue_core::fem::{FemBody, FemConfig, FemError};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::msd::{MsdBody, MsdConfig, MsdError, Spring};
use soft_tissue_core::scenario::{CYLINDER_MSD, ORGAN_FEM};
use soft_tissue_core::{NodalModel, Vec3};

fn mesh() -> TetMesh {
    block(Vec3::zeros(), Vec3::repeat(1.0), [2, 2, 2]).unwrap()
}

#[test]
fn bad_fem_configs_name_the_field() {
    let good = FemConfig::paper(&ORGAN_FEM.params, 0.01);
    let cases: Vec<(&str, FemConfig)> = vec![
        (
            "poisson_ratio",
            FemConfig {
                poisson_ratio: 0.5,
                ..good
            },
        ),
        (
            "young_modulus",
            FemConfig {
                young_modulus: -1.0,
                ..good
            },
        ),
        ("dt", FemConfig { dt: 0.0, ..good }),
        (
            "gravity",
            FemConfig {
                gravity: Vec3::new(0.0, f64::NAN, 0.0),
                ..good
            },
        ),
        (
            "mass_damping",
            FemConfig {
                mass_damping: f64::INFINITY,
                ..good
            },
        ),
        (
            "cg_max_iterations",
            FemConfig {
                cg_max_iterations: 0,
                ..good
            },
        ),
        (
            "stiffness_update_angle",
            FemConfig {
                stiffness_update_angle: -0.1,
                ..good
            },
        ),
    ];
    for (field, c) in cases {
        match FemBody::new(&mesh(), c, &Boundary::free()) {
            Err(FemError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
            other => panic!(
                "{field}: expected InvalidConfig, got {:?}",
                other.map(|_| ())
            ),
        }
    }
}

#[test]
fn bad_boundaries_name_the_node() {
    let c = FemConfig::paper(&ORGAN_FEM.params, 0.01);
    let n = mesh().positions().len();
    let err = FemBody::new(&mesh(), c, &Boundary::fixed_nodes([n + 3])).unwrap_err();
    assert_eq!(
        err,
        FemError::Boundary(BoundaryError::NodeOutOfRange {
            what: "fixed",
            node: n + 3,
            nodes: n
        })
    );
    let b = Boundary {
        fixed: vec![],
        anchors: vec![(2, -5.0)],
    };
    let err = FemBody::new(&mesh(), c, &b).unwrap_err();
    assert!(err.to_string().contains("node 2"), "{err}");
}

#[test]
fn non_finite_inputs_are_refused_and_leave_the_state_alone() {
    let c = FemConfig::paper(&ORGAN_FEM.params, 0.01);
    let mut body = FemBody::new(&mesh(), c, &Boundary::fixed_nodes([0])).unwrap();
    body.add_force(7, Vec3::new(f64::NAN, 0.0, 0.0));
    let before = body.positions().to_vec();
    assert_eq!(
        body.step().unwrap_err(),
        FemError::NonFinite {
            what: "external force",
            node: 7
        }
    );
    assert_eq!(body.positions(), &before[..]);
    body.external_forces_mut()[7] = Vec3::zeros();
    body.velocities_mut()[4].y = f64::INFINITY;
    assert_eq!(
        body.step().unwrap_err(),
        FemError::NonFinite {
            what: "velocity",
            node: 4
        }
    );
    // Static solve without constraints is refused, not attempted.
    let mut free = FemBody::new(&mesh(), c, &Boundary::free()).unwrap();
    assert_eq!(
        free.solve_static(1e-9, 10).unwrap_err(),
        FemError::Unconstrained
    );
}

#[test]
fn bad_msd_input_names_the_spring_or_node() {
    let c = MsdConfig::paper(&CYLINDER_MSD.params, 0.02);
    let pos = vec![Vec3::zeros(), Vec3::x(), Vec3::y()];
    let spring = |a, b, k, l| Spring {
        a,
        b,
        stiffness: k,
        rest_length: l,
    };
    let cases = [
        (
            vec![spring(0, 1, 1.0, 1.0), spring(1, 5, 1.0, 1.0)],
            "spring 1",
        ),
        (vec![spring(2, 2, 1.0, 1.0)], "spring 0"),
        (vec![spring(0, 1, -1.0, 1.0)], "spring 0"),
        (vec![spring(0, 1, 1.0, f64::NAN)], "spring 0"),
    ];
    for (springs, expected) in cases {
        let err =
            MsdBody::new(pos.clone(), vec![1.0; 3], springs, c, &Boundary::free()).unwrap_err();
        assert!(matches!(err, MsdError::BadSpring { .. }), "{err}");
        assert!(err.to_string().starts_with(expected), "{err}");
    }
    let err = MsdBody::new(
        pos.clone(),
        vec![1.0, 0.0, 1.0],
        vec![],
        c,
        &Boundary::free(),
    )
    .unwrap_err();
    assert!(matches!(err, MsdError::BadNode { node: 1, .. }), "{err}");
    let err = MsdBody::new(pos.clone(), vec![1.0; 2], vec![], c, &Boundary::free()).unwrap_err();
    assert!(
        matches!(
            err,
            MsdError::InvalidConfig {
                field: "masses",
                ..
            }
        ),
        "{err}"
    );
    let bad = MsdConfig { damping: -1.0, ..c };
    let err = MsdBody::new(pos, vec![1.0; 3], vec![], bad, &Boundary::free()).unwrap_err();
    assert!(
        matches!(
            err,
            MsdError::InvalidConfig {
                field: "damping",
                ..
            }
        ),
        "{err}"
    );
    // Coincident nodes: no direction, no force, no NaN.
    let mut body = MsdBody::new(
        vec![Vec3::zeros(), Vec3::zeros()],
        vec![1.0; 2],
        vec![spring(0, 1, 10.0, 0.5)],
        c,
        &Boundary::free(),
    )
    .unwrap();
    body.step().unwrap();
    assert!(
        body.positions()
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite()))
    );
}
