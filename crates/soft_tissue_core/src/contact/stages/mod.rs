//! The contact stages of a step: [`detect_contacts`] on the positions at the start of the
//! step (who is touched, so it rises before the contact is resolved; grabs; cautery), and
//! [`solve_contacts`] after every body's free motion: detection on the moved positions, the
//! contact problem ([`super::problem`]) over all touching bodies, tools and obstacles, each
//! body's correction, in rounds until nothing penetrates beyond the tolerance.
//!
//! The forces of a step load the next step's free motion: each body's own solve answers them
//! exactly, and the contact problem then solves for the whole force with the loads already
//! applied, so the correction covers only their change. A body at rest in contact is then
//! in the equilibrium its own solver finds (its forces balance as exactly as its solve), and
//! the approximation of a compliance (the corotational model's warped rest compliance)
//! costs only while the contact changes. A row of the last step that is not found again
//! (the surfaces parted) stays in the problem with its gap measured along its old normal, so
//! its force is taken back.
//!
//! Body pairs whose grown bounds overlap are looked at on the candidate vertices of
//! [`PairCandidates`] (kept from step to step while the bodies move less than the slack), so
//! a step pays for the contact zone, not for the surfaces. No stage allocates once its
//! workspaces have grown to the scene's needs; a new overlapping pair of bodies or the first
//! contact of a body (events, like a switch) may.

use std::borrow::BorrowMut;
use std::time::Instant;

use nalgebra::Matrix3;
use rayon::prelude::*;

use super::detect::ShapeContact;
use super::problem::{ContactRow, ContactSolver, Counterpart, SolverSettings};
use super::{
    BodyContact, ContactConfig, Obstacle, PairCandidates, SurfaceCollider, Tool, ToolContact,
    broad_phase, detect_candidates, detect_tool, grab_vertices, pair_reach, tool_distance,
};
use crate::Vec3;
use crate::precision::Level;
use crate::world::{WorldBody, WorldError};

mod rows;
use rows::{build_rows, drop_mirrored, find_again, old_plane, other_body};

/// What the last contact solve did (whole scene).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactStats {
    /// Rows of the last round solved (contacts within the margins, grips).
    pub rows: u32,
    /// Rows with a force.
    pub active: u32,
    /// Rounds solved.
    pub rounds: u32,
    /// Gauss-Seidel sweeps over all rounds.
    pub sweeps: u32,
    /// Rows sliding at the end.
    pub sliding: u32,
    /// Largest penetration after the last round (below the thickness between bodies and
    /// against obstacles, into a tool), scene units.
    pub max_penetration: f64,
    /// Detection on the moved positions, microseconds.
    pub detect_us: f64,
    /// Assembly of the contact problem and its solve, microseconds.
    pub solve_us: f64,
    /// The bodies' corrections (their own solves), microseconds.
    pub correct_us: f64,
}

/// Contacts and pairs of the current step (kept between stages, reused between steps).
#[derive(Debug, Default)]
pub struct ContactState {
    /// Body pairs whose grown bounds overlap (at the start of the step).
    pub pairs: Vec<(u32, u32)>,
    /// Tool contacts at the start of the step.
    pub tool_contacts: Vec<ToolContact>,
    /// Body contacts at the start of the step.
    pub body_contacts: Vec<BodyContact>,
    /// Candidate vertices of every pair that ever overlapped, sorted by pair, with the
    /// pair's contacts found by the last query (see [`query_pairs`]).
    candidates: Vec<((u32, u32), PairCandidates, Vec<BodyContact>)>,
    /// The pairs queried this stage, sorted.
    queried: Vec<(u32, u32)>,
    /// Pairs of the solve (bounds after the free motion).
    solve_pairs: Vec<(u32, u32)>,
    bounds: Vec<(Vec3, Vec3)>,
    order: Vec<u32>,
    triangles: Vec<u32>,
    shapes: Vec<ShapeContact>,
    /// Rows of the round being built, and of the last round solved.
    rows: Vec<ContactRow>,
    solved: Vec<ContactRow>,
    /// The last step's rows with their forces, sorted by key: those forces loaded this
    /// step's free motion (see [`solve_contacts`]).
    previous: Vec<ContactRow>,
    /// The bodies' surface identities the previous rows were made for.
    previous_ids: Vec<u64>,
    solver: ContactSolver,
    /// Rows of the last round that nothing can move along their normal (fixed nodes against
    /// a tool or each other), sorted: their penetration does not start another round.
    immovable: Vec<super::problem::RowKey>,
    stats: ContactStats,
}

