//! Levels of precision: state transfer without jumps, the automatic return to the cage,
//! hysteresis, pinning and run-time method changes.

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::FemModel;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;

use soft_tissue_core::precision::{BodySettings, Level, LeveledModel, PreciseMethod};
use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD, CageKind, ORGAN_FEM};
use soft_tissue_core::{NodalModel, Vec3};

fn asset(name: &str) -> TetMesh {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../../assets/meshes/{name}.vtk"));
    read_tet_mesh(path).unwrap().mesh
}

fn cylinder_settings(method: PreciseMethod, cage: CageKind, mesh: &TetMesh) -> BodySettings {
    let mut s = BodySettings::new(CYLINDER_FEM.params, CYLINDER_MSD.params, CYLINDER_FEM.dt);
    s.precise = method;
    s.cage = cage;
    s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    s
}

/// Nodes in the top 5 % of the mesh's height.
fn top_nodes(mesh: &TetMesh) -> Vec<usize> {
    let hi = mesh.bbox().max.y;
    (0..mesh.node_count())
        .filter(|&i| mesh.positions()[i].y > hi - 0.05 * mesh.bbox().extent().y)
        .collect()
}

const METHODS: [PreciseMethod; 3] = [
    PreciseMethod::CorotationalFem,
    PreciseMethod::LinearFem,
    PreciseMethod::MsdImplicit,
];

#[test]
fn switching_at_rest_is_seamless() {
    let mesh = asset("liver");
    for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 48 }] {
        for method in METHODS {
            let mut s = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
            s.precise = method;
            s.cage = cage;
            let mut body = LeveledModel::new(&mesh, s).unwrap();
            assert_eq!(body.level(), Level::Cage);
            let up = body.raise().unwrap().unwrap();
            assert_eq!((up.from, up.to), (Level::Cage, Level::Precise));
            // The f32 evaluation of the rest shape against the exact one: rounding only.
            assert!(
                up.jump_ratio < 1e-9,
                "{method:?} {cage:?}: up jump {}",
                up.jump_ratio
            );
            let down = body.lower().unwrap().unwrap();
            assert!(
                down.jump_ratio < 1e-6,
                "{method:?} {cage:?}: down jump {}",
                down.jump_ratio
            );
            assert!(down.residual / body.smallest_dimension() < 1e-6);
            assert_eq!(body.switch_count(), 2);
        }
    }
}

#[test]
fn a_poked_body_rises_then_returns_to_its_cage_with_a_small_jump() {
    let mesh = asset("cylinder");
    let top = top_nodes(&mesh);
    for method in METHODS {
        for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 40 }] {
            let mut body =
                LeveledModel::new(&mesh, cylinder_settings(method, cage, &mesh)).unwrap();
            // A contact raises the body before the contact force acts.
            let up = body.raise().unwrap().unwrap();
            assert!(up.jump_ratio < 1e-9);
            let mut deformed: f64 = 0.0;
            for step in 0..3000 {
                let touching = step < 30;
                if touching {
                    for &i in &top {
                        body.add_force(i, Vec3::new(2.0, 0.0, 0.0)).unwrap();
                    }
                }
                body.step(touching).unwrap();
                if body.level() == Level::Cage {
                    break;
                }
                let d = body
                    .node_positions()
                    .iter()
                    .zip(mesh.positions())
                    .map(|(a, b)| (a - b).norm())
                    .fold(0.0, f64::max);
                deformed = deformed.max(d);
                assert!(d.is_finite());
            }
            assert!(
                deformed > 0.02 * body.smallest_dimension(),
                "{method:?}: the poke should bend the cylinder (max {deformed})"
            );
            assert_eq!(
                body.level(),
                Level::Cage,
                "{method:?} {cage:?} did not return to the cage"
            );
            let down = body.last_switch().unwrap();
            assert_eq!(down.to, Level::Cage);
            assert!(
                down.jump_ratio < 0.005,
                "{method:?} {cage:?}: down jump {:.4} % of the width",
                100.0 * down.jump_ratio
            );
            assert_eq!(body.switch_count(), 2, "no flicker");
            println!(
                "{} {cage:?}: max deformation {:.1} % of the width, back at the cage at step {}, jump {:.3} %",
                method.name(),
                100.0 * deformed / body.smallest_dimension(),
                down.step,
                100.0 * down.jump_ratio
            );
            // At the cage level it stays put and stays at the cage.
            for _ in 0..50 {
                assert_eq!(body.step(false).unwrap().switched, None);
            }
        }
    }
}

