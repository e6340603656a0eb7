//! The levels-of-precision world on the paper's scenes: which bodies rise and fall, switch
//! jumps, no interpenetration, determinism, tools and heat.

use std::path::Path;

use soft_tissue_core::Vec3;
use soft_tissue_core::contact::{Tool, ToolShape};
use soft_tissue_core::heat::HeatParams;
use soft_tissue_core::precision::Level;
use soft_tissue_core::scenario::{PreciseMethod, Scene};
use soft_tissue_core::world::burn::tissue_fraction;
use soft_tissue_core::world::{Script, ScriptAction, SoftTissueWorld, WorldError};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"))
}

fn cylinders() -> SoftTissueWorld {
    let scene = Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem);
    SoftTissueWorld::from_scene(&scene, assets()).unwrap()
}

fn organs() -> SoftTissueWorld {
    SoftTissueWorld::from_scene(&Scene::paper_organs(), assets()).unwrap()
}

/// What happened to each body over a run.
#[derive(Debug, Default, Clone)]
struct History {
    raised: bool,
    worst_jump_ratio: f64,
    switches: u64,
}

/// Runs `script` for `steps` steps, calling `check` after each; returns per-body histories.
fn run(
    world: &mut SoftTissueWorld,
    script: &Script,
    steps: usize,
    mut check: impl FnMut(&SoftTissueWorld),
) -> Vec<History> {
    let tool = world.add_tool(Tool::new("tool", script.tool).unwrap());
    let dt = world.config().dt;
    let mut hist = vec![History::default(); world.bodies().len()];
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        let (p, a) = script.pose_at(t);
        world.tools_mut()[tool].set_pose(p, a).unwrap();
        for e in script.events_in(t - dt, t) {
            let tl = &mut world.tools_mut()[tool];
            e.action.apply(tl).unwrap();
        }
        world.step_fixed().unwrap();
        for (h, b) in hist.iter_mut().zip(world.bodies()) {
            let d = b.diagnostics();
            assert!(d.max_displacement.is_finite(), "{} NaN", b.name());
            h.raised |= d.level == Level::Precise;
            if let Some(s) = d.switched {
                h.worst_jump_ratio = h.worst_jump_ratio.max(s.jump_ratio);
            }
            h.switches = d.switch_count;
        }
        check(world);
    }
    hist
}

fn levels(world: &SoftTissueWorld) -> Vec<Level> {
    world.bodies().iter().map(|b| b.model().level()).collect()
}

#[test]
fn table_ii_poking_a_raises_only_a_and_a_returns_to_its_cage() {
    let mut w = cylinders();
    let s = Script::builtin("poke-a", &w).unwrap();
    let h = run(&mut w, &s, 600, |_| {});
    let (a, b) = (&h[0], &h[1]);
    assert!(a.raised, "A never rose");
    assert!(!b.raised && b.switches == 0, "B left its cage: {b:?}");
    assert_eq!(levels(&w), vec![Level::Cage, Level::Cage], "{h:?}");
    assert!(
        a.worst_jump_ratio < 0.005,
        "A jump {:.4}",
        a.worst_jump_ratio
    );
}

#[test]
fn table_iii_pushing_a_into_b_raises_both_and_both_return() {
    let mut w = cylinders();
    let s = Script::builtin("push-a-into-b", &w).unwrap();
    let h = run(&mut w, &s, 600, |_| {});
    assert!(h[0].raised && h[1].raised, "{h:?}");
    assert_eq!(levels(&w), vec![Level::Cage, Level::Cage], "{h:?}");
    for x in &h {
        assert!(x.worst_jump_ratio < 0.005, "{h:?}");
    }
}

/// Deepest surface vertex of any body inside another, as a fraction of the smaller body's
/// smallest dimension.
fn deepest_overlap(w: &SoftTissueWorld) -> f64 {
    let bodies = w.bodies();
    let mut worst: f64 = 0.0;
    for a in bodies {
        for b in bodies {
            if std::ptr::eq(a, b) {
                continue;
            }
            let scale = a
                .model()
                .smallest_dimension()
                .min(b.model().smallest_dimension());
            for p in a.collider().positions() {
                if let Some(hit) = b.collider().closest(p, 0.2 * scale) {
                    worst = worst.max(-hit.distance / scale);
                }
            }
        }
    }
    worst
}

