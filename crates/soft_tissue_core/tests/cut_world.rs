//! Cutting bodies while they simulate: a blade tool's sweep cuts, pieces become bodies,
//! and the state (positions, velocities, temperatures, damage, supports, masses, grips)
//! carries over. Checked against free fall, conservation and linear fields.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::{ContactConfig, Tool, ToolShape};
use soft_tissue_core::heat::{HeatBoundary, HeatParams};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::cut::{CutOptions, CutTriangle};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, Level, PreciseMethod};
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig, WorldError};

const DT: f64 = 0.005;
const G: f64 = 9.81;

/// A bar 2 x 10 x 2 cm of soft tissue (1000 kg/m^3), fixed at its lowest layer (y = 0)
/// with gravity along +y: it hangs from its support. `damping` is the rate (1/s) of the
/// mass-proportional damping, which slows a rigid motion too.
fn hanging_bar(method: PreciseMethod, damping: f64) -> WorldBody {
    let mesh = block(Vec3::zeros(), Vec3::new(0.02, 0.1, 0.02), [2, 10, 2]).unwrap();
    let fem = FemParams {
        young_modulus: 2.0e4,
        poisson_ratio: 0.4,
        mass: 1000.0 * mesh.volume(),
        damping,
    };
    let msd = MsdParams {
        stiffness: 200.0,
        mass: 1000.0 * mesh.volume(),
        // The MSD's damping is per node against the ground (a drag): the same rate.
        damping: damping * 1000.0 * mesh.volume() / mesh.node_count() as f64,
    };
    let mut s = BodySettings::new(fem, msd, DT);
    s.precise = method;
    s.gravity = Vec3::new(0.0, G, 0.0);
    s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
    WorldBody::new("bar", Arc::new(mesh), s, None).unwrap()
}

fn world_with(body: WorldBody) -> SoftTissueWorld {
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt: DT,
        contact: ContactConfig::for_scale(0.1),
    })
    .unwrap();
    w.add_body(body).unwrap();
    w
}

/// A scalpel edge along z across the bar at height `y`, moved across it in x over one step
/// with cutting on; returns the step the cut happened in.
fn sweep_blade(w: &mut SoftTissueWorld, y: f64) {
    let mut blade = Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap();
    blade
        .set_pose(Vec3::new(-0.01, y, -0.02), Vec3::z())
        .unwrap();
    let t = w.add_tool(blade);
    w.step_fixed().unwrap();
    w.tools_mut()[t].set_cutting(true).unwrap();
    w.tools_mut()[t]
        .set_pose(Vec3::new(0.04, y, -0.02), Vec3::z())
        .unwrap();
    w.step_fixed().unwrap();
    w.tools_mut()[t].set_cutting(false).unwrap();
}

/// Blade tool `t` moved across the hanging bar at mid-height over 30 steps (1.7 mm a step),
/// cutting.
fn stroke_through_bar(w: &mut SoftTissueWorld, t: usize) {
    let y = 0.055;
    w.tools_mut()[t]
        .set_pose(Vec3::new(-0.01, y, -0.02), Vec3::z())
        .unwrap();
    w.step_fixed().unwrap();
    w.tools_mut()[t].set_cutting(true).unwrap();
    for k in 1..=30 {
        let x = -0.01 + 0.05 * k as f64 / 30.0;
        w.tools_mut()[t]
            .set_pose(Vec3::new(x, y, -0.02), Vec3::z())
            .unwrap();
        w.step_fixed().unwrap();
    }
}

/// Mass-weighted centre of a body's nodes.
fn centre(b: &WorldBody) -> Vec3 {
    let m = b.model().precise().masses();
    let x = b.model().node_positions();
    let total: f64 = m.iter().sum();
    x.iter().zip(m).map(|(x, m)| x * *m).sum::<Vec3>() / total
}