#[test]
fn motion_is_carried_across_switches() {
    let mesh = asset("stomach");
    for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 40 }] {
        let mut s = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
        s.cage = cage;
        let mut body = LeveledModel::new(&mesh, s).unwrap();
        // Cage spinning rigidly about its centre: the nodes get the same rigid velocity field.
        let w = Vec3::new(0.1, -0.3, 0.2);
        let u0 = Vec3::new(0.05, 0.0, -0.02);
        let c = mesh.bbox().center();
        let cage_x = body.cage().cage_positions().to_vec();
        // (through the cage MSD's accessors)
        {
            let cage_body = body_cage_mut(&mut body);
            for (v, x) in cage_body.velocities_mut().iter_mut().zip(&cage_x) {
                *v = u0 + w.cross(&(x - c));
            }
        }
        body.raise().unwrap();
        let p = body.precise();
        for (v, x) in p.velocities().iter().zip(p.positions()) {
            let expected = u0 + w.cross(&(x - c));
            assert!((v - expected).norm() < 1e-6, "{v:?} vs {expected:?}");
        }
        // And back: a rigid motion of the nodes fits the same rigid motion of the cage, in
        // position (a finite rotation) and velocity.
        let rot = nalgebra::Rotation3::from_scaled_axis(Vec3::new(0.4, 0.2, -0.3));
        let moved: Vec<Vec3> = mesh.positions().iter().map(|x| c + rot * (x - c)).collect();
        let vel: Vec<Vec3> = moved.iter().map(|x| u0 + w.cross(&(x - c))).collect();
        body.precise_mut().positions_mut().copy_from_slice(&moved);
        body.precise_mut().velocities_mut().copy_from_slice(&vel);
        let down = body.lower().unwrap().unwrap();
        // The displayed surface is the f32 evaluation: rounding of a large displacement.
        assert!(
            down.jump_ratio < 1e-6,
            "rigid motion: jump {}",
            down.jump_ratio
        );
        for (x, x0) in body
            .cage()
            .cage_positions()
            .iter()
            .zip(body.cage().cage().vertices())
        {
            let e = (x - (c + rot * (x0 - c))).norm();
            // The fit iterates on the face terms (linear convergence): 1e-7 of the size.
            assert!(
                e < 1e-7,
                "cage vertex off by {e:e}, residual {:e}",
                down.residual
            );
        }
        // (velocities)
        for (v, x) in body
            .cage()
            .msd()
            .velocities()
            .iter()
            .zip(body.cage().cage_positions())
        {
            let expected = u0 + w.cross(&(x - c));
            assert!((v - expected).norm() < 1e-6, "cage {v:?} vs {expected:?}");
        }
    }
}

/// Test access to the cage MSD (velocities), through the public `CageModel` API.
fn body_cage_mut(body: &mut LeveledModel) -> &mut soft_tissue_core::msd::MsdBody {
    body.cage_mut().msd_mut()
}

#[test]
fn pins_and_hysteresis() {
    let mesh = asset("cylinder");
    let s = cylinder_settings(PreciseMethod::CorotationalFem, CageKind::BoundingBox, &mesh);
    let min_steps = s.policy.min_precise_steps as u64;
    let mut body = LeveledModel::new(&mesh, s).unwrap();
    // Pinned to the cage: contact cannot raise it.
    body.pin(Some(Level::Cage)).unwrap();
    assert_eq!(body.raise().unwrap(), None);
    assert_eq!(body.level(), Level::Cage);
    // Pinned to the precise level: it switches now and never drops, even at rest.
    body.pin(Some(Level::Precise)).unwrap();
    assert_eq!(body.level(), Level::Precise);
    for _ in 0..200 {
        assert_eq!(body.step(false).unwrap().switched, None);
    }
    assert_eq!(body.lower().unwrap(), None);
    // Unpinned at rest: drops, but not before the minimum time at the precise level.
    body.pin(None).unwrap();
    body.lower().unwrap();
    body.raise().unwrap();
    let mut steps = 0;
    while body.level() == Level::Precise {
        body.step(false).unwrap();
        steps += 1;
        assert!(steps < 1000);
    }
    assert!(steps >= min_steps, "dropped after {steps} steps");
    // Contact every step keeps it up however still it is.
    body.raise().unwrap();
    for _ in 0..200 {
        body.step(true).unwrap();
    }
    assert_eq!(body.level(), Level::Precise);
}

