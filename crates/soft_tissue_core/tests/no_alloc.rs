//! A simulation step must not allocate: workspaces are sized when a body is built.
//!
//! A counting global allocator counts every allocation of the process while a window is
//! open (an atomic flag), on whichever thread makes it: the caller's and a world's pool
//! workers alike. So that nothing else allocates in a window, this test binary has no test
//! harness (`harness = false` in `Cargo.toml`): `main` runs the cases one after another on
//! one thread (an optional argument keeps the cases whose name contains it).

#![allow(unsafe_code)] // the counting allocator

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::fem::{FemBody, FemConfig, FemIntegrator, FemModel};
use soft_tissue_core::mesh::generate::{Organ, block};
use soft_tissue_core::msd::{ExplicitLimit, MsdBody, MsdConfig, MsdIntegrator};
use soft_tissue_core::parallel::Threads;
use soft_tissue_core::precision::{Level, PreciseMethod};
use soft_tissue_core::scenario::{CYLINDER_MSD, MeshSource, ORGAN_FEM, Scene};
use soft_tissue_core::world::{Script, ScriptAction, SoftTissueWorld};
use soft_tissue_core::{NodalModel, Vec3};

struct Counting;

/// Whether a window is open.
static COUNTING: AtomicBool = AtomicBool::new(false);
/// Allocations (and reallocations) in open windows, on every thread.
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
/// The sizes of the first [`SIZES`] of them since the last [`allocations`] call.
const SIZES: usize = 64;
static SIZE: [AtomicUsize; SIZES] = [const { AtomicUsize::new(0) }; SIZES];

