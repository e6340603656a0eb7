//! The cut in the 1 kHz haptic loop: a friction across the blade's edge whose breakaway force
//! is the toughness times the edge's length in tissue (`haptics::cutting`). Checked against
//! what a friction must do: a steady stroke across the edge is held back by exactly the
//! breakaway force once the bristle and the coupling are stretched; a trembling hand feels a
//! spring bounded by its tremor, not the breakaway force flipping sign, and takes no energy
//! from it; below the breakaway the proxy does not creep; along the edge, or not cutting,
//! nothing changes; bad models are refused by name. And from the physics: a blade resting
//! in a block hands over the toughness times the block's thickness.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::{ContactConfig, Tool, ToolShape};
use soft_tissue_core::haptics::coupling::Coupling;
use soft_tissue_core::haptics::{
    ContactModel, CouplingParams, CutModel, DevicePort, HapticConfig, HapticError, HapticThread,
    RecordedSample, Recording, ReplayDevice, cut_model,
};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, PreciseMethod};
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig};

/// The haptic period, s.
const H: f64 = 1e-3;
/// Bovine liver, J/m^2 (Gokgol, Basdogan and Canadinc 2012).
const LIVER: f64 = 164.0;
/// Length of the edge in tissue, m: a 2 cm thick block.
const THICK: f64 = 0.02;
/// The breakaway force: the toughness times the length in tissue, N.
const STRENGTH: f64 = LIVER * THICK;

/// The loop's default gains (metres, newtons), the device limit out of the way.
fn params() -> CouplingParams {
    CouplingParams {
        max_force: 1e3,
        ..CouplingParams::default()
    }
}

/// A cut along z with the liver's breakaway force and the default bristle.
fn cut() -> CutModel {
    let p = params();
    CutModel::new(
        Vec3::z(),
        STRENGTH,
        CutModel::STIFFNESS_PER_COUPLING * p.stiffness,
    )
    .unwrap()
}

/// The haptic loop's tick without its thread: its device port (the device velocity from
/// finite differences through the loop's low-pass filter, and the passivity controller
/// where the loop's default has it), then the coupling's step.
struct Loop {
    coupling: Coupling,
    port: DevicePort,
}

impl Loop {
    fn new(params: CouplingParams, at: Vec3, cut: CutModel) -> Self {
        let d = HapticConfig::default();
        Self::filtered(params, at, cut, d.velocity_cutoff_hz, d.passivity)
    }

    /// With the device velocity's filter at `cutoff` Hz, the controller on or off.
    fn filtered(
        params: CouplingParams,
        at: Vec3,
        cut: CutModel,
        cutoff: f64,
        passivity: bool,
    ) -> Self {
        let mut coupling = Coupling::new(params, at);
        coupling.set_cut(cut);
        Loop {
            coupling,
            port: DevicePort::new(1.0 / H, cutoff, passivity),
        }
    }

    /// One tick with the hand at `hand`: the force on it.
    fn tick(&mut self, hand: Vec3) -> Vec3 {
        self.port.tick(&mut self.coupling, &hand, H)
    }
}

/// Forces on a hand that follows `hand(t)` for `ticks` ticks from rest at `hand(0)`.
fn forces(cut: CutModel, ticks: usize, hand: impl Fn(f64) -> Vec3) -> Vec<Vec3> {
    let d = HapticConfig::default();
    forces_filtered(cut, ticks, hand, d.velocity_cutoff_hz, d.passivity)
}

/// [`forces`] with the device velocity's filter at `cutoff` Hz, the passivity controller
/// on or off.
fn forces_filtered(
    cut: CutModel,
    ticks: usize,
    hand: impl Fn(f64) -> Vec3,
    cutoff: f64,
    passivity: bool,
) -> Vec<Vec3> {
    let mut l = Loop::filtered(params(), hand(0.0), cut, cutoff, passivity);
    (0..ticks).map(|k| l.tick(hand(k as f64 * H))).collect()
}