#[test]
fn the_precise_method_changes_at_run_time_without_a_jump() {
    let mesh = asset("cylinder");
    let s = cylinder_settings(PreciseMethod::CorotationalFem, CageKind::BoundingBox, &mesh);
    let mut body = LeveledModel::new(&mesh, s).unwrap();
    body.raise().unwrap();
    for _ in 0..20 {
        body.add_force(mesh.node_count() - 1, Vec3::new(5.0, 0.0, 0.0))
            .unwrap();
        body.step(true).unwrap();
    }
    for method in [
        PreciseMethod::MsdImplicit,
        PreciseMethod::LinearFem,
        PreciseMethod::CorotationalFem,
        PreciseMethod::MsdRk4,
    ] {
        let before = body.node_positions().to_vec();
        body.set_precise_method(&mesh, method).unwrap();
        assert_eq!(body.settings().precise, method);
        assert_eq!(body.node_positions(), &before[..], "{method:?}");
        assert!(body.msd().is_some() != method.is_fem());
        for _ in 0..10 {
            body.step(true).unwrap();
        }
        assert!(
            body.node_positions()
                .iter()
                .all(|p| p.iter().all(|c| c.is_finite()))
        );
    }
    // Reset: back to the cage at rest.
    body.reset().unwrap();
    assert_eq!(body.level(), Level::Cage);
    for (a, b) in body.node_positions().iter().zip(mesh.positions()) {
        assert!((a - b).norm() < 1e-9);
    }
}

fn surface_gap(body: &LeveledModel, other: &[Vec3]) -> (f64, f64) {
    let x = body.node_positions();
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    for &i in body.surface_vertices() {
        let d = (x[i as usize] - other[i as usize]).norm();
        sum += d;
        max = max.max(d);
    }
    (sum / body.surface_vertices().len() as f64, max)
}

#[test]
fn a_shadow_is_the_precise_method_under_the_same_loads_and_leaves_the_cage_alone() {
    let mesh = asset("cylinder");
    let top = top_nodes(&mesh);
    for method in METHODS {
        let settings = cylinder_settings(method, CageKind::BoundingBox, &mesh);
        let mut plain = LeveledModel::new(&mesh, settings.clone()).unwrap();
        let mut shadowed = LeveledModel::new(&mesh, settings.clone()).unwrap();
        shadowed.set_shadow(&mesh, true).unwrap();
        assert!(shadowed.has_shadow() && !plain.has_shadow());
        // An independent precise run: the same solver pinned to its level, raised from the
        // same cage state the shadow starts from.
        let mut precise = LeveledModel::new(&mesh, settings).unwrap();
        precise.pin(Some(Level::Precise)).unwrap();
        let mut worst: f64 = 0.0;
        for step in 0..300 {
            // Loads applied at the cage level: no contact is reported, so the body stays at
            // its cage.
            if step < 40 {
                for &i in &top {
                    let f = Vec3::new(0.5, 0.0, 0.2);
                    plain.add_force(i, f).unwrap();
                    shadowed.add_force(i, f).unwrap();
                    precise.add_force(i, f).unwrap();
                }
            }
            plain.step(false).unwrap();
            shadowed.step(false).unwrap();
            precise.step(false).unwrap();
            assert_eq!(shadowed.level(), Level::Cage);
            // The shadow changes nothing in the body it watches.
            assert_eq!(plain.node_positions(), shadowed.node_positions());
            // The shadow is the precise method under the same loads, bit for bit.
            let sh = shadowed.shadow_positions().unwrap();
            assert_eq!(sh, precise.node_positions(), "{method:?} step {step}");
            // Its report is the surface distance between the two.
            let e = shadowed.shadow_error().unwrap();
            let (mean, max) = surface_gap(&shadowed, sh);
            assert_eq!(e.steps, step as u64 + 1);
            assert!((e.mean - mean).abs() <= 1e-12 * (1.0 + mean));
            assert!((e.max - max).abs() <= 1e-12 * (1.0 + max));
            assert!((e.max_ratio - max / shadowed.smallest_dimension()).abs() < 1e-12);
            worst = worst.max(e.max_ratio);
            assert!((e.worst_ratio - worst).abs() < 1e-15);
            if step == 0 {
                // Both start from the same rest state: one step apart only by the load.
                assert!(
                    e.max_ratio < 0.01,
                    "{method:?}: first step gap {}",
                    e.max_ratio
                );
            }
        }
        // A cage cannot bend a cylinder the way its FEM or MSD does: the gap is real.
        assert!(worst > 1e-4, "{method:?}: worst gap {worst}");
        println!(
            "{}: worst cage-vs-shadow gap {:.3} % of the width",
            method.name(),
            100.0 * worst
        );
        shadowed.set_shadow(&mesh, false).unwrap();
        assert!(shadowed.shadow_error().is_none() && shadowed.shadow_positions().is_none());
    }
}

