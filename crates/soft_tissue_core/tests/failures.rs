//! Failure paths of a step: a stage that meets a non-finite value fails with an error that
//! names the body and the stage, leaves the bodies as they were before it, never writes a
//! non-finite surface, and the world then refuses to step until it is resumed or reset. A
//! solve that stops at its iteration cap is reported, and is an error when asked to be.
//!
//! The stages are run one by one here (as the Bevy plugin runs them) so a value can be
//! poisoned between two of them.

use std::path::Path;
use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::contact::{ContactConfig, Tool};
use soft_tissue_core::precision::{Level, PrecisionError};
use soft_tissue_core::scenario::{PreciseMethod, Scene};
use soft_tissue_core::state::NodalModel;
use soft_tissue_core::world::{
    ContactState, Script, SoftTissueWorld, WorldBody, WorldError, detect_contacts, prepare,
    scene_bodies, solve_contacts, step_solvers, switch_precision, writeback,
};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"))
}

/// The paper's two cylinders (corotational FEM), their stages run by hand, and the `poke-a`
/// script (cylinder A poked by a sphere).
struct Staged {
    bodies: Vec<WorldBody>,
    tools: Vec<Tool>,
    contacts: ContactState,
    contact: ContactConfig,
    dt: f64,
    script: Script,
    steps: usize,
}

impl Staged {
    fn cylinders() -> Self {
        let scene = Scene::paper_cylinders(
            PreciseMethod::CorotationalFem,
            PreciseMethod::CorotationalFem,
        );
        let world = SoftTissueWorld::from_scene(&scene, assets()).unwrap();
        let script = Script::builtin("poke-a", &world).unwrap();
        let (config, built) = scene_bodies(&scene, assets()).unwrap();
        let bodies = built
            .into_iter()
            .map(|b| WorldBody::new(b.name, Arc::new(b.mesh), b.settings, b.heat).unwrap())
            .collect();
        Staged {
            bodies,
            tools: vec![Tool::new("tool", script.tool).unwrap()],
            contacts: ContactState::default(),
            contact: config.contact,
            dt: config.dt,
            script,
            steps: 0,
        }
    }

    /// Prepare, detect, switch and solve of the next step.
    fn up_to_solve(&mut self) {
        self.steps += 1;
        let (p, r) = self.script.pose_rotation_at(self.steps as f64 * self.dt);
        self.tools[0].set_pose_rotation(p, r).unwrap();
        prepare(&mut self.bodies, &mut self.tools, self.dt);
        detect_contacts(
            &mut self.bodies,
            &mut self.tools,
            &self.contact,
            &mut self.contacts,
        );
        switch_precision(&mut self.bodies).unwrap();
        step_solvers(&mut self.bodies, &self.tools, &self.contacts).unwrap();
    }

    fn collide(&mut self) -> Result<(), WorldError> {
        solve_contacts(
            &mut self.bodies,
            &mut self.tools,
            &[],
            &self.contact,
            &mut self.contacts,
        )
    }

    /// Whole steps until the tool presses into cylinder A at its precise level.
    fn until_pressing(&mut self) {
        for _ in 0..400 {
            self.up_to_solve();
            self.collide().unwrap();
            writeback(&mut self.bodies).unwrap();
            let pressing = self
                .contacts
                .tool_contacts
                .iter()
                .any(|c| c.body == 0 && c.depth > 0.0);
            if pressing && self.bodies[0].model().level() == Level::Precise {
                return;
            }
        }
        panic!("the tool never pressed into cylinder A");
    }
}

/// Positions and velocities of a body's current level, bit for bit.
fn level_state(b: &WorldBody) -> Vec<u64> {
    let l = b.model();
    let (x, v) = match l.level() {
        Level::Precise => (l.precise().positions(), l.precise().velocities()),
        Level::Cage => (l.cage().msd().positions(), l.cage().msd().velocities()),
    };
    x.iter()
        .chain(v)
        .flat_map(|p| p.iter().map(|c| c.to_bits()))
        .collect()
}

fn surface_bits(b: &WorldBody) -> Vec<u32> {
    b.surface_positions()
        .iter()
        .flat_map(|p| p.map(f32::to_bits))
        .collect()
}

#[test]
fn a_contact_response_that_leaves_a_non_finite_state_is_undone_for_every_body() {
    let mut s = Staged::cylinders();
    s.until_pressing();
    s.up_to_solve();
    // The tool presses into A: the response will move A's contact nodes.
    assert!(
        s.contacts
            .tool_contacts
            .iter()
            .any(|c| c.body == 0 && c.depth > 0.0)
    );
    // A velocity the response does not look at goes bad between the solver and the response.
    s.bodies[0].model_mut().precise_mut().velocities_mut()[0].y = f64::NAN;
    let before: Vec<_> = s.bodies.iter().map(level_state).collect();
    let err = s.collide().unwrap_err();
    match &err {
        WorldError::NonFinite { body, node, stage } => {
            assert_eq!(body, "Model A");
            assert_eq!(*node, 0);
            assert!(stage.starts_with("contact solve"), "{stage}");
        }
        other => panic!("unexpected {other}"),
    }
    let after: Vec<_> = s.bodies.iter().map(level_state).collect();
    assert_eq!(before, after, "the response was not undone");
    // Nothing of the failed stage is pending, and the tool kept no reaction from it.
    assert_eq!(s.tools[0].reaction_force(), Vec3::zeros());
}

