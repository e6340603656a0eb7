//! An electrode's heat at the millimetre scale on the coarse liver mesh, against closed forms:
//! a sphere heated at constant power (Carslaw and Jaeger 9.10), its steady state with Pennes
//! perfusion, and the coagulated radius the closed-form field gives with the same Arrhenius
//! parameters. The electrode sits on the surface (half of its sphere in tissue), whose field
//! is the whole sphere's at twice the power.

use std::path::Path;

use soft_tissue_core::Vec3;
use soft_tissue_core::heat::closed_form::{pennes_sphere_steady, sphere_rise};
use soft_tissue_core::heat::{
    ElectrodeSource, HeatBoundary, HeatField, HeatParams, HeatSample, Perfusion,
};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::SoftTissueWorld;

mod support;

const DT: f64 = 1.0 / 64.0;
const RADIUS: f64 = 1e-3;

fn liver() -> TetMesh {
    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let w = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    let i = w.body_index("Liver").unwrap();
    (**w.bodies()[i].mesh()).clone()
}

/// The liver's highest node and the unit vector from it into the organ (towards its centre).
fn electrode_site(mesh: &TetMesh) -> (usize, Vec3, Vec3) {
    let x = mesh.positions();
    let top = (0..x.len())
        .max_by(|&a, &b| x[a].y.total_cmp(&x[b].y))
        .unwrap();
    let centre = x.iter().sum::<Vec3>() / x.len() as f64;
    (top, x[top], (centre - x[top]).normalize())
}

struct Run {
    field: HeatField,
    node: usize,
    at: Vec3,
    inward: Vec3,
}

impl Run {
    fn new(params: HeatParams, dt: f64) -> Run {
        let mesh = liver();
        let (node, at, inward) = electrode_site(&mesh);
        let field = HeatField::new(&mesh, params, dt, &HeatBoundary::insulated()).unwrap();
        Run {
            field,
            node,
            at,
            inward,
        }
    }