fn note(size: usize) {
    if COUNTING.load(Ordering::SeqCst) {
        let k = ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        if let Some(s) = SIZE.get(k) {
            s.store(size, Ordering::SeqCst);
        }
    }
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// What a window saw: how many allocations, on every thread, and the sizes of the first
/// [`SIZES`].
#[derive(Debug, Default, Clone)]
struct Seen {
    count: usize,
    sizes: Vec<usize>,
}

/// Allocations made by `f`, on every thread of the process, while it runs.
fn allocations(f: impl FnOnce()) -> Seen {
    ALLOCATIONS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
    f();
    COUNTING.store(false, Ordering::SeqCst);
    let count = ALLOCATIONS.load(Ordering::SeqCst);
    let sizes = SIZE[..count.min(SIZES)]
        .iter()
        .map(|s| s.load(Ordering::SeqCst))
        .collect();
    Seen { count, sizes }
}

/// The counter sees allocations on the calling thread and on a pool's worker threads (the
/// last seen only with a process-wide count: the old per-thread counter missed them).
fn counter_sees_allocations_on_every_thread() {
    let here = allocations(|| drop(std::hint::black_box(vec![0u8; 64])));
    assert_eq!(here.count, 1, "{here:?}");
    assert_eq!(here.sizes, [64]);
    let pool = Threads::new(2).unwrap();
    // Warm the pool first: every worker started and ran once (its own lazily made state; a
    // worker that starts late, on a loaded machine, would otherwise allocate in a later
    // test's window).
    pool.run(|| rayon::broadcast(|_| ()));
    let caller = std::thread::current().id();
    let mut on_worker = false;
    let seen = allocations(|| {
        on_worker = pool.run(|| {
            let v = std::hint::black_box(vec![0u8; 48]);
            drop(v);
            std::thread::current().id() != caller
        });
    });
    // Never dropped: a pool's workers exit (and free their thread-local state) after the pool
    // is dropped, at a time of their choosing, which could fall into a later window.
    std::mem::forget(pool);
    assert!(on_worker, "the pool ran the closure on the caller");
    assert!(
        seen.sizes.contains(&48),
        "an allocation on a worker was not counted: {seen:?}"
    );
}

/// Allocations during 50 loaded steps of `body`, energies and speed read after each.
fn allocations_in_steps<B: NodalModel>(
    body: &mut B,
    node: usize,
    step: fn(&mut B),
    elastic: fn(&B) -> f64,
) -> Seen {
    allocations(|| {
        for s in 0..50 {
            body.add_force(node, Vec3::new((s as f64 * 0.3).sin(), 0.0, 0.0));
            step(body);
            let _ = body.kinetic_energy() + elastic(body) + body.max_speed();
        }
    })
}

/// Every FEM model and integrator (the prefactored model has backward Euler only) and every
/// MSD integrator, 50 loaded steps each.
fn body_steps_do_not_allocate() {
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [4, 2, 2]).unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let top = mesh.positions().len() - 1;
    use FemIntegrator::{BackwardEuler, Bdf2};
    for (model, integrator, lag) in [
        (FemModel::Linear, BackwardEuler, 0.0),
        (FemModel::Linear, Bdf2, 0.0),
        (FemModel::Corotational, BackwardEuler, 0.0),
        (FemModel::Corotational, BackwardEuler, 0.01),
        (FemModel::Corotational, Bdf2, 0.01),
        (FemModel::CorotationalPrefactored, BackwardEuler, 0.01),
    ] {
        let mut c = FemConfig::paper(&ORGAN_FEM.params, 0.01);
        c.model = model;
        c.integrator = integrator;
        c.stiffness_update_angle = lag;
        c.gravity = Vec3::new(0.0, -9.81, 0.0);
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        // Two steps: BDF2 starts with one backward Euler step.
        for _ in 0..2 {
            body.step().unwrap();
        }
        let n = allocations_in_steps(
            &mut body,
            top,
            |b| b.step().map(|_| ()).unwrap(),
            FemBody::elastic_energy,
        );
        assert_eq!(
            n.count, 0,
            "{model:?} {integrator:?} (lag {lag}) allocated in 50 steps: {n:?}"
        );
    }
    for integrator in [
        MsdIntegrator::Rk4,
        MsdIntegrator::SymplecticEuler,
        MsdIntegrator::ImplicitEuler,
        MsdIntegrator::ImplicitBdf2,
    ] {
        for volume in [0.0, 500.0] {
            let mut c = MsdConfig::paper(&CYLINDER_MSD.params, 0.02);
            c.integrator = integrator;
            c.volume_stiffness = volume;
            c.explicit_limit = ExplicitLimit::Substep { max_substeps: 1000 };
            c.gravity = Vec3::new(0.0, -9.81, 0.0);
            let mut body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
            for _ in 0..2 {
                body.step().unwrap();
            }
            let n = allocations_in_steps(
                &mut body,
                top,
                |b| b.step().map(|_| ()).unwrap(),
                MsdBody::elastic_energy,
            );
            assert_eq!(
                n.count, 0,
                "{integrator:?} (volume {volume}) allocated in 50 steps: {n:?}"
            );
        }
    }
}

/// A cage body, and a leveled model at either level with each FEM model (the rest checks'
/// cage fit included at the precise level).
fn cage_and_leveled_body_steps_do_not_allocate() {
    use soft_tissue_core::cage::{CageModel, CageModelConfig, FitOptions, fitted_cage};
    use soft_tissue_core::precision::{BodySettings, LeveledModel};
    let mesh = block(Vec3::zeros(), Vec3::new(1.0, 2.0, 1.0), [3, 6, 3]).unwrap();
    let cage = fitted_cage(
        mesh.positions(),
        mesh.surface().triangles(),
        &FitOptions::for_points(mesh.positions(), 40),
    )
    .unwrap();
    let mut body = CageModel::new(cage, mesh.positions(), &CageModelConfig::paper(0.02)).unwrap();
    let n = allocations(|| {
        for s in 0..50 {
            body.apply_point_force(3, Vec3::new((s as f64).sin(), 0.0, 0.0))
                .unwrap();
            body.step().unwrap();
        }
    });
    assert_eq!(n.count, 0, "cage body steps allocated: {n:?}");
    // Switches themselves may allocate and are kept out of the count.
    for (method, integrator) in [
        (PreciseMethod::CorotationalFem, FemIntegrator::BackwardEuler),
        (PreciseMethod::CorotationalFem, FemIntegrator::Bdf2),
        (PreciseMethod::PrefactoredFem, FemIntegrator::BackwardEuler),
    ] {
        let mut s = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
        s.precise = method;
        s.fem_integrator = integrator;
        s.policy.rest_steps = 5;
        s.policy.min_precise_steps = 0;
        s.policy.rest_residual = -1.0; // the fit runs every 5 steps, the switch never happens
        let mut body = LeveledModel::new(&mesh, s).unwrap();
        let at_cage = allocations(|| {
            for _ in 0..50 {
                body.step(false).unwrap();
            }
        });
        assert_eq!(
            at_cage.count, 0,
            "{method:?}: cage-level steps allocated: {at_cage:?}"
        );
        body.raise().unwrap();
        body.step(false).unwrap();
        let at_precise = allocations(|| {
            for _ in 0..50 {
                body.step(false).unwrap();
            }
        });
        assert_eq!(body.level(), Level::Precise);
        assert_eq!(
            at_precise.count, 0,
            "{method:?} {integrator:?}: precise-level steps allocated: {at_precise:?}"
        );
    }
}