#[test]
fn a_non_finite_surface_refuses_the_contact_response_and_is_never_written() {
    let mut s = Staged::cylinders();
    s.until_pressing();
    let written = surface_bits(&s.bodies[0]);
    s.up_to_solve();
    let node = s.bodies[0].surface_nodes()[3] as usize;
    s.bodies[0].model_mut().precise_mut().positions_mut()[node].z = f64::INFINITY;
    let before: Vec<_> = s.bodies.iter().map(level_state).collect();
    let err = s.collide().unwrap_err();
    assert!(
        matches!(&err, WorldError::NonFinite { body, node: n, stage }
            if body == "Model A" && *n == node && stage.contains("input")),
        "{err}"
    );
    assert_eq!(before, s.bodies.iter().map(level_state).collect::<Vec<_>>());
    // The writeback refuses it too: the surface keeps its last finite positions.
    let err = writeback(&mut s.bodies).unwrap_err();
    assert!(
        matches!(&err, WorldError::NonFinite { body, stage, .. } if body == "Model A" && *stage == "writeback"),
        "{err}"
    );
    assert_eq!(surface_bits(&s.bodies[0]), written);
    assert!(s.bodies[0].diagnostics().max_displacement.is_nan());
    assert!(!s.bodies[0].surface_written());
}

#[test]
fn a_switch_from_a_non_finite_cage_is_refused_and_the_body_stays_at_its_cage() {
    let mut s = Staged::cylinders();
    assert_eq!(s.bodies[0].model().level(), Level::Cage);
    s.bodies[0]
        .model_mut()
        .cage_mut()
        .msd_mut()
        .velocities_mut()[2]
        .x = f64::NAN;
    let err = s.bodies[0].model_mut().raise().unwrap_err();
    assert!(
        matches!(
            err,
            PrecisionError::NonFiniteSwitch {
                from: Level::Cage,
                what: "velocity",
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(s.bodies[0].model().level(), Level::Cage);
    assert_eq!(s.bodies[0].model().switch_count(), 0);
    assert!(
        s.bodies[0]
            .model()
            .precise()
            .positions()
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite()))
    );
}

fn organs() -> SoftTissueWorld {
    SoftTissueWorld::from_scene(&Scene::paper_organs(), assets()).unwrap()
}

/// Steps `poke-liver` until the liver is at its precise level; returns the liver's index.
fn poke_until_liver_precise(w: &mut SoftTissueWorld, script: &Script) -> usize {
    if w.tools().is_empty() {
        w.add_tool(Tool::new("tool", script.tool).unwrap());
    }
    let liver = w.body_index("Liver").unwrap();
    for _ in 0..400 {
        let (p, a) = script.pose_at(w.time() + w.config().dt);
        w.tools_mut()[0].set_pose(p, a).unwrap();
        w.step_fixed().unwrap();
        if w.bodies()[liver].model().level() == Level::Precise {
            return liver;
        }
    }
    panic!("the liver never rose");
}

#[test]
fn a_failed_solver_step_leaves_its_body_halts_the_world_until_resumed_or_reset() {
    let mut w = organs();
    let script = Script::builtin("poke-liver", &w).unwrap();
    let liver = poke_until_liver_precise(&mut w, &script);
    let before = level_state(&w.bodies()[liver]);
    let surface = surface_bits(&w.bodies()[liver]);
    let steps = w.step_count();
    w.bodies_mut()[liver]
        .model_mut()
        .add_force(5, Vec3::new(0.0, f64::NAN, 0.0))
        .unwrap();
    let err = w.step_fixed().unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(&err, WorldError::Precision { body, .. } if body == "Liver"),
        "{text}"
    );
    assert!(
        text.contains("external force") && text.contains("node 5"),
        "{text}"
    );
    assert_eq!(level_state(&w.bodies()[liver]), before);
    assert_eq!(surface_bits(&w.bodies()[liver]), surface);
    assert_eq!(w.step_count(), steps);
    // Stopped: no stage runs until the world is resumed or reset.
    assert!(matches!(w.step_fixed(), Err(WorldError::Halted(_))));
    assert!(w.halted().is_some_and(|h| h.contains("Liver")));
    assert_eq!(w.step_count(), steps);
    // Resumed with the cause still there, it fails again in the same way.
    w.resume();
    assert!(matches!(w.step_fixed(), Err(WorldError::Precision { .. })));
    w.reset().unwrap();
    assert!(w.halted().is_none());
    poke_until_liver_precise(&mut w, &script);
}

