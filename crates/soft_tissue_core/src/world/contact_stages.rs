//! The contact stages of a step: [`detect_contacts`] on the positions at the start of the
//! step, [`collide`] (the response) on the positions after the solvers.
//!
//! Both stages look at body pairs whose grown bounds overlap, and within a pair only at the
//! candidate vertices of [`PairCandidates`] (kept from step to step while the bodies move less
//! than the slack), so a step pays for the contact zone, not for the surfaces. No stage
//! allocates once its workspaces have grown to the scene's needs; a new overlapping pair of
//! bodies (an event, like a switch) may.

use std::borrow::BorrowMut;

use rayon::prelude::*;

use super::{SimBody, WorldError};
use crate::Vec3;
use crate::contact::{
    BodyContact, ContactConfig, PairCandidates, SurfaceCollider, Tool, ToolContact, broad_phase,
    detect_candidates, detect_tool, grab_vertices, pair_reach, tool_distance,
};
use crate::precision::Level;

/// Fraction of a body-body penetration corrected per step. Correcting all of it at once (a
/// full projection) pushes the contact layers apart faster than the solvers can follow and
/// adds elastic energy (+4.7 % in the colliding-blocks test); half per step removes the
/// overlap within a few steps and the collision then gains no energy.
const RELAX: f64 = 0.5;

/// Jacobi rounds of the tool response per step.
const TOOL_ROUNDS: usize = 3;

/// Contacts and pairs of the current step (kept between stages, reused between steps).
#[derive(Debug, Default)]
pub struct ContactState {
    /// Body pairs whose grown bounds overlap.
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
    bounds: Vec<(Vec3, Vec3)>,
    order: Vec<u32>,
    tool_scratch: Vec<ToolContact>,
    triangles: Vec<u32>,
}

/// Makes sure pair `key` has its entry in `list` (created empty, so stale, the first time).
fn ensure_entry(list: &mut Vec<((u32, u32), PairCandidates, Vec<BodyContact>)>, key: (u32, u32)) {
    if let Err(k) = list.binary_search_by_key(&key, |c| c.0) {
        list.insert(k, (key, PairCandidates::default(), Vec::new()));
    }
}

/// The contacts found for pair `key` by the last [`query_pairs`].
fn found_of(state: &ContactState, key: (u32, u32)) -> &[BodyContact] {
    state
        .candidates
        .binary_search_by_key(&key, |c| c.0)
        .map_or(&[], |k| &state.candidates[k].2)
}

/// Contacts of every body pair in `state.queried` (their candidates refreshed first), both
/// ways, each pair's into its own list; in a pool the pairs side by side. A pair's query
/// only reads the two surfaces, so the lists do not depend on the thread count; the callers
/// use them in pair order.
fn query_pairs<B: BorrowMut<SimBody> + Sync>(
    bodies: &[B],
    state: &mut ContactState,
    config: &ContactConfig,
    margin: f64,
) {
    let (reach, slack) = reach_and_slack(config);
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
        let a = &bodies[*i as usize].borrow().collider;
        let b = &bodies[*j as usize].borrow().collider;
        candidates.update(a, b, reach, slack);
        both_ways(candidates, (*i, a), (*j, b), config, margin, out);
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
    }

    /// The candidate lists of pair `(i, j)`, if the pair was ever looked at.
    pub fn candidates(&self, i: u32, j: u32) -> Option<&PairCandidates> {
        self.candidates
            .binary_search_by_key(&(i, j), |c| c.0)
            .ok()
            .map(|k| &self.candidates[k].1)
    }
}

/// The reach of detection and how far a pair may move before its candidates are rebuilt.
fn reach_and_slack(config: &ContactConfig) -> (f64, f64) {
    let reach = pair_reach(config, config.body_margin);
    (reach, reach)
}

