//! The rows of a contact round: built from the current positions (body pairs, tools,
//! grips, obstacles), rows of the last round or step measured again, and the keys that
//! match a row from one round to the next.

use std::borrow::BorrowMut;

use super::{ContactState, found_of, query_pairs, takes_part};
use crate::Vec3;
use crate::contact::detect::detect_shape;
use crate::contact::problem::{
    BodyPoint, ContactRow, Counterpart, KEY_BODY, KEY_GRIP, KEY_OBSTACLE, KEY_TOOL, RowKey,
};
use crate::contact::rigid::Friction;
use crate::contact::{ContactConfig, Obstacle, Tool, pair_reach};
use crate::precision::Level;
use crate::world::WorldBody;

/// Body row `old` of the last round measured again against the same triangle's plane: its
/// points (same vertices and weights) on the current positions, along its normal.
pub(super) fn old_plane<B: BorrowMut<WorldBody>>(
    bodies: &[B],
    config: &ContactConfig,
    old: &ContactRow,
) -> ContactRow {
    let a = bodies[old.a.body as usize].borrow();
    let Counterpart::Body(q) = old.other else {
        return *old;
    };
    let b = bodies[q.body as usize].borrow();
    let pa = old.a.position(a.collider.positions());
    let pb = q.position(b.collider.positions());
    let mut row = *old;
    row.gap = old.normal().dot(&(pa - pb)) - config.thickness;
    let relative = motion(a, &old.a) - motion(b, &q);
    row.slip = [
        old.frame.column(1).dot(&relative),
        old.frame.column(2).dot(&relative),
    ];
    row
}

/// Row `old` (of the last step) measured again on the current positions, whatever the
/// distance: its point against its tool part, obstacle or body (a vertex against the other
/// body's nearest triangle within four times the pair reach; farther, its old frame with that
/// distance as its gap).
pub(super) fn find_again<B: BorrowMut<WorldBody>, T: BorrowMut<Tool>>(
    bodies: &[B],
    tools: &[T],
    obstacles: &[Obstacle],
    config: &ContactConfig,
    old: &ContactRow,
) -> ContactRow {
    let a = bodies[old.a.body as usize].borrow();
    let p = old.a.position(a.collider.positions());
    let moved = motion(a, &old.a);
    // A grip let go comes back as a contact: what its force held is then only pushed.
    let redo = |normal: Vec3, gap: f64, relative: Vec3, other: Counterpart, f: (f64, f64)| {
        ContactRow::contact(old.key, old.a, other, normal, gap, relative, f.0, f.1)
    };
    match old.other {
        Counterpart::Tool { tool, part } => {
            let t = tools[tool as usize].borrow();
            let k = part as usize;
            let pose = t.part_pose(k);
            let local = pose
                .inverse_transform_point(&nalgebra::Point3::from(p))
                .coords;
            let friction = Friction::combine(&a.friction, t.friction());
            match t.part_shape(k).query(&local, f64::INFINITY) {
                Some(h) => redo(
                    pose.rotation * h.normal,
                    h.distance,
                    moved - t.point_motion(k, &p),
                    old.other,
                    friction,
                ),
                None => *old,
            }
        }
        Counterpart::Obstacle(o) => {
            let ob = &obstacles[o as usize];
            let friction = Friction::combine(&a.friction, ob.friction());
            match ob.query(&p, f64::INFINITY) {
                Some(h) => redo(
                    h.normal,
                    h.distance - config.thickness,
                    moved,
                    old.other,
                    friction,
                ),
                None => *old,
            }
        }
        Counterpart::Body(q) => {
            let b = bodies[q.body as usize].borrow();
            let friction = Friction::combine(&a.friction, &b.friction);
            let reach = 4.0 * pair_reach(config, config.body_margin);
            match b.collider.closest(&p, reach) {
                Some(h) => {
                    let triangle = b.collider.triangles()[h.triangle as usize];
                    let other = snapped(q.body, triangle, h.weights);
                    let mut r = redo(
                        h.normal,
                        h.distance - config.thickness,
                        moved - motion(b, &other),
                        Counterpart::Body(other),
                        friction,
                    );
                    r.key = body_key(old.a.body, old.a.vertices[0], &other);
                    r
                }
                None => {
                    let mut r = *old;
                    r.gap = reach;
                    r
                }
            }
        }
    }
}

pub(super) fn other_body(r: &ContactRow) -> Option<u32> {
    match r.other {
        Counterpart::Body(p) => Some(p.body),
        _ => None,
    }
}