#[test]
fn a_shadow_restarts_from_the_precise_state_at_a_down_switch() {
    let mesh = asset("cylinder");
    let method = PreciseMethod::CorotationalFem;
    let settings = cylinder_settings(method, CageKind::BoundingBox, &mesh);
    let mut body = LeveledModel::new(&mesh, settings.clone()).unwrap();
    body.set_shadow(&mesh, true).unwrap();
    body.raise().unwrap();
    // A twin that stays precise under the same loads: what the shadow must go on doing.
    let mut twin = LeveledModel::new(&mesh, settings).unwrap();
    twin.pin(Some(Level::Precise)).unwrap();
    let top = (0..mesh.node_count())
        .max_by(|&a, &b| mesh.positions()[a].y.total_cmp(&mesh.positions()[b].y))
        .unwrap();
    for _ in 0..20 {
        body.add_force(top, Vec3::new(1.0, 0.0, 0.0)).unwrap();
        twin.add_force(top, Vec3::new(1.0, 0.0, 0.0)).unwrap();
        body.step(true).unwrap();
        twin.step(true).unwrap();
    }
    assert_eq!(body.level(), Level::Precise);
    assert_eq!(body.node_positions(), twin.node_positions());
    let x = body.precise().positions().to_vec();
    // Forced down mid-motion: the cage takes over, the shadow carries on precisely.
    let down = body.lower().unwrap().unwrap();
    assert_eq!(body.shadow_positions().unwrap(), &x[..]);
    assert_eq!(body.shadow_error().unwrap().steps, 0);
    let scale = body.smallest_dimension();
    let mut worst_twin: f64 = 0.0;
    for k in 0..30 {
        body.step(false).unwrap();
        twin.step(false).unwrap();
        let gap = body
            .shadow_positions()
            .unwrap()
            .iter()
            .zip(twin.node_positions())
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        // Equal but for the warm-started rotations and the CG tolerance (1e-6).
        assert!(gap < 1e-5 * scale, "step {k}: shadow vs twin {gap}");
        worst_twin = worst_twin.max(gap);
    }
    println!("shadow vs twin: {:.2e} of the width", worst_twin / scale);
    // The gap it reports starts from the fit residual of the switch and grows as the cage
    // and the bent cylinder go their own ways.
    let e = body.shadow_error().unwrap();
    assert!(
        e.worst_ratio * scale >= down.residual * 0.5,
        "{e:?} {down:?}"
    );
    // Reset puts it back beside the rest state.
    body.reset().unwrap();
    body.step(false).unwrap();
    assert!(body.shadow_error().unwrap().max_ratio < 1e-9);
}

// Calibrated cage dynamics (the default): the cage moves as the Galerkin projection of its
// precise model onto the cage's motions.

use soft_tissue_core::cage::CageDynamics;

#[test]
fn a_free_calibrated_cage_accelerates_as_a_whole_by_newtons_law() {
    // A free body, no damping, a force on every node proportional to its mass: Newton's law
    // gives the uniform acceleration `a = F / M` and no deformation; implicit Euler from rest
    // gives, after k steps, the displacement `h^2 a k (k + 1) / 2`.
    let mesh = asset("liver");
    for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 48 }] {
        for method in [PreciseMethod::CorotationalFem, PreciseMethod::MsdImplicit] {
            let mut fem = ORGAN_FEM.params;
            fem.damping = 0.0;
            let mut msd = CYLINDER_MSD.params;
            msd.damping = 0.0;
            let mut s = BodySettings::new(fem, msd, ORGAN_FEM.dt);
            s.precise = method;
            s.cage = cage;
            let mut body = LeveledModel::new(&mesh, s).unwrap();
            let a = Vec3::new(0.3, -0.2, 0.1);
            let masses = body.precise().masses().to_vec();
            let rest = body.node_positions().to_vec();
            let steps = 20;
            for _ in 0..steps {
                for (i, m) in masses.iter().enumerate() {
                    body.add_force(i, a * *m).unwrap();
                }
                body.step(false).unwrap();
            }
            let h = ORGAN_FEM.dt;
            let expected = a * (h * h * (steps * (steps + 1)) as f64 / 2.0);
            let worst = body
                .node_positions()
                .iter()
                .zip(&rest)
                .map(|(x, r)| (x - r - expected).norm())
                .fold(0.0, f64::max);
            // f32 evaluation of the points: about 1e-7 of the displacement.
            assert!(
                worst < 1e-5 * expected.norm(),
                "{method:?} {cage:?}: off by {worst} of {}",
                expected.norm()
            );
        }
    }
}