/// Detect contacts on the positions at the start of the step (margins included) and resolve
/// pending grabs; marks touched bodies.
pub fn detect_contacts<B: BorrowMut<SimBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    config: &ContactConfig,
    state: &mut ContactState,
) {
    state.bounds.clear();
    state
        .bounds
        .extend(bodies.iter().map(|b| b.borrow().collider.bounds()));
    let grow = 0.5
        * config
            .search_radius
            .max(config.thickness + config.body_margin);
    broad_phase(&state.bounds, grow, &mut state.order, &mut state.pairs);
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
        // Resting cages have no contact response and do not wake each other: nothing to
        // find, so a resting scene pays nothing here.
        if !(bi.body.level() == Level::Cage && bj.body.level() == Level::Cage) {
            state.queried.push((i, j));
        }
    }
    query_pairs(bodies, state, config, config.body_margin);
    for p in 0..state.pairs.len() {
        let (i, j) = state.pairs[p];
        let (bi, bj) = pair_mut(bodies, i as usize, j as usize);
        if bi.body.level() == Level::Cage && bj.body.level() == Level::Cage {
            continue;
        }
        bi.active = true;
        bj.active = true;
        let k = state
            .candidates
            .binary_search_by_key(&(i, j), |c| c.0)
            .expect("queried above");
        let found = state.candidates[k].2.len() as u32;
        state
            .body_contacts
            .extend_from_slice(&state.candidates[k].2);
        if found > 0 {
            // Bodies resting against each other (organs do, in the paper's scene) do not
            // count as touching: a pair counts while one side is precise and still moving.
            if bi.moving() || bj.moving() {
                bi.touched = true;
                bj.touched = true;
            }
            bi.contacts += found;
            bj.contacts += found;
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
    out: &mut Vec<BodyContact>,
) {
    detect_candidates(i, a, candidates.near(0), j, b, config, margin, out);
    detect_candidates(j, b, candidates.near(1), i, a, config, margin, out);
}

pub(super) fn pair_mut<B: BorrowMut<SimBody>>(
    bodies: &mut [B],
    i: usize,
    j: usize,
) -> (&mut SimBody, &mut SimBody) {
    debug_assert!(i < j);
    let (lo, hi) = bodies.split_at_mut(j);
    (lo[i].borrow_mut(), hi[0].borrow_mut())
}

/// Inverse mass of a node for contact (0 when fixed or when its body is at the cage level).
fn inverse_mass(b: &SimBody, node: usize) -> f64 {
    if b.body.level() == Level::Cage {
        return 0.0;
    }
    let p = b.body.precise();
    if p.fixed()[node].iter().any(|&f| f) {
        return 0.0;
    }
    1.0 / p.masses()[node]
}

/// Contact response on the positions after the solvers, grips, reaction forces.
///
/// All or nothing: the stage refuses bodies whose surface is not finite, and when it fails
/// (a correction, an impulse or a force that is not finite, a state it leaves that is not
/// finite) every body it changed is put back as it was before the stage, pending corrections
/// are dropped, and the error names the body and node. Tools' reaction forces of the failed
/// stage are not kept either (they are cleared).
pub fn collide<B: BorrowMut<SimBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    config: &ContactConfig,
    state: &mut ContactState,
    dt: f64,
) -> Result<(), WorldError> {
    let mut result = collide_all(bodies, tools, config, state, dt);
    // What the stage changed must be finite.
    for b in bodies.iter_mut() {
        let b = b.borrow();
        if result.is_ok()
            && b.undo.is_saved()
            && let Some((what, node)) = b.body.first_non_finite_level_state()
        {
            result = Err(WorldError::NonFinite {
                body: b.name.clone(),
                node,
                stage: if what == "position" {
                    "collide"
                } else {
                    "collide (velocity or force)"
                },
            });
        }
    }
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        if result.is_err() {
            for &i in &b.corrected {
                b.correction[i as usize] = Vec3::zeros();
                b.weight[i as usize] = 0.0;
            }
            b.corrected.clear();
            if b.undo.is_saved() && b.body.restore_level_state(&b.undo) {
                b.collider.gather(b.body.node_positions());
            }
        }
        b.undo.clear();
    }
    if result.is_err() {
        for t in tools.iter_mut() {
            t.borrow_mut().clear_reaction();
        }
    }
    result
}

