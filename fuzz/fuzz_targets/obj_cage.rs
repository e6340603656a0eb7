#![no_main]
//! Fuzz target: an OBJ surface becomes the embedded points of a box cage and of a fitted
//! cage, and (as in `cage deform --cage-rest`) a cage itself; Green coordinates of the points
//! follow. Every step returns Ok or a typed error; coordinates that are accepted are finite
//! and reproduce the rest points.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::Vec3;
use soft_tissue_core::cage::{Cage, FitOptions, GreenCoordinates, box_cage, fitted_cage};
use soft_tissue_core::mesh::io::parse_obj;

fn check(cage: &Cage, points: &[Vec3]) {
    let Ok(coords) = GreenCoordinates::new(cage, points) else {
        return;
    };
    // The rest cage maps every point to itself (up to rounding at the coordinates' scale).
    let mut terms = vec![Vec3::zeros(); coords.face_count()];
    coords.face_terms(cage.vertices(), &mut terms);
    let mut out = vec![Vec3::zeros(); points.len()];
    coords
        .evaluate(cage.vertices(), &terms, &mut out)
        .expect("lengths match");
    let scale = cage.vertices().iter().fold(1.0f64, |m, v| m.max(v.amax()));
    for (p, q) in points.iter().zip(&out) {
        assert!(q.iter().all(|c| c.is_finite()), "{p} maps to {q}");
        assert!((p - q).amax() <= 1e-3 * scale, "{p} maps to {q}");
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(surface) = parse_obj(data, "fuzz.obj") else {
        return;
    };
    let points = &surface.positions;
    // Green coordinates cost points x cage size: keep each run short.
    if points.len() > 256 || surface.triangles.len() > 512 {
        return;
    }
    let margin = soft_tissue_core::cage::build::default_margin(points);
    if let Ok(cage) = box_cage(points, margin) {
        check(&cage, points);
    }
    if let Ok(cage) = fitted_cage(
        points,
        &surface.triangles,
        &FitOptions::for_points(points, 32),
    ) {
        check(&cage, points);
    }
    if let Ok(cage) = Cage::from_surface(&surface) {
        let n = cage.vertices().len() as f64;
        let centre = cage.vertices().iter().sum::<Vec3>() / n;
        check(&cage, &[centre]);
    }
});