/// The acceleration of body `i`'s centre over the next 40 steps (second difference over two
/// spans of 20).
fn acceleration(w: &mut SoftTissueWorld, i: usize) -> Vec3 {
    let n = 20;
    let mut c = Vec::new();
    for k in 0..=2 * n {
        if k % n == 0 {
            c.push(centre(&w.bodies()[i]));
        }
        if k < 2 * n {
            w.step_fixed().unwrap();
        }
    }
    let span = n as f64 * DT;
    (c[2] - 2.0 * c[1] + c[0]) / (span * span)
}

fn total_mass(b: &WorldBody) -> f64 {
    b.model().precise().masses().iter().sum()
}

#[test]
fn a_hanging_bar_cut_through_falls_in_two_the_lower_piece_at_g() {
    for method in [
        PreciseMethod::CorotationalFem,
        PreciseMethod::LinearFem,
        PreciseMethod::PrefactoredFem,
        PreciseMethod::MsdImplicit,
        PreciseMethod::MsdBdf2,
    ] {
        let body = hanging_bar(method, 0.0);
        let mass = total_mass(&body);
        let volume = body.mesh().volume();
        let nodes = body.mesh().node_count();
        let mut w = world_with(body);
        sweep_blade(&mut w, 0.055);
        assert_eq!(w.bodies().len(), 2, "{method:?}: the cut makes two bodies");
        let (upper, lower) = (&w.bodies()[0], &w.bodies()[1]);
        assert_eq!(upper.name(), "bar");
        assert_eq!(lower.name(), "bar.1");
        let pieces_volume = upper.mesh().volume() + lower.mesh().volume();
        assert!(
            ((pieces_volume - volume) / volume).abs() < 1e-9,
            "{method:?}: volume {pieces_volume} of {volume}"
        );
        let pieces_mass = total_mass(upper) + total_mass(lower);
        assert!(
            ((pieces_mass - mass) / mass).abs() < 1e-9,
            "{method:?}: mass {pieces_mass} of {mass}"
        );
        assert!(
            lower
                .model()
                .precise()
                .fixed()
                .iter()
                .all(|f| !f.iter().any(|&a| a)),
            "{method:?}: the loose piece holds no support"
        );
        assert!(upper.model().precise().fixed().iter().any(|f| f[1]));
        for b in w.bodies() {
            let r = b.cut_record().unwrap();
            assert!(r.closed, "{method:?}: {} has a closed surface", b.name());
            // Made within the step: nothing waited for.
            assert_eq!(r.wait_us, 0.0);
            assert!(
                r.area > 0.9 * 0.02 * 0.02,
                "{method:?}: cut area {}",
                r.area
            );
            assert_eq!(b.model().level(), Level::Precise);
        }
        // Free fall of the loose piece: its centre accelerates at g (no damping; the
        // internal forces sum to zero).
        let a = acceleration(&mut w, 1);
        assert!(
            (a.y - G).abs() < 0.02 * G && a.x.abs() < 0.02 * G && a.z.abs() < 0.02 * G,
            "{method:?}: the loose piece accelerates at {a:?}, not g along +y"
        );
        // The piece on the support comes to rest and drops to its cage (with damping, which
        // BDF2 otherwise all but lacks).
        let mut w = world_with(hanging_bar(method, 5.0));
        sweep_blade(&mut w, 0.055);
        let mut rested = false;
        for _ in 0..2000 {
            w.step_fixed().unwrap();
            if w.bodies()[0].model().level() == Level::Cage {
                rested = true;
                break;
            }
        }
        assert!(
            rested,
            "{method:?}: the supported piece came to rest on its cage"
        );
        // `reset` restores the uncut body.
        w.reset().unwrap();
        assert_eq!(w.bodies().len(), 1);
        assert_eq!(w.bodies()[0].mesh().node_count(), nodes);
        assert!(w.bodies()[0].cut_record().is_none());
    }
}