impl SimBody {
    /// Saves this body's level state before the contact response first changes it this
    /// step (see [`collide`]).
    fn before_change(&mut self) {
        if !self.undo.is_saved() {
            self.body.save_level_state(&mut self.undo);
        }
    }
}

fn collide_all<B: BorrowMut<SimBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    config: &ContactConfig,
    state: &mut ContactState,
    dt: f64,
) -> Result<(), WorldError> {
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        if b.active {
            b.collider.gather(b.body.node_positions());
            if let Some(v) = b
                .collider
                .positions()
                .iter()
                .position(|p| !p.iter().all(|c| c.is_finite()))
            {
                return Err(WorldError::NonFinite {
                    body: b.name.clone(),
                    node: b.collider.nodes()[v] as usize,
                    stage: "collide (its input)",
                });
            }
        }
    }
    // Body against body: Jacobi average of the mass-weighted splits, on the candidates of
    // detection (checked still valid after the solvers moved the bodies); the pairs are
    // queried side by side in a pool, the corrections added in pair order.
    state.queried.clear();
    state
        .queried
        .extend(state.pairs.iter().copied().filter(|&(i, j)| {
            !(bodies[i as usize].borrow().body.level() == Level::Cage
                && bodies[j as usize].borrow().body.level() == Level::Cage)
        }));
    query_pairs(bodies, state, config, 0.0);
    for p in 0..state.pairs.len() {
        let (i, j) = state.pairs[p];
        let (bi, bj) = pair_mut(bodies, i as usize, j as usize);
        if bi.body.level() == Level::Cage && bj.body.level() == Level::Cage {
            continue;
        }
        for c in found_of(state, (i, j)) {
            let (a, b) = if c.a == i {
                (&mut *bi, &mut *bj)
            } else {
                (&mut *bj, &mut *bi)
            };
            resolve_body_contact(a, b, c, dt);
        }
    }
    for b in bodies.iter_mut() {
        apply_corrections(b.borrow_mut(), None, dt)?;
    }
    // Tools: every surface vertex inside a tool goes to its surface and every triangle
    // crossing it is pushed out as a whole, a few Jacobi rounds on fresh positions.
    for (it, tool) in tools.iter_mut().enumerate() {
        let tool = tool.borrow_mut();
        let (lo, hi) = tool.bounds(0.0);
        for (ib, b) in bodies.iter_mut().enumerate() {
            let b = b.borrow_mut();
            let (blo, bhi) = b.collider.bounds();
            if (0..3).any(|k| lo[k] > bhi[k] || blo[k] > hi[k]) {
                continue;
            }
            for round in 0..TOOL_ROUNDS {
                if round > 0 {
                    b.collider.gather(b.body.node_positions());
                }
                let mut touched = 0u32;
                for v in 0..b.collider.positions().len() {
                    let p = b.collider.positions()[v];
                    // Outside the tool's box is outside the tool.
                    if (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]) {
                        continue;
                    }
                    let (d, n) = tool_distance(tool, &p);
                    if d < 0.0 {
                        let node = b.collider.nodes()[v] as usize;
                        b.add_correction(node, -d * n);
                        touched += 1;
                    }
                }
                state.tool_scratch.clear();
                detect_tool(
                    it as u32,
                    tool,
                    ib as u32,
                    &b.collider,
                    0.0,
                    &mut state.triangles,
                    &mut state.tool_scratch,
                );
                for c in &state.tool_scratch {
                    if c.depth <= 0.0 {
                        continue;
                    }
                    touched += 1;
                    let ids = c.vertices.map(|v| b.collider.nodes()[v as usize] as usize);
                    let denom: f64 = ids
                        .iter()
                        .zip(&c.weights)
                        .map(|(&n, w)| w * w * inverse_mass_or_one(b, n))
                        .sum();
                    if denom <= 0.0 {
                        continue;
                    }
                    for (&n, w) in ids.iter().zip(&c.weights) {
                        let s = w * inverse_mass_or_one(b, n) / denom;
                        b.add_correction(n, c.normal * (c.depth * s));
                    }
                }
                if touched == 0 {
                    break;
                }
                if round == 0 {
                    tool.add_contacts(touched);
                }
                let reaction = apply_corrections(b, Some(tool.velocity()), dt)?;
                tool.add_reaction(-reaction);
            }
            b.collider.gather(b.body.node_positions());
        }
        // Grips follow the tool (all on one body: a grab takes the nearest one).
        let Some(held) = tool.grips().first().map(|g| g.body as usize) else {
            continue;
        };
        let b = bodies[held].borrow_mut();
        for g in tool.grips() {
            let node = g.node as usize;
            let target = tool.position() + g.offset;
            let x = b.body.node_positions()[node];
            b.add_correction(node, target - x);
        }
        let reaction = apply_corrections(b, Some(tool.velocity()), dt)?;
        tool.add_reaction(-reaction);
    }
    Ok(())
}