/// Work of the forces `f` on a hand following `hand` over ticks `from..to`, per period of
/// `period` ticks: as a device renders them, each tick's force held over the hand's motion
/// to the next tick (`held`), and as the virtual environment computes them, each tick's
/// force over the motion that led to it.
fn work(
    f: &[Vec3],
    hand: impl Fn(f64) -> Vec3,
    to: usize,
    periods: usize,
    period: usize,
) -> (f64, f64) {
    let from = to - periods * period;
    let at = |k: usize| hand(k as f64 * H);
    let held: f64 = (from..to).map(|k| f[k].dot(&(at(k + 1) - at(k)))).sum();
    let environment: f64 = (from..to).map(|k| f[k].dot(&(at(k) - at(k - 1)))).sum();
    (held / periods as f64, environment / periods as f64)
}

/// Pushed steadily across its edge, the blade is held back by exactly the breakaway force
/// once the hand has gone the stick distance (the bristle's `J L / k_b` and the coupling's
/// `J L / k_c`) and the coupling has settled (ten of its time constants): on a stroke at 45
/// degrees too, where it acts against the motion's part across the edge (the work per
/// distance across is `J L`, as in the physics) with nothing along the edge.
#[test]
fn a_steady_stroke_across_the_edge_is_held_back_by_the_breakaway_force() {
    let p = params();
    let c = cut();
    let speed = 0.05;
    let omega = (p.stiffness / p.proxy_mass).sqrt();
    let stick = STRENGTH / c.stiffness + STRENGTH / p.stiffness;
    for (name, dir) in [
        ("across", Vec3::x()),
        ("45 degrees", Vec3::new(1.0, 0.0, 1.0).normalize()),
    ] {
        let f = forces(c, 1000, |t| dir * (speed * t));
        let across = c.across(&dir).normalize();
        // The stick distance is gone across the edge.
        let settled = stick / (speed * c.across(&dir).norm()) + 10.0 / omega;
        let mut worst: f64 = 0.0;
        for (k, f) in f.iter().enumerate() {
            if (k as f64) * H < settled {
                continue;
            }
            worst = worst.max((f + across * STRENGTH).norm());
            assert!(f.z.abs() <= 1e-9 * STRENGTH, "{name}: along the edge {f}");
        }
        let last = f.last().unwrap();
        println!(
            "{name}: stick distance {:.2} mm, settled after {settled:.3} s; force {last:.6} N, \
             expected {:.4} N against the motion across the edge; worst deviation after \
             settling {worst:.2e} N",
            stick * 1e3,
            STRENGTH
        );
        assert!(worst <= 1e-3 * STRENGTH, "{name}: {worst} N off");
        // Before the stick distance it held back less: a spring, not a step.
        let early = f[(0.5 * stick / speed / H) as usize].norm();
        let _ = settled;
        assert!(
            early < 0.9 * STRENGTH,
            "{name}: {early} N before the stick distance"
        );
    }
}