    fn step(&mut self, watts: f64) {
        let source = ElectrodeSource {
            center: self.at,
            watts,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        self.field
            .add_electrode(&source, &[(self.node, 1.0)])
            .unwrap();
        self.field.step().unwrap();
    }

    /// The point `mm` millimetres into the tissue from the electrode's centre.
    fn point(&self, mm: f64) -> Vec3 {
        self.at + self.inward * (mm * 1e-3 / self.field.params().meters_per_unit)
    }

    fn rise(&self, mm: f64) -> f64 {
        let p = self.point(mm);
        self.field
            .temperature_at(&p, &[(self.node as u32, 1.0)])
            .unwrap()
            - self.field.params().initial_temperature
    }
}

#[test]
fn constant_power_matches_carslaw_and_jaeger_within_10_percent() {
    let p = HeatParams::liver();
    let (k, kappa) = (p.conductivity, p.diffusivity());
    // 0.25 W on the surface: the whole sphere's field at 0.5 W, which stays below 100 C.
    let watts = 0.25;
    let mut run = Run::new(p, DT);
    let q0 = run.field.heat_content();
    let mut worst: f64 = 0.0;
    let mut compared = 0;
    for (steps, t) in [(64, 1.0), (320, 5.0), (1280, 20.0)] {
        while run.field.time() < t - 0.5 * DT {
            run.step(watts);
        }
        assert_eq!((run.field.time() / DT).round() as usize, steps);
        for mm in [1.5, 2.0, 3.0] {
            let exact = sphere_rise(2.0 * watts, RADIUS, k, kappa, mm * 1e-3, t);
            let got = run.rise(mm);
            let error = (got - exact) / exact;
            println!(
                "t {t:>4} s  r {mm} mm: closed form {exact:8.3} K, sub-grid + coarse {got:8.3} K ({:+.2} %)",
                100.0 * error
            );
            if exact > 1.0 {
                compared += 1;
                worst = worst.max(error.abs());
            }
        }
    }
    assert!(compared >= 6, "only {compared} points rose over 1 K");
    // The goal is 10 %; the model does far better, and a regression shows here.
    assert!(worst < 0.02, "worst relative error {worst}");
    // Energy: P t, split between the coarse field and the spot.
    let delivered = run.field.heat_content() - q0;
    let expected = watts * run.field.time();
    println!(
        "energy: delivered {delivered:.9} J of {expected:.9} J; sub-grid {:.6} J, coarse {:.6} J",
        run.field.subgrid_heat_content(),
        run.field.coarse_heat_content() - q0
    );
    assert!(
        (delivered - expected).abs() <= 1e-9 * expected,
        "delivered {delivered} J, expected {expected} J"
    );
    assert!(run.field.subgrid_heat_content() > 0.5 * expected);
    assert!(run.field.coarse_heat_content() - q0 >= -1e-9 * expected);
    // Nothing reaches boiling at this power: no charred or vaporized tissue.
    assert!(run.field.max_temperature() < 100.0);
    let v = run.field.burn_volumes();
    assert_eq!((v.charred, v.vaporized), (0.0, 0.0));
}

#[test]
fn the_spot_converges_with_its_step() {
    // Halving the heat step moves the near field little: the substeps carry the time
    // accuracy (a guard that the coarse step does not drive the sub-grid error).
    let p = HeatParams::liver();
    let mut a = Run::new(p, DT);
    let mut b = Run::new(p, DT / 2.0);
    while a.field.time() < 2.0 - 0.5 * DT {
        a.step(0.5);
    }
    while b.field.time() < 2.0 - 0.25 * DT {
        b.step(0.5);
    }
    for mm in [1.5, 2.0] {
        let (x, y) = (a.rise(mm), b.rise(mm));
        assert!((x - y).abs() < 0.01 * y, "{mm} mm: {x} K and {y} K");
    }
}

#[test]
fn perfusion_steady_state_matches_pennes_within_10_percent() {
    let p = HeatParams {
        perfusion: Perfusion::liver(),
        ..HeatParams::liver()
    };
    let length = p.perfusion.length(p.conductivity);
    let watts = 0.3;
    let dt = 0.125;
    let mut run = Run::new(p, dt);
    while run.field.time() < 600.0 {
        run.step(watts);
    }
    let (mut worst, mut near): (f64, f64) = (0.0, 0.0);
    for mm in [1.5, 2.0, 3.0, 5.0] {
        let exact = pennes_sphere_steady(2.0 * watts, RADIUS, p.conductivity, length, mm * 1e-3);
        let got = run.rise(mm);
        let error = (got - exact) / exact;
        println!(
            "Pennes steady, L {:.2} mm, r {mm} mm: closed form {exact:.3} K, model {got:.3} K ({:+.2} %)",
            length * 1e3,
            100.0 * error
        );
        if exact > 1.0 {
            worst = worst.max(error.abs());
        }
        if mm <= 3.0 {
            near = near.max(error.abs());
        }
    }
    // Goal 10 %; within 3 mm the sub-grid shells hold the field (3 %), farther the coarse
    // field's share grows.
    assert!(
        worst < 0.10 && near < 0.03,
        "worst {worst}, within 3 mm {near}"
    );
}

/// The coagulated radius (damage 1) of the closed-form field, by the Arrhenius integral at
/// each radius and bisection.
fn closed_form_coagulated_radius(p: &HeatParams, watts: f64, seconds: f64) -> f64 {
    let (k, kappa) = (p.conductivity, p.diffusivity());
    let omega = |r: f64| {
        let n = 20_000;
        let h = seconds / n as f64;
        (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) * h;
                let temp = p.initial_temperature + sphere_rise(2.0 * watts, RADIUS, k, kappa, r, t);
                if temp > p.damage_threshold {
                    h * p.damage_frequency
                        * (-p.damage_activation_energy
                            / (soft_tissue_core::heat::GAS_CONSTANT
                                * (temp + soft_tissue_core::heat::KELVIN_OFFSET)))
                            .exp()
                } else {
                    0.0
                }
            })
            .sum::<f64>()
    };
    let (mut lo, mut hi) = (RADIUS, 20e-3);
    assert!(omega(lo) > 1.0, "nothing coagulates at the electrode");
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if omega(mid) >= 1.0 {
            lo = mid
        } else {
            hi = mid
        }
    }
    lo
}

