//! The force a blade feels as it cuts: the work of fracture of what it cuts (toughness
//! times the area its edge sweeps through tissue), against its motion, and the opposite
//! force on the tissue. Checked against that closed form on a block whose thickness along
//! the edge is known, and against the momentum the tissue takes.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::{ContactConfig, Tool, ToolShape};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, Level, PreciseMethod};
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig, WorldError};

const DT: f64 = 0.005;
/// Bovine liver, J/m^2 (Gokgol, Basdogan and Canadinc 2012).
const LIVER: f64 = 164.0;
/// The block's thickness along the blade's edge (z), m.
const THICK: f64 = 0.02;

/// A block 4 x 2 x 2 cm of soft tissue (1000 kg/m^3, no damping, no gravity), free or
/// held at its bottom layer, with the liver's toughness.
fn tissue(held: bool) -> WorldBody {
    tissue_of(held, 2.0e4)
}

/// [`tissue`] with Young's modulus `young`, Pa.
fn tissue_of(held: bool, young: f64) -> WorldBody {
    let mesh = block(Vec3::zeros(), Vec3::new(0.04, 0.02, THICK), [4, 2, 2]).unwrap();
    let fem = FemParams {
        young_modulus: young,
        poisson_ratio: 0.4,
        mass: 1000.0 * mesh.volume(),
        damping: 0.0,
    };
    let msd = MsdParams {
        stiffness: 200.0,
        mass: 1000.0 * mesh.volume(),
        damping: 0.0,
    };
    let mut s = BodySettings::new(fem, msd, DT);
    s.precise = PreciseMethod::LinearFem;
    if held {
        s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
    }
    let mut b = WorldBody::new("block", Arc::new(mesh), s, None).unwrap();
    b.set_toughness(LIVER).unwrap();
    // At its precise level throughout (its momentum is read there).
    b.model_mut().pin(Some(Level::Precise)).unwrap();
    b
}

/// A world with `body` and a scalpel whose edge runs along z through the block's whole
/// thickness (from z = -2 cm to 4 cm) at height 1.5 cm, 1 cm before its x = 0 face, after
/// one step there; returns the world and the tool's index.
fn scalpel_before(body: WorldBody) -> (SoftTissueWorld, usize) {
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt: DT,
        contact: ContactConfig::for_scale(0.1),
    })
    .unwrap();
    w.add_body(body).unwrap();
    let mut blade = Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap();
    blade
        .set_pose(Vec3::new(-0.01, 0.015, -0.02), Vec3::z())
        .unwrap();
    let t = w.add_tool(blade);
    w.step_fixed().unwrap();
    (w, t)
}

/// The edge moved by `motion` over one step, cutting.
fn cut_by(w: &mut SoftTissueWorld, t: usize, from: Vec3, motion: Vec3) -> Vec3 {
    w.tools_mut()[t].set_pose(from, Vec3::z()).unwrap();
    w.step_fixed().unwrap();
    w.tools_mut()[t].set_cutting(true).unwrap();
    w.tools_mut()[t].set_pose(from + motion, Vec3::z()).unwrap();
    w.step_fixed().unwrap();
    w.tools()[t].reaction_force()
}

/// Pushed across its edge, the blade is held back by the toughness times the thickness it
/// cuts (the fracture energy per distance); moved at 45 degrees to its edge, by that times
/// the sine (only the motion across the edge opens a crack), still against its motion;
/// drawn along its edge, by nothing. The work it does is the fracture energy of the area it
/// swept in tissue.
#[test]
fn a_blade_is_held_back_by_the_fracture_energy_of_what_it_cuts() {
    let inside = Vec3::new(0.005, 0.015, -0.02);
    let s = 0.003;
    let cases = [
        (Vec3::new(s, 0.0, 0.0), 1.0),
        (Vec3::new(s, 0.0, s), std::f64::consts::FRAC_1_SQRT_2),
        (Vec3::new(0.0, 0.0, s), 0.0),
    ];
    for (motion, sine) in cases {
        let (mut w, t) = scalpel_before(tissue(true));
        let f = cut_by(&mut w, t, inside, motion);
        let expected = -motion.normalize() * (LIVER * THICK * sine);
        println!("motion {motion:?}: force {f:?}, expected {expected:?}");
        assert!(
            (f - expected).norm() <= 1e-6 * LIVER * THICK,
            "force {f:?}, expected {expected:?}"
        );
        // The work against it: toughness times the area swept across the edge in tissue.
        let work = -f.dot(&motion);
        let area = THICK * (motion - Vec3::z() * motion.z).norm();
        assert!((work - LIVER * area).abs() <= 1e-6 * LIVER * THICK * s);
        assert_eq!(w.tools()[t].cutting_resistance(), f);
    }
}