/// A hand trembling +-0.1 mm across the edge at 50 to 200 Hz around a point in tissue: the
/// force stays below what the coupling's spring and damper give on the whole tremor
/// (`(k_c + b_c w) A`, far below the breakaway force) and changes sign at most twice per
/// tremor period (it follows the tremor, it does not flip every tick). The loop takes energy
/// from the hand over each period, never gives it: as the virtual environment computes it
/// (each tick's force over the motion that led to it), and as a device renders it (each
/// tick's force held over the next tick, no damping of the device's own), at every
/// frequency with the loop's defaults (its 40 Hz filter on the device velocity and the
/// passivity controller) and with a 400 Hz filter. Without the controller, above about
/// 150 Hz the 40 Hz filter's lag makes the coupling's damper give energy with or without a
/// cut (printed, with the coupling alone beside it); the cut's bristle is passive on its own
/// (a spring that stores at most `(J L)^2 / 2 k_b` and an anchor that only moves to
/// release it).
#[test]
fn a_trembling_hand_feels_a_bounded_spring_and_gets_no_energy() {
    let p = params();
    let amplitude = 1e-4;
    let defaults = HapticConfig::default();
    let cutoff = defaults.velocity_cutoff_hz;
    for hz in [50.0, 100.0, 150.0, 200.0] {
        let w = 2.0 * std::f64::consts::PI * hz;
        let hand = |t: f64| Vec3::new(amplitude * (w * t).sin(), 0.0, 0.0);
        let ticks = 2000;
        let period = (1.0 / (hz * H)).round() as usize;
        let f = forces(cut(), ticks, hand);
        let bound = (p.stiffness + p.damping() * w) * amplitude;
        let peak = f.iter().map(|f| f.norm()).fold(0.0, f64::max);
        let flips = f.windows(2).filter(|p| p[0].x * p[1].x < 0.0).count();
        let periods = ticks as f64 * H * hz;
        // The last ten periods (the first were the start from rest), and the whole run.
        let (held, environment) = work(&f, hand, ticks - 1, 10, period);
        let (all_held, _) = work(&f, hand, ticks - 1, (ticks - 2) / period, period);
        let (bare, _) = work(
            &forces_filtered(cut(), ticks, hand, cutoff, false),
            hand,
            ticks - 1,
            10,
            period,
        );
        let alone = work(
            &forces_filtered(CutModel::NONE, ticks, hand, cutoff, false),
            hand,
            ticks - 1,
            10,
            period,
        );
        let fast = forces_filtered(cut(), ticks, hand, 400.0, defaults.passivity);
        let (fast_held, _) = work(&fast, hand, ticks - 1, 10, period);
        println!(
            "{hz} Hz: peak force {peak:.4} N (bound {bound:.4} N, breakaway {STRENGTH:.2} N), \
             {flips} sign changes in {periods} periods; work on the hand per period: \
             environment {environment:.2e} J, held {held:.2e} J (whole run {all_held:.2e} J; \
             without the controller {bare:.2e} J, the coupling alone {:.2e} J), held with a \
             400 Hz filter {fast_held:.2e} J",
            alone.0
        );
        assert!(peak <= bound, "{hz} Hz: {peak} N");
        assert!(peak < 0.2 * STRENGTH);
        assert!(
            flips as f64 <= 2.0 * periods + 2.0,
            "{hz} Hz: {flips} flips"
        );
        assert!(environment <= 0.0, "{hz} Hz: the hand got {environment} J");
        assert!(fast_held <= 0.0, "{hz} Hz, 400 Hz filter: {fast_held} J");
        assert!(held <= 0.0, "{hz} Hz: the hand got {held} J a period");
        assert!(
            all_held <= 0.0,
            "{hz} Hz: the hand got {all_held} J a period"
        );
        assert_eq!(cutoff, 40.0, "the filter these numbers are for");
        assert!(defaults.passivity);
    }
}

/// Leaning on the blade at 90 % of the breakaway force and trembling (+-0.1 mm at 100 Hz)
/// for two seconds: the proxy stays where it stuck (a bristle does not creep below the
/// breakaway, Hayward and Armstrong 2000, where Dahl's model drifts).
#[test]
fn below_the_breakaway_the_proxy_does_not_creep() {
    let p = params();
    {
        let lean = 0.9;
        let offset = lean * STRENGTH * (1.0 / p.stiffness + 1.0 / cut().stiffness);
        let w = 2.0 * std::f64::consts::PI * 100.0;
        let hand = |t: f64| {
            // Leans in over the first 0.2 s, then trembles around the leaning point.
            let ramp = (t / 0.2).min(1.0);
            Vec3::new(offset * ramp + 1e-4 * (w * t).sin(), 0.0, 0.0)
        };
        let mut l = Loop::new(params(), Vec3::zeros(), cut());
        // The proxy's mean over a tremor period at 1 s and at 3 s.
        let (mut at_one, mut at_three) = (0.0, 0.0);
        for k in 0..3000 {
            l.tick(hand(k as f64 * H));
            let x = l.coupling.position().x / 10.0;
            if (1000..1010).contains(&k) {
                at_one += x;
            }
            if k >= 2990 {
                at_three += x;
            }
        }
        let moved = at_three - at_one;
        println!(
            "leaning at {lean} of the breakaway and trembling: the proxy moved {moved:.3e} m \
             in 2 s"
        );
        assert!(moved.abs() < 1e-9, "crept {moved} m");
        // It is held by the bristle at 90 % of its breakaway, not resting.
        let f = l.coupling.cutting_force().x;
        assert!((f / STRENGTH + 0.9).abs() < 0.05, "{f}");
    }
}