/// How the bodies of a world run are set up.
#[derive(Debug, Clone, Copy)]
enum Bodies {
    /// The organs scene as it is (levels switch with contact).
    Organs,
    /// The organs scene, every body rising to the prefactored corotational model.
    Prefactored,
    /// The organs scene, every body rising to corotational FEM with BDF2.
    Bdf2,
    /// The organs with the liver at twice the paper's resolution (2513 nodes, 8321
    /// tetrahedra: its element loop, corner sums and stiffness updates split in a pool),
    /// every body held at its precise level.
    LargeLiver,
    /// The organs with an electrode of 1 mm held pressed into the liver at 0.5 W (the
    /// `cauterize-liver` script at a power that boils nothing, so nothing is carved): the
    /// electrode's spot, its sub-grid field and the tissue fraction every step.
    Electrode,
}

/// Allocations, on every thread, in each step of a warm run of the organs under a poke of
/// the liver on `threads` threads: per step, and the bodies' switches in the run.
/// Also the steps in which an electrode's spot started (its shells and nodes are allocated
/// once, when a burn begins at a new place).
fn world_step_allocations(
    bodies: Bodies,
    threads: usize,
    steps: usize,
) -> (Vec<Seen>, usize, Vec<usize>) {
    let assets = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let mut scene = Scene::paper_organs();
    if let Bodies::LargeLiver = bodies {
        for b in scene.bodies.iter_mut().filter(|b| b.name == "Liver") {
            b.mesh = MeshSource::Generated {
                organ: Organ::Liver,
                resolution: 2.0,
            };
        }
    }
    let mut world = SoftTissueWorld::from_scene(&scene, assets).unwrap();
    world.set_threads(threads).unwrap();
    for b in world.bodies_mut() {
        let mesh = b.mesh().clone();
        let body = b.model_mut();
        match bodies {
            Bodies::Organs => {}
            Bodies::Prefactored => body
                .set_precise_method(&mesh, PreciseMethod::PrefactoredFem)
                .unwrap(),
            Bodies::Bdf2 => {
                body.set_precise_method(&mesh, PreciseMethod::CorotationalFem)
                    .unwrap();
                body.set_fem_integrator(FemIntegrator::Bdf2).unwrap();
            }
            Bodies::LargeLiver => {
                body.pin(Some(Level::Precise)).unwrap();
            }
            Bodies::Electrode => {}
        }
    }
    let script = match bodies {
        Bodies::Electrode => {
            let mut s = Script::builtin("cauterize-liver", &world).unwrap();
            for e in &mut s.events {
                if let ScriptAction::Cautery(w) = &mut e.action
                    && *w > 0.0
                {
                    *w = 0.5;
                }
            }
            s
        }
        _ => Script::builtin("poke-liver", &world).unwrap(),
    };
    let tool = world.add_tool(Tool::new("tool", script.tool).unwrap());
    let dt = world.config().dt;
    let step = |world: &mut SoftTissueWorld, k: usize| {
        let t = (k + 1) as f64 * dt;
        let (p, a) = script.pose_at(t);
        world.tools_mut()[tool].set_pose(p, a).unwrap();
        // The electrode's power switched as its script says (the pokes only move).
        if let Bodies::Electrode = bodies {
            for e in script.events_in(t - dt, t) {
                e.action.apply(&mut world.tools_mut()[tool]).unwrap();
            }
        }
        world.step_fixed().unwrap();
    };
    // The first runs size every workspace (contact lists, the pairs' candidates; in a pool,
    // each worker thread's own lazily made state, whichever bodies it happened to step).
    for _ in 0..3 {
        for k in 0..steps {
            step(&mut world, k);
        }
        world.reset().unwrap();
    }
    // The same interaction again: contact, solvers, switches up and down, heat, writeback.
    let mut switches = 0;
    let mut seen = Vec::with_capacity(steps);
    let spots = |w: &SoftTissueWorld| -> usize {
        w.bodies()
            .iter()
            .filter_map(|b| b.heat().map(|h| h.spot_count()))
            .sum()
    };
    let mut started = Vec::new();
    for k in 0..steps {
        let before = spots(&world);
        seen.push(allocations(|| step(&mut world, k)));
        if spots(&world) > before {
            started.push(k);
        }
        switches += world
            .bodies()
            .iter()
            .filter(|b| b.diagnostics().switched.is_some())
            .count();
    }
    // Never dropped, like the pool above: its workers stay asleep for the rest of the run.
    std::mem::forget(world);
    (seen, switches, started)
}