fn inverse_mass_or_one(b: &SimBody, node: usize) -> f64 {
    match b.body.level() {
        Level::Cage => 1.0,
        Level::Precise => inverse_mass(b, node),
    }
}

/// Splits one vertex-triangle correction between the two bodies by inverse mass, removes the
/// approaching relative normal velocity (an inelastic impulse), and maps what a cage-level side
/// receives onto its cage as a force.
fn resolve_body_contact(a: &mut SimBody, b: &mut SimBody, c: &BodyContact, dt: f64) {
    if c.depth <= 0.0 {
        return;
    }
    let pa = a.collider.nodes()[c.vertex as usize] as usize;
    let tb = c.vertices.map(|v| b.collider.nodes()[v as usize] as usize);
    let wa = inverse_mass(a, pa);
    let wb: f64 = tb
        .iter()
        .zip(&c.weights)
        .map(|(&n, w)| w * w * inverse_mass(b, n))
        .sum();
    let n = c.normal;
    if a.body.level() == Level::Cage && b.body.level() == Level::Cage {
        // Two cages resting against each other: the cheap level has no contact response.
        return;
    }
    a.before_change();
    b.before_change();
    if wa + wb <= 0.0 {
        // Both sides immovable here (cage level or fixed): push the cages apart instead.
        let k = 0.5 / (dt * dt);
        let ma = a.body.precise().masses()[pa];
        if a.body.level() == Level::Cage {
            let _ = a.body.add_force(pa, n * (c.depth * ma * k));
        }
        if b.body.level() == Level::Cage {
            for (&nb, w) in tb.iter().zip(&c.weights) {
                let _ = b.body.add_force(nb, -n * (c.depth * ma * k * w));
            }
        }
        return;
    }
    let lambda = RELAX * c.depth / (wa + wb);
    if wa > 0.0 {
        a.add_correction(pa, n * (lambda * wa));
    }
    for (&nb, w) in tb.iter().zip(&c.weights) {
        let wi = inverse_mass(b, nb);
        if wi > 0.0 {
            b.add_correction(nb, -n * (lambda * w * wi));
        }
    }
    // Inelastic normal impulse.
    let va = if wa > 0.0 {
        a.body.precise().velocities()[pa]
    } else {
        Vec3::zeros()
    };
    let vb: Vec3 = if wb > 0.0 {
        let v = b.body.precise().velocities();
        tb.iter().zip(&c.weights).map(|(&nb, w)| v[nb] * *w).sum()
    } else {
        Vec3::zeros()
    };
    let vn = (va - vb).dot(&n);
    if vn < 0.0 {
        let j = -vn / (wa + wb);
        if wa > 0.0 {
            a.body.precise_mut().velocities_mut()[pa] += n * (j * wa);
        } else if a.body.level() == Level::Cage {
            let _ = a.body.add_force(pa, -n * (j / dt));
        }
        if wb > 0.0 {
            let inv: [f64; 3] = tb.map(|nb| inverse_mass(b, nb));
            let v = b.body.precise_mut().velocities_mut();
            for ((&nb, w), wi) in tb.iter().zip(&c.weights).zip(inv) {
                v[nb] -= n * (j * w * wi);
            }
        } else if b.body.level() == Level::Cage {
            for (&nb, w) in tb.iter().zip(&c.weights) {
                let _ = b.body.add_force(nb, n * (j * w / dt));
            }
        }
    }
}