#[test]
fn a_cut_carries_a_linear_temperature_and_damage_field_exactly() {
    let mesh = block(Vec3::zeros(), Vec3::new(0.04, 0.02, 0.02), [4, 2, 2]).unwrap();
    let fem = FemParams {
        young_modulus: 1.0e4,
        poisson_ratio: 0.45,
        mass: 1000.0 * mesh.volume(),
        damping: 1.0,
    };
    let s = BodySettings::new(
        fem,
        MsdParams {
            stiffness: 100.0,
            mass: fem.mass,
            damping: 0.1,
        },
        DT,
    );
    let heat = HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    };
    let mut body = WorldBody::new(
        "slab",
        Arc::new(mesh),
        s,
        Some((heat, HeatBoundary::insulated())),
    )
    .unwrap();
    let temperature = |p: &Vec3| 37.0 + 100.0 * p.x + 50.0 * p.y - 20.0 * p.z;
    let damage = |p: &Vec3| 2.0 * p.x + p.z;
    let rest = body.mesh().positions().to_vec();
    let h = body.heat_mut().unwrap();
    h.set_temperatures(|i| temperature(&rest[i])).unwrap();
    h.set_damage(|i| damage(&rest[i])).unwrap();
    // A slanted cut through the whole slab.
    let blade = [
        CutTriangle {
            corners: [
                Vec3::new(0.013, -0.01, -0.01),
                Vec3::new(0.027, 0.03, -0.01),
                Vec3::new(0.027, 0.03, 0.03),
            ],
        },
        CutTriangle {
            corners: [
                Vec3::new(0.013, -0.01, -0.01),
                Vec3::new(0.027, 0.03, 0.03),
                Vec3::new(0.013, -0.01, 0.03),
            ],
        },
    ];
    let cut = body
        .cut(&blade, &Default::default())
        .unwrap()
        .expect("the blade crosses the slab");
    assert!(cut.separated > 0 && cut.bisected > 0);
    assert_eq!(cut.pieces.len(), 1);
    for b in std::iter::once(&body).chain(&cut.pieces) {
        let h = b.heat().unwrap();
        for (i, p) in b.mesh().positions().iter().enumerate() {
            assert!((h.temperatures()[i] - temperature(p)).abs() < 1e-9);
            assert!((h.damage()[i] - damage(p).max(0.0)).abs() < 1e-9);
        }
    }
}

#[test]
fn a_grip_follows_the_node_it_held_into_its_piece() {
    let body = hanging_bar(PreciseMethod::CorotationalFem, 1.0);
    let mut w = world_with(body);
    // A probe grabs the free end (y = 0.1 at rest, hanging a little further).
    let tip = w.bodies()[0]
        .model()
        .node_positions()
        .iter()
        .copied()
        .fold(Vec3::zeros(), |a, p| if p.y > a.y { p } else { a });
    let mut probe = Tool::new("probe", ToolShape::Sphere { radius: 0.004 }).unwrap();
    probe
        .set_pose(tip + Vec3::new(0.0, 0.003, 0.0), Vec3::y())
        .unwrap();
    let p = w.add_tool(probe);
    w.tools_mut()[p].grab();
    w.step_fixed().unwrap();
    let held = w.tools()[p].grips().len();
    assert!(held > 0, "the probe holds the end");
    sweep_blade(&mut w, 0.055);
    assert_eq!(w.bodies().len(), 2);
    let grips = w.tools()[p].grips();
    assert_eq!(grips.len(), held, "every grip kept");
    for g in grips {
        assert_eq!(g.body, 1, "the grips moved to the loose piece");
        let b = &w.bodies()[1];
        assert_eq!(b.surface_nodes()[g.vertex as usize], g.node);
    }
    // Held by the probe, the loose piece does not fall.
    for _ in 0..100 {
        w.step_fixed().unwrap();
    }
    let lowest_free = w.bodies()[1]
        .model()
        .node_positions()
        .iter()
        .map(|p| p.y)
        .fold(f64::INFINITY, f64::min);
    assert!(
        lowest_free < 0.07,
        "the held piece hangs from the probe ({lowest_free})"
    );
}