#[test]
fn organs_poking_the_liver_reaches_its_neighbours_and_all_return() {
    let mut w = organs();
    let rest_overlap = deepest_overlap(&w);
    let s = Script::builtin("poke-liver", &w).unwrap();
    let mut worst_overlap: f64 = 0.0;
    let mut k = 0;
    let h = run(&mut w, &s, 700, |w| {
        k += 1;
        if k % 5 == 0 {
            worst_overlap = worst_overlap.max(deepest_overlap(w));
        }
    });
    let liver = w.body_index("Liver").unwrap();
    assert!(h[liver].raised);
    let neighbours = h
        .iter()
        .enumerate()
        .filter(|(i, x)| *i != liver && x.raised)
        .count();
    assert!(neighbours >= 1, "contact did not propagate: {h:?}");
    assert!(levels(&w).iter().all(|&l| l == Level::Cage), "{h:?}");
    for x in &h {
        assert!(x.worst_jump_ratio < 0.005, "{h:?}");
    }
    // Pressed together, the organs do not pass through each other: no vertex goes deeper
    // than 2 % of the smaller organ (beyond what the meshes overlap at rest).
    assert!(
        worst_overlap < rest_overlap + 0.02,
        "overlap {worst_overlap:.4} (at rest {rest_overlap:.4})"
    );
}

/// At real-mesh sizes the organs' surfaces press on each other at rest (within the contact
/// skin), so a precise body held against a neighbour is pushed every step; the solver alone
/// then moves the nodes at the contact each step. Rest is judged after the contact response,
/// so all of them still come back to their cages.
#[test]
fn organs_at_real_mesh_sizes_pressed_together_return_to_their_cages() {
    let mut w = SoftTissueWorld::from_scene(&Scene::fine_organs(), assets()).unwrap();
    let tets: Vec<usize> = w.bodies().iter().map(|b| b.mesh().tet_count()).collect();
    assert!(tets.iter().all(|&t| (1500..=8000).contains(&t)), "{tets:?}");
    let s = Script::builtin("poke-liver", &w).unwrap();
    let h = run(&mut w, &s, 800, |_| {});
    let liver = w.body_index("Liver").unwrap();
    assert!(h[liver].raised);
    assert!(h.iter().filter(|x| x.raised).count() >= 2, "{h:?}");
    assert!(levels(&w).iter().all(|&l| l == Level::Cage), "{h:?}");
    for x in &h {
        assert!(x.worst_jump_ratio < 0.005, "{h:?}");
    }
}

/// A step that fails on a non-finite position is recovered by a reset: the contact surfaces
/// forget it (their travel is finite again, so pairs keep their candidates) and the next run
/// is the first one again.
#[test]
fn a_reset_after_a_non_finite_state_recovers_contact() {
    let mut w = organs();
    let s = Script::builtin("poke-liver", &w).unwrap();
    let first = run(&mut w, &s, 300, |_| {});
    let liver = w.body_index("Liver").unwrap();
    w.bodies_mut()[liver]
        .model_mut()
        .pin(Some(Level::Precise))
        .unwrap();
    w.bodies_mut()[liver]
        .model_mut()
        .precise_mut()
        .positions_mut()[0]
        .x = f64::NAN;
    assert!(w.step_fixed().is_err());
    w.bodies_mut()[liver]
        .model_mut()
        .pin(None)
        .unwrap_or_default();
    w.reset().unwrap();
    for b in w.bodies() {
        assert!(b.collider().is_finite(), "{}", b.name());
        assert_eq!(b.collider().travel(), 0.0, "{}", b.name());
    }
    // Tools were reset with the world; the same script again gives the same histories.
    let tools = w.tools().len();
    assert_eq!(tools, 1);
    let again = run_existing(&mut w, &s, 300);
    for (a, b) in first.iter().zip(&again) {
        assert_eq!(a.raised, b.raised);
        assert_eq!(a.switches, b.switches);
    }
}