#[test]
fn a_calibrated_cage_resists_no_rigid_motion() {
    // Green coordinates move the points rigidly with a rigidly moved cage, and elastic
    // forces vanish under rigid motions: the projected stiffness annihilates the cage's
    // translations and infinitesimal rotations.
    let mesh = asset("liver");
    for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 48 }] {
        for method in METHODS {
            let mut s = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
            s.precise = method;
            s.cage = cage;
            let body = LeveledModel::new(&mesh, s).unwrap();
            let model = body.cage().reduced().unwrap();
            let d = model.dim();
            let k = model.stiffness();
            let verts = body.cage().cage().vertices();
            let c = verts.iter().sum::<Vec3>() / verts.len() as f64;
            let kmax = k.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for axis in [Vec3::x(), Vec3::y(), Vec3::z()] {
                for rotation in [false, true] {
                    let motion: Vec<f64> = verts
                        .iter()
                        .flat_map(|v| {
                            let m = if rotation { axis.cross(&(v - c)) } else { axis };
                            [m.x, m.y, m.z]
                        })
                        .collect();
                    let norm = motion.iter().map(|x| x * x).sum::<f64>().sqrt();
                    let worst = (0..d)
                        .map(|r| (0..d).map(|q| k[r * d + q] * motion[q]).sum::<f64>().abs())
                        .fold(0.0, f64::max);
                    assert!(
                        worst < 1e-5 * kmax * norm,
                        "{method:?} {cage:?} rotation {rotation}: |K r| {worst}, |K| {kmax}"
                    );
                }
            }
        }
    }
}

#[test]
fn identical_bodies_share_a_calibrated_cage_and_the_paper_option_keeps_springs() {
    let mesh = asset("cylinder");
    let method = PreciseMethod::CorotationalFem;
    let s = cylinder_settings(method, CageKind::BoundingBox, &mesh);
    let a = LeveledModel::new(&mesh, s.clone()).unwrap();
    let b = LeveledModel::new(&mesh, s.clone()).unwrap();
    let (ma, mb) = (a.cage().reduced().unwrap(), b.cage().reduced().unwrap());
    assert!(std::sync::Arc::ptr_eq(ma, mb));
    // Another material is another model.
    let mut stiffer = s.clone();
    stiffer.fem.young_modulus *= 2.0;
    let c = LeveledModel::new(&mesh, stiffer).unwrap();
    assert!(!std::sync::Arc::ptr_eq(ma, c.cage().reduced().unwrap()));
    // A run-time change of the precise method calibrates the cage again, against the new
    // method: the same model as a body built with it.
    let mut changed = LeveledModel::new(&mesh, s.clone()).unwrap();
    let msd = PreciseMethod::MsdImplicit;
    changed.set_precise_method(&mesh, msd).unwrap();
    let mut msd_settings = s.clone();
    msd_settings.precise = msd;
    let built = LeveledModel::new(&mesh, msd_settings).unwrap();
    assert!(!std::sync::Arc::ptr_eq(
        ma,
        changed.cage().reduced().unwrap()
    ));
    assert!(std::sync::Arc::ptr_eq(
        built.cage().reduced().unwrap(),
        changed.cage().reduced().unwrap()
    ));
    // An MSD whose springs come from the material is another model than one with the
    // constant springs, though every other setting is the same.
    let mut material = s.clone();
    material.precise = msd;
    material.msd_spring_stiffness = soft_tissue_core::msd::SpringStiffness::Material {
        young_modulus: s.fem.young_modulus,
        poisson_ratio: s.fem.poisson_ratio,
    };
    let m = LeveledModel::new(&mesh, material).unwrap();
    let (mm, mc) = (m.cage().reduced().unwrap(), built.cage().reduced().unwrap());
    assert!(!std::sync::Arc::ptr_eq(mm, mc));
    assert_ne!(mm.stiffness(), mc.stiffness());
    let mut paper = s;
    paper.cage_dynamics = CageDynamics::Paper;
    let d = LeveledModel::new(&mesh, paper).unwrap();
    assert!(d.cage().reduced().is_none());
}