/// A stiffer bristle handed over while the proxy sticks keeps the force, not the stretch:
/// the same stretch in a spring four times as stiff would hold four times the energy put in,
/// and could give it to the hand.
#[test]
fn a_new_bristle_stiffness_keeps_the_force_not_the_stretch() {
    let p = params();
    let offset = 0.5 * STRENGTH * (1.0 / p.stiffness + 1.0 / cut().stiffness);
    let mut l = Loop::new(params(), Vec3::zeros(), cut());
    for k in 0..1500 {
        let ramp = (k as f64 * H / 0.2).min(1.0);
        l.tick(Vec3::new(offset * ramp, 0.0, 0.0));
    }
    let before = l.coupling.cutting_force().x;
    let stiffer = CutModel::new(Vec3::z(), STRENGTH, 4.0 * cut().stiffness).unwrap();
    l.coupling.set_cut(stiffer);
    l.tick(Vec3::new(offset, 0.0, 0.0));
    let after = l.coupling.cutting_force().x;
    println!("held at {before:.6} N; the bristle four times stiffer: {after:.6} N");
    assert!((before / STRENGTH + 0.5).abs() < 0.05, "{before}");
    assert!(
        (after - before).abs() < 0.05 * before.abs(),
        "the force jumped from {before} to {after}"
    );
}

/// Drawn along its edge, or with no cut (not cutting, or cutting nothing), the hand feels
/// exactly what the coupling alone gives.
#[test]
fn along_the_edge_or_not_cutting_the_cut_adds_nothing() {
    let stroke = |t: f64| Vec3::new(0.0, 0.0, 0.05 * t + 0.01 * (30.0 * t).sin());
    let free = forces(CutModel::NONE, 800, stroke);
    let along = forces(cut(), 800, stroke);
    let nothing = forces(
        CutModel::new(Vec3::z(), 0.0, cut().stiffness).unwrap(),
        800,
        stroke,
    );
    let worst = free
        .iter()
        .zip(&along)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    println!("along the edge: largest difference from the coupling alone {worst:.1e} N");
    assert!(worst <= 1e-12, "{worst}");
    assert_eq!(free, nothing);
    // Across the edge with no cut: the coupling alone, which ends at rest with no force.
    let across = forces(CutModel::NONE, 800, |t| Vec3::x() * (0.05 * t));
    assert!(across.last().unwrap().norm() < 1e-3 * STRENGTH);
}

/// Models that are not finite or out of range are refused with `HapticError::BadModel`
/// naming the number; `publish` hands over nothing then, and a coupling ignores them.
#[test]
fn bad_cut_models_are_refused_by_name() {
    let k = cut().stiffness;
    let cases = [
        (CutModel::new(Vec3::new(f64::NAN, 0.0, 1.0), 1.0, k), "edge"),
        (CutModel::new(Vec3::zeros(), 1.0, k), "edge"),
        (CutModel::new(Vec3::z(), f64::NAN, k), "strength"),
        (CutModel::new(Vec3::z(), -1.0, k), "strength"),
        (CutModel::new(Vec3::z(), f64::INFINITY, k), "strength"),
        (CutModel::new(Vec3::z(), 1.0, 0.0), "stiffness"),
        (CutModel::new(Vec3::z(), 1.0, f64::NAN), "stiffness"),
    ];
    for (result, field) in cases {
        match result {
            Err(HapticError::BadModel { what, .. }) => assert_eq!(what, field),
            other => panic!("{field}: {other:?}"),
        }
    }
    let broken = CutModel {
        strength: f64::NAN,
        ..cut()
    };
    assert!(matches!(
        broken.validate(),
        Err(HapticError::BadModel {
            what: "strength",
            ..
        })
    ));
    let skewed = CutModel {
        edge: Vec3::new(0.0, 0.0, 2.0),
        ..cut()
    };
    assert!(matches!(
        skewed.validate(),
        Err(HapticError::BadModel { what: "edge", .. })
    ));
    // The loop's cell: a refused model hands over nothing.
    let thread = HapticThread::spawn(
        Box::new(soft_tissue_core::haptics::NullDevice::new(Vec3::zeros())),
        HapticConfig {
            record_seconds: 1.0,
            stats_seconds: 1.0,
            ..HapticConfig::default()
        },
    )
    .unwrap();
    let shared = thread.shared();
    shared.publish(&ContactModel::NONE, &cut()).unwrap();
    assert!(matches!(
        shared.publish(&ContactModel::NONE, &broken),
        Err(HapticError::BadModel { .. })
    ));
    assert_eq!(shared.cut_model(), cut());
    thread.stop().unwrap();
    // A coupling keeps its cut.
    let mut c = Coupling::new(params(), Vec3::zeros());
    c.set_cut(cut());
    c.set_cut(broken);
    assert_eq!(*c.cut(), cut());
    // The physics side: a stiffness that is not usable.
    let blade = Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap();
    assert!(matches!(
        cut_model(&blade, f64::NAN),
        Err(HapticError::BadModel {
            what: "stiffness",
            ..
        })
    ));
    assert!(cut_model(&blade, -1.0).is_err());
}