#[test]
fn a_solve_stopped_at_its_cap_is_counted_and_is_an_error_when_convergence_is_required() {
    let mut w = organs();
    let script = Script::builtin("poke-liver", &w).unwrap();
    let liver = w.body_index("Liver").unwrap();
    // Corotational FEM (the organs' method) with a CG allowed one iteration at 1e-12: it
    // cannot meet its tolerance while the poke deforms the liver.
    w.bodies_mut()[liver]
        .model_mut()
        .set_precise_cg(1e-12, 1)
        .unwrap();
    poke_until_liver_precise(&mut w, &script);
    let counted = w.bodies()[liver].diagnostics().unconverged_solves;
    // (While no element has turned enough to update the matrix, the preconditioner is the
    // exact inverse and one iteration converges; the poke then turns some.)
    let mut seen = 0;
    for _ in 0..40 {
        let (p, a) = script.pose_at(w.time() + w.config().dt);
        w.tools_mut()[0].set_pose(p, a).unwrap();
        w.step_fixed().unwrap();
        let cg = w.bodies()[liver].diagnostics().cg.expect("a CG step");
        assert_eq!(cg.iterations, 1);
        seen += u64::from(!cg.converged);
    }
    assert!(seen >= 10, "only {seen} of 40 steps stopped at the cap");
    let d = *w.bodies()[liver].diagnostics();
    assert_eq!(d.unconverged_solves - counted, seen);

    // Required to converge: the step is an error naming the body and the residual, and the
    // liver is left as it was.
    w.bodies_mut()[liver]
        .model_mut()
        .set_precise_cg_must_converge(true);
    let mut failed = None;
    for _ in 0..40 {
        let before = level_state(&w.bodies()[liver]);
        let (p, a) = script.pose_at(w.time() + w.config().dt);
        w.tools_mut()[0].set_pose(p, a).unwrap();
        if let Err(e) = w.step_fixed() {
            failed = Some((e, before));
            break;
        }
    }
    let (err, before) = failed.expect("no step stopped at its cap");
    let text = err.to_string();
    assert!(
        text.contains("Liver") && text.contains("did not converge"),
        "{text}"
    );
    assert_eq!(level_state(&w.bodies()[liver]), before);
    // With iterations enough, the same requirement is met and the world carries on.
    w.bodies_mut()[liver]
        .model_mut()
        .set_precise_cg(1e-6, 500)
        .unwrap();
    w.resume();
    w.step_fixed().unwrap();
    assert!(w.bodies()[liver].diagnostics().cg.unwrap().converged);
}

#[test]
fn every_bad_scene_value_is_refused_naming_the_body_and_the_field() {
    let good = std::fs::read_to_string(assets().join("scenes/organs.scene.ron")).unwrap();
    let generated = good.replacen(
        "File(\"meshes/liver.vtk\")",
        "Generated(organ: Liver, resolution: 1.0)",
        1,
    );
    // (what the file says instead, the text naming the field)
    let cases: Vec<(String, &str)> = vec![
        (
            good.replacen("young_modulus: 140.0", "young_modulus: -140.0", 1),
            "young_modulus",
        ),
        (
            good.replacen("young_modulus: 140.0", "young_modulus: NaN", 1),
            "young_modulus",
        ),
        (
            good.replacen("poisson_ratio: 0.23", "poisson_ratio: 0.5", 1),
            "poisson_ratio",
        ),
        (good.replacen("dt: 0.01", "dt: 0.0", 1), "dt"),
        (good.replacen("mass: 10.0", "mass: inf", 1), "mass"),
        (
            good.replacen("damping: 10.0", "damping: -1.0", 1),
            "damping",
        ),
        (
            good.replacen("stiffness: 50.0", "stiffness: NaN", 1),
            "stiffness",
        ),
        (
            good.replacen("meshes/liver.vtk", "meshes/no-such-liver.vtk", 1),
            "no-such-liver.vtk",
        ),
        (
            good.replacen("meshes/liver.vtk", "../../etc/liver.vtk", 1),
            "leaves the assets folder",
        ),
        (
            good.replacen(
                "translation: (0.0, 0.0, 0.0)",
                "translation: (NaN, 0.0, 0.0)",
                1,
            ),
            "translation",
        ),
        (
            generated.replacen("resolution: 1.0", "resolution: 1e19", 1),
            "resolution",
        ),
        (
            generated.replacen("resolution: 1.0", "resolution: 0.0", 1),
            "resolution",
        ),
        (
            generated.replacen("resolution: 1.0", "resolution: NaN", 1),
            "resolution",
        ),
    ];
    for (text, field) in cases {
        assert_ne!(text, good, "the case for {field} changed nothing");
        let result = Scene::from_ron(&text, "bad.scene.ron")
            .map_err(|e| e.to_string())
            .and_then(|scene| scene_bodies(&scene, assets()).map_err(|e| e.to_string()));
        let message = match result {
            Ok(_) => panic!("a bad {field} was accepted"),
            Err(e) => e,
        };
        assert!(
            message.contains("Liver") && message.contains(field),
            "{field}: {message}"
        );
    }
}
