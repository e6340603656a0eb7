//! Condensed cage dynamics (`calibration::condense_cage`, `cage::condense`): the cage's
//! lowest frequencies against the precise model's own, computed independently from the
//! MSD's analytic spring stiffness; and the errors a condensation names.

use std::path::Path;
use std::sync::Arc;

use nalgebra::DMatrix;
use soft_tissue_core::calibration::condense_cage;
use soft_tissue_core::precision::{BodySettings, LeveledModel, PreciseMethod};
use soft_tissue_core::scenario::{CYLINDER_MSD, ORGAN_FEM, Scene};
use soft_tissue_core::world::{WorldBody, scene_bodies};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"))
}

/// Generalised eigenvalues of `(K, M)`, ascending (dense, row-major, `d x d`).
fn eigenvalues(k: &DMatrix<f64>, m: &DMatrix<f64>) -> Vec<f64> {
    let l = m.clone().cholesky().unwrap().l();
    let li = l.try_inverse().unwrap();
    let a = &li * k * li.transpose();
    let a = (&a + a.transpose()) * 0.5;
    let mut e: Vec<f64> = a.symmetric_eigen().eigenvalues.iter().copied().collect();
    e.sort_by(|a, b| a.total_cmp(b));
    e
}

/// Model A of the paper's cylinders with the RK4 MSD (the report's Fig. 5 body), settled.
fn msd_cylinder() -> WorldBody {
    let scene = Scene::paper_cylinders(PreciseMethod::MsdImplicit, PreciseMethod::MsdImplicit);
    let (_, bodies) = scene_bodies(&scene, assets()).unwrap();
    let mut b = bodies.into_iter().next().unwrap();
    b.settings.precise = PreciseMethod::MsdRk4;
    WorldBody::new(b.name, Arc::new(b.mesh), b.settings, b.heat).unwrap()
}

/// The MSD's two lowest frequencies (its analytic spring and anchor stiffness at rest, fixed
/// nodes removed) against the cage's: the projected box cage is locked (its lowest two are
/// more than twice the MSD's), the condensed one within 1 % of them.
#[test]
fn condensed_box_cage_has_the_msds_lowest_frequencies() {
    let mut sim = msd_cylinder();
    let body = sim.model_mut();
    let msd = body.msd().unwrap();
    assert_eq!(
        msd.config().volume_stiffness,
        0.0,
        "springs and anchors only"
    );
    let x = body.cage().coordinates().rest_points().to_vec();
    let n = x.len();
    let k = msd.stiffness_dense(&x);
    let (masses, fixed) = (
        body.precise().masses().to_vec(),
        body.precise().fixed().to_vec(),
    );
    let free: Vec<usize> = (0..3 * n).filter(|&r| !fixed[r / 3][r % 3]).collect();
    let kf = DMatrix::from_fn(free.len(), free.len(), |r, c| k[free[r] * 3 * n + free[c]]);
    let mf = DMatrix::from_fn(free.len(), free.len(), |r, c| {
        if r == c { masses[free[r] / 3] } else { 0.0 }
    });
    let precise: Vec<f64> = eigenvalues(&kf, &mf).iter().map(|l| l.sqrt()).collect();
    let cage_frequencies = |body: &LeveledModel| -> Vec<f64> {
        let m = body.cage().reduced().unwrap();
        let d = m.dim();
        let kc = DMatrix::from_row_slice(d, d, m.stiffness());
        let mc = DMatrix::from_row_slice(d, d, m.mass());
        eigenvalues(&kc, &mc)
            .iter()
            .map(|l| l.max(0.0).sqrt())
            .collect()
    };
    let projected = cage_frequencies(body);
    condense_cage(body).unwrap();
    let condensed = cage_frequencies(body);
    for i in 0..2 {
        assert!(
            projected[i] > 2.0 * precise[i],
            "mode {i}: projected {} against the MSD's {}",
            projected[i],
            precise[i]
        );
        assert!(
            (condensed[i] - precise[i]).abs() < 0.01 * precise[i],
            "mode {i}: condensed {} against the MSD's {}",
            condensed[i],
            precise[i]
        );
    }
    // The reduced matrices stay symmetric.
    let m = body.cage().reduced().unwrap();
    let d = m.dim();
    for (name, a) in [
        ("mass", m.mass()),
        ("stiffness", m.stiffness()),
        ("damping", m.damping()),
    ] {
        for r in 0..d {
            for c in 0..d {
                assert_eq!(a[r * d + c], a[c * d + r], "{name} ({r}, {c})");
            }
        }
    }
}

/// A body with the paper's cage MSD has nothing to condense, and a free body (no fixed
/// nodes, no anchors) has no compliance to take: both are errors saying so.
#[test]
fn condensation_refuses_paper_cages_and_free_bodies() {
    let mesh = soft_tissue_core::mesh::generate::Organ::Liver
        .generate(0.5)
        .unwrap();
    let mut paper = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
    paper.cage_dynamics = soft_tissue_core::cage::CageDynamics::Paper;
    let mut body = LeveledModel::new(&mesh, paper).unwrap();
    let e = condense_cage(&mut body).unwrap_err().to_string();
    assert!(e.contains("cage MSD"), "{e}");
    let free = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
    let mut body = LeveledModel::new(&mesh, free).unwrap();
    let e = condense_cage(&mut body).unwrap_err().to_string();
    assert!(e.contains("fixed nodes or anchors"), "{e}");
}