#[test]
fn a_poked_cylinder_held_at_a_calibrated_cage_is_nearer_its_precise_shadow_than_with_the_paper_cage()
 {
    // A cylinder with a fixed base pushed sideways at its top and released, held at its box
    // cage beside its precise shadow: the calibrated cage stays nearer the precise method
    // than the paper's cage MSD, on the worst and on the mean surface distance.
    let mesh = asset("cylinder");
    let top = top_nodes(&mesh);
    for method in [PreciseMethod::CorotationalFem, PreciseMethod::MsdImplicit] {
        let mut results = Vec::new();
        for dynamics in [CageDynamics::Calibrated, CageDynamics::Paper] {
            let mut s = cylinder_settings(method, CageKind::BoundingBox, &mesh);
            s.cage_dynamics = dynamics;
            let mut body = LeveledModel::new(&mesh, s).unwrap();
            body.pin(Some(Level::Cage)).unwrap();
            body.set_shadow(&mesh, true).unwrap();
            let mut peak = 0.0f64;
            let mut mean_sum = 0.0;
            let rest = body.node_positions().to_vec();
            let steps = 200;
            for step in 0..steps {
                if step < 40 {
                    for &i in &top {
                        body.add_force(i, Vec3::new(0.5, 0.0, 0.2)).unwrap();
                    }
                }
                body.step(false).unwrap();
                let moved = body
                    .shadow_positions()
                    .unwrap()
                    .iter()
                    .zip(&rest)
                    .map(|(x, r)| (x - r).norm())
                    .fold(0.0, f64::max);
                peak = peak.max(moved);
                mean_sum += body.shadow_error().unwrap().mean;
            }
            let worst = body.shadow_error().unwrap().worst_ratio;
            let mean = mean_sum / steps as f64 / body.smallest_dimension();
            println!(
                "{} {dynamics:?}: worst {:.2} %, mean {:.3} % of the width, shadow peak motion {:.2} %",
                method.name(),
                100.0 * worst,
                100.0 * mean,
                100.0 * peak / body.smallest_dimension()
            );
            // The load moves the precise body visibly.
            assert!(
                peak > 0.005 * body.smallest_dimension(),
                "{method:?}: peak {peak}"
            );
            results.push((worst, mean));
        }
        let (calibrated, paper) = (results[0], results[1]);
        assert!(
            calibrated.0 < paper.0 && calibrated.1 < paper.1,
            "{method:?}: calibrated {calibrated:?}, paper {paper:?}"
        );
    }
}