#[test]
fn a_bad_blade_is_refused_by_name_and_the_body_is_unchanged() {
    let body = hanging_bar(PreciseMethod::CorotationalFem, 1.0);
    let nodes = body.mesh().node_count();
    let mut w = world_with(body);
    let nan = [CutTriangle {
        corners: [
            Vec3::new(f64::NAN, 0.05, 0.0),
            Vec3::new(0.03, 0.05, 0.0),
            Vec3::new(0.03, 0.05, 0.03),
        ],
    }];
    match w.cut_body(0, &nan) {
        Err(WorldError::Cut { body, reason }) => {
            assert_eq!(body.name, "bar");
            assert!(reason.contains("blade triangle 0"), "{reason}");
        }
        other => panic!("a NaN blade must be refused, got {other:?}"),
    }
    assert_eq!(w.bodies()[0].mesh().node_count(), nodes);
    assert!(matches!(
        w.cut_body(7, &nan),
        Err(WorldError::Unknown { kind: "body", .. })
    ));
    // A blade away from the body changes nothing.
    let away = [CutTriangle {
        corners: [
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.1, 1.0, 1.0),
            Vec3::new(1.1, 1.1, 1.0),
        ],
    }];
    assert!(w.cut_body(0, &away).unwrap().is_empty());
    let mut t = Tool::new("probe", ToolShape::Sphere { radius: 0.01 }).unwrap();
    assert!(t.set_cutting(true).is_err(), "only a blade cuts");
    assert!(Tool::new("edge", ToolShape::Blade { length: -1.0 }).is_err());
}

/// An incision grown step by step (each step's strip bisects, the stroke so far is where
/// faces separate) through tissue that moves between the steps cuts as one stroke: the same
/// faces as one cut at once, two pieces.
#[test]
fn an_incision_grown_over_steps_through_moving_tissue_cuts_as_one_stroke() {
    use soft_tissue_core::mesh::cut::{CutHistory, cut, recut_within};
    use soft_tissue_core::world::Incision;
    let start = block(Vec3::zeros(), Vec3::new(0.02, 0.1, 0.02), [2, 10, 2]).unwrap();
    let y = 0.055;
    let edge = |x: f64| (Vec3::new(x, y, -0.02), Vec3::new(x, y, 0.04));
    let whole = soft_tissue_core::world::swept_triangles(
        edge(-0.01).0,
        edge(-0.01).1,
        edge(0.04).0,
        edge(0.04).1,
    );
    let at_once = cut(&start, &whole, &Default::default()).unwrap();
    for stretch in [0.0, 0.002] {
        let mut mesh = start.clone();
        let mut history: Option<CutHistory> = None;
        let mut incision = Incision::new(edge(-0.01));
        let mut separated = 0;
        for k in 1..=30 {
            let stroke = incision.advance(edge(-0.01 + 0.05 * k as f64 / 30.0));
            let (strip, mark) = incision.pending(0);
            let c = recut_within(
                &mesh,
                history.as_ref(),
                &strip,
                &stroke,
                incision.id(),
                &Default::default(),
            )
            .unwrap();
            // The worlds' rule: a strip that crossed without separating stays pending.
            if c.separated > 0 {
                separated += c.separated;
                mesh = c.mesh;
                history = Some(c.history);
                incision.consumed(0, mark);
            } else if c.bisected == 0 {
                incision.consumed(0, mark);
            }
            // The tissue moves between the steps: a stretch along y.
            let moved = mesh
                .positions()
                .iter()
                .map(|p| Vec3::new(p.x, p.y * (1.0 + stretch), p.z))
                .collect();
            let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
            mesh = soft_tissue_core::mesh::TetMesh::new(moved, tets).unwrap();
        }
        assert_eq!(mesh.component_count(), 2, "stretch {stretch}");
        assert_eq!(separated, at_once.separated, "stretch {stretch}");
    }
}