/// Outside the tissue, with cutting off, or with no toughness, a moving blade feels
/// nothing.
#[test]
fn no_resistance_outside_uncut_or_without_toughness() {
    let motion = Vec3::new(0.003, 0.0, 0.0);
    // Outside: the edge above the block.
    let (mut w, t) = scalpel_before(tissue(true));
    let f = cut_by(&mut w, t, Vec3::new(0.005, 0.05, -0.02), motion);
    assert_eq!(f, Vec3::zeros());
    // Cutting off: moved through the block.
    let (mut w, t) = scalpel_before(tissue(true));
    w.tools_mut()[t]
        .set_pose(Vec3::new(0.005, 0.015, -0.02), Vec3::z())
        .unwrap();
    w.step_fixed().unwrap();
    w.tools_mut()[t]
        .set_pose(Vec3::new(0.008, 0.015, -0.02), Vec3::z())
        .unwrap();
    w.step_fixed().unwrap();
    assert_eq!(w.tools()[t].reaction_force(), Vec3::zeros());
    // No toughness.
    let mut b = tissue(true);
    b.set_toughness(0.0).unwrap();
    let (mut w, t) = scalpel_before(b);
    let f = cut_by(&mut w, t, Vec3::new(0.005, 0.015, -0.02), motion);
    assert_eq!(f, Vec3::zeros());
}

/// The tissue takes the opposite force: a free block at rest, cut for one step, gains the
/// momentum of that force over the step (backward Euler: internal forces sum to zero).
#[test]
fn the_tissue_takes_the_opposite_force() {
    let (mut w, t) = scalpel_before(tissue(false));
    let f = cut_by(
        &mut w,
        t,
        Vec3::new(0.005, 0.015, -0.02),
        Vec3::new(0.003, 0.0, 0.0),
    );
    assert!(f.norm() > 0.0);
    let momentum: Vec3 = w
        .bodies()
        .iter()
        .map(|b| {
            let p = b.model().precise();
            p.masses()
                .iter()
                .zip(p.velocities())
                .map(|(m, v)| v * *m)
                .sum::<Vec3>()
        })
        .sum();
    let expected = -f * DT;
    println!("momentum {momentum:?}, impulse {expected:?}");
    assert!(
        (momentum - expected).norm() <= 1e-6 * expected.norm(),
        "momentum {momentum:?}, expected {expected:?}"
    );
}

/// A toughness that is negative or not finite is refused, naming the body.
#[test]
fn a_bad_toughness_is_refused_by_name() {
    let mut b = tissue(true);
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let e = b.set_toughness(bad).unwrap_err();
        assert!(matches!(e, WorldError::Contact { .. }), "{e}");
        assert!(e.to_string().contains("block"), "{e}");
    }
    assert_eq!(b.toughness(), LIVER);
}