/// One thread: no step allocates once the workspaces are sized, on any setup.
fn world_steps_do_not_allocate_once_warm() {
    for (bodies, steps) in [
        (Bodies::Organs, 700),
        (Bodies::Prefactored, 700),
        (Bodies::Bdf2, 700),
        (Bodies::LargeLiver, 320),
        (Bodies::Electrode, 300),
    ] {
        let (seen, switches, started) = world_step_allocations(bodies, 1, steps);
        for (k, s) in seen.iter().enumerate() {
            if !started.contains(&k) {
                assert_eq!(s.count, 0, "{bodies:?}: step {k} allocated: {s:?}");
            }
        }
        // The electrode burns at one place: one spot, then steps pressed on it.
        if let Bodies::Electrode = bodies {
            assert_eq!(started.len(), 1, "spots started at steps {started:?}");
            assert!(
                started[0] + 100 < steps,
                "the spot started at {}",
                started[0]
            );
        } else {
            assert!(started.is_empty());
        }
        if !matches!(bodies, Bodies::LargeLiver | Bodies::Electrode) {
            assert!(switches >= 4, "{bodies:?}: {switches} switches");
        }
    }
}

/// In a pool, handing each step to the pool goes through `rayon`'s injector queue, which
/// takes a new block of slots every 63 jobs (`crossbeam-deque`'s block holds 63 jobs); the
/// steps themselves, on every worker, allocate nothing. So the only allocations in a pool's
/// run are blocks of one size, at most one per 50 steps.
fn world_steps_in_a_pool_allocate_only_the_job_queue_blocks() {
    for (bodies, steps) in [
        (Bodies::Organs, 700),
        (Bodies::Prefactored, 700),
        (Bodies::Bdf2, 700),
        (Bodies::LargeLiver, 320),
    ] {
        let (seen, _, _) = world_step_allocations(bodies, 2, steps);
        let total: usize = seen.iter().map(|s| s.count).sum();
        let sizes: Vec<usize> = seen.iter().flat_map(|s| s.sizes.iter().copied()).collect();
        println!(
            "  {bodies:?} on 2 threads: {total} allocations in {steps} steps, sizes {sizes:?}"
        );
        assert!(
            total <= steps / 50 + 1,
            "{bodies:?}: {total} allocations in {steps} steps: {sizes:?}"
        );
        assert!(
            sizes.windows(2).all(|w| w[0] == w[1]),
            "{bodies:?}: allocations of several sizes: {sizes:?}"
        );
        for (k, s) in seen.iter().enumerate() {
            assert!(s.count <= 1, "{bodies:?}: step {k} allocated: {s:?}");
        }
    }
}