/// A scalpel moved through a hanging bar over 30 steps (a strip of a few millimetres a
/// step, narrower than an element) cuts it in two, the whole section.
#[test]
fn a_blade_moved_through_a_hanging_bar_step_by_step_cuts_it_in_two() {
    let mut w = world_with(hanging_bar(PreciseMethod::CorotationalFem, 1.0));
    let t = w.add_tool(Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap());
    stroke_through_bar(&mut w, t);
    assert_eq!(w.bodies().len(), 2);
    for b in w.bodies() {
        let r = b.cut_record().unwrap();
        assert!(r.closed);
        // The section, 2 x 2 cm, on each piece.
        assert!(
            (r.area - 4e-4).abs() < 0.05 * 4e-4,
            "{} cut area {}",
            b.name(),
            r.area
        );
    }
}

/// The state after a blade cut a body (all its pieces) every step, on one thread and on
/// two, and again after a reset: bit for bit the same; also with the cuts prepared on
/// threads of their own (whenever those threads ran, the cut lands at its step).
#[test]
fn cutting_is_bit_identical_on_one_and_two_threads_and_after_a_reset() {
    let run = |w: &mut SoftTissueWorld, t: usize| {
        stroke_through_bar(w, t);
        w.tools_mut()[t].set_cutting(false).unwrap();
        for _ in 0..100 {
            w.step_fixed().unwrap();
        }
        assert_eq!(w.bodies().len(), 2);
        w.state_hash()
    };
    for background_steps in [0, 3] {
        let mut hashes = Vec::new();
        for threads in [1, 2] {
            let mut w = world_with(hanging_bar(PreciseMethod::CorotationalFem, 1.0));
            w.set_threads(threads).unwrap();
            w.set_cut_options(CutOptions {
                background_steps,
                ..CutOptions::default()
            })
            .unwrap();
            let t = w.add_tool(Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap());
            hashes.push(run(&mut w, t));
            // In the background on two threads, the cuts took a thread of the world's pool;
            // on one, or within the step, none.
            let lent = w.threads().lends();
            assert_eq!(
                lent > 0,
                background_steps > 0 && threads > 1,
                "{lent} cuts lent a pool thread"
            );
            w.reset().unwrap();
            assert_eq!(w.bodies().len(), 1);
            hashes.push(run(&mut w, t));
        }
        assert!(
            hashes.iter().all(|h| *h == hashes[0]),
            "background {background_steps}: {hashes:x?}"
        );
    }
}