#[test]
fn coagulated_radius_matches_the_closed_form_field_within_20_percent() {
    let p = HeatParams::liver();
    let (watts, seconds) = (0.2, 20.0);
    let mut run = Run::new(p, DT);
    // Samples every 0.05 mm into the tissue, as a rendered surface's vertices would be.
    let samples: Vec<HeatSample> = (0..100)
        .map(|i| HeatSample {
            position: run.point(1.0 + 0.05 * i as f64),
            nodes: [(run.node as u32, 1.0), (0, 0.0), (0, 0.0), (0, 0.0)],
        })
        .collect();
    run.field.set_samples(samples).unwrap();
    while run.field.time() < seconds - 0.5 * DT {
        run.step(watts);
    }
    assert!(
        run.field.max_temperature() < 100.0,
        "{} C",
        run.field.max_temperature()
    );
    let exact = closed_form_coagulated_radius(&p, watts, seconds);
    let damage = run.field.sample_damage();
    let last = damage
        .iter()
        .rposition(|&d| d >= 1.0)
        .expect("no sample coagulated");
    let sampled = (1.0 + 0.05 * last as f64) * 1e-3;
    let spot = run.field.coagulated_radii()[0];
    println!(
        "coagulated radius after {seconds} s at {watts} W: closed form {:.3} mm, samples {:.3} mm, spot shells {:.3} mm; hottest {:.1} C",
        exact * 1e3,
        sampled * 1e3,
        spot * 1e3,
        run.field.max_temperature()
    );
    // Goal 20 %; the samples lie every 0.05 mm and the shells are about 0.05 mm wide there.
    assert!((sampled - exact).abs() < 0.05 * exact);
    assert!((spot - exact).abs() < 0.05 * exact);
    let v = run.field.burn_volumes();
    // The coagulated volume is the half ball of that radius (to the shells' resolution).
    let half_ball = 2.0 / 3.0 * std::f64::consts::PI * (spot.powi(3) - RADIUS.powi(3));
    assert!(
        (v.coagulated - half_ball).abs() < 0.2 * half_ball,
        "{v:?} {half_ball}"
    );
}

#[test]
fn thirty_watts_boil_and_vaporize_only_where_tissue_reached_boiling() {
    let p = HeatParams::liver();
    let mut run = Run::new(p, DT);
    let q0 = run.field.heat_content();
    let mut vaporized = Vec::new();
    for _ in 0..4 {
        while run.field.time() < (vaporized.len() + 1) as f64 * 0.5 - 0.5 * DT {
            run.step(30.0);
        }
        let v = run.field.burn_volumes();
        vaporized.push(v.vaporized);
        // Vaporized shells reached boiling, and at 100 C the Arrhenius rate (about 6e3 1/s)
        // coagulates within the step.
        assert!(v.vaporized <= v.charred && v.charred <= v.coagulated);
        assert!(run.field.max_temperature().is_finite());
    }
    println!(
        "30 W: vaporized {:?} mm^3 at 0.5, 1, 1.5, 2 s; charred {:.2} mm^3, coagulated {:.2} mm^3, hottest {:.0} C",
        vaporized.iter().map(|v| v * 1e9).collect::<Vec<_>>(),
        run.field.burn_volumes().charred * 1e9,
        run.field.burn_volumes().coagulated * 1e9,
        run.field.max_temperature()
    );
    assert!(vaporized[0] > 0.0);
    // The crater: the vaporized half shell around the electrode.
    let crater = run.field.crater_radii()[0];
    let half_shell = 2.0 / 3.0 * std::f64::consts::PI * (crater.powi(3) - RADIUS.powi(3));
    println!("crater radius {:.2} mm", crater * 1e3);
    assert!(crater > RADIUS);
    assert!(half_shell >= vaporized[3] * (1.0 - 1e-9));
    // Vaporizing takes at least the water's latent heat, and the tissue's heating to
    // boiling: no more can vaporize than 60 J pay for.
    let per_volume = p.vaporization.water_fraction * p.density * p.vaporization.latent_heat
        + p.density * p.specific_heat * (p.vaporization.boiling_temperature - 37.0);
    assert!(
        vaporized[3] * per_volume <= 60.0,
        "{} J",
        vaporized[3] * per_volume
    );
    // And most of the heat went there, at 30 W into a 1 mm electrode.
    assert!(
        vaporized[3] * per_volume > 0.5 * 60.0,
        "{} J",
        vaporized[3] * per_volume
    );
    for w in vaporized.windows(2) {
        assert!(w[1] > w[0], "vaporized volume did not grow: {vaporized:?}");
    }
    // The heat taken by boiling counts in the energy: 30 W for 2 s.
    let delivered = run.field.heat_content() - q0;
    assert!((delivered - 60.0).abs() < 1e-9 * 60.0, "{delivered}");
}