/// [`run`] with the world's first tool (already added).
fn run_existing(world: &mut SoftTissueWorld, script: &Script, steps: usize) -> Vec<History> {
    let dt = world.config().dt;
    let mut hist = vec![History::default(); world.bodies().len()];
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        let (p, a) = script.pose_at(t);
        world.tools_mut()[0].set_pose(p, a).unwrap();
        world.step_fixed().unwrap();
        for (h, b) in hist.iter_mut().zip(world.bodies()) {
            h.raised |= b.diagnostics().level == Level::Precise;
            h.switches = b.diagnostics().switch_count;
        }
    }
    hist
}

fn snapshot(w: &SoftTissueWorld) -> Vec<u64> {
    w.bodies()
        .iter()
        .flat_map(|b| {
            b.model()
                .node_positions()
                .iter()
                .flat_map(|p| p.iter().map(|x| x.to_bits()))
        })
        .chain(w.tools().iter().flat_map(|t| {
            t.reaction_force()
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        }))
        .collect()
}

#[test]
fn runs_are_bit_identical_and_reset_restores_the_start() {
    let mut w = organs();
    let start = snapshot(&w);
    let s = Script::builtin("poke-liver", &w).unwrap();
    run(&mut w, &s, 200, |_| {});
    let first = snapshot(&w);
    w.reset().unwrap();
    assert_eq!(w.step_count(), 0);
    let tools_len = w.tools().len();
    assert_eq!(
        snapshot(&w)[..start.len()],
        start[..],
        "reset did not restore the bodies"
    );
    // Same script again with the same tool (index 0).
    let dt = w.config().dt;
    for k in 0..200 {
        let t = (k + 1) as f64 * dt;
        let (p, a) = s.pose_at(t);
        w.tools_mut()[0].set_pose(p, a).unwrap();
        w.step_fixed().unwrap();
    }
    assert_eq!(tools_len, 1);
    assert_eq!(snapshot(&w), first, "second run differs");
    // A fresh world gives the same run too.
    let mut fresh = organs();
    run(&mut fresh, &s, 200, |_| {});
    assert_eq!(snapshot(&fresh), first);
}

/// The cauterize-liver script with the electrode of `radius` (m; `None`: nodal heating):
/// the world after it, the liver's index, the heat delivered and the heat expected (J).
fn cauterize(radius: Option<f64>) -> (SoftTissueWorld, usize, f64, f64) {
    use soft_tissue_core::contact::Counterpart;
    let mut w = organs();
    let s = Script::builtin("cauterize-liver", &w).unwrap();
    let liver = w.body_index("Liver").unwrap();
    let q0 = w.bodies()[liver].heat().unwrap().heat_content();
    let dt = w.config().dt;
    let mut on_steps = 0;
    let tool = w.add_tool(Tool::new("cautery", s.tool).unwrap());
    w.tools_mut()[tool].set_electrode_radius(radius).unwrap();
    for k in 0..400 {
        let t = (k + 1) as f64 * dt;
        let (p, a) = s.pose_at(t);
        w.tools_mut()[tool].set_pose(p, a).unwrap();
        for e in s.events_in(t - dt, t) {
            if let ScriptAction::Cautery(x) = e.action {
                w.tools_mut()[tool].set_cautery(x).unwrap();
            }
        }
        // The step delivers the power over the points the tool pressed in the last step's
        // contact solve (a normal force on a row of this tool).
        let touching = w.tools()[tool].cautery_watts() > 0.0;
        let delivering = w.contacts().solved_rows().iter().any(|r| {
            matches!(r.other, Counterpart::Tool { tool: t, .. } if t == tool as u32)
                && r.is_contact()
                && r.force.x > 0.0
        });
        w.step_fixed().unwrap();
        if touching && delivering {
            on_steps += 1;
        }
    }
    // Heat that left with carved tissue counts as delivered.
    let h = w.bodies()[liver].heat().unwrap();
    let delivered = h.heat_content() + h.departed_heat() - q0;
    assert!(
        on_steps > 100,
        "the cautery touched for {on_steps} steps only"
    );
    (w, liver, delivered, 30.0 * dt * on_steps as f64)
}