/// A cut prepared in the background lands exactly `background_steps` steps after the
/// blade crossed the body; meanwhile the body steps on uncut. It then holds the state of
/// the step it landed in (the bar, set moving once the cut began, is cut where it moved
/// to), and the loose piece falls at g, with the mass and volume of the body.
#[test]
fn a_cut_prepared_in_the_background_lands_steps_later_in_the_state_then() {
    let body = hanging_bar(PreciseMethod::CorotationalFem, 0.0);
    let (mass, volume) = (total_mass(&body), body.mesh().volume());
    let mut w = world_with(body);
    w.set_cut_options(CutOptions {
        background_steps: 4,
        ..CutOptions::default()
    })
    .unwrap();
    sweep_blade(&mut w, 0.055);
    // Once the cut began, the bar is set moving sideways (a bar at rest would hand the same
    // state at any step).
    let v = 0.2;
    for vel in w.bodies_mut()[0]
        .model_mut()
        .precise_mut()
        .velocities_mut()
        .iter_mut()
    {
        vel.x = v;
    }
    // The sweep's step began the cut; three steps after it, it is still one body.
    for k in 1..4 {
        w.step_fixed().unwrap();
        assert_eq!(w.bodies().len(), 1, "landed early, {k} steps after");
    }
    let before: Vec<(Vec3, Vec3)> = {
        let b = &w.bodies()[0];
        b.mesh()
            .positions()
            .iter()
            .copied()
            .zip(b.model().node_positions().iter().copied())
            .collect()
    };
    w.step_fixed().unwrap();
    assert_eq!(w.bodies().len(), 2, "landed 4 steps after the sweep");
    // The step's wait is the landing's (one landing).
    let waited = w.stage_times().cut_wait_us;
    assert_eq!(waited, w.bodies()[0].cut_record().unwrap().wait_us);
    assert_eq!(waited, w.bodies()[0].landing_wait_us());
    // The pieces hold the state of the step the cut landed in: each node of the loose piece
    // that was a node of the bar moved by one step from where it was, not by four.
    let lower = &w.bodies()[1];
    let mut matched = 0;
    for (rest, now) in lower
        .mesh()
        .positions()
        .iter()
        .zip(lower.model().node_positions())
    {
        if let Some((_, was)) = before.iter().find(|(r, _)| r == rest) {
            matched += 1;
            assert!(
                (now - was).norm() < 1.5 * v * DT,
                "a node moved {} in the landing step (one step at {v} is {})",
                (now - was).norm(),
                v * DT
            );
        }
    }
    assert!(
        matched > 10,
        "{matched} nodes of the bar found in the loose piece"
    );
    let (upper, lower) = (&w.bodies()[0], &w.bodies()[1]);
    let m = total_mass(upper) + total_mass(lower);
    let v = upper.mesh().volume() + lower.mesh().volume();
    assert!(((m - mass) / mass).abs() < 1e-9 && ((v - volume) / volume).abs() < 1e-9);
    let r = lower.cut_record().unwrap();
    assert!(r.closed && r.mesh_us > 0.0 && r.build_us > 0.0, "{r:?}");
    // Whatever the landing waited for its thread is part of what it spent.
    assert!(r.wait_us >= 0.0 && r.wait_us <= r.land_us, "{r:?}");
    let a = acceleration(&mut w, 1);
    assert!(
        (a.y - G).abs() < 0.02 * G && a.x.abs() < 0.02 * G && a.z.abs() < 0.02 * G,
        "the loose piece accelerates at {a:?}, not g along +y"
    );
}

/// With `land_when_ready` a cut due before its thread is done lands in a later step instead
/// of the due step waiting for it: no landing waits, however early it is due, and the cut
/// still separates the bar (mass and volume kept).
#[test]
fn a_cut_that_lands_when_ready_never_waits_for_its_thread() {
    let body = hanging_bar(PreciseMethod::CorotationalFem, 0.0);
    let (mass, volume) = (total_mass(&body), body.mesh().volume());
    let mut w = world_with(body);
    w.set_cut_options(CutOptions {
        background_steps: 1,
        land_when_ready: true,
        ..CutOptions::default()
    })
    .unwrap();
    sweep_blade(&mut w, 0.055);
    let mut steps = 0;
    while w.cuts_in_flight() > 0 {
        w.step_fixed().unwrap();
        assert_eq!(
            w.stage_times().cut_wait_us,
            0.0,
            "a step waited for the cut"
        );
        steps += 1;
        assert!(steps < 100_000, "the cut never landed");
    }
    assert_eq!(w.bodies().len(), 2, "landed after {steps} more steps");
    for b in w.bodies() {
        let r = b.cut_record().unwrap();
        assert_eq!(r.wait_us, 0.0, "a landing waited {} us", r.wait_us);
        assert!(r.closed);
    }
    let m = total_mass(&w.bodies()[0]) + total_mass(&w.bodies()[1]);
    let v = w.bodies()[0].mesh().volume() + w.bodies()[1].mesh().volume();
    assert!(((m - mass) / mass).abs() < 1e-9 && ((v - volume) / volume).abs() < 1e-9);
}

