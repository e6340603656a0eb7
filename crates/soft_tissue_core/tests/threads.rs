//! The thread count never changes a state, shown where the threads do work.
//!
//! The world splits work in a pool in these places, each with a size below which it runs on
//! one thread (`crates/soft_tissue_core/src/`):
//!
//! - `world/mod.rs`, `step_solvers`: the bodies side by side (more than one body), and a
//!   body's heat field beside its mechanics (`rayon::join`, a body with heat);
//! - `world/contact_stages.rs`, `query_pairs`: the body pairs' contact queries side by side
//!   (more than one pair queried in a step);
//! - `fem/packed.rs`: the corotational element loop in parts of 32 packs of 8 elements (at
//!   least 64 packs: 505 elements or more), and the nodes' corner sums in parts of 1024 nodes
//!   (at least 2048 nodes);
//! - `fem/step.rs`, `update_stale_elements`: the warped-stiffness changes in parts of 128
//!   elements (at least 256 stale elements in a step, so a body of 1024 elements or more:
//!   a step updates at most a quarter of them).
//!
//! Counted with temporary counters in those branches (not kept): in one run of this test on
//! two or three threads, the corner sums and the body and heat tasks ran in all 400 steps,
//! the element loop's parts 1600 times, the pair queries 800 times, and the stiffness
//! updates' parts in 58 steps (the CG model; the prefactored model has no such update); on
//! one thread none of them.
//!
//! The scene: the paper's organs with the liver generated at twice the paper's resolution
//! (2513 nodes, 8321 tetrahedra: every size above), its heat field on, every body held at its
//! precise level, the liver pressed onto its neighbours by `poke-liver` played at 0.7 times
//! its speed (so the tool touches the liver for about 230 steps, from 0.7 s to 3 s), with the
//! cautery on while it presses; 400 steps (4 s). The liver starts with a spin (3 rad/s about
//! the vertical), so that hundreds of its elements turn past the stiffness update's angle in
//! a step.

use std::path::Path;

use soft_tissue_core::Vec3;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::fem::FemModel;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::precision::{Level, PreciseMethod};
use soft_tissue_core::scenario::{MeshSource, Scene};
use soft_tissue_core::world::{Script, SoftTissueWorld};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"))
}

const STEPS: usize = 400;

/// The script's time per world time.
const PACE: f64 = 0.7;

/// The liver's spin at the start, rad/s.
const SPIN: f64 = 3.0;

/// What one run ended in and what happened on the way.
#[derive(Debug, PartialEq)]
struct Run {
    /// `state_hash` after the last step.
    hash: u64,
    /// The liver's temperatures after the last step, then its largest temperature and its
    /// heat content (bits).
    temperatures: Vec<u64>,
    /// `state_hash` before the first step.
    start_hash: u64,
    /// Steps that began with the tool touching a body.
    tool_steps: usize,
    /// Steps that began with two bodies touching.
    body_steps: usize,
    /// Most body pairs whose bounds overlapped in one step.
    most_pairs: usize,
    /// Largest distance of a liver node from where it started, over the run, as a fraction
    /// of the liver's smallest dimension.
    liver_moved: f64,
    /// Heat the cautery put into the liver, J.
    heated: f64,
}

