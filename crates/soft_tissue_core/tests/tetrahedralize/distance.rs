//! Meshing to a distance: the walls' thickness against the closed form, and the count grown
//! until the boundary lies within 1 % of the diagonal, on generated cups.

use std::f64::consts::PI;

use soft_tissue_core::mesh::tetrahedralize::{
    DistanceGoal, tetrahedralize_to_distance, wall_advice,
};

use super::shapes::cup;
use super::volume_of;

/// The cup's volume in closed form: the cylinder less the hollow.
fn cup_volume(radius: f64, height: f64, wall: f64) -> f64 {
    PI * radius * radius * height - PI * (radius - wall).powi(2) * (height - wall)
}

/// The thin-walled cup of issue 40 (1 across, 1 high, its wall and bottom 2 % of its
/// diameter, 17,472 triangles): before any meshing, its walls are measured at their
/// thickness (the closed form: 0.02; the inscribed balls at the triangles' centroids touch
/// both sides of the wall), and the spacing advised is that thickness, the count far above
/// the mesher's default.
#[test]
fn a_thin_cup_s_walls_are_measured_before_meshing() {
    let s = cup(0.5, 1.0, 0.02, 96);
    assert_eq!(s.triangles.len(), 17_472);
    let a = wall_advice(&s).unwrap().expect("walls");
    eprintln!("{a:?}");
    assert!((a.walls.median / 0.02 - 1.0).abs() < 0.05, "{a:?}");
    assert!((0.8..=1.02).contains(&(a.walls.thin / 0.02)), "{a:?}");
    assert_eq!(a.spacing, a.walls.thin);
    assert!(a.tets > 50_000, "{a:?}");
    let text = a.describe();
    assert!(text.contains(&format!("{:.4}", a.walls.thin)), "{text}");
    // A ball's walls: more than half its diameter, the median 0.66 of it on this 48 x 24
    // grid (its facets lie at different depths, so the balls inside touching one at its
    // centroid are smaller than the sphere), 25 times the cup's or more.
    let ball = wall_advice(&super::shapes::sphere(0.5)).unwrap().unwrap();
    eprintln!("{ball:?}");
    assert!(
        ball.walls.thin > 0.5 && (0.6..0.72).contains(&ball.walls.median),
        "{ball:?}"
    );
}

/// A cup whose wall is a tenth of its diameter, meshed to 1 % of the diagonal: meshed at
/// the walls' spacing, then finer, until the boundary lies within 1 % both ways, the
/// volume within 3 % of the closed form; with a cap below what that takes, the search stops
/// at the cap and says so, naming the walls.
#[test]
fn a_cup_meshes_to_one_percent_by_growing_the_count() {
    let (radius, height, wall) = (0.5, 1.0, 0.1);
    let s = cup(radius, height, wall, 48);
    let goal = DistanceGoal {
        max_distance: 0.01,
        max_tets: 40_000,
        ..DistanceGoal::default()
    };
    let found =
        tetrahedralize_to_distance(&s, &goal, &mut |_| {}, &mut |t| eprintln!("{t:?}")).unwrap();
    eprintln!("{:?}", found.tries);
    assert!(found.reached, "{:?}", found.shortfall());
    let r = &found.report;
    let worst = r.mesh_to_surface.max(r.surface_to_mesh) / r.bbox_diagonal;
    assert!(worst <= 0.01, "{worst}");
    let exact = cup_volume(radius, height, wall);
    let v = volume_of(&found.mesh);
    assert!((v / exact - 1.0).abs() <= 0.03, "{v} against {exact}");
    assert_eq!(found.shortfall(), None);
    assert!(found.tries.windows(2).all(|w| w[1].tets > w[0].tets));
    // Its median wall needs more than the default start: the first try is at that wall's
    // spacing.
    assert_eq!(found.tries[0].spacing, found.advice.map(|a| a.walls.median));

    let capped = DistanceGoal {
        max_distance: 0.002,
        start_tets: 300,
        max_tets: 600,
        ..DistanceGoal::default()
    };
    let found = tetrahedralize_to_distance(&s, &capped, &mut |_| {}, &mut |_| {}).unwrap();
    assert!(!found.reached);
    // One mesh, at the spacing whose estimated count is the cap (a finer one would pass
    // it).
    assert_eq!(found.tries.len(), 1, "{:?}", found.tries);
    assert!(found.tries[0].spacing.is_some(), "{:?}", found.tries);
    let short = found.shortfall().expect("a shortfall");
    assert!(short.contains("cap of 600 tetrahedra"), "{short}");
    assert!(short.contains("walls as thin as"), "{short}");
}

/// Where the walls ask for no more than the start count (a torus: its walls are its tube's
/// diameter), the count grows instead: to 0.3 % of the diagonal, from 1500 tetrahedra, the
/// boundary checked here against the closed-form distance to the torus.
#[test]
fn a_torus_meshes_to_a_third_of_a_percent_by_growing_the_count() {
    let (big, small) = (1.0, 0.35);
    let goal = DistanceGoal {
        max_distance: 0.003,
        max_tets: 40_000,
        ..DistanceGoal::default()
    };
    let found = tetrahedralize_to_distance(
        &super::shapes::torus(big, small),
        &goal,
        &mut |_| {},
        &mut |t| eprintln!("{t:?}"),
    )
    .unwrap();
    assert!(found.reached, "{:?}", found.shortfall());
    assert_eq!(found.tries[0].target_tets, Some(1500));
    assert!(
        found.tries.len() > 1,
        "1500 tetrahedra were enough: {:?}",
        found.tries
    );
    assert!(
        found
            .tries
            .windows(2)
            .all(|w| w[1].target_tets > w[0].target_tets)
    );
    let d = super::farthest_on_boundary(&found.mesh, |p| {
        ((p.x.hypot(p.y) - big).hypot(p.z) - small).abs()
    });
    // The grid torus's facets lie up to 0.13 % of the diagonal inside the exact one.
    assert!(d <= (0.003 + 0.0015) * found.report.bbox_diagonal, "{d}");
}
