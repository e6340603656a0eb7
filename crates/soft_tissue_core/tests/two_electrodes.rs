//! Two electrodes of one radius on one body each heat a spot of their own, and each goes on
//! at its own spot in the step a carve lands (when the last contact solve's rows name the
//! old mesh's nodes and the world asks the heat field for the spot an electrode powered).
//! Before, that step gave both electrodes' power to the newest spot of the radius.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::contact::{Counterpart, Tool, ToolShape};
use soft_tissue_core::heat::{ElectrodeSource, HeatBoundary, HeatField, HeatParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::world::SoftTissueWorld;

mod support;

const DT: f64 = 1.0 / 64.0;
const RADIUS: f64 = 1e-3;
const WATTS: f64 = 30.0;

fn params() -> HeatParams {
    HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    }
}

fn nearest(mesh: &TetMesh, p: Vec3) -> usize {
    let x = mesh.positions();
    (0..x.len())
        .min_by(|&a, &b| (x[a] - p).norm().total_cmp(&(x[b] - p).norm()))
        .unwrap()
}

#[test]
fn each_electrode_finds_the_spot_it_powered() {
    let mesh = block(Vec3::zeros(), Vec3::new(0.02, 0.01, 0.01), [10, 5, 5]).unwrap();
    let mut field = HeatField::new(&mesh, params(), DT, &HeatBoundary::insulated()).unwrap();
    let (a, b) = (Vec3::new(0.006, 0.01, 0.005), Vec3::new(0.014, 0.01, 0.005));
    let heat = |field: &mut HeatField, electrode: u32, at: Vec3| {
        let source = ElectrodeSource {
            center: at,
            watts: WATTS,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        field
            .add_electrode_of(electrode, &source, &[(nearest(&mesh, at), 1.0)])
            .unwrap();
    };
    // Electrode 3 at a, electrode 7 at b (the newer spot).
    heat(&mut field, 3, a);
    heat(&mut field, 7, b);
    field.step().unwrap();
    assert_eq!(field.spot_count(), 2);
    let at = |field: &HeatField, electrode: u32| {
        field
            .powered_spot(electrode, RADIUS)
            .map(|s| (s.center, s.nodes, s.tissue_fraction))
    };
    assert_eq!(
        at(&field, 3),
        Some((a, vec![(nearest(&mesh, a), 1.0)], 0.5))
    );
    assert_eq!(at(&field, 7).map(|s| s.0), Some(b));
    assert_eq!(at(&field, 5), None, "an electrode that powered nothing");
    assert_eq!(field.powered_spot(3, 2.0 * RADIUS), None, "another radius");
    // Both on one spot: each finds it. Then only 7 heats: 3 powered nothing in that step.
    heat(&mut field, 3, b);
    heat(&mut field, 7, b);
    field.step().unwrap();
    assert_eq!(at(&field, 3).map(|s| s.0), Some(b));
    assert_eq!(at(&field, 7).map(|s| s.0), Some(b));
    heat(&mut field, 7, b);
    field.step().unwrap();
    assert_eq!(at(&field, 3), None);
    assert_eq!(at(&field, 7).map(|s| s.0), Some(b));
    // An electrode without a number powers a spot no numbered one finds.
    let source = ElectrodeSource {
        center: a,
        watts: WATTS,
        radius: RADIUS,
        tissue_fraction: 0.5,
    };
    field
        .add_electrode(&source, &[(nearest(&mesh, a), 1.0)])
        .unwrap();
    field.step().unwrap();
    assert_eq!(at(&field, 3), None);
}

/// A block of liver 12 by 8 by 8 mm meshed at 1 mm, fixed below; two 1 mm spherical
/// electrodes at 30 W pressed 0.3 mm into its top 5 mm apart, held there until a crater is
/// carved out (in the step, as the world does by default). In the step the carve lands each
/// electrode heats the spot it powered before; the energy delivered is the power of every
/// step an electrode pressed, to 1e-9.
#[test]
fn two_electrodes_go_on_at_their_own_spots_as_a_carve_lands() {
    let size = Vec3::new(0.012, 0.008, 0.008);
    let mesh = block(Vec3::zeros(), size, [12, 8, 8]).unwrap();
    let mut w = support::tissue::heated_block("block", mesh, params(), DT, size.y);
    let q0 = w.bodies()[0].heat().unwrap().heat_content();
    let places = [0.0035, 0.0085].map(|x| Vec3::new(x, size.y + 0.7 * RADIUS, 0.004));
    for (k, p) in places.iter().enumerate() {
        let t = w.add_tool(
            Tool::new(
                format!("electrode {k}"),
                ToolShape::Sphere { radius: RADIUS },
            )
            .unwrap(),
        );
        assert_eq!(t, k);
        let tool = &mut w.tools_mut()[t];
        tool.set_electrode_radius(Some(RADIUS)).unwrap();
        tool.set_position(*p).unwrap();
        tool.set_cautery(WATTS).unwrap();
    }
    let pressing = |w: &SoftTissueWorld, t: usize| {
        w.contacts().solved_rows().iter().any(|r| {
            matches!(r.other, Counterpart::Tool { tool, .. } if tool == t as u32)
                && r.is_contact()
                && r.force.x > 0.0
        })
    };
    let (mut on_steps, mut landed) = (0, None);
    for k in 0..96 {
        // The step heats through the points each tool pressed in the last step's solve.
        on_steps += (0..2).filter(|&t| pressing(&w, t)).count();
        let both = (0..2).all(|t| pressing(&w, t));
        let mesh = Arc::as_ptr(w.bodies()[0].mesh());
        w.step_fixed().unwrap();
        if Arc::as_ptr(w.bodies()[0].mesh()) == mesh || landed.is_some() {
            continue;
        }
        assert!(
            both,
            "step {k}: a carve landed with an electrode off the tissue"
        );
        landed = Some(k);
        // Each electrode heated its own spot in the landing step: the one nearest it.
        let h = w.bodies()[0].heat().unwrap();
        for (t, p) in places.iter().enumerate() {
            let spot = h
                .powered_spot(t as u32, RADIUS)
                .unwrap_or_else(|| panic!("step {k}: electrode {t} powered no spot"));
            let d = |q: &Vec3| ((spot.center - q).x.powi(2) + (spot.center - q).z.powi(2)).sqrt();
            println!(
                "step {k}: electrode {t}'s spot {:.2} mm from it, {:.2} mm from the other; tissue fraction {:.3}",
                d(p) * 1e3,
                d(&places[1 - t]) * 1e3,
                spot.tissue_fraction
            );
            assert!(
                d(p) < 1e-3,
                "electrode {t}'s spot is {:.2} mm away",
                d(p) * 1e3
            );
            // It stands at the carved mesh's node nearest its centre.
            let node = nearest(w.bodies()[0].mesh(), spot.center);
            assert_eq!(spot.nodes, vec![(node, 1.0)], "electrode {t}'s spot");
        }
    }
    let k = landed.expect("no carve landed in 1.5 s");
    let h = w.bodies()[0].heat().unwrap();
    let delivered = h.heat_content() + h.departed_heat() - q0;
    let expected = WATTS * DT * on_steps as f64;
    println!(
        "carve landed in step {k}; {} spots; {delivered:.4} J delivered of {expected:.4}",
        h.spot_count()
    );
    assert!(
        (delivered - expected).abs() < 1e-9 * expected,
        "delivered {delivered} J, expected {expected} J"
    );
}