/// On the organs' liver (a real, curved mesh whose surface a line crosses through edges and
/// vertices too), the resistance to an edge pushed across itself is the toughness times the
/// length of the edge inside the liver, measured independently by sampling the edge and
/// testing each sample against every tetrahedron.
#[test]
fn on_the_liver_the_length_inside_is_the_sampled_one() {
    use soft_tissue_core::scenario::Scene;
    let assets =
        std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets")).to_path_buf();
    for (k, (dy, dz)) in [(0.0, 0.0), (0.11, 0.07), (-0.23, 0.13)]
        .into_iter()
        .enumerate()
    {
        let mut w = SoftTissueWorld::from_scene(&Scene::paper_organs(), &assets).unwrap();
        let i = w.body_index("Liver").unwrap();
        w.bodies_mut()[i].set_toughness(1.0).unwrap();
        let mesh = w.bodies()[i].mesh().clone();
        let (lo, hi) = {
            let b = mesh.bbox();
            (b.min, b.max)
        };
        let c = (lo + hi) * 0.5;
        // An edge along z through the whole liver, at a height and depth of its box.
        let start = Vec3::new(c.x, c.y + dy * (hi.y - lo.y), lo.z - 0.1);
        let length = hi.z - lo.z + 0.2;
        let mut blade = Tool::new("scalpel", ToolShape::Blade { length }).unwrap();
        blade.set_pose(start, Vec3::z()).unwrap();
        let t = w.add_tool(blade);
        w.step_fixed().unwrap();
        w.tools_mut()[t].set_cutting(true).unwrap();
        let to = start + Vec3::new(0.002 + dz * 0.01, 0.0, 0.0);
        w.tools_mut()[t].set_pose(to, Vec3::z()).unwrap();
        w.step_fixed().unwrap();
        let force = w.tools()[t].cutting_resistance().norm();
        // Sampled: the edge at `to`, against the liver's tetrahedra as they were (at rest:
        // the liver is not touched before the cut).
        let x = mesh.positions();
        let n = 4000;
        let inside = (0..n)
            .filter(|&s| {
                let p = to + Vec3::z() * (length * (s as f64 + 0.5) / n as f64);
                mesh.tets().iter().any(|tet| {
                    let [x0, x1, x2, x3] = tet.map(|v| x[v as usize]);
                    let m = nalgebra::Matrix3::from_columns(&[x1 - x0, x2 - x0, x3 - x0]);
                    m.try_inverse().is_some_and(|inv| {
                        let l = inv * (p - x0);
                        l.x >= 0.0 && l.y >= 0.0 && l.z >= 0.0 && l.x + l.y + l.z <= 1.0
                    })
                })
            })
            .count();
        let sampled = length * inside as f64 / n as f64;
        println!("line {k}: resistance / toughness {force:.5}, sampled length inside {sampled:.5}");
        assert!(sampled > 0.1 * (hi.z - lo.z), "the edge misses the liver");
        // The samples resolve the length to one spacing per crossing.
        assert!(
            (force - sampled).abs() <= 4.0 * length / n as f64,
            "{force} vs {sampled}"
        );
    }
}

/// Cuts that land within the step (the core's default) open the tissue the blade just went
/// through; the resistance is measured before they do, so a blade pushed through a stiff
/// block (little pulled along) is held back by J times its thickness every step, in the
/// step and with the cuts prepared in the background alike.
#[test]
fn the_resistance_holds_while_cuts_land() {
    use soft_tissue_core::mesh::cut::CutOptions;
    for background in [0, 4] {
        let (mut w, t) = scalpel_before(tissue_of(true, 2.0e7));
        w.set_cut_options(CutOptions {
            background_steps: background,
            ..CutOptions::default()
        })
        .unwrap();
        let mut x = 0.002;
        w.tools_mut()[t]
            .set_pose(Vec3::new(x, 0.015, -0.02), Vec3::z())
            .unwrap();
        w.step_fixed().unwrap();
        w.tools_mut()[t].set_cutting(true).unwrap();
        for k in 0..14 {
            x += 0.0025;
            w.tools_mut()[t]
                .set_pose(Vec3::new(x, 0.015, -0.02), Vec3::z())
                .unwrap();
            w.step_fixed().unwrap();
            let f = w.tools()[t].cutting_resistance().x;
            println!("background {background}, step {k}: {f:.4}");
            assert!(
                (f + LIVER * THICK).abs() <= 0.02 * LIVER * THICK,
                "step {k}: {f} against {}",
                -LIVER * THICK
            );
        }
    }
}