/// The haptic loop renders a blade's cut without allocating: a loop driven by a replayed
/// hand that rests, strokes across the edge at 5 cm/s (the cut's friction stuck, then
/// slipping at its breakaway force) and trembles, while the physics hands over a cut model
/// every 10 ms, some refused as invalid.
fn haptic_loop_with_a_cut_does_not_allocate() {
    use soft_tissue_core::haptics::{
        ContactModel, CouplingParams, CutModel, HapticConfig, HapticThread, RecordedSample,
        Recording, ReplayDevice,
    };
    let h = 1e-3;
    let samples = (0..=1600)
        .map(|i| {
            let t = i as f64 * h;
            let x = 0.05 * (t - 0.1).clamp(0.0, 1.0)
                + 1e-4 * (2.0 * std::f64::consts::PI * 100.0 * t).sin() * f64::from(t > 1.1);
            RecordedSample {
                t,
                position: [x, 0.0, 0.0],
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
        coupling: CouplingParams {
            max_force: 1e3,
            ..CouplingParams::default()
        },
        record_seconds: 3.0,
        stats_seconds: 3.0,
        ..HapticConfig::default()
    };
    let thread =
        HapticThread::spawn(Box::new(ReplayDevice::new(recording, 1e3).unwrap()), config).unwrap();
    let shared = thread.shared().clone();
    // The thread's first ticks (its own lazily made state) are kept out of the count.
    while shared.ticks() < 20 {
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    let strength = 164.0 * 0.02;
    let cut = CutModel::new(Vec3::z(), strength, 1600.0).unwrap();
    let broken = CutModel {
        strength: f64::NAN,
        ..cut
    };
    let mut refused = 0;
    let seen = allocations(|| {
        for k in 0..150 {
            // The length in tissue varies a little from step to step.
            let model = CutModel {
                strength: strength * (1.0 + 0.01 * (k as f64).sin()),
                ..cut
            };
            let handed = if k % 25 == 24 { broken } else { model };
            if shared.publish(&ContactModel::NONE, &handed).is_err() {
                refused += 1;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    });
    let ticks = shared.ticks();
    let run = thread.stop().unwrap();
    println!(
        "  haptic loop with a cut: {} allocations in {ticks} ticks, largest force {:.3} N \
         (breakaway {strength:.3} N), {refused} models refused",
        seen.count, run.max_force
    );
    assert_eq!(seen.count, 0, "the haptic loop allocated: {seen:?}");
    assert_eq!(refused, 6);
    // The cut was rendered: slipping at about its breakaway force.
    assert!(run.max_force > 0.95 * strength, "{}", run.max_force);
}

fn main() {
    let cases: [(&str, fn()); 6] = [
        (
            "counter_sees_allocations_on_every_thread",
            counter_sees_allocations_on_every_thread,
        ),
        ("body_steps_do_not_allocate", body_steps_do_not_allocate),
        (
            "cage_and_leveled_body_steps_do_not_allocate",
            cage_and_leveled_body_steps_do_not_allocate,
        ),
        (
            "world_steps_do_not_allocate_once_warm",
            world_steps_do_not_allocate_once_warm,
        ),
        (
            "world_steps_in_a_pool_allocate_only_the_job_queue_blocks",
            world_steps_in_a_pool_allocate_only_the_job_queue_blocks,
        ),
        (
            "haptic_loop_with_a_cut_does_not_allocate",
            haptic_loop_with_a_cut_does_not_allocate,
        ),
    ];
    // `cargo test` passes the harness's flags and an optional filter; a filter keeps the
    // cases whose name contains it, `--list` lists them.
    let args: Vec<String> = std::env::args().skip(1).collect();
    let filter = args.iter().find(|a| !a.starts_with('-'));
    let selected: Vec<_> = cases
        .iter()
        .filter(|(name, _)| filter.is_none_or(|f| name.contains(f.as_str())))
        .collect();
    // No case is ignored: `--ignored` runs none.
    if args.iter().any(|a| a == "--ignored") {
        println!("\nrunning 0 tests\n\ntest result: ok. 0 passed");
        return;
    }
    if args.iter().any(|a| a == "--list") {
        for (name, _) in &selected {
            println!("{name}: test");
        }
        return;
    }
    println!("\nrunning {} tests", selected.len());
    for (name, case) in &selected {
        println!("test {name} ...");
        case();
        println!("test {name} ... ok");
    }
    println!("\ntest result: ok. {} passed", selected.len());
}