/// A blade that nicks the bar (crossing it without separating anything), withdraws and
/// goes around it with cutting still on cuts nothing it did not pass through: the strips
/// swept step by step bisect, not a straight sweep from the nick to where the blade is.
#[test]
fn a_blade_that_nicks_and_goes_around_cuts_nothing_it_did_not_pass() {
    let mut w = world_with(hanging_bar(PreciseMethod::CorotationalFem, 1.0));
    let y = 0.055;
    let t = w.add_tool(Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap());
    let go = |w: &mut SoftTissueWorld, x: f64, z: f64| {
        w.tools_mut()[t]
            .set_pose(Vec3::new(x, y, z), Vec3::z())
            .unwrap();
        w.step_fixed().unwrap();
    };
    go(&mut w, -0.01, -0.02);
    w.tools_mut()[t].set_cutting(true).unwrap();
    // In by 3 mm (an element is 1 cm) and out again.
    for x in [-0.005, 0.0, 0.003, 0.0, -0.01] {
        go(&mut w, x, -0.02);
    }
    // Slide along the edge away from the bar, pass it beyond its side, slide back.
    for (x, z) in [
        (-0.01, -0.1),
        (0.01, -0.1),
        (0.03, -0.1),
        (0.05, -0.1),
        (0.05, -0.02),
    ] {
        go(&mut w, x, z);
    }
    assert_eq!(w.bodies().len(), 1, "nothing came loose");
    let faces = w.bodies()[0]
        .cut_record()
        .map_or(0, |r| r.surface_faces.len());
    assert!(
        faces <= 8,
        "at most the nick's faces are cut ({faces} cut faces)"
    );
}

/// A cut prepared in the background computes, with the new bodies, the compliance columns
/// of the nodes where a probe presses on the body: the contact of the step it lands in
/// solves for no column (it solved for them all before this).
#[test]
fn a_background_cut_warms_the_columns_a_pressing_probe_needs() {
    let mut w = world_with(hanging_bar(PreciseMethod::CorotationalFem, 1.0));
    w.set_cut_options(CutOptions {
        background_steps: 4,
        ..CutOptions::default()
    })
    .unwrap();
    // A ball pressed 3 mm into the +x face of the bar (where the node of rest
    // (0.02, 0.07, 0.01) hangs now), above where the blade cuts.
    let node = w.bodies()[0]
        .mesh()
        .positions()
        .iter()
        .position(|q| (q - Vec3::new(0.02, 0.07, 0.01)).norm() < 1e-9)
        .unwrap();
    let at = w.bodies()[0].model().node_positions()[node];
    let p = w.add_tool(Tool::new("probe", ToolShape::Sphere { radius: 0.005 }).unwrap());
    for k in 0..=40 {
        let x = 0.01 - 0.008 * (k.min(5) as f64 / 5.0);
        w.tools_mut()[p]
            .set_position(at + Vec3::new(x, 0.0, 0.0))
            .unwrap();
        w.step_fixed().unwrap();
    }
    assert!(
        w.bodies()[0].diagnostics().contacts > 0,
        "the probe presses on the bar"
    );
    sweep_blade(&mut w, 0.055);
    // Pressed on while the cut is prepared (0.5 mm further each step).
    for k in 1..=4 {
        w.tools_mut()[p]
            .set_position(at + Vec3::new(0.002 - 0.0005 * k as f64, 0.0, 0.0))
            .unwrap();
        w.step_fixed().unwrap();
    }
    assert_eq!(w.bodies().len(), 2, "the cut landed");
    let loose = &w.bodies()[1];
    let warmed = loose.cut_record().unwrap().warmed_nodes;
    assert!(
        loose.diagnostics().contacts > 0,
        "the probe presses on the loose piece"
    );
    assert!(
        warmed > 0 && warmed <= loose.surface_nodes().len(),
        "{warmed} nodes warmed"
    );
    assert_eq!(
        loose.model().contact_columns_computed(),
        warmed as u64,
        "the landing step's contact solved for columns it was not given"
    );
}

