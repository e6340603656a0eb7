//! The share of a sphere inside a mesh found through the grid of its tetrahedra is the one a
//! scan of every tetrahedron gives, to the bit, anywhere about a mesh (its faces, a carved
//! crater, a real organ, outside it); a kept [`Occupancy`] answers for each mesh it is asked
//! about, and asked again it allocates nothing.

#![allow(unsafe_code)] // the counting allocator

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::sync::Arc;

use nalgebra::Matrix3;
use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::{Ball, carve};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::mesh::occupancy::{DIRECTIONS, Occupancy, sphere_share_inside};
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::SoftTissueWorld;
use soft_tissue_core::world::burn::{FRACTION_RADII, tissue_fraction, tissue_fraction_in};

/// Counts the allocations of the thread that opened a window (each test runs on its own).
struct Counting;

thread_local! {
    static OPEN: Cell<bool> = const { Cell::new(false) };
    static SEEN: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    if OPEN.try_with(Cell::get).unwrap_or(false) {
        let _ = SEEN.try_with(|s| s.set(s.get() + 1));
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

/// Allocations `f` makes on this thread.
fn allocations<R>(f: impl FnOnce() -> R) -> (usize, R) {
    SEEN.with(|s| s.set(0));
    OPEN.with(|o| o.set(true));
    let r = f();
    OPEN.with(|o| o.set(false));
    (SEEN.with(Cell::get), r)
}

/// The definition itself: of [`DIRECTIONS`] lattice points on each sphere, the share inside
/// some tetrahedron whose bounding box comes within the largest radius, every tetrahedron
/// of the mesh looked at.
fn scanned(mesh: &TetMesh, centre: &Vec3, radii: &[f64]) -> f64 {
    let reach = radii.iter().copied().fold(0.0, f64::max);
    if radii.is_empty()
        || !(reach.is_finite() && reach > 0.0)
        || !centre.iter().all(|c| c.is_finite())
    {
        return 0.0;
    }
    let p = mesh.positions();
    let near: Vec<(Vec3, Matrix3<f64>)> = mesh
        .tets()
        .iter()
        .filter_map(|t| {
            let x = t.map(|n| p[n as usize]);
            let (lo, hi) = x
                .iter()
                .fold((x[0], x[0]), |(lo, hi), v| (lo.inf(v), hi.sup(v)));
            let gap = (lo - centre).sup(&(centre - hi)).sup(&Vec3::zeros());
            if gap.norm() > reach {
                return None;
            }
            Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]])
                .try_inverse()
                .map(|inv| (x[0], inv))
        })
        .collect();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut inside = 0usize;
    for &r in radii {
        for i in 0..DIRECTIONS {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / DIRECTIONS as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f64;
            let q = centre + Vec3::new(s * a.cos(), s * a.sin(), z) * r;
            let hit = near.iter().any(|(x0, inv)| {
                let b = inv * (q - x0);
                let tol = -1e-12;
                b.x >= tol && b.y >= tol && b.z >= tol && b.x + b.y + b.z <= 1.0 - tol
            });
            inside += usize::from(hit);
        }
    }
    inside as f64 / (DIRECTIONS * radii.len()) as f64
}

/// A crater of radius 0.5 carved into the top of a 4 x 4 x 2 block of 0.25 elements (the
/// carve refines about it: elements of many sizes).
fn cratered_block() -> (TetMesh, Vec3) {
    let mesh = block(Vec3::zeros(), Vec3::new(4.0, 4.0, 2.0), [16, 16, 8]).unwrap();
    let top = Vec3::new(2.05, 1.95, 2.0);
    let ball = Ball {
        centre: top,
        radius: 0.5,
    };
    (carve(&mesh, None, &[ball], 0.3).unwrap().mesh, top)
}

/// The organs scene's liver (rest mesh, scene units).
fn liver() -> TetMesh {
    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let w = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    let i = w.body_index("Liver").unwrap();
    (**w.bodies()[i].mesh()).clone()
}

/// Points about `mesh`: on its surface nodes, at its nodes pushed out and in, and spread
/// over its box grown by a quarter (a fixed sequence).
fn centres(mesh: &TetMesh, count: usize) -> Vec<Vec3> {
    let bbox = mesh.bbox();
    let (lo, size) = (bbox.min - bbox.extent() * 0.25, bbox.extent() * 1.5);
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let x = mesh.positions();
    let mut out = Vec::new();
    for k in 0..count {
        let p = match k % 3 {
            0 => lo + Vec3::new(next() * size.x, next() * size.y, next() * size.z),
            1 => x[(next() * x.len() as f64) as usize % x.len()],
            _ => {
                let n = x[(next() * x.len() as f64) as usize % x.len()];
                n + Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * (0.1 * size.min())
            }
        };
        out.push(p);
    }
    out
}

