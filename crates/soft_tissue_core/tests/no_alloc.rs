//! A simulation step must not allocate: workspaces are sized when a body is built. A counting
//! global allocator (counting only on the test's own thread) checks every method.

#![allow(unsafe_code)] // the counting allocator

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemConfig, FemModel};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::msd::{ExplicitLimit, MsdBody, MsdConfig, MsdIntegrator};
use soft_tissue_core::scenario::{CYLINDER_MSD, ORGAN_FEM};
use soft_tissue_core::{NodalBody, Vec3};

struct Counting;

// Both per thread: tests run side by side, and one that allocates (a pool's job queue) must
// not show up in another's count.
thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    if COUNTING.with(|c| c.get()) {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
    }
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Allocations made by `f` on this thread.
fn allocations(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(|a| a.get());
    COUNTING.with(|c| c.set(true));
    f();
    COUNTING.with(|c| c.set(false));
    ALLOCATIONS.with(|a| a.get()) - before
}

/// Allocations during 50 loaded steps of `body`, energies and speed read after each.
fn allocations_in_steps<B: NodalBody>(
    body: &mut B,
    node: usize,
    step: fn(&mut B),
    elastic: fn(&B) -> f64,
) -> usize {
    allocations(|| {
        for s in 0..50 {
            body.add_force(node, Vec3::new((s as f64 * 0.3).sin(), 0.0, 0.0));
            step(body);
            let _ = body.kinetic_energy() + elastic(body) + body.max_speed();
        }
    })
}

#[test]
fn steps_do_not_allocate() {
    // The counter sees allocations at all.
    assert!(allocations(|| drop(std::hint::black_box(vec![0u8; 64]))) > 0);
    let mesh = block(Vec3::zeros(), Vec3::new(2.0, 1.0, 1.0), [4, 2, 2]).unwrap();
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let top = mesh.positions().len() - 1;
    for (model, lag) in [
        (FemModel::Linear, 0.0),
        (FemModel::Corotational, 0.0),
        (FemModel::Corotational, 0.01),
    ] {
        let mut c = FemConfig::paper(&ORGAN_FEM.params, 0.01);
        c.model = model;
        c.stiffness_update_angle = lag;
        c.gravity = Vec3::new(0.0, -9.81, 0.0);
        let mut body = FemBody::new(&mesh, c, &boundary).unwrap();
        body.step().unwrap();
        let n = allocations_in_steps(
            &mut body,
            top,
            |b| b.step().map(|_| ()).unwrap(),
            FemBody::elastic_energy,
        );
        assert_eq!(
            n, 0,
            "{model:?} (lag {lag}) allocated {n} times in 50 steps"
        );
    }
    for integrator in [
        MsdIntegrator::Rk4,
        MsdIntegrator::SymplecticEuler,
        MsdIntegrator::ImplicitEuler,
    ] {
        for volume in [0.0, 500.0] {
            let mut c = MsdConfig::paper(&CYLINDER_MSD.params, 0.02);
            c.integrator = integrator;
            c.volume_stiffness = volume;
            c.explicit_limit = ExplicitLimit::Substep { max_substeps: 1000 };
            c.gravity = Vec3::new(0.0, -9.81, 0.0);
            let mut body = MsdBody::from_mesh(&mesh, c, &boundary).unwrap();
            body.step().unwrap();
            let n = allocations_in_steps(
                &mut body,
                top,
                |b| b.step().map(|_| ()).unwrap(),
                MsdBody::elastic_energy,
            );
            assert_eq!(
                n, 0,
                "{integrator:?} (volume {volume}) allocated {n} times in 50 steps"
            );
        }
    }
}

