//! Burnt volumes an electrode reports are bounded by the energy it delivered: tissue charred
//! (it reached boiling) took at least `rho c (T_boil - T_0)` per unit volume, and tissue
//! coagulated within a few seconds was above 50 C (below it the liver's Arrhenius rate needs
//! a minute to reach a damage integral of 1), so took at least `rho c (50 - T_0)`. An
//! electrode that moves (dragged along the surface, or sinking as the craters it burns are
//! carved out of the mesh) starts new spots beside the hot ones; each spot's burns must stay
//! where its heat is, not take the neighbour's heat (or the coarse field's heat handed to a
//! crater's small nodes) as the temperature of its whole 20 mm sphere.

use soft_tissue_core::Vec3;
use soft_tissue_core::heat::{
    BurnVolumes, ElectrodeSource, GAS_CONSTANT, HeatBoundary, HeatField, HeatParams, KELVIN_OFFSET,
};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use std::sync::Arc;

mod support;

const DT: f64 = 1.0 / 64.0;
const RADIUS: f64 = 1e-3;
const WATTS: f64 = 30.0;
/// Below this no tissue coagulates within the runs here (checked against the Arrhenius rate).
const COAGULATION_FLOOR_C: f64 = 50.0;

fn params() -> HeatParams {
    HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    }
}

/// Checks `v` against what `joules` can burn in `seconds`, with the volumes in the message.
fn assert_bounded(v: BurnVolumes, joules: f64, seconds: f64, what: &str) {
    let p = params();
    let rho_c = p.density * p.specific_heat;
    let t0 = p.initial_temperature;
    // At the floor the damage integral stays well below 1 for the whole run, so tissue that
    // coagulated was hotter than the floor at some time.
    let kelvin = COAGULATION_FLOOR_C + KELVIN_OFFSET;
    let rate = p.damage_frequency * (-p.damage_activation_energy / (GAS_CONSTANT * kelvin)).exp();
    assert!(rate * seconds < 0.1, "floor too high: {}", rate * seconds);
    let coagulated = joules / (rho_c * (COAGULATION_FLOOR_C - t0));
    let charred = joules / (rho_c * (p.vaporization.boiling_temperature - t0));
    let vap = &p.vaporization;
    let vaporized = joules
        / (vap.water_fraction * p.density * vap.latent_heat
            + rho_c * (vap.boiling_temperature - t0));
    let mm3 = |x: f64| x * 1e9;
    println!(
        "{what}: {joules:.1} J; coagulated {:.1} mm^3 (at most {:.1}), charred {:.2} (at most {:.1}), vaporized {:.2} (at most {:.2})",
        mm3(v.coagulated),
        mm3(coagulated),
        mm3(v.charred),
        mm3(charred),
        mm3(v.vaporized),
        mm3(vaporized)
    );
    assert!(
        v.coagulated <= coagulated,
        "{what}: coagulated {:.1} mm^3, more than {joules:.1} J can heat to {COAGULATION_FLOOR_C} C ({:.1} mm^3)",
        mm3(v.coagulated),
        mm3(coagulated)
    );
    assert!(
        v.charred <= charred,
        "{what}: charred {:.1} mm^3, more than {joules:.1} J can heat to boiling ({:.1} mm^3)",
        mm3(v.charred),
        mm3(charred)
    );
    assert!(
        v.vaporized <= vaporized,
        "{what}: vaporized {:.2} mm^3, more than {joules:.1} J can boil away ({:.2} mm^3)",
        mm3(v.vaporized),
        mm3(vaporized)
    );
}

/// The node of `mesh` nearest `p`.
fn nearest(mesh: &TetMesh, p: Vec3) -> usize {
    let x = mesh.positions();
    (0..x.len())
        .min_by(|&a, &b| (x[a] - p).norm().total_cmp(&(x[b] - p).norm()))
        .unwrap()
}