/// Every centre: the one-off grid, a kept grid and the scan agree to the bit.
fn assert_same(mesh: &Arc<TetMesh>, centres: &[Vec3], radius: f64) -> (usize, usize) {
    let radii = FRACTION_RADII.map(|k| k * radius);
    let mut kept = Occupancy::default();
    let (mut partial, mut cases) = (0, 0);
    for c in centres {
        let want = scanned(mesh, c, &radii);
        assert_eq!(
            sphere_share_inside(mesh, c, &radii),
            want,
            "one-off at {c:?}"
        );
        assert_eq!(
            kept.sphere_share_inside(mesh, c, &radii),
            want,
            "kept at {c:?}"
        );
        cases += 1;
        if want > 0.0 && want < 1.0 {
            partial += 1;
        }
    }
    (partial, cases)
}

#[test]
fn the_grid_finds_what_a_scan_of_every_tetrahedron_finds() {
    let (cratered, top) = cratered_block();
    let cratered = Arc::new(cratered);
    let mut points = centres(&cratered, 600);
    // About the crater's floor and rim, where the refined elements are.
    for k in 0..40 {
        let a = k as f64 * 0.7;
        points.push(top + Vec3::new(0.5 * a.cos(), 0.5 * a.sin(), -0.1 * (k % 6) as f64));
    }
    let (partial, cases) = assert_same(&cratered, &points, 0.1);
    println!("cratered block: {cases} centres, {partial} on the surface");
    assert!(partial > 100, "only {partial} centres on the surface");
    // A real organ's mesh, at the electrode's size and at ten times it.
    let liver = Arc::new(liver());
    let points = centres(&liver, 300);
    let size = liver.bbox().extent().max();
    for radius in [0.003 * size, 0.03 * size] {
        let (partial, cases) = assert_same(&liver, &points, radius);
        println!("liver, radius {radius:.4}: {cases} centres, {partial} on the surface");
        assert!(partial > 20, "only {partial} centres on the surface");
    }
    // A flat slab, and radii larger than the mesh.
    let slab = Arc::new(block(Vec3::zeros(), Vec3::new(8.0, 8.0, 0.05), [32, 32, 1]).unwrap());
    let points = centres(&slab, 200);
    for radius in [0.02, 10.0] {
        assert_same(&slab, &points, radius);
    }
}

#[test]
fn a_kept_occupancy_answers_for_the_mesh_it_is_asked_about() {
    let (cratered, top) = cratered_block();
    let cratered = Arc::new(cratered);
    let whole = Arc::new(block(Vec3::zeros(), Vec3::new(4.0, 4.0, 2.0), [16, 16, 8]).unwrap());
    let floor = top - Vec3::new(0.0, 0.0, 0.49);
    let mut kept = Occupancy::default();
    // The floor of the crater is more than half tissue; without the crater, the spheres
    // about the same point lie inside.
    let r = 0.12;
    assert!(floor.z + FRACTION_RADII[2] * r < 2.0);
    for _ in 0..2 {
        let sunk = tissue_fraction_in(&mut kept, &cratered, &floor, r);
        let inside = tissue_fraction_in(&mut kept, &whole, &floor, r);
        assert_eq!(sunk, tissue_fraction(&cratered, &floor, r));
        assert_eq!(inside, tissue_fraction(&whole, &floor, r));
        assert!(sunk > 0.55 && sunk < 0.95, "{sunk}");
        assert_eq!(inside, 1.0);
    }
    // Bad input is 0 (the world's rule keeps it at 1/8), not a panic.
    assert_eq!(
        kept.sphere_share_inside(&whole, &Vec3::new(f64::NAN, 0.0, 0.0), &[0.1]),
        0.0
    );
    assert_eq!(kept.sphere_share_inside(&whole, &top, &[]), 0.0);
    assert_eq!(
        kept.sphere_share_inside(&whole, &top, &[f64::INFINITY]),
        0.0
    );
}

#[test]
fn a_kept_occupancy_asked_again_does_not_allocate() {
    let (cratered, top) = cratered_block();
    let cratered = Arc::new(cratered);
    let mut kept = Occupancy::default();
    let radii = FRACTION_RADII.map(|k| k * 0.2);
    // The first question builds the grid (and the inverses of the tetrahedra it meets).
    let (first, _) = allocations(|| kept.sphere_share_inside(&cratered, &top, &[1.0]));
    assert!(first > 0);
    // An electrode dragged across the crater: a spot every half radius.
    let (again, shares) = allocations(|| {
        let mut shares = [0.0; 16];
        for (k, s) in shares.iter_mut().enumerate() {
            let c = top + Vec3::new(0.05 * k as f64 - 0.4, 0.0, -0.3);
            *s = kept.sphere_share_inside(&cratered, &c, &radii);
        }
        shares
    });
    assert_eq!(again, 0, "{again} allocations asking again");
    assert!(shares.iter().any(|&s| s > 0.5), "{shares:?}");
}