/// A row's key: body `a`, the vertices of its point with a weight (sorted, `u32::MAX` after
/// them), the counterpart's kind and index.
pub(super) fn key_of(
    a: u32,
    vertices: [u32; 3],
    weights: [f64; 3],
    kind: u32,
    index: u32,
) -> RowKey {
    let mut f = [u32::MAX; 3];
    let mut n = 0;
    for k in 0..3 {
        if weights[k] != 0.0 {
            f[n] = vertices[k];
            n += 1;
        }
    }
    f[..n].sort_unstable();
    [
        a,
        f[0],
        f[1],
        f[2],
        kind,
        index,
        u32::MAX,
        u32::MAX,
        u32::MAX,
    ]
}

/// A weight below this (barycentric) is taken as zero: a point this close to an edge or a
/// corner of its triangle is on that edge or corner.
const SNAP: f64 = 1e-3;

/// The point of triangle `t` of body `b` with `weights`, on the edge or corner it is within
/// [`SNAP`] of. A vertex near a corner (two meshes whose nodes nearly meet) is then found
/// against that corner whichever triangle around it the search returned, so one constraint
/// keeps one row (two rows of one constraint make the problem singular).
pub(super) fn snapped(b: u32, t: [u32; 3], mut weights: [f64; 3]) -> BodyPoint {
    for w in weights.iter_mut() {
        if *w < SNAP {
            *w = 0.0;
        }
    }
    let sum: f64 = weights.iter().sum();
    if sum > 0.0 {
        for w in weights.iter_mut() {
            *w /= sum;
        }
    }
    BodyPoint::triangle(b, t, weights)
}

/// The key of vertex `v` of body `a` against point `p` of the other body: the vertices with a
/// weight, sorted (`u32::MAX` after them).
pub(super) fn body_key(a: u32, v: u32, p: &BodyPoint) -> RowKey {
    let mut f = [u32::MAX; 3];
    for (k, (u, _)) in p.terms().enumerate() {
        f[k] = u;
    }
    let n = p.terms().count();
    f[..n].sort_unstable();
    [a, v, u32::MAX, u32::MAX, KEY_BODY, p.body, f[0], f[1], f[2]]
}

/// How far a body point moved since the start of the step.
pub(super) fn motion(b: &WorldBody, p: &BodyPoint) -> Vec3 {
    let x = b.collider.positions();
    p.terms()
        .map(|(v, w)| (x[v as usize] - b.start[v as usize]) * w)
        .sum()
}

/// The rows of the current positions: body pairs, tools, grips, obstacles.
pub(super) fn build_rows<B: BorrowMut<WorldBody> + Sync, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    obstacles: &[Obstacle],
    config: &ContactConfig,
    state: &mut ContactState,
) {
    state.rows.clear();
    // Body pairs (one side precise, or an awake cage against anything awake).
    state.queried.clear();
    for &(i, j) in &state.solve_pairs {
        let (bi, bj) = (bodies[i as usize].borrow(), bodies[j as usize].borrow());
        let both_cages = bi.model.level() == Level::Cage && bj.model.level() == Level::Cage;
        if !both_cages {
            state.queried.push((i, j));
        }
    }
    query_pairs(bodies, state, config, config.body_margin);
    for &(i, j) in &state.queried {
        for c in found_of(&state.candidates, (i, j)) {
            let (ba, bb) = (bodies[c.a as usize].borrow(), bodies[c.b as usize].borrow());
            let a = BodyPoint::vertex(c.a, c.vertex);
            let b = snapped(c.b, c.vertices, c.weights);
            let (mu_s, mu_k) = Friction::combine(&ba.friction, &bb.friction);
            state.rows.push(ContactRow::contact(
                body_key(c.a, c.vertex, &b),
                a,
                Counterpart::Body(b),
                c.normal,
                -c.depth,
                motion(ba, &a) - motion(bb, &b),
                mu_s,
                mu_k,
            ));
        }
    }
    // Tools.
    for (it, tool) in tools.iter().enumerate() {
        let tool = tool.borrow();
        let (lo, hi) = tool.bounds(config.tool_margin);
        for (ib, b) in bodies.iter().enumerate() {
            let b = b.borrow();
            let (blo, bhi) = b.collider.bounds();
            if (0..3).any(|k| lo[k] > bhi[k] || blo[k] > hi[k]) {
                continue;
            }
            for k in 0..tool.shape().parts() {
                state.shapes.clear();
                detect_shape(
                    &tool.part_shape(k),
                    &tool.part_pose(k),
                    &b.collider,
                    config.tool_margin,
                    &mut state.triangles,
                    &mut state.shapes,
                );
                let (mu_s, mu_k) = Friction::combine(&b.friction, tool.friction());
                for s in &state.shapes {
                    let a = BodyPoint::triangle(ib as u32, s.vertices, s.weights);
                    let p = a.position(b.collider.positions());
                    state.rows.push(ContactRow::contact(
                        key_of(
                            ib as u32,
                            s.vertices,
                            s.weights,
                            KEY_TOOL,
                            ((it as u32) << 8) | k as u32,
                        ),
                        a,
                        Counterpart::Tool {
                            tool: it as u32,
                            part: k as u8,
                        },
                        s.normal,
                        s.distance,
                        motion(b, &a) - tool.point_motion(k, &p),
                        mu_s,
                        mu_k,
                    ));
                }
            }
        }
        // Grips: each held vertex stays at its place on the tool.
        for g in tool.grips() {
            let b = bodies[g.body as usize].borrow();
            let target = tool.position() + tool.rotation() * g.offset;
            let x = b.collider.positions()[g.vertex as usize];
            state.rows.push(ContactRow::attachment(
                [
                    g.body,
                    g.vertex,
                    u32::MAX,
                    u32::MAX,
                    KEY_GRIP,
                    it as u32,
                    u32::MAX,
                    u32::MAX,
                    u32::MAX,
                ],
                BodyPoint::vertex(g.body, g.vertex),
                Counterpart::Tool {
                    tool: it as u32,
                    part: 0,
                },
                x - target,
            ));
        }
    }
    // Obstacles, against the bodies that take part.
    for (io, o) in obstacles.iter().enumerate() {
        let (olo, ohi) = o.bounds();
        for (ib, b) in bodies.iter().enumerate() {
            let b = b.borrow();
            if !takes_part(b) {
                continue;
            }
            let (blo, bhi) = b.collider.bounds();
            let m = config.thickness + config.body_margin;
            if (0..3).any(|k| olo[k] - m > bhi[k] || blo[k] - m > ohi[k]) {
                continue;
            }
            state.shapes.clear();
            detect_shape(
                o.shape(),
                o.pose(),
                &b.collider,
                config.thickness + config.body_margin,
                &mut state.triangles,
                &mut state.shapes,
            );
            let (mu_s, mu_k) = Friction::combine(&b.friction, o.friction());
            for s in &state.shapes {
                let a = BodyPoint::triangle(ib as u32, s.vertices, s.weights);
                state.rows.push(ContactRow::contact(
                    key_of(ib as u32, s.vertices, s.weights, KEY_OBSTACLE, io as u32),
                    a,
                    Counterpart::Obstacle(io as u32),
                    s.normal,
                    s.distance - config.thickness,
                    motion(b, &a),
                    mu_s,
                    mu_k,
                ));
            }
        }
    }
    state.rows.sort_unstable_by_key(|r| r.key);
    // One point found twice (an edge point from both of its triangles) keeps its first row.
    state.rows.dedup_by_key(|r| r.key);
    drop_mirrored(&mut state.rows);
}