#[test]
fn cautery_burns_a_millimetre_spot_with_its_power() {
    let (w, liver, delivered, expected) = cauterize(Some(1e-3));
    let heat = w.bodies()[liver].heat().unwrap();
    assert!(
        (delivered - expected).abs() < 1e-9 * expected,
        "delivered {delivered} J, expected {expected} J"
    );
    // 30 W into a 1 mm electrode boil the tissue at it, vaporize a crater and coagulate
    // around it; the coarse nodes stay far cooler.
    let v = heat.burn_volumes();
    println!(
        "{} spots, coagulated {:.2} mm^3, charred {:.2} mm^3, vaporized {:.2} mm^3, craters {:?} mm, {:.1} C now",
        heat.spot_count(),
        v.coagulated * 1e9,
        v.charred * 1e9,
        v.vaporized * 1e9,
        heat.crater_radii()
            .iter()
            .map(|r| r * 1e3)
            .collect::<Vec<_>>(),
        heat.max_temperature()
    );
    assert!(v.vaporized > 0.0 && v.charred >= v.vaporized && v.coagulated >= v.charred);
    assert!(heat.crater_radii().iter().any(|&r| r > 1e-3));
    // The first spot (made before any carve, and carried through it) takes the rest mesh's
    // share of tissue about its centre: under 1/2 on the liver's faceted, convex top.
    let places: Vec<_> = heat.spot_places().collect();
    println!("spots (centre, radius m, tissue fraction) {places:.4?}");
    let before = organs();
    let (centre, radius, fraction) = places[0];
    let s = heat.params().meters_per_unit;
    let expected = tissue_fraction(before.bodies()[liver].mesh(), &centre, radius / s);
    assert_eq!(fraction, expected);
    // The tool presses at one place: every spot lies within 2 mm of the first. (In the step
    // a carve lands the last solve's rows name the old mesh's nodes; read against the new
    // mesh they once put a spot 9.5 mm away.)
    for p in &places {
        let d = (p.0 - centre).norm() * s;
        assert!(
            d < 2e-3,
            "a spot {:.1} mm from the first: {places:?}",
            d * 1e3
        );
    }
    assert!(
        (fraction - 0.5).abs() < 0.1 && fraction != 0.5,
        "{places:?}"
    );
    let coarse = heat.temperatures().iter().copied().fold(f64::MIN, f64::max);
    assert!(coarse < 60.0, "hottest node {coarse} C");
    assert_eq!(
        w.bodies()[liver].diagnostics().max_temperature,
        Some(heat.max_temperature())
    );
    // The heat the water took stays counted: the energy above holds with it.
    assert!(heat.subgrid_heat_content() > 0.5 * expected);
    // Bodies without heat parameters pay nothing for heat.
    assert!(w.bodies().iter().filter(|b| b.heat().is_some()).count() == 1);
}

#[test]
fn cautery_without_an_electrode_heats_the_nodes() {
    let (w, liver, delivered, expected) = cauterize(None);
    let heat = w.bodies()[liver].heat().unwrap();
    assert!(
        (delivered - expected).abs() < 1e-6 * expected,
        "delivered {delivered} J, expected {expected} J"
    );
    assert_eq!(heat.spot_count(), 0);
    // The organ meshes are coarse (a node stands for about 3 cm^3 of liver, 11 J/K), so
    // 60 J warm the tip's nodes by a few kelvin rather than burning a millimetre spot; the
    // rise is bounded by the energy over the capacity of the hottest node.
    let (hot, hottest) = heat
        .temperatures()
        .iter()
        .copied()
        .enumerate()
        .fold((0, f64::MIN), |a, b| if b.1 > a.1 { b } else { a });
    assert!(hottest > 40.0, "hottest {hottest} C");
    assert!(hottest - 37.0 < delivered / heat.capacities()[hot]);
    // Above 43 C damage accumulates, below it does not.
    assert!(heat.damage()[hot] > 0.0);
    for (t, d) in heat.temperatures().iter().zip(heat.damage()) {
        if *d > 0.0 {
            assert!(*t > 37.0, "damage at {t} C");
        }
    }
    let _ = HeatParams::liver();
}