/// The body pairs whose bounds, grown by the contact reach, overlap (sweep and prune on the
/// bodies' current bounds), into `out`.
fn body_pairs<B: BorrowMut<WorldBody>>(
    bodies: &[B],
    config: &ContactConfig,
    state: &mut ContactState,
    out: &mut Vec<(u32, u32)>,
) {
    state.bounds.clear();
    state
        .bounds
        .extend(bodies.iter().map(|b| b.borrow().collider.bounds()));
    let grow = 0.5
        * config
            .search_radius
            .max(config.thickness + config.body_margin);
    broad_phase(&state.bounds, grow, &mut state.order, out);
}

/// Makes sure pair `key` has its entry in `list` (created empty, so stale, the first time).
fn ensure_entry(list: &mut Vec<((u32, u32), PairCandidates, Vec<BodyContact>)>, key: (u32, u32)) {
    if let Err(k) = list.binary_search_by_key(&key, |c| c.0) {
        list.insert(k, (key, PairCandidates::default(), Vec::new()));
    }
}

/// The contacts found for pair `key` by the last [`query_pairs`].
fn found_of(
    candidates: &[((u32, u32), PairCandidates, Vec<BodyContact>)],
    key: (u32, u32),
) -> &[BodyContact] {
    candidates
        .binary_search_by_key(&key, |c| c.0)
        .map_or(&[], |k| &candidates[k].2)
}

/// Contacts of every body pair in `state.queried` (their candidates refreshed first), both
/// ways, each pair's into its own list; in a pool the pairs side by side. A pair's query
/// only reads the two surfaces, so the lists do not depend on the thread count; the callers
/// use them in pair order.
fn query_pairs<B: BorrowMut<WorldBody> + Sync>(
    bodies: &[B],
    state: &mut ContactState,
    config: &ContactConfig,
    margin: f64,
) {
    let (base, slack) = reach_and_slack(config);
    state.queried.sort_unstable();
    for &key in &state.queried {
        ensure_entry(&mut state.candidates, key);
    }
    let queried = &state.queried;
    let query = |entry: &mut ((u32, u32), PairCandidates, Vec<BodyContact>)| {
        let ((i, j), candidates, out) = entry;
        out.clear();
        if queried.binary_search(&(*i, *j)).is_err() {
            return;
        }
        let (bi, bj) = (bodies[*i as usize].borrow(), bodies[*j as usize].borrow());
        // A vertex may have gone as deep as the two moved in the step.
        let reach = base + bi.moved + bj.moved;
        let (a, b) = (&bi.collider, &bj.collider);
        candidates.update(a, b, reach, slack);
        both_ways(candidates, (*i, a), (*j, b), config, margin, reach, out);
    };
    if crate::parallel::in_pool() && queried.len() > 1 {
        state
            .candidates
            .par_iter_mut()
            .with_max_len(1)
            .for_each(query);
    } else {
        state.candidates.iter_mut().for_each(query);
    }
}

impl ContactState {
    /// Forgets the contacts and pairs of the last step and every pair's candidates, keeping
    /// the room of every list.
    pub fn clear(&mut self) {
        self.pairs.clear();
        self.tool_contacts.clear();
        self.body_contacts.clear();
        for (_, c, found) in &mut self.candidates {
            c.invalidate();
            found.clear();
        }
        self.rows.clear();
        self.solved.clear();
        self.previous.clear();
        self.previous_ids.clear();
        self.stats = ContactStats::default();
    }

    /// The candidate lists of pair `(i, j)`, if the pair was ever looked at.
    pub fn candidates(&self, i: u32, j: u32) -> Option<&PairCandidates> {
        self.candidates
            .binary_search_by_key(&(i, j), |c| c.0)
            .ok()
            .map(|k| &self.candidates[k].1)
    }

