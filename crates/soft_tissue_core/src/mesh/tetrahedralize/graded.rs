//! The graded mesh: where the uniform lattice leaves the boundary more than 1 % of the
//! diagonal off the surface, a finer lattice fitted to it, its boundary coarsened where the
//! surface is flat back toward the target count, kept where it is nearer.

use super::fitting::onto_surface;
use super::passes::{Finished, Goal};
use super::stuffing::Stuffing;
use super::{AIMED_DISTANCE, GRADED_TOLERANCE, TetrahedralizeOptions};
use crate::mesh::TetMesh;

/// A near miss, as a multiple of [`AIMED_DISTANCE`]: the misses the near-miss search and
/// the graded levels 3 and 4 times finer run for.
const NEAR_MISS: f64 = 1.5;

/// Replaces `done` (the uniform mesh at `spacing`) by a graded one where that is nearer the
/// surface (for a tetrahedron count only); returns how many times finer than `spacing` the
/// kept mesh's lattice is (1: the uniform one was kept).
pub(super) fn grade(
    done: &mut Finished,
    stuffing: &Stuffing<'_>,
    goal: &Goal<'_>,
    options: &TetrahedralizeOptions,
    spacing: f64,
    diagonal: f64,
) -> f64 {
    let near = goal.tree;
    let min_dihedral = goal.min_dihedral;
    // Graded: where the uniform lattice leaves the boundary more than 1 % of the diagonal
    // off the surface (or the surface off it), mesh finer, fit that, coarsen its boundary
    // where the surface is flat down to the target, and keep the nearer of the two.
    // The fine mesh has about factor^2.5 times the tetrahedra (most in the boundary layer):
    // at most 2.5 times finer, and at most about 25k tetrahedra, so that large targets stay
    // fast; below 1.2 times finer there is nothing to gain. Where the kept mesh still
    // misses 1 % but stays within 2.5 % (a thin part: where it is about two fine
    // lattice spacings thick, its tetrahedra have every node on the boundary and no split
    // there keeps the bound; a tip folded nearly flat), again from finer meshes in turn:
    // at most 3, 3.5 and 4 times finer and about 45k, 60k and 90k tetrahedra (see `levels`
    // for which misses each runs for), until one is within 1 %. Each finer lattice puts interior nodes where the last had none, and each
    // gives the coarsening and the splits after it other nodes to work with (where a result
    // lies near 1 %, which side it falls on changes with the lattice, not steadily).
    // Surfaces that need it pay for it; the others stop at the first level.
    // The distance the graded mesh is there to reach: 1 % of the diagonal.
    let one_percent = AIMED_DISTANCE * diagonal;
    // The fine mesh's boundary coarsened toward `target` tetrahedra (the same at each level).
    // First within the tolerance; while the count stays a tenth over the target, again
    // within up to twice it, then, a fifth over, three times (a surface too detailed for
    // the count: the count first, within 1.5 % of the diagonal, since the edge splits
    // after it add tetrahedra).
    let coarsened = |fine: &TetMesh, target: usize| -> Option<TetMesh> {
        use crate::mesh::coarsen_boundary::{BoundaryCoarsening, coarsen_boundary};
        let mut settings = BoundaryCoarsening {
            min_dihedral_deg: min_dihedral,
            tolerance: GRADED_TOLERANCE * diagonal,
            target_tets: target,
            levels: &[0.25, 0.5, 1.0],
        };
        let mut coarse = coarsen_boundary(fine, near, &settings).ok()?;
        if coarse.tet_count() as f64 > 1.1 * target as f64 {
            settings.levels = &[1.25, 1.5, 1.75, 2.0];
            coarse = coarsen_boundary(&coarse, near, &settings).ok()?;
        }
        if coarse.tet_count() as f64 > 1.2 * target as f64 {
            settings.levels = &[2.25, 2.5, 2.75, 3.0];
            coarse = coarsen_boundary(&coarse, near, &settings).ok()?;
        }
        Some(coarse)
    };
    // How many times finer the kept mesh's lattice is than the uniform one (1: uniform).
    let mut finer = 1.0;
    // Each level: the count, how many times finer, and the largest miss (in % of the
    // diagonal) it runs for. The finer levels only after the first ran: the one 3.5 times
    // finer for a miss up to 2.5 % (1.4 times finer than the first's, it shrinks a chord's
    // distance about 1.4^2 = 2 times); those 3 and 4 times finer only for a near miss, up
    // to 1.5 %, where another lattice is another chance (a far miss, a thin-walled heart
    // at 1.8 %, gained nothing from them, and a small intestine at 10000 tetrahedra took
    // over 120 s instead of 53 s). A surface farther off (a long tube) is not followed at
    // this count by any.
    let levels: Vec<(usize, f64, f64)> = match (options.edge_length, options.target_tets) {
        (None, Some(n)) => {
            let factor = |budget: f64, cap: f64| (budget / n as f64).powf(0.4).min(cap);
            [
                (25_000.0, 2.5, f64::INFINITY),
                (45_000.0, 3.0, NEAR_MISS),
                (60_000.0, 3.5, 2.5),
                (90_000.0, 4.0, NEAR_MISS),
            ]
            .map(|(budget, cap, reach)| (n, factor(budget, cap), reach))
            .to_vec()
        }
        _ => Vec::new(),
    };
    for (n, factor, reach) in levels {
        let worst = done.worst();
        if worst <= one_percent || factor < 1.2 {
            break;
        }
        if worst > reach * one_percent {
            continue;
        }
        // The graded mesh is an improvement on the uniform one: should any step of it fail
        // (a lattice too large, a mesh the coarsening left invalid), the uniform one stays.
        let Some((fine, projected, snapped)) = stuffing
            .mesh_at(spacing / factor)
            .ok()
            .map(|m| onto_surface(m, goal))
        else {
            break;
        };
        // Kept when nearer the surface and within a third of the target. Where the count
        // came out farther off (the edge splits add tetrahedra, the interior removal after
        // the coarsening takes some), the coarsening runs again from the fine mesh toward a
        // corrected target.
        // The count after the splits follows the coarsening's target only roughly: the
        // next target comes from the last two tries (a secant), or from the ratio after
        // the first.
        let try_target = |target: f64| {
            let coarse = coarsened(&fine, target.max(1.0) as usize)?;
            Some(Finished::split_and_measure(
                coarse, goal, projected, snapped,
            ))
        };
        let within_third = |m: &Finished| {
            (2.0 / 3.0..=4.0 / 3.0).contains(&(m.mesh.tet_count() as f64 / n as f64))
        };
        let mut target = n as f64;
        let mut tried: Vec<(f64, f64)> = Vec::new();
        let mut in_window = None;
        for _attempt in 0..4 {
            let Some(graded) = try_target(target.round()) else {
                break;
            };
            let count = graded.mesh.tet_count() as f64;
            tried.push((target, count));
            if within_third(&graded) {
                if done.take_if_nearer(graded) {
                    finer = factor;
                }
                in_window = Some(target);
                break;
            }
            target = match tried[..] {
                [.., (t0, c0), (t1, c1)] if (c1 - c0) * (t1 - t0) > 0.0 => {
                    t1 + (n as f64 - c1) * (t1 - t0) / (c1 - c0)
                }
                _ => target * n as f64 / count.max(1.0),
            };
            if !(target.is_finite() && target >= 1.0) {
                break;
            }
        }
        // A near miss (over 1 %, by at most half as much again): which boundary nodes the
        // coarsening keeps, and so where the splits can reach, changes with its target,
        // and not steadily (a tolerance level stalls, the interior removal after it takes
        // a share that varies). Other targets around the one that gave the count, while
        // the kept mesh misses; a result outside the third is not kept.
        if let Some(t) = in_window {
            for f in [1.2, 0.85, 1.4, 0.7] {
                if !(one_percent..=NEAR_MISS * one_percent).contains(&done.worst()) {
                    break;
                }
                if let Some(graded) = try_target((t * f).round()).filter(within_third)
                    && done.take_if_nearer(graded)
                {
                    finer = factor;
                }
            }
        }
    }
    finer
}