/// The vertex of the other body a body row's point lands on, when it lands on a corner of
/// the triangle (see [`snapped`]): `(body a, vertex, body b, vertex of b)`.
pub(super) fn corner_of(r: &ContactRow) -> Option<(u32, u32, u32, u32)> {
    let Counterpart::Body(q) = r.other else {
        return None;
    };
    let k = (0..3).find(|&k| q.weights[k] == 1.0)?;
    Some((r.a.body, r.a.vertices[0], q.body, q.vertices[k]))
}

/// Two vertices at one place (two meshes whose nodes meet on their contact) are found both
/// ways, each at a corner of the other's triangles: the two rows are one constraint, and
/// both together make the problem singular (the solve does not converge, and rounds pile
/// forces on them without bound: two flush blocks that collided flew apart with eight times
/// the energy they met with). The row from the higher body goes; what force it carries (it
/// loaded the free motion, or a round applied it) moves to its mirror, which acts on the same
/// two vertices. `rows` is sorted by key.
pub(super) fn drop_mirrored(rows: &mut Vec<ContactRow>) {
    let mirror = |rows: &[ContactRow], r: &ContactRow| -> Option<usize> {
        let (a, v, b, u) = corner_of(r)?;
        if a <= b {
            return None;
        }
        let prefix = [b, u, u32::MAX, u32::MAX, KEY_BODY, a];
        let from = rows.partition_point(|x| x.key[..6] < prefix[..]);
        rows[from..]
            .iter()
            .take_while(|x| x.key[..6] == prefix[..])
            .position(|x| corner_of(x).is_some_and(|(.., w)| w == v))
            .map(|k| from + k)
    };
    // In place: a row's mirror has a lower first key (its body), so it sorts before it and
    // is among the rows kept so far (a mirror is never dropped itself).
    let mut kept = 0;
    for i in 0..rows.len() {
        let r = rows[i];
        match mirror(&rows[..kept], &r) {
            Some(j) => {
                let m = &mut rows[j];
                let to_m = m.frame.transpose() * r.frame;
                m.force -= to_m * r.force;
                m.applied -= to_m * r.applied;
            }
            None => {
                rows[kept] = r;
                kept += 1;
            }
        }
    }
    rows.truncate(kept);
}