impl SimBody {
    /// Adds a position correction of node `node` for the next [`apply_corrections`].
    fn add_correction(&mut self, node: usize, dx: Vec3) {
        if self.weight[node] == 0.0 {
            self.corrected.push(node as u32);
        }
        self.correction[node] += dx;
        self.weight[node] += 1.0;
    }
}

/// Applies the averaged corrections gathered in a body's workspace. With a tool velocity, the
/// approach toward the tool along each correction is removed. Returns `sum m dx / dt^2`, the
/// force the corrections stand for (on the body). Clears the workspace.
fn apply_corrections(
    b: &mut SimBody,
    tool_velocity: Option<Vec3>,
    dt: f64,
) -> Result<Vec3, WorldError> {
    let mut force = Vec3::zeros();
    if b.corrected.is_empty() {
        return Ok(force);
    }
    b.before_change();
    let mut result = Ok(());
    match b.body.level() {
        Level::Precise => {
            // One mutable borrow of the node state: positions, velocities, masses and fixed
            // axes side by side, without copies.
            let nodes = b.body.precise_mut().nodes_mut();
            for &i in &b.corrected {
                let i = i as usize;
                let mut dx = b.correction[i] / b.weight[i];
                for k in 0..3 {
                    if nodes.fixed[i][k] {
                        dx[k] = 0.0;
                    }
                }
                nodes.x[i] += dx;
                force += dx * (nodes.mass[i] / (dt * dt));
                if let (Some(vt), Some(dir)) = (tool_velocity, dx.try_normalize(0.0)) {
                    let v = &mut nodes.v[i];
                    let vn = (*v - vt).dot(&dir);
                    if vn < 0.0 {
                        *v -= dir * vn;
                    }
                }
                if result.is_ok() && !nodes.x[i].iter().all(|x| x.is_finite()) {
                    result = Err(WorldError::NonFinite {
                        body: b.name.clone(),
                        node: i,
                        stage: "collide",
                    });
                }
            }
        }
        Level::Cage => {
            // The cage level takes contact as forces through the coordinates' transpose (the
            // paper's mapping): the force that would move each corrected node by its
            // correction in one step, spread on the cage vertices by their coordinates. (A
            // least-squares displacement of the cage with the face terms held fixed amplifies
            // a few nearby contact points into large cage motions.)
            for &i in &b.corrected {
                let i = i as usize;
                let m = b.body.precise().masses()[i];
                let f = b.correction[i] / b.weight[i] * (m / (dt * dt));
                force += f;
                b.body.add_shadow_force(i, f);
                if let Err(e) = b.body.cage_mut().apply_point_force(i, f)
                    && result.is_ok()
                {
                    result = Err(WorldError::Precision {
                        body: b.name.clone(),
                        source: e.into(),
                    });
                }
            }
        }
    }
    for &i in &b.corrected {
        b.correction[i as usize] = Vec3::zeros();
        b.weight[i as usize] = 0.0;
    }
    b.corrected.clear();
    result.map(|()| force)
}