/// An electrode dragged along the surface, 1 mm every 0.1 s for 2 s at 30 W: each move
/// starts a spot 1 mm from the last, where that one is at boiling. The new spot's outer
/// shells are 20 mm from it, where the tissue is at body temperature.
#[test]
fn a_dragged_electrode_burns_no_more_than_its_energy_can_heat() {
    let cell = 0.002;
    let mesh = block(
        Vec3::zeros(),
        Vec3::new(30.0, 10.0, 20.0) * cell,
        [30, 10, 20],
    )
    .unwrap();
    let mut field = HeatField::new(&mesh, params(), DT, &HeatBoundary::insulated()).unwrap();
    let q0 = field.heat_content();
    let steps = 128;
    let mut hottest = f64::MIN;
    for k in 0..steps {
        let t = k as f64 * DT;
        let moved = (t / 0.1).floor() * 1e-3;
        let centre = Vec3::new(0.02 + moved, 10.0 * cell, 10.0 * cell);
        let source = ElectrodeSource {
            center: centre,
            watts: WATTS,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        field
            .add_electrode(&source, &[(nearest(&mesh, centre), 1.0)])
            .unwrap();
        field.step().unwrap();
        hottest = hottest.max(field.max_temperature());
    }
    let joules = WATTS * steps as f64 * DT;
    let held = field.heat_content() - q0;
    assert!(
        (held - joules).abs() < 1e-9 * joules,
        "{held} J of {joules}"
    );
    println!("{} spots, hottest {hottest:.1} C", field.spot_count());
    assert_bounded(field.burn_volumes(), joules, steps as f64 * DT, "dragged");
}

/// A spot started where the coarse field holds heat in a few nodes (as a crater's wall
/// holds what a carve handed it): those nodes at 90 C, the tissue around at 37 C. The spot
/// may burn only as far as that heat and its own reach, not its whole 20 mm sphere.
#[test]
fn a_spot_on_a_few_hot_nodes_burns_no_more_than_their_heat_can() {
    let cell = 0.001;
    let mesh = block(
        Vec3::zeros(),
        Vec3::new(20.0, 10.0, 20.0) * cell,
        [20, 10, 20],
    )
    .unwrap();
    let mut field = HeatField::new(&mesh, params(), DT, &HeatBoundary::insulated()).unwrap();
    let centre = Vec3::new(10.0, 10.0, 10.0) * cell;
    let x = mesh.positions().to_vec();
    let hot = |i: usize| (x[i] - centre).norm() < 1.5 * cell;
    field
        .set_temperatures(|i| if hot(i) { 90.0 } else { 37.0 })
        .unwrap();
    let c = field.capacities();
    let stored: f64 = (0..x.len()).filter(|&i| hot(i)).map(|i| c[i] * 53.0).sum();
    let node = nearest(&mesh, centre);
    let watts = 0.05;
    let steps = 64;
    for _ in 0..steps {
        let source = ElectrodeSource {
            center: centre,
            watts,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        field.add_electrode(&source, &[(node, 1.0)]).unwrap();
        field.step().unwrap();
    }
    let joules = stored + watts * steps as f64 * DT;
    assert_bounded(field.burn_volumes(), joules, steps as f64 * DT, "hot nodes");
}

/// A block of liver 8 by 16 by 8 mm meshed at 1 mm, an electrode of 1 mm at 30 W on the centre
/// of its top face, pressed down into the craters it burns as they are carved out (as in
/// `electrode.rs`): every carve builds the body again, its spots' heat handed to the crater's
/// nodes, and the electrode goes on in a new spot on the crater's floor.
#[test]
fn an_electrode_sinking_through_carves_burns_no_more_than_its_energy_can_heat() {
    let side = 0.008;
    let mesh = block(Vec3::zeros(), Vec3::new(side, 2.0 * side, side), [8, 16, 8]).unwrap();
    let mut w = support::tissue::heated_block("cube", mesh, params(), DT, side);
    let q0 = w.bodies()[0].heat().unwrap().heat_content();
    let start = Vec3::new(0.5 * side, 2.0 * side, 0.5 * side);
    let steps = 128;
    let mut meshes = 1;
    for k in 0..steps {
        let before = Arc::as_ptr(w.bodies()[0].mesh());
        let (centre, nodes) = floor_on_axis(w.bodies()[0].mesh(), start)
            .unwrap_or_else(|| panic!("step {k}: the axis does not meet the body"));
        let source = ElectrodeSource {
            center: centre,
            watts: WATTS,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        let b = &mut w.bodies_mut()[0];
        b.heat_mut()
            .unwrap()
            .add_electrode(&source, &nodes)
            .unwrap();
        let spots: Vec<Vec3> = w.bodies()[0]
            .heat()
            .unwrap()
            .spot_places()
            .map(|p| p.0)
            .collect();
        w.step_fixed().unwrap();
        if Arc::as_ptr(w.bodies()[0].mesh()) != before {
            meshes += 1;
            // The spots go on through the carve (their millimetre fields are not handed to
            // the coarse nodes and started again).
            let after: Vec<Vec3> = w.bodies()[0]
                .heat()
                .unwrap()
                .spot_places()
                .map(|p| p.0)
                .collect();
            assert!(
                spots.iter().all(|c| after.contains(c)),
                "step {k}: spots {spots:?} before the carve, {after:?} after"
            );
        }
    }
    assert!(meshes >= 3, "only {} carves landed", meshes - 1);
    // A carve lands before the heat step; the spots go on in the new body's field with the
    // power queued on them, so every step's power is delivered (before the spots were
    // carried over a carve, the power queued in a landing step was lost).
    let joules = WATTS * steps as f64 * DT;
    let h: Vec<_> = w.bodies().iter().filter_map(|b| b.heat()).collect();
    let held: f64 = h
        .iter()
        .map(|h| h.heat_content() + h.departed_heat())
        .sum::<f64>()
        - q0;
    assert!(
        (held - joules).abs() < 1e-6 * joules,
        "{held} J of {joules}"
    );
    let mut v = BurnVolumes::default();
    for h in &h {
        v += h.burn_volumes();
    }
    println!("{} carves", meshes - 1);
    assert_bounded(v, joules, steps as f64 * DT, "sinking");
}

/// The organs scene's `cauterize-liver` script with the tool the electrode's size (a 1 mm
/// capsule instead of about 6 mm) pressed 2 mm further in while it burns: 30 W for 2 s, the
/// electrode sinking into the craters carved out of the liver, several carves landing. Each
/// carve hands the spots' heat to the crater's small nodes and the electrode goes on in new
/// spots beside them.
#[test]
fn the_liver_cauterized_through_carves_burns_no_more_than_its_energy_can_heat() {
    use soft_tissue_core::contact::{DEFAULT_ELECTRODE_RADIUS, Tool, ToolShape};
    use soft_tissue_core::scenario::Scene;
    use soft_tissue_core::world::{Script, SoftTissueWorld};
    use std::path::Path;
    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let mut w = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    let liver = w.body_index("Liver").unwrap();
    let units = w.bodies()[liver].heat().unwrap().params().meters_per_unit;
    let mut script = Script::builtin("cauterize-liver", &w).unwrap();
    let ToolShape::Capsule { radius, length } = script.tool else {
        panic!("the script's tool is not a capsule: {:?}", script.tool)
    };
    // The script touches the liver's top with the capsule's tip at `contact` (waypoint 1),
    // presses half a radius in (2), holds while it burns (3) and leaves (4): the same, with
    // the electrode's radius, sinking 2 radii more while it burns.
    let r = DEFAULT_ELECTRODE_RADIUS / units;
    let at = |i: usize| Vec3::from(script.waypoints[i].position);
    let top = at(1) - Vec3::y() * radius;
    let contact = top + Vec3::y() * r;
    let press = contact - Vec3::y() * 0.5 * r;
    let start = contact + (at(0) - at(1));
    for (i, p) in [start, contact, press, press - Vec3::y() * 2.0 * r, start]
        .into_iter()
        .enumerate()
    {
        script.waypoints[i].position = p.into();
    }
    script.tool = ToolShape::Capsule { radius: r, length };
    let ti = w.add_tool(Tool::new(script.name.clone(), script.tool).unwrap());
    // As `simulate --cut-background-steps 4`: each carve prepared over 4 steps.
    w.set_cut_options(soft_tissue_core::mesh::cut::CutOptions {
        background_steps: 4,
        ..Default::default()
    })
    .unwrap();
    let held = |w: &SoftTissueWorld| -> f64 {
        w.bodies()
            .iter()
            .filter_map(|b| b.heat())
            .map(|h| h.heat_content() + h.departed_heat())
            .sum()
    };
    let q0 = held(&w);
    let dt = w.config().dt;
    let steps = (3.3 / dt).round() as usize;
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        let (p, rot) = script.pose_rotation_at(t);
        let tool = &mut w.tools_mut()[ti];
        tool.set_pose_rotation(p, rot).unwrap();
        for e in script.events_in(t - dt, t) {
            e.action.apply(tool).unwrap();
        }
        w.step_fixed().unwrap();
    }
    // The body's record counts its topology changes (a freed mesh's address may be reused,
    // so addresses do not count them).
    let carves = w.bodies()[liver].cut_record().map_or(0, |r| r.cuts);
    // At most 30 W for the 2 s the script heats (only while the electrode presses).
    let joules = 30.0 * 2.0;
    let delivered = held(&w) - q0;
    println!("{carves} carves, {delivered:.2} J delivered");
    assert!(carves >= 2, "only {carves} carves landed");
    assert!(
        delivered > 0.5 * joules && delivered <= joules * (1.0 + 1e-9),
        "{delivered} J"
    );
    let mut v = BurnVolumes::default();
    for h in w.bodies().iter().filter_map(|b| b.heat()) {
        v += h.burn_volumes();
    }
    assert_bounded(v, delivered, steps as f64 * dt, "liver");
}

/// The highest point where the vertical line through `start` meets `mesh`'s surface, with
/// its surface triangle's nodes and their weights there.
fn floor_on_axis(mesh: &TetMesh, start: Vec3) -> Option<(Vec3, Vec<(usize, f64)>)> {
    let x = mesh.positions();
    let mut best: Option<(Vec3, Vec<(usize, f64)>)> = None;
    for t in mesh.surface().triangles() {
        let [a, b, c] = t.map(|i| x[i as usize]);
        let d = (b.x - a.x) * (c.z - a.z) - (c.x - a.x) * (b.z - a.z);
        if d.abs() < 1e-30 {
            continue;
        }
        let (px, pz) = (start.x - a.x, start.z - a.z);
        let wb = (px * (c.z - a.z) - (c.x - a.x) * pz) / d;
        let wc = ((b.x - a.x) * pz - px * (b.z - a.z)) / d;
        let wa = 1.0 - wb - wc;
        if wa < -1e-12 || wb < -1e-12 || wc < -1e-12 {
            continue;
        }
        let p = a * wa + b * wb + c * wc;
        if best.as_ref().is_none_or(|(q, _)| p.y > q.y) {
            let total: f64 = [wa, wb, wc].iter().map(|w| w.max(0.0)).sum();
            let nodes = t
                .iter()
                .zip([wa, wb, wc])
                .map(|(&i, w)| (i as usize, w.max(0.0) / total))
                .collect();
            best = Some((p, nodes));
        }
    }
    best
}