#[test]
fn cage_and_leveled_body_steps_do_not_allocate() {
    use soft_tissue_core::cage::{CageBody, CageBodyConfig, FitOptions, fitted_cage};
    use soft_tissue_core::precision::{BodySettings, Level, LeveledBody};
    let mesh = block(Vec3::zeros(), Vec3::new(1.0, 2.0, 1.0), [3, 6, 3]).unwrap();
    let cage = fitted_cage(
        mesh.positions(),
        mesh.surface().triangles(),
        &FitOptions::for_points(mesh.positions(), 40),
    )
    .unwrap();
    let mut body = CageBody::new(cage, mesh.positions(), &CageBodyConfig::paper(0.02)).unwrap();
    let n = allocations(|| {
        for s in 0..50 {
            body.apply_point_force(3, Vec3::new((s as f64).sin(), 0.0, 0.0))
                .unwrap();
            body.step().unwrap();
        }
    });
    assert_eq!(n, 0, "cage body steps allocated {n} times");
    // A leveled body at either level, including the rest checks (the cage fit) at the
    // precise level; switches themselves may allocate and are kept out of the count.
    let mut s = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, ORGAN_FEM.dt);
    s.policy.rest_steps = 5;
    s.policy.min_precise_steps = 0;
    s.policy.rest_residual = -1.0; // the fit runs every 5 steps, the switch never happens
    let mut body = LeveledBody::new(&mesh, s).unwrap();
    let at_cage = allocations(|| {
        for _ in 0..50 {
            body.step(false).unwrap();
        }
    });
    assert_eq!(at_cage, 0, "cage-level steps allocated {at_cage} times");
    body.raise().unwrap();
    let at_precise = allocations(|| {
        for _ in 0..50 {
            body.step(false).unwrap();
        }
    });
    assert_eq!(body.level(), Level::Precise);
    assert_eq!(
        at_precise, 0,
        "precise-level steps allocated {at_precise} times"
    );
}

/// Allocations on the calling thread during a warm run of the organs under a poke of the
/// liver on `threads` threads (asserting none in any step for one thread).
fn world_step_allocations(threads: usize) -> usize {
    use soft_tissue_core::contact::Tool;
    use soft_tissue_core::scenario::Scene;
    use soft_tissue_core::world::{Script, SoftTissueWorld};
    let assets = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let mut world = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    world.set_threads(threads).unwrap();
    let script = Script::builtin("poke-liver", &world).unwrap();
    let tool = world.add_tool(Tool::new("tool", script.tool).unwrap());
    let dt = world.config().dt;
    let step = |world: &mut SoftTissueWorld, k: usize| {
        let (p, a) = script.pose_at((k + 1) as f64 * dt);
        world.tools_mut()[tool].set_pose(p, a).unwrap();
        world.step_fixed().unwrap();
    };
    // The first runs size every workspace (contact lists, the pairs' candidates; in a pool,
    // each worker thread's own lazily made state, whichever bodies it happened to step).
    for _ in 0..3 {
        for k in 0..700 {
            step(&mut world, k);
        }
        world.reset().unwrap();
    }
    // The same interaction again: contact, solvers, switches up and down, heat, writeback.
    let mut switches = 0;
    let mut total = 0;
    for k in 0..700 {
        let n = allocations(|| step(&mut world, k));
        if threads == 1 {
            assert_eq!(n, 0, "step {k} allocated {n} times");
        }
        total += n;
        switches += world
            .bodies()
            .iter()
            .filter(|b| b.diagnostics().switched.is_some())
            .count();
    }
    assert!(switches >= 4, "{switches} switches");
    total
}

/// One thread: no step allocates once the workspaces are sized.
#[test]
fn world_steps_do_not_allocate_once_warm() {
    assert_eq!(world_step_allocations(1), 0);
}

/// In a pool, handing each step to the pool goes through `rayon`'s job queue, which takes a
/// new block of slots about every 60 jobs (measured: one allocation every 40-60 steps on the
/// calling thread). Bounded here at one per 25 steps. (The counter sees the calling thread
/// only; the workers run the same allocation-free step code as the one-thread test.)
#[test]
fn world_steps_in_a_pool_allocate_only_the_job_queue_blocks() {
    let n = world_step_allocations(2);
    assert!(n <= 700 / 25, "{n} allocations in 700 steps");
}