/// The highest point where the vertical line through `start` meets `mesh`'s surface, with
/// its surface triangle's nodes and their weights there.
fn surface_on_axis(mesh: &TetMesh, start: Vec3) -> Option<(Vec3, Vec<(usize, f64)>)> {
    let x = mesh.positions();
    let mut best: Option<(Vec3, Vec<(usize, f64)>)> = None;
    for t in mesh.surface().triangles() {
        let [a, b, c] = t.map(|i| x[i as usize]);
        // Barycentric weights of the axis point in the triangle's projection on y = 0.
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
            let nodes = t
                .iter()
                .zip([wa, wb, wc])
                .map(|(&i, w)| (i as usize, w.max(0.0)));
            let total: f64 = [wa, wb, wc].iter().map(|w| w.max(0.0)).sum();
            best = Some((p, nodes.map(|(i, w)| (i, w / total)).collect()));
        }
    }
    best
}

/// A block of liver 8 by 16 by 8 mm meshed at 1 mm, an electrode of 1 mm at 30 W on the centre
/// of its top face, pressed down into the crater it burns. The ball of tissue each crater
/// vaporized is carved out of the mesh by the cut's topology change: the body stays valid (every element positive, its boundary 2-manifold, mass by
/// volume), the removed volume grows with time, no more is removed than the energy
/// delivered can vaporize, and tissue farther than 4 mm from the electrode stays.
#[test]
fn vaporized_tissue_leaves_the_mesh_and_the_electrode_sinks_in() {
    use soft_tissue_core::mesh::generate::block;
    let side = 0.008;
    let mesh = block(Vec3::zeros(), Vec3::new(side, 2.0 * side, side), [8, 16, 8]).unwrap();
    let heat = HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    };
    let original: Vec<Vec3> = mesh.positions().to_vec();
    let volume0 = mesh.volume();
    let mut w = support::tissue::heated_block("cube", mesh, heat, DT, side);
    let start = Vec3::new(0.5 * side, 2.0 * side, 0.5 * side);
    let mut centres = vec![start];
    let mut removed_at = Vec::new();
    let p = heat;
    let per_volume = p.vaporization.water_fraction * p.density * p.vaporization.latent_heat
        + p.density * p.specific_heat * (p.vaporization.boiling_temperature - 37.0);
    for k in 1..=128 {
        // The electrode is pressed down the vertical axis through where it started: it
        // sits where that axis first meets the body's surface from above (the crater's
        // floor, once there is one) and heats through that surface triangle's nodes.
        let (centre, nodes) = surface_on_axis(w.bodies()[0].mesh(), start)
            .unwrap_or_else(|| {
                panic!(
                    "step {k}: the axis does not meet the body: {} bodies, {} tetrahedra, {:.3} mm^3; electrode at {centres:?}",
                    w.bodies().len(),
                    w.bodies()[0].mesh().tet_count(),
                    w.bodies()[0].mesh().volume() * 1e9
                )
            });
        if (centre - *centres.last().unwrap()).norm() > 0.0 {
            centres.push(centre);
        }
        let source = ElectrodeSource {
            center: centre,
            watts: 30.0,
            radius: RADIUS,
            tissue_fraction: 0.5,
        };
        let b = &mut w.bodies_mut()[0];
        b.heat_mut()
            .unwrap()
            .add_electrode(&source, &nodes)
            .unwrap();
        w.step_fixed().unwrap();
        let volume: f64 = w.bodies().iter().map(|b| b.mesh().volume()).sum();
        if k % 32 == 0 {
            removed_at.push(volume0 - volume);
        }
    }
    let removed = *removed_at.last().unwrap();
    let depth = start.y - centres.iter().map(|c| c.y).fold(f64::INFINITY, f64::min);
    println!(
        "removed {:?} mm^3 after 0.5, 1, 1.5, 2 s; the electrode sank {:.2} mm; {} bodies, {} tetrahedra",
        removed_at.iter().map(|v| v * 1e9).collect::<Vec<_>>(),
        depth * 1e3,
        w.bodies().len(),
        w.bodies()[0].mesh().tet_count()
    );
    assert!(removed > 0.0, "nothing was removed");
    assert!(
        removed_at.windows(2).all(|v| v[1] >= v[0]) && removed_at[3] > removed_at[1],
        "{removed_at:?}"
    );
    assert!(depth > 0.0, "the electrode did not sink in");
    // No more than 60 J can vaporize.
    assert!(removed * per_volume <= 60.0, "{} J", removed * per_volume);
    for b in w.bodies() {
        let m = b.mesh();
        assert!(m.tet_volumes().iter().all(|&v| v > 0.0));
        let mut edges: Vec<(u32, u32)> = m
            .surface()
            .triangles()
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, c)| (a.min(c), a.max(c)))
            .collect();
        edges.sort_unstable();
        assert!(edges.chunk_by(|a, c| a == c).all(|r| r.len() == 2));
    }
    // Mass goes with the volume removed.
    let mass: f64 = w
        .bodies()
        .iter()
        .map(|b| b.model().settings().fem.mass)
        .sum();
    let volume: f64 = w.bodies().iter().map(|b| b.mesh().volume()).sum();
    assert!(
        (mass - support::tissue::LIVER_DENSITY * volume).abs() < 1e-9 * mass,
        "{mass} {}",
        support::tissue::LIVER_DENSITY * volume
    );
    // Tissue 4 mm or more from every place the electrode sat is all there.
    let kept = w.bodies()[0].mesh().positions();
    for q in original
        .iter()
        .filter(|q| centres.iter().all(|c| (*q - c).norm() >= 0.004))
    {
        assert!(
            kept.iter().any(|k| (k - q).norm() < 1e-12),
            "{q:?} was removed"
        );
    }
}