/// The scene above on `threads` threads, every body on `model`.
fn run(threads: usize, model: FemModel) -> Run {
    let mut scene = Scene::paper_organs();
    let liver = scene.bodies.iter_mut().find(|b| b.name == "Liver").unwrap();
    liver.mesh = MeshSource::Generated {
        organ: Organ::Liver,
        resolution: 2.0,
    };
    assert!(liver.heat.is_some(), "the liver has its heat field");
    let mut w = SoftTissueWorld::from_scene(&scene, assets()).unwrap();
    w.set_threads(threads).unwrap();
    assert_eq!(w.threads().count(), threads);
    for b in w.bodies_mut() {
        let mesh = b.mesh().clone();
        let body = b.model_mut();
        body.set_precise_method(&mesh, PreciseMethod::fem(model))
            .unwrap();
        body.pin(Some(Level::Precise)).unwrap();
    }
    let li = w.body_index("Liver").unwrap();
    let mesh = w.bodies()[li].mesh().clone();
    assert!(
        mesh.positions().len() >= 2048 && mesh.tet_count() >= 1024,
        "the liver is large enough for every parallel path: {} nodes, {} tetrahedra",
        mesh.positions().len(),
        mesh.tet_count()
    );
    // A spin about the vertical through the liver's centre: its elements turn by more than
    // the 0.01 rad that makes an element's warped stiffness stale, hundreds in a step.
    {
        let body = w.bodies_mut()[li].model_mut().precise_mut();
        let n = body.positions().len() as f64;
        let centre = body.positions().iter().sum::<Vec3>() / n;
        let spin = Vec3::new(0.0, SPIN, 0.0);
        let x = body.positions().to_vec();
        for (v, p) in body.velocities_mut().iter_mut().zip(&x) {
            *v = spin.cross(&(p - centre));
        }
    }
    let start: Vec<_> = w.bodies()[li].model().node_positions().to_vec();
    let start_heat = w.bodies()[li].heat().unwrap().heat_content();
    let smallest = w.bodies()[li].model().smallest_dimension();
    let start_hash = w.state_hash();
    let s = Script::builtin("poke-liver", &w).unwrap();
    let tool = w.add_tool(Tool::new("tool", s.tool).unwrap());
    let dt = w.config().dt;
    let (mut tool_steps, mut body_steps, mut most_pairs, mut liver_moved) = (0, 0, 0, 0.0f64);
    for k in 0..STEPS {
        let t = PACE * (k + 1) as f64 * dt;
        let (p, a) = s.pose_at(t);
        let tl = &mut w.tools_mut()[tool];
        tl.set_pose(p, a).unwrap();
        // The cautery on while the tool presses (script time 0.5 s to 2 s).
        tl.set_cautery(if (0.5..2.0).contains(&t) { 30.0 } else { 0.0 })
            .unwrap();
        w.step_fixed().unwrap();
        let c = w.contacts();
        tool_steps += usize::from(!c.tool_contacts.is_empty());
        body_steps += usize::from(!c.body_contacts.is_empty());
        most_pairs = most_pairs.max(c.pairs.len());
        let x = w.bodies()[li].model().node_positions();
        let moved = x
            .iter()
            .zip(&start)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max);
        liver_moved = liver_moved.max(moved / smallest);
    }
    let heat = w.bodies()[li].heat().unwrap();
    // The electrode's spot included (the nodes themselves warm little).
    let heated = heat.heat_content() - start_heat;
    let mut temperatures: Vec<u64> = heat.temperatures().iter().map(|t| t.to_bits()).collect();
    temperatures.push(heat.max_temperature().to_bits());
    temperatures.push(heat.heat_content().to_bits());
    Run {
        hash: w.state_hash(),
        temperatures,
        start_hash,
        tool_steps,
        body_steps,
        most_pairs,
        liver_moved,
        heated,
    }
}

/// One, two and three threads (more than this 2-core machine has) end in the same
/// `state_hash` and the same temperatures, with the CG and the prefactored corotational
/// models; and the runs did what the parallel paths need: the tool touched the liver for
/// most of the run, the liver pressed on its neighbours with several pairs overlapping, it
/// moved by a tenth of its size or more, and it warmed.
#[test]
fn one_two_and_three_threads_end_in_the_same_state_under_a_long_contact() {
    for model in [FemModel::Corotational, FemModel::CorotationalPrefactored] {
        let one = run(1, model);
        assert!(
            one.tool_steps >= 200,
            "{model:?}: the tool touched in {} of {STEPS} steps",
            one.tool_steps
        );
        assert!(
            one.body_steps >= 100,
            "{model:?}: bodies touched in {} steps",
            one.body_steps
        );
        assert!(
            one.most_pairs >= 2,
            "{model:?}: at most {} pairs",
            one.most_pairs
        );
        assert!(
            one.liver_moved >= 0.1,
            "{model:?}: the liver moved by {:.4} of its size",
            one.liver_moved
        );
        assert_ne!(
            one.hash, one.start_hash,
            "{model:?}: the state did not move"
        );
        assert!(
            one.heated > 10.0,
            "{model:?}: the liver took {} J",
            one.heated
        );
        for threads in [2, 3] {
            let other = run(threads, model);
            assert_eq!(
                format!("{:016x}", other.hash),
                format!("{:016x}", one.hash),
                "{model:?}: {threads} threads against one"
            );
            assert!(
                other.temperatures == one.temperatures,
                "{model:?}: {threads} threads changed the temperatures"
            );
            assert_eq!(other, one, "{model:?}: {threads} threads against one");
        }
    }
}