    /// The rows of the last contact solve with their forces (the haptic loop and the
    /// diagnostics read them).
    pub fn solved_rows(&self) -> &[ContactRow] {
        &self.solved
    }

    /// The rows of the last solve on body `body` (its side `a`) while they name its nodes:
    /// while it is the body whose collider's [`SurfaceCollider::id`] is `id`, the one they
    /// were solved on. None once a cut or a carve replaced it since (in the step a carve
    /// lands the rows still name the old mesh's nodes, and could index past a smaller
    /// piece's).
    pub fn fitting_rows(&self, body: u32, id: u64) -> impl Iterator<Item = &ContactRow> + '_ {
        let fit = self.previous_ids.get(body as usize) == Some(&id);
        let rows = if fit { &self.solved[..] } else { &[] };
        rows.iter().filter(move |r| r.a.body == body)
    }

    /// What the last contact solve did.
    pub fn stats(&self) -> ContactStats {
        self.stats
    }

    /// The assembled contact problem of the last round solved (its Delassus blocks), for a
    /// caller that solves it again (the haptic loop with a newer tool pose).
    pub fn solver(&self) -> &ContactSolver {
        &self.solver
    }
}

/// The reach of detection and how far a pair may move before its candidates are rebuilt.
fn reach_and_slack(config: &ContactConfig) -> (f64, f64) {
    let reach = pair_reach(config, config.body_margin);
    (reach, reach)
}

/// Detect contacts on the positions at the start of the step (margins included) and resolve
/// pending grabs; marks touched bodies.
pub fn detect_contacts<B: BorrowMut<WorldBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    config: &ContactConfig,
    state: &mut ContactState,
) {
    let mut pairs = std::mem::take(&mut state.pairs);
    body_pairs(bodies, config, state, &mut pairs);
    state.pairs = pairs;
    state.tool_contacts.clear();
    state.body_contacts.clear();
    // Tools.
    for (it, tool) in tools.iter_mut().enumerate() {
        let tool = tool.borrow_mut();
        let (lo, hi) = tool.bounds(config.tool_margin);
        for (ib, b) in bodies.iter_mut().enumerate() {
            let b = b.borrow_mut();
            let (blo, bhi) = b.collider.bounds();
            if (0..3).any(|k| lo[k] > bhi[k] || blo[k] > hi[k]) {
                continue;
            }
            b.active = true;
            let before = state.tool_contacts.len();
            detect_tool(
                it as u32,
                tool,
                ib as u32,
                &b.collider,
                config.tool_margin,
                &mut state.triangles,
                &mut state.shapes,
                &mut state.tool_contacts,
            );
            let found = (state.tool_contacts.len() - before) as u32;
            if found > 0 {
                b.touched = true;
                b.contacts += found;
            }
        }
        if tool.grab_requested() {
            // The nearest body under the tip.
            let mut best: Option<(f64, usize)> = None;
            for (ib, b) in bodies.iter().enumerate() {
                let b = b.borrow();
                for p in b.collider.positions() {
                    let d = tool_distance(tool, p).0;
                    if d <= config.tool_margin && best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, ib));
                    }
                }
            }
            let grips = match best {
                Some((_, ib)) => grab_vertices(
                    tool,
                    ib as u32,
                    &bodies[ib].borrow().collider,
                    config.tool_margin,
                ),
                None => Vec::new(),
            };
            tool.take_grips(grips);
        }
        for g in tool.grips() {
            let b = bodies[g.body as usize].borrow_mut();
            b.touched = true;
            b.active = true;
        }
    }
    // Body pairs: the pairs with a side above the cage level are queried (side by side in
    // a pool), then their contacts are taken in pair order.
    state.queried.clear();
    for &(i, j) in &state.pairs {
        let (bi, bj) = (bodies[i as usize].borrow(), bodies[j as usize].borrow());
        // Resting cages do not touch each other: nothing to find, so a resting scene pays
        // nothing here.
        if !(bi.model.level() == Level::Cage && bj.model.level() == Level::Cage) {
            state.queried.push((i, j));
        }
    }
    query_pairs(bodies, state, config, config.body_margin);
    for p in 0..state.pairs.len() {
        let (i, j) = state.pairs[p];
        let (bi, bj) = pair_mut(bodies, i as usize, j as usize);
        if bi.model.level() == Level::Cage && bj.model.level() == Level::Cage {
            continue;
        }
        bi.active = true;
        bj.active = true;
        let found = found_of(&state.candidates, (i, j));
        state.body_contacts.extend_from_slice(found);
        if !found.is_empty() {
            // Bodies resting against each other (organs do, in the paper's scene) do not
            // count as touching: a pair counts while one side is precise and still moving.
            if bi.moving() || bj.moving() {
                bi.touched = true;
                bj.touched = true;
            }
            bi.contacts += found.len() as u32;
            bj.contacts += found.len() as u32;
        }
    }
}