/// A spot whose hot core no node samples (its centre in the middle of a 10 mm element's
/// face, the nearest node 7 mm away) gives its heat to the nodes without heating any of
/// them beyond the spot's own excess there plus an even share: the heat it holds, to
/// round-off, and no node hotter than the field it hands over says.
#[test]
fn a_spot_the_mesh_does_not_sample_hands_its_heat_over_without_a_hot_node() {
    use soft_tissue_core::mesh::generate::block;
    let cell = 0.01;
    let mesh = block(Vec3::zeros(), Vec3::new(4.0, 2.0, 4.0) * cell, [4, 2, 4]).unwrap();
    let params = HeatParams {
        meters_per_unit: 1.0,
        ..HeatParams::liver()
    };
    let mut field = HeatField::new(&mesh, params, DT, &HeatBoundary::insulated()).unwrap();
    // The middle of the top face of a cell (on its diagonal, 7.07 mm from its corners),
    // heated through the face's corners.
    let centre = Vec3::new(1.5, 2.0, 1.5) * cell;
    let x = mesh.positions();
    let corners: Vec<(usize, f64)> = (0..x.len())
        .filter(|&i| {
            (x[i].y - 2.0 * cell).abs() < 1e-12
                && (x[i].x - centre.x).abs() < 0.6 * cell
                && (x[i].z - centre.z).abs() < 0.6 * cell
        })
        .map(|i| (i, 0.25))
        .collect();
    assert_eq!(corners.len(), 4);
    let source = ElectrodeSource {
        center: centre,
        watts: 0.5,
        radius: RADIUS,
        tissue_fraction: 0.5,
    };
    for _ in 0..64 {
        field.add_electrode(&source, &corners).unwrap();
        field.step().unwrap();
    }
    assert!(field.max_temperature() < 100.0, "nothing boils");
    let before = field.temperatures().to_vec();
    let c = field.capacities();
    let after = field.temperatures_with_spots();
    let handed: f64 = (0..c.len()).map(|i| c[i] * (after[i] - before[i])).sum();
    let held = field.subgrid_heat_content();
    assert!(
        (handed - held).abs() <= 1e-9 * held,
        "handed {handed} J of the spot's {held} J"
    );
    // The spot's excess at each node, and the even share the rest of its heat makes over
    // the nodes within its reach (20 mm).
    let excess: Vec<f64> = (0..c.len())
        .map(|i| field.temperature_at(&x[i], &[(i as u32, 1.0)]).unwrap() - before[i])
        .collect();
    let reach: f64 = (0..c.len())
        .filter(|&i| (x[i] - centre).norm() < 0.02)
        .map(|i| c[i])
        .sum();
    let bound = held / reach;
    let worst = (0..c.len())
        .map(|i| after[i] - before[i] - excess[i])
        .fold(f64::MIN, f64::max);
    println!(
        "spot {held:.4} J; largest rise {:.3} K, its excess there at most {:.3} K, even share at most {bound:.4} K",
        (0..c.len())
            .map(|i| after[i] - before[i])
            .fold(f64::MIN, f64::max),
        excess.iter().copied().fold(f64::MIN, f64::max)
    );
    assert!(
        worst <= bound * (1.0 + 1e-9),
        "a node rose {worst} K beyond the spot's excess at it (even share at most {bound} K)"
    );
}