#[test]
fn pick_tool_drags_the_surface_and_lets_go() {
    let mut w = organs();
    let liver = w.body_index("Liver").unwrap();
    let top = w.bodies()[liver]
        .collider()
        .positions()
        .iter()
        .copied()
        .fold(Vec3::repeat(f64::MIN), |a, b| if b.y > a.y { b } else { a });
    let r = 0.05;
    let tool = w.add_tool(Tool::new("grasper", ToolShape::Sphere { radius: r }).unwrap());
    w.tools_mut()[tool]
        .set_position(top + Vec3::y() * r)
        .unwrap();
    w.tools_mut()[tool].grab();
    w.step_fixed().unwrap();
    let grips = w.tools()[tool].grips().to_vec();
    assert!(!grips.is_empty(), "nothing grabbed");
    assert!(grips.iter().all(|g| g.body == liver as u32));
    assert_eq!(w.bodies()[liver].model().level(), Level::Precise);
    // Lift by 0.1 over 0.5 s: the held nodes follow the tool, and the tissue pulls it back.
    let lift = 0.1;
    for k in 1..=50 {
        let p = top + Vec3::y() * (r + lift * k as f64 / 50.0);
        w.tools_mut()[tool].set_position(p).unwrap();
        w.step_fixed().unwrap();
    }
    let tp = w.tools()[tool].position();
    let x = w.bodies()[liver].model().node_positions();
    for g in &grips {
        let err = (x[g.node as usize] - (tp + g.offset)).norm();
        assert!(err < 1e-9, "grip off by {err}");
    }
    let f = w.tools()[tool].reaction_force();
    assert!(f.y < 0.0, "the tissue should pull the tool down: {f:?}");
    w.tools_mut()[tool].release();
    w.tools_mut()[tool]
        .set_position(top + Vec3::y() * 2.0)
        .unwrap();
    for _ in 0..800 {
        w.step_fixed().unwrap();
    }
    assert_eq!(w.bodies()[liver].model().level(), Level::Cage);
}

#[test]
fn world_inputs_are_checked() {
    let mut w = organs();
    assert!(w.tools_mut().is_empty());
    let mut t = Tool::new("t", ToolShape::Sphere { radius: 0.1 }).unwrap();
    assert!(t.set_position(Vec3::new(f64::NAN, 0.0, 0.0)).is_err());
    assert!(t.set_pose(Vec3::zeros(), Vec3::zeros()).is_err());
    assert!(t.set_cautery(-1.0).is_err());
    assert!(Tool::new("bad", ToolShape::Sphere { radius: 0.0 }).is_err());
    assert!(matches!(w.step(f64::NAN), Err(WorldError::TimeStep(_))));
    assert!(matches!(
        w.body_index("Heart"),
        Err(WorldError::Unknown { .. })
    ));
    // Frame time is split into fixed steps with the remainder carried.
    let dt = w.config().dt;
    assert_eq!(w.step(2.5 * dt).unwrap(), 2);
    assert_eq!(w.step(0.5 * dt).unwrap(), 1);
    // A scene whose bodies disagree on the step is refused, naming the body.
    let mut scene = Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem);
    if let Some(f) = scene.bodies[1].fem.as_mut() {
        f.dt = 0.01;
    }
    let err = SoftTissueWorld::from_scene(&scene, assets()).unwrap_err();
    assert!(err.to_string().contains("Model B"), "{err}");
}

#[test]
fn resting_bodies_sleep_and_a_push_wakes_them() {
    let mut w = organs();
    let start = snapshot(&w);
    for _ in 0..50 {
        w.step_fixed().unwrap();
    }
    assert!(w.bodies().iter().all(|b| b.model().is_asleep()));
    assert_eq!(snapshot(&w), start, "a resting scene moved");
    // A force on a sleeping cage wakes it and moves it; it falls asleep again at rest.
    let spleen = w.body_index("Spleen").unwrap();
    w.bodies_mut()[spleen]
        .model_mut()
        .add_force(0, Vec3::new(0.0, 5.0, 0.0))
        .unwrap();
    assert!(!w.bodies()[spleen].model().is_asleep());
    w.step_fixed().unwrap();
    assert!(w.bodies()[spleen].diagnostics().max_displacement > 0.0);
    // The paper's cage damping is light (0.3 on 2.5 mass units a vertex, amplitude e-folding
    // in about 17 s): give it 300 s.
    let mut slept_at = None;
    for k in 0..30_000 {
        w.step_fixed().unwrap();
        if w.bodies()[spleen].model().is_asleep() {
            slept_at = Some(k);
            break;
        }
    }
    assert!(slept_at.is_some(), "never settled back");
    assert!(w.bodies()[spleen].diagnostics().max_displacement < 1e-3);
}