/// The candidates of a pair against each other's surface, both ways.
fn both_ways(
    candidates: &PairCandidates,
    (i, a): (u32, &SurfaceCollider),
    (j, b): (u32, &SurfaceCollider),
    config: &ContactConfig,
    margin: f64,
    reach: f64,
    out: &mut Vec<BodyContact>,
) {
    detect_candidates(i, a, candidates.near(0), j, b, config, margin, reach, out);
    detect_candidates(j, b, candidates.near(1), i, a, config, margin, reach, out);
}

pub(crate) fn pair_mut<B: BorrowMut<WorldBody>>(
    bodies: &mut [B],
    i: usize,
    j: usize,
) -> (&mut WorldBody, &mut WorldBody) {
    debug_assert!(i < j);
    let (lo, hi) = bodies.split_at_mut(j);
    (lo[i].borrow_mut(), hi[0].borrow_mut())
}

/// Whether a body takes part in the contact solve: at its precise level, or a cage that is
/// awake (a sleeping cage joins only through a contact with a precise body or a tool).
fn takes_part(b: &WorldBody) -> bool {
    b.model.level() == Level::Precise || !b.model.is_asleep()
}

/// The contact solve after the free motion, the bodies' corrections, the forces on the tools
/// (see the module docs).
///
/// All or nothing: the stage refuses bodies whose surface is not finite, and when it fails
/// (a compliance or correction that fails, a state it leaves that is not finite) every body
/// it changed is put back as it was before the stage, and the error names the body and node.
/// Tools' forces of the failed stage are not kept either (they are cleared).
pub fn solve_contacts<B: BorrowMut<WorldBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    obstacles: &[Obstacle],
    config: &ContactConfig,
    state: &mut ContactState,
) -> Result<(), WorldError> {
    let mut result = solve_all(bodies, tools, obstacles, config, state);
    // What the stage changed must be finite.
    for b in bodies.iter_mut() {
        let b = b.borrow();
        if result.is_ok()
            && b.undo.is_saved()
            && let Some((what, node)) = b.model.first_non_finite_level_state()
        {
            result = Err(WorldError::NonFinite {
                body: b.label(),
                node,
                stage: if what == "position" {
                    "contact solve"
                } else {
                    "contact solve (velocity or force)"
                },
            });
        }
    }
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        if result.is_err() && b.undo.is_saved() && b.model.restore_level_state(&b.undo) {
            b.collider.gather(b.model.node_positions());
        }
        b.undo.clear();
    }
    for t in tools.iter_mut() {
        let t = t.borrow_mut();
        if result.is_err() {
            t.clear_reaction();
        }
        t.keep_last_pose();
    }
    result
}

fn lap(t: &mut Instant) -> f64 {
    let e = t.elapsed().as_secs_f64() * 1e6;
    *t = Instant::now();
    e
}