/// A block 4 x 2 x 2 cm of soft tissue with the liver's toughness, held at its bottom.
fn block_world() -> SoftTissueWorld {
    let mesh = block(Vec3::zeros(), Vec3::new(0.04, 0.02, THICK), [4, 2, 2]).unwrap();
    let mass = 1000.0 * mesh.volume();
    let fem = FemParams {
        young_modulus: 2.0e4,
        poisson_ratio: 0.4,
        mass,
        damping: 0.0,
    };
    let msd = MsdParams {
        stiffness: 200.0,
        mass,
        damping: 0.0,
    };
    let mut s = BodySettings::new(fem, msd, 0.005);
    s.precise = PreciseMethod::LinearFem;
    s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
    let mut b = WorldBody::new("block", Arc::new(mesh), s, None).unwrap();
    b.set_toughness(LIVER).unwrap();
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt: 0.005,
        contact: ContactConfig::for_scale(0.1),
    })
    .unwrap();
    w.add_body(b).unwrap();
    w
}

/// From the physics: a blade resting in the block with cutting on hands over the toughness
/// times the block's thickness along its edge (though, at rest, it is not held back), its
/// edge's direction, and nothing with cutting off or outside the tissue; the loop then
/// renders that force on a stroke (through the thread, with a replayed hand).
#[test]
fn the_physics_hands_over_the_toughness_times_the_length_and_the_loop_renders_it() {
    let mut w = block_world();
    let mut blade = Tool::new("scalpel", ToolShape::Blade { length: 0.06 }).unwrap();
    let inside = Vec3::new(0.005, 0.015, -0.02);
    blade.set_pose(inside, Vec3::z()).unwrap();
    let t = w.add_tool(blade);
    let k = CutModel::STIFFNESS_PER_COUPLING * params().stiffness;
    w.step_fixed().unwrap();
    // Cutting off: no cut model.
    assert_eq!(cut_model(&w.tools()[t], k).unwrap(), CutModel::NONE);
    w.tools_mut()[t].set_cutting(true).unwrap();
    w.step_fixed().unwrap();
    let tool = &w.tools()[t];
    assert_eq!(tool.cutting_resistance(), Vec3::zeros(), "at rest");
    let m = cut_model(tool, k).unwrap();
    println!(
        "resting in the block: strength {:.6} N against J times the thickness {STRENGTH:.6} N, \
         edge {:?}",
        m.strength, m.edge
    );
    assert!((m.strength - STRENGTH).abs() <= 1e-12 * STRENGTH);
    assert!((m.edge - Vec3::z()).norm() <= 1e-12);
    assert!(m.active && m.stiffness == k);
    // Moved out of the tissue (above the block): nothing.
    w.tools_mut()[t]
        .set_pose(Vec3::new(0.005, 0.05, -0.02), Vec3::z())
        .unwrap();
    w.step_fixed().unwrap();
    assert_eq!(cut_model(&w.tools()[t], k).unwrap(), CutModel::NONE);

    // Through the thread: a hand replayed stroking across the edge at 5 cm/s for 1 s, read
    // at 0.6 s.
    let samples = (0..=1000)
        .map(|i| {
            let t = i as f64 * H;
            RecordedSample {
                t,
                position: [0.05 * t, 0.0, 0.0],
                buttons: 0,
            }
        })
        .collect();
    let recording = Recording {
        rate_hz: 1000.0,
        samples,
        truncated: false,
    };
    let config = HapticConfig {
        coupling: params(),
        record_seconds: 2.0,
        stats_seconds: 2.0,
        ..HapticConfig::default()
    };
    let device = ReplayDevice::new(recording, 1e3).unwrap();
    let thread = HapticThread::spawn(Box::new(device), config).unwrap();
    thread.shared().publish(&ContactModel::NONE, &m).unwrap();
    let seen = thread.shared().ticks();
    while thread.shared().ticks() < 600 {
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let sample = thread.shared().tool();
    let run = thread.stop().unwrap();
    println!(
        "through the thread (model handed over at tick {seen}): tick {} force {:.5} N",
        sample.tick, sample.force
    );
    // Handed over within the first ticks; by tick 600 the stroke has long settled.
    assert!(seen < 100, "{seen}");
    assert!(run.ticks >= 600);
    assert!(
        (sample.force + Vec3::x() * STRENGTH).norm() <= 2e-3 * STRENGTH,
        "{}",
        sample.force
    );
}

/// How stiff the bristle should be, measured (printed with `--nocapture`): for bristles of 1,
/// 4, 16 and 64 times the coupling's stiffness, the hand's travel until the force stays
/// within 1 % of the breakaway force on strokes at 0.5 and 5 cm/s, the force's spread over
/// the last half second of the slow stroke (stick-slip would show here), and under a +-0.1 mm
/// tremor at 100 and 200 Hz the peak force and the work on the hand per period. Asserts
/// what must hold for every stiffness: the stroke reaches the breakaway force, the tremor's
/// force stays below the coupling's bound, and no work goes to the hand.
#[test]
fn the_bristle_stiffness_measured() {
    let p = params();
    println!(
        "bristle/coupling | travel to 1 % at 0.5 / 5 cm/s (mm) | slow stroke spread (N) | \
         tremor 100 / 200 Hz: peak (N), work per period (J) environment / held"
    );
    for ratio in [1.0, 4.0, 16.0, 64.0] {
        let c = CutModel::new(Vec3::z(), STRENGTH, ratio * p.stiffness).unwrap();
        let mut travel = Vec::new();
        let mut spread = 0.0;
        for speed in [0.005, 0.05] {
            let ticks = 8000;
            let f = forces(c, ticks, |t| Vec3::x() * (speed * t));
            let within = |f: &Vec3| (f + Vec3::x() * STRENGTH).norm() <= 1e-2 * STRENGTH;
            let last_out = f.iter().rposition(|f| !within(f)).map_or(0, |k| k + 1);
            assert!(last_out < ticks - 100, "{ratio}: never settled at {speed}");
            travel.push(speed * last_out as f64 * H * 1e3);
            if speed < 0.01 {
                let tail = &f[ticks - 500..];
                let (lo, hi) = tail
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(l, h), f| (l.min(f.x), h.max(f.x)));
                spread = hi - lo;
            }
        }
        let mut tremor = Vec::new();
        for hz in [100.0, 200.0] {
            let w = 2.0 * std::f64::consts::PI * hz;
            let hand = |t: f64| Vec3::x() * (1e-4 * (w * t).sin());
            let ticks = 2000;
            let f = forces(c, ticks, hand);
            let period = (1.0 / (hz * H)).round() as usize;
            let (held, environment) = work(&f, hand, ticks - 1, 10, period);
            let peak = f.iter().map(|f| f.norm()).fold(0.0, f64::max);
            assert!(
                peak <= (p.stiffness + p.damping() * w) * 1e-4,
                "{ratio} {hz}"
            );
            assert!(environment <= 0.0, "{ratio} {hz}: {environment}");
            tremor.push(format!("{peak:.4}, {environment:.2e} / {held:.2e}"));
        }
        println!(
            "{ratio:>4} | {:.2} / {:.2} | {spread:.1e} | {} / {}",
            travel[0], travel[1], tremor[0], tremor[1]
        );
    }
}
