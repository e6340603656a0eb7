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
        self.field.temperature_at(&p, &[(self.node as u32, 1.0)])
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
    assert!(worst < 0.10, "worst relative error {worst}");
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
    let mut worst: f64 = 0.0;
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
    }
    assert!(worst < 0.10, "worst {worst}");
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
    assert!((sampled - exact).abs() < 0.2 * exact);
    assert!((spot - exact).abs() < 0.2 * exact);
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
    assert!((half_shell - vaporized[3]).abs() < 1e-9 * half_shell);
    for w in vaporized.windows(2) {
        assert!(w[1] > w[0], "vaporized volume did not grow: {vaporized:?}");
    }
    // The heat taken by boiling counts in the energy: 30 W for 2 s.
    let delivered = run.field.heat_content() - q0;
    assert!((delivered - 60.0).abs() < 1e-9 * 60.0, "{delivered}");
}