#[test]
fn a_calibrated_cage_reproduces_a_response_it_can_represent() {
    // A uniform dilation `u = ε (x - c)` is a constant strain: linear tetrahedra represent it
    // exactly, and it is the linear FEM body's static response to a uniform normal traction
    // `t = 3 κ ε n` on its boundary (κ the bulk modulus), whose consistent nodal loads are
    // `t A / 3` on each corner of every boundary triangle, computed here from the surface
    // alone. Green coordinates move the points by the same dilation when the cage is
    // dilated. So the Galerkin projection is exact for this load: the calibrated stiffness
    // applied to the dilated cage, `Kc dV`, equals the generalised load `Σ J_pᵀ f_p`.
    let mesh = asset("liver");
    let mut fem = ORGAN_FEM.params;
    fem.poisson_ratio = 0.3;
    let kappa3 = fem.young_modulus / (1.0 - 2.0 * fem.poisson_ratio);
    let eps = 1e-3;
    for model in [FemModel::Linear, FemModel::Corotational] {
        for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 48 }] {
            let mut s = BodySettings::new(fem, CYLINDER_MSD.params, ORGAN_FEM.dt);
            s.precise = PreciseMethod::fem(model);
            s.cage = cage;
            let body = LeveledModel::new(&mesh, s).unwrap();
            let reduced = body.cage().reduced().unwrap().clone();
            let coords = body.cage().coordinates().clone();
            let verts = body.cage().cage().vertices();
            let c = verts.iter().sum::<Vec3>() / verts.len() as f64;
            // Loads from the traction.
            let x = mesh.positions();
            let mut f = vec![Vec3::zeros(); x.len()];
            for t in mesh.surface().triangles() {
                let [a, b, d] = t.map(|i| x[i as usize]);
                let area_normal = (b - a).cross(&(d - a)) / 2.0;
                for &i in t {
                    f[i as usize] += area_normal * (kappa3 * eps / 3.0);
                }
            }
            let mut load = vec![Vec3::zeros(); verts.len()];
            for (p, fp) in f.iter().enumerate() {
                if fp.norm() > 0.0 {
                    reduced.add_point_force(coords.phi(p), coords.psi(p), *fp, &mut load);
                }
            }
            // The calibrated stiffness on the dilated cage.
            let dv: Vec<f64> = verts
                .iter()
                .flat_map(|v| {
                    let m = (v - c) * eps;
                    [m.x, m.y, m.z]
                })
                .collect();
            let dim = reduced.dim();
            let k = reduced.stiffness();
            let mut worst = 0.0f64;
            let mut size = 0.0f64;
            for r in 0..dim {
                let kv: f64 = (0..dim).map(|q| k[r * dim + q] * dv[q]).sum();
                let l = load[r / 3][r % 3];
                worst = worst.max((kv - l).abs());
                size = size.max(l.abs());
            }
            assert!(
                worst < 1e-3 * size,
                "{model:?} {cage:?}: |Kc dV - J^T f| {worst} against {size}"
            );
        }
    }
}

/// The largest distance between matching points.
fn largest_gap(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max)
}

/// A material changed at run time acts from then on exactly as a body built with it: the
/// same state, stepped under the same loads, gives the same positions, and the change
/// itself moves nothing.
#[test]
fn a_material_changed_at_run_time_acts_as_one_built_with_it() {
    let mesh = asset("cylinder");
    let top = top_nodes(&mesh);
    for method in [PreciseMethod::CorotationalFem, PreciseMethod::MsdImplicit] {
        let soft = cylinder_settings(method, CageKind::BoundingBox, &mesh);
        let mut stiff = soft.clone();
        stiff.fem.young_modulus *= 4.0;
        stiff.msd.stiffness *= 4.0;
        let mut changed = LeveledModel::new(&mesh, soft.clone()).unwrap();
        let mut built = LeveledModel::new(&mesh, stiff.clone()).unwrap();
        changed.raise().unwrap();
        built.raise().unwrap();
        let push = |b: &mut LeveledModel| {
            for &i in &top {
                b.add_force(i, Vec3::new(2.0, 0.0, 0.0)).unwrap();
            }
            b.step(true).unwrap();
        };
        let before = changed.node_positions().to_vec();
        changed
            .set_materials(&mesh, stiff.fem, stiff.msd, stiff.msd_spring_stiffness)
            .unwrap();
        assert_eq!(changed.node_positions(), &before[..], "{method:?}: a jump");
        assert_eq!(changed.settings().fem, stiff.fem);
        for _ in 0..30 {
            push(&mut changed);
            push(&mut built);
        }
        let gap = largest_gap(changed.node_positions(), built.node_positions());
        let moved = largest_gap(built.node_positions(), mesh.positions());
        assert!(
            moved > 1e-3,
            "{method:?}: the push must move the body ({moved})"
        );
        assert!(
            gap < 1e-9 * moved.max(1.0),
            "{method:?}: {gap} from a stiff-built body"
        );
        // A softer body under the same push moves farther.
        let mut plain = LeveledModel::new(&mesh, soft.clone()).unwrap();
        plain.raise().unwrap();
        for _ in 0..30 {
            push(&mut plain);
        }
        let soft_moved = largest_gap(plain.node_positions(), mesh.positions());
        assert!(
            soft_moved > 1.5 * moved,
            "{method:?}: soft {soft_moved}, stiff {moved}"
        );
        // Refused materials leave the body as it was.
        let mut bad = stiff.fem;
        bad.poisson_ratio = 0.7;
        let refused = changed
            .set_materials(&mesh, bad, stiff.msd, stiff.msd_spring_stiffness)
            .unwrap_err();
        assert!(refused.to_string().contains("poisson"), "{refused}");
        assert_eq!(changed.settings().fem, stiff.fem);
    }
}