fn solve_all<B: BorrowMut<WorldBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    obstacles: &[Obstacle],
    config: &ContactConfig,
    state: &mut ContactState,
) -> Result<(), WorldError> {
    let mut stats = ContactStats::default();
    let mut t = Instant::now();
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        b.penetration = 0.0;
        b.solve_contacts = 0;
        if takes_part(b) || b.active {
            b.collider.gather(b.model.node_positions());
            b.moved = b
                .collider
                .positions()
                .iter()
                .zip(&b.start)
                .map(|(x, s)| (x - s).norm_squared())
                .fold(0.0, f64::max)
                .sqrt();
            if let Some(v) = b
                .collider
                .positions()
                .iter()
                .position(|p| !p.iter().all(|c| c.is_finite()))
            {
                return Err(WorldError::NonFinite {
                    body: b.label(),
                    node: b.collider.nodes()[v] as usize,
                    stage: "contact solve (its input)",
                });
            }
        }
    }
    // Pairs on the moved bounds.
    let mut pairs = std::mem::take(&mut state.solve_pairs);
    body_pairs(bodies, config, state, &mut pairs);
    state.solve_pairs = pairs;
    state.solved.clear();
    let settings = SolverSettings {
        max_sweeps: config.max_sweeps,
        // A tenth of the penetration a round may leave.
        gap_tolerance: 0.1 * config.tolerance,
        ..SolverSettings::default()
    };
    let mut failure: Option<WorldError> = None;
    // The last step's rows belong to these bodies only while every body is the one it was.
    let same_bodies = state.previous_ids.len() == bodies.len()
        && bodies
            .iter()
            .zip(&state.previous_ids)
            .all(|(b, id)| b.borrow().collider.id() == *id);
    if !same_bodies {
        state.previous.clear();
    }
    for round in 0..=config.max_rounds {
        build_rows(bodies, tools, obstacles, config, state);
        // Forces carried: from the last round, or in the first from the last step (they
        // loaded the free motion: applied either way).
        let from = if round > 0 {
            std::mem::take(&mut state.solved)
        } else {
            std::mem::take(&mut state.previous)
        };
        for row in state.rows.iter_mut() {
            if let Ok(k) = from.binary_search_by_key(&row.key, |r| r.key) {
                let old = &from[k];
                let to_new = row.frame.transpose() * old.frame;
                row.force = to_new * old.force;
                row.applied = to_new * old.applied;
                if round == 0 {
                    row.applied = row.force;
                }
                row.sliding = old.sliding;
            }
        }
        // A row of the last step or round with a force that is not found again keeps its
        // force until the solve takes it back (it loaded the free motion, or a correction
        // applied it). Within a step, a vertex against another body keeps the plane of the
        // triangle it was against (a vertex in a crease then stays out of both faces, where
        // the nearest face alone would flip from one to the other every round); otherwise
        // the row is measured again however far its sides parted, and joins the row of the
        // same point found now, if any.
        for &old in &from {
            let gone = old.force == Vec3::zeros() && (round == 0 || old.gap >= 0.0);
            if gone || state.rows.binary_search_by_key(&old.key, |r| r.key).is_ok() {
                continue;
            }
            let row = if round > 0 && matches!(old.other, Counterpart::Body(_)) {
                old_plane(bodies, config, &old)
            } else {
                let mut row = find_again(bodies, tools, obstacles, config, &old);
                let to_new = row.frame.transpose() * old.frame;
                row.force = to_new * old.force;
                row.applied = to_new * if round == 0 { old.force } else { old.applied };
                row
            };
            match state.rows.binary_search_by_key(&row.key, |r| r.key) {
                Ok(at) => {
                    let r = &mut state.rows[at];
                    let to_r = r.frame.transpose() * row.frame;
                    r.force += to_r * row.force;
                    r.applied += to_r * row.applied;
                }
                Err(at) => state.rows.insert(at, row),
            }
        }
        drop_mirrored(&mut state.rows);
        if round > 0 {
            state.solved = from;
        } else {
            state.previous = from;
        }
        // The deepest penetration, and the deepest another round could correct (no round
        // moves a row nothing can move).
        let (penetration, movable) =
            state
                .rows
                .iter()
                .fold((0.0f64, 0.0f64), |(all, fixable), r| {
                    let depth = if r.is_contact() {
                        (-r.gap).max(0.0)
                    } else {
                        Vec3::new(r.gap, r.slip[0], r.slip[1]).norm()
                    };
                    let moves = !r.is_contact() || state.immovable.binary_search(&r.key).is_err();
                    (
                        all.max(depth),
                        if moves { fixable.max(depth) } else { fixable },
                    )
                });
        stats.max_penetration = penetration;
        stats.detect_us += lap(&mut t);
        let settled = round > 0 && movable <= config.tolerance;
        if state.rows.is_empty() || round == config.max_rounds || settled {
            // The final measurement: per body, its deepest contact.
            for r in &state.rows {
                if r.is_contact() && r.gap < 0.0 {
                    for body in [Some(r.a.body), other_body(r)].into_iter().flatten() {
                        let b = bodies[body as usize].borrow_mut();
                        b.penetration = b.penetration.max(-r.gap);
                    }
                }
            }
            break;
        }
        // The problem, its solve, the corrections.
        {
            let mut compliance = |body: u32, vertices: &[u32], out: &mut [Matrix3<f64>]| {
                let b = bodies[body as usize].borrow_mut();
                if let Err(e) = b.contact_compliance(vertices, out)
                    && failure.is_none()
                {
                    failure = Some(e);
                }
                // A compliance that is not finite fails the step here: the sweeps take a row
                // whose diagonal is NaN as one that nothing moves, and skip rows without
                // force, so it would otherwise be dropped silently. (A failed solve leaves
                // NaN in a node's columns, its diagonal block among them.)
                let n = vertices.len();
                if failure.is_none()
                    && let Some(k) = (0..n).find(|&k| !out[k * n + k].iter().all(|v| v.is_finite()))
                {
                    failure = Some(WorldError::NonFinite {
                        body: b.label(),
                        node: b.collider.nodes()[vertices[k] as usize] as usize,
                        stage: "contact compliance",
                    });
                }
            };
            state.solver.assemble(&state.rows, &mut compliance);
        }
        if let Some(e) = failure.take() {
            return Err(e);
        }
        let s = state.solver.solve(&mut state.rows, &settings);
        state.immovable.clear();
        for (c, r) in state.rows.iter().enumerate() {
            if r.is_contact() && !state.solver.movable(c) {
                state.immovable.push(r.key);
            }
        }
        state.immovable.sort_unstable();
        stats.sweeps += s.sweeps;
        stats.rounds += 1;
        stats.solve_us += lap(&mut t);
        {
            let mut apply = |body: u32, forces: &[(u32, Vec3)]| {
                let b = bodies[body as usize].borrow_mut();
                b.before_change();
                if let Err(e) = b.apply_contact_forces(forces)
                    && failure.is_none()
                {
                    failure = Some(e);
                }
                b.collider.gather(b.model.node_positions());
            };
            state.solver.apply(&mut state.rows, &mut apply);
        }
        if let Some(e) = failure.take() {
            return Err(e);
        }
        stats.correct_us += lap(&mut t);
        std::mem::swap(&mut state.rows, &mut state.solved);
        state.solved.sort_unstable_by_key(|r| r.key);
    }
    // Forces on the tools and the bodies' counts, from the last round solved.
    for r in &state.solved {
        let active = r.force != Vec3::zeros();
        if active {
            stats.active += 1;
        }
        if r.sliding {
            stats.sliding += 1;
        }
        if let Counterpart::Tool { tool, part } = r.other {
            let t = tools[tool as usize].borrow_mut();
            let normal = if r.is_contact() { r.force.x } else { 0.0 };
            t.add_reaction(-r.world_force(), part as usize, normal);
            if active {
                t.add_contacts(1);
            }
        }
        if active {
            for body in [Some(r.a.body), other_body(r)].into_iter().flatten() {
                bodies[body as usize].borrow_mut().solve_contacts += 1;
            }
        }
    }
    stats.rows = state.solved.len() as u32;
    // The forces found load the next step's free motion.
    for b in bodies.iter_mut() {
        b.borrow_mut().contact_load.clear();
    }
    for r in &state.solved {
        if r.force == Vec3::zeros() {
            continue;
        }
        let f = r.world_force();
        let b = bodies[r.a.body as usize].borrow_mut();
        b.contact_load.extend(r.a.terms().map(|(v, w)| (v, f * w)));
        if let Counterpart::Body(p) = &r.other {
            let b = bodies[p.body as usize].borrow_mut();
            b.contact_load.extend(p.terms().map(|(v, w)| (v, -f * w)));
        }
    }
    state.previous.clear();
    state.previous.extend_from_slice(&state.solved);
    state.previous_ids.clear();
    state
        .previous_ids
        .extend(bodies.iter().map(|b| b.borrow().collider.id()));
    stats.detect_us += lap(&mut t);
    state.stats = stats;
    Ok(())
}
