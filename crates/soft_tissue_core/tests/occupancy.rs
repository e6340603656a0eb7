//! The share of an electrode's surroundings that is tissue, against the geometry's own
//! closed forms: a half-space 1/2, a right-angled edge 1/4, a corner 1/8, the floor of a
//! hemispherical crater `(1 + min(rho / 2R, R / rho)) / 2`; and the world's electrode gives a
//! new spot that share.

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::cut::{Ball, carve};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::mesh::occupancy::{DIRECTIONS, sphere_share_inside};
use soft_tissue_core::world::burn::{FRACTION_RADII, tissue_fraction};

/// What a lattice of [`DIRECTIONS`] points may miss a cap's area share by (a few rows of
/// points).
fn lattice_tolerance() -> f64 {
    4.0 / (DIRECTIONS as f64).sqrt() / 2.0
}

#[test]
fn faces_edges_and_corners_of_a_block() {
    let mesh = block(Vec3::zeros(), Vec3::new(4.0, 3.0, 2.0), [8, 6, 4]).unwrap();
    let radii = [0.1, 0.2, 0.3];
    let tol = lattice_tolerance();
    let cases = [
        ("inside", Vec3::new(2.0, 1.5, 1.0), 1.0),
        ("outside", Vec3::new(5.0, 1.5, 1.0), 0.0),
        ("top face", Vec3::new(2.1, 1.3, 2.0), 0.5),
        ("side face", Vec3::new(4.0, 1.3, 0.7), 0.5),
        ("edge", Vec3::new(4.0, 1.4, 2.0), 0.25),
        ("corner", Vec3::new(0.0, 0.0, 0.0), 0.125),
    ];
    for (what, centre, expected) in cases {
        let got = sphere_share_inside(&mesh, &centre, &radii);
        println!("{what}: {got:.4} (closed form {expected})");
        assert!(
            (got - expected).abs() <= tol,
            "{what}: {got} against {expected} (tolerance {tol})"
        );
    }
    assert_eq!(sphere_share_inside(&mesh, &Vec3::zeros(), &[]), 0.0);
    assert_eq!(
        sphere_share_inside(&mesh, &Vec3::new(f64::NAN, 0.0, 0.0), &radii),
        0.0
    );
}

/// Hemispherical crater of radius `big_r` in the top face of a block: on the sphere of
/// radius `rho` about the crater's floor, the void is the cap within the ball (`cos > rho /
/// 2R`) together with the cap above the face (`cos > R / rho`), both about the face's normal.
fn crater_floor_share(rho: f64, big_r: f64) -> f64 {
    (1.0 + (rho / (2.0 * big_r)).min(big_r / rho).min(1.0)) / 2.0
}

#[test]
fn the_floor_of_a_crater_is_more_than_half_tissue() {
    // Elements of 0.25 about a crater of 0.5: the carve's faceted wall lies within its
    // sphere (warped nodes on it, facets a chord inside).
    let mesh = block(Vec3::zeros(), Vec3::new(4.0, 4.0, 2.0), [16, 16, 8]).unwrap();
    let big_r = 0.5;
    let top = Vec3::new(2.05, 1.95, 2.0);
    let cut = carve(
        &mesh,
        None,
        &[Ball {
            centre: top,
            radius: big_r,
        }],
        0.3,
    )
    .unwrap();
    let floor = top - Vec3::new(0.0, 0.0, big_r * 0.98);
    for rho in [0.25, 0.4, 0.7, 1.0] {
        let got = sphere_share_inside(&cut.mesh, &floor, &[rho]);
        let expected = crater_floor_share(rho, big_r);
        println!("rho {rho}: {got:.4} (closed form {expected:.4})");
        // The wall's chords and the centre set a little above the faceted floor leave a
        // little more tissue than the ball's closed form.
        assert!(
            (got - expected).abs() <= 0.03,
            "rho {rho}: {got} against {expected}"
        );
        assert!(
            got > 0.5 + 0.05,
            "the crater's floor is more than half tissue"
        );
    }
    // The world's rule (clamped, at its own radii) on the flat face and in the crater.
    let a = 0.05;
    let flat = tissue_fraction(&mesh, &top, a);
    assert!((flat - 0.5).abs() <= lattice_tolerance(), "{flat}");
    let sunk = tissue_fraction(&cut.mesh, &floor, big_r / FRACTION_RADII[1]);
    let expected: f64 = FRACTION_RADII
        .iter()
        .map(|k| crater_floor_share(k * big_r / FRACTION_RADII[1], big_r))
        .sum::<f64>()
        / FRACTION_RADII.len() as f64;
    println!("world rule: flat {flat:.4}, crater floor {sunk:.4} (closed form {expected:.4})");
    assert!((sunk - expected).abs() <= 0.03, "{sunk} against {expected}");
}