/// Warm columns are the columns contact would compute: the compliance of a warmed body is
/// the cold body's, to the last bit.
#[test]
fn warm_compliance_columns_are_the_cold_ones() {
    let nodes: Vec<u32> = vec![3, 17, 40, 41];
    let mut blocks = Vec::new();
    for warm in [false, true] {
        let mut b = hanging_bar(PreciseMethod::CorotationalFem, 1.0);
        let m = b.model_mut();
        m.pin(Some(Level::Precise)).unwrap();
        if warm {
            m.warm_contact_columns(&nodes).unwrap();
            assert_eq!(m.contact_columns_computed(), nodes.len() as u64);
        }
        let mut out = vec![nalgebra::Matrix3::zeros(); nodes.len() * nodes.len()];
        m.contact_compliance(&nodes, &mut out).unwrap();
        assert_eq!(m.contact_columns_computed(), nodes.len() as u64);
        blocks.push(out);
    }
    assert_eq!(blocks[0], blocks[1]);
    let mut b = hanging_bar(PreciseMethod::CorotationalFem, 1.0);
    let n = b.mesh().node_count() as u32;
    assert!(b.model_mut().warm_contact_columns(&[n]).is_err());
}

/// A piece a cut takes off a burnt spot keeps the burn drawn: the marks of what the spots
/// burnt go with every piece (the burnt volumes and the heat the water took stay with the
/// body, counted once). An electrode burns the top of a heated bar for 0.25 s, a blade then
/// cuts the top 2 cm off: a sample on the loose piece at the burn's centre shows the damage,
/// one on the kept piece far from it none.
#[test]
fn a_piece_cut_off_a_burn_keeps_its_marks() {
    use soft_tissue_core::heat::{ElectrodeSource, HeatSample};
    let mesh = block(Vec3::zeros(), Vec3::new(0.02, 0.1, 0.02), [2, 10, 2]).unwrap();
    let fem = FemParams {
        young_modulus: 2.0e4,
        poisson_ratio: 0.4,
        mass: 1000.0 * mesh.volume(),
        damping: 1.0,
    };
    let msd = MsdParams {
        stiffness: 200.0,
        mass: fem.mass,
        damping: 0.1,
    };
    let mut s = BodySettings::new(fem, msd, DT);
    s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
    let heat = HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    };
    let body = WorldBody::new(
        "bar",
        Arc::new(mesh),
        s,
        Some((heat, HeatBoundary::insulated())),
    )
    .unwrap();
    let mut w = world_with(body);
    let burn = Vec3::new(0.01, 0.1, 0.01);
    let nearest = |b: &WorldBody, p: Vec3| {
        let x = b.mesh().positions();
        (0..x.len())
            .min_by(|&i, &j| (x[i] - p).norm().total_cmp(&(x[j] - p).norm()))
            .unwrap()
    };
    let top = nearest(&w.bodies()[0], burn);
    for _ in 0..50 {
        let source = ElectrodeSource {
            center: burn,
            watts: 10.0,
            radius: 1e-3,
            tissue_fraction: 0.5,
        };
        w.bodies_mut()[0]
            .heat_mut()
            .unwrap()
            .add_electrode(&source, &[(top, 1.0)])
            .unwrap();
        w.step_fixed().unwrap();
    }
    sweep_blade(&mut w, 0.08);
    assert_eq!(w.bodies().len(), 2, "the top did not come off");
    let damage_at = |w: &mut SoftTissueWorld, i: usize, p: Vec3| {
        let k = nearest(&w.bodies()[i], p);
        let at = w.bodies()[i].mesh().positions()[k];
        let h = w.bodies_mut()[i].heat_mut().unwrap();
        h.set_samples(vec![HeatSample {
            position: at,
            nodes: [
                (k as u32, 1.0),
                (k as u32, 0.0),
                (k as u32, 0.0),
                (k as u32, 0.0),
            ],
        }])
        .unwrap();
        h.sample_damage()[0]
    };
    let (kept, loose) = (0, 1);
    let on_loose = damage_at(&mut w, loose, burn);
    let far = damage_at(&mut w, kept, Vec3::new(0.01, 0.0, 0.01));
    println!("damage at the burn on the loose piece {on_loose:.3e}, far on the kept one {far:.3e}");
    assert!(on_loose >= 1.0, "the loose piece lost the burn: {on_loose}");
    assert_eq!(far, 0.0);
}