#[test]
fn a_collision_between_two_bodies_gains_no_energy() {
    use soft_tissue_core::contact::ContactConfig;
    use soft_tissue_core::material::{FemParams, MsdParams};
    use soft_tissue_core::mesh::generate::block;
    use soft_tissue_core::precision::{BodySettings, PreciseMethod as Method};
    use soft_tissue_core::world::{WorldBody, WorldConfig};
    use std::sync::Arc;
    let dt = 0.005;
    let mut world = SoftTissueWorld::new(WorldConfig {
        dt,
        contact: ContactConfig::for_scale(1.0),
    })
    .unwrap();
    let fem = FemParams {
        young_modulus: 2000.0,
        poisson_ratio: 0.3,
        mass: 1.0,
        damping: 0.0,
    };
    let msd = MsdParams {
        stiffness: 100.0,
        mass: 1.0,
        damping: 0.0,
    };
    for (name, x0) in [("left", -1.05), ("right", 0.05)] {
        let mesh = block(
            Vec3::new(x0, 0.0, 0.0),
            Vec3::new(x0 + 1.0, 1.0, 1.0),
            [4, 4, 4],
        )
        .unwrap();
        let mut s = BodySettings::new(fem, msd, dt);
        s.precise = Method::CorotationalFem;
        let body = WorldBody::new(name, Arc::new(mesh), s, None).unwrap();
        world.add_body(body).unwrap();
    }
    // Both precise for the whole run; the left block flies right at 2 units/s.
    for b in world.bodies_mut() {
        b.model_mut().pin(Some(Level::Precise)).unwrap();
    }
    for v in world.bodies_mut()[0]
        .model_mut()
        .precise_mut()
        .velocities_mut()
    {
        *v = Vec3::new(2.0, 0.0, 0.0);
    }
    let energy = |w: &SoftTissueWorld| -> f64 {
        w.bodies()
            .iter()
            .map(|b| {
                b.model().precise().kinetic_energy() + b.model().fem().unwrap().elastic_energy()
            })
            .sum()
    };
    let momentum = |w: &SoftTissueWorld| -> Vec3 {
        w.bodies()
            .iter()
            .map(|b| {
                let p = b.model().precise();
                p.velocities()
                    .iter()
                    .zip(p.masses())
                    .map(|(v, m)| v * *m)
                    .sum::<Vec3>()
            })
            .sum()
    };
    let e0 = energy(&world);
    let p0 = momentum(&world);
    let mut touched = false;
    for _ in 0..200 {
        world.step_fixed().unwrap();
        touched |= world.bodies()[1].diagnostics().contacts > 0;
        let e = energy(&world);
        assert!(e <= e0 * (1.0 + 1e-9), "energy rose from {e0} to {e}");
    }
    assert!(touched, "the blocks never met");
    // The right block was pushed, and momentum along x is conserved within the
    // implicit-Euler damping (no external force acts).
    let p1 = momentum(&world);
    let right_vx: f64 = {
        let p = world.bodies()[1].model().precise();
        p.velocities().iter().map(|v| v.x).sum::<f64>() / p.velocities().len() as f64
    };
    assert!(right_vx > 0.1, "right block at {right_vx}");
    assert!(
        (p1.x - p0.x).abs() < 0.05 * p0.x,
        "momentum {p0:?} -> {p1:?}"
    );
}

/// The paper's Fig. 5 protocol: the same poke on two copies of the cylinders (box cages),
/// every body held at its cage level in one and at its precise level in the other. The cage
/// level meets the tool with its precise model's compliance and keeps the dent its cage
/// cannot show (`precision::contact`); it must respond (the poked body moves) and stay near
/// the precise run over the first 150 steps: measured 9.45 % of the width with linear FEM,
/// 4.67 % with corotational FEM; allowed the measured value plus 1 and 2 % of the width.
/// With the cage's own compliance in the contact rows (measured by disabling the dent) they
/// were 10.97 % and 27.23 %; before forces reached the cage at all it flew tens of widths
/// away.
#[test]
fn a_body_held_at_its_cage_level_follows_its_precise_twin_under_a_poke() {
    for (method, allowed) in [
        (PreciseMethod::LinearFem, 0.105),
        (PreciseMethod::CorotationalFem, 0.067),
    ] {
        let scene = Scene::paper_cylinders(method, method);
        let mut worlds: Vec<(SoftTissueWorld, Script, usize)> = [Level::Cage, Level::Precise]
            .into_iter()
            .map(|level| {
                let mut w = SoftTissueWorld::from_scene(&scene, assets()).unwrap();
                for b in w.bodies_mut() {
                    b.model_mut().pin(Some(level)).unwrap();
                }
                let s = Script::builtin("poke-a", &w).unwrap();
                let ti = w.add_tool(Tool::new("tool", s.tool).unwrap());
                (w, s, ti)
            })
            .collect();
        let dt = worlds[0].0.config().dt;
        let width = worlds[1].0.bodies()[0].model().smallest_dimension();
        let (mut worst, mut cage_moved, mut precise_moved) = (0.0f64, 0.0f64, 0.0f64);
        for k in 0..150 {
            let t = (k + 1) as f64 * dt;
            for (w, s, ti) in &mut worlds {
                let (p, a) = s.pose_at(t);
                w.tools_mut()[*ti].set_pose(p, a).unwrap();
                w.step_fixed().unwrap();
            }
            let (a, b) = (&worlds[0].0.bodies()[0], &worlds[1].0.bodies()[0]);
            for (p, q) in a
                .model()
                .node_positions()
                .iter()
                .zip(b.model().node_positions())
            {
                worst = worst.max((p - q).norm() / width);
            }
            cage_moved = cage_moved.max(a.diagnostics().max_displacement);
            precise_moved = precise_moved.max(b.diagnostics().max_displacement);
        }
        eprintln!(
            "{method:?}: cage level at most {:.2} % of the width from its precise twin",
            100.0 * worst
        );
        assert!(
            worst < allowed,
            "{method:?}: cage level {:.2} % of the width away",
            100.0 * worst
        );
        assert!(
            cage_moved > 0.25 * precise_moved,
            "{method:?}: the cage level did not respond: {cage_moved} against {precise_moved}"
        );
    }
}

/// Replays are exact: the organs scene poked twice from the same start ends in the same
/// `state_hash`, also with every body on the prefactored corotational model (whose switches
/// up and down run through its own solver); and the two models end in different states.
#[test]
fn replays_end_in_the_same_state_hash() {
    use soft_tissue_core::precision::PreciseMethod;
    let end = |prefactored: bool| {
        let mut w = organs();
        if prefactored {
            for b in w.bodies_mut() {
                let mesh = b.mesh().clone();
                b.model_mut()
                    .set_precise_method(&mesh, PreciseMethod::PrefactoredFem)
                    .unwrap();
            }
        }
        let s = Script::builtin("poke-liver", &w).unwrap();
        run(&mut w, &s, 300, |_| {});
        w.state_hash()
    };
    let (a, b) = (end(false), end(false));
    assert_eq!(a, b, "the same run twice");
    let (c, d) = (end(true), end(true));
    assert_eq!(c, d, "the same prefactored run twice");
    assert_ne!(a, c, "the model changes the result");
}

/// A scene's mesh paths stay inside the assets folder unless the caller allows otherwise: an
/// absolute path and a `..` path are errors naming the body and the path; allowed, they load.
#[test]
fn mesh_paths_stay_inside_the_assets_folder_unless_allowed() {
    use soft_tissue_core::scenario::MeshSource;
    use soft_tissue_core::world::SceneOptions;
    let inside = Scene::paper_organs();
    let absolute = assets().join("meshes/liver.vtk").canonicalize().unwrap();
    let climbing = format!(
        "../{}/meshes/liver.vtk",
        assets()
            .canonicalize()
            .unwrap()
            .file_name()
            .unwrap()
            .to_string_lossy()
    );
    for path in [absolute.display().to_string(), climbing] {
        let mut scene = inside.clone();
        scene.bodies[0].mesh = MeshSource::File(path.clone());
        let e = SoftTissueWorld::from_scene(&scene, assets()).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("Liver") && text.contains(&path) && text.contains("assets folder"),
            "{text}"
        );
        let allowed = SceneOptions {
            allow_outside_assets: true,
        };
        let w = SoftTissueWorld::from_scene_with(&scene, assets(), allowed).unwrap();
        assert_eq!(w.bodies()[0].mesh().tet_count(), 1561);
    }
}
