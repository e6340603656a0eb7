//! The force a blade feels as it cuts: the work of fracture.
//!
//! Cutting soft tissue costs the energy of the crack it makes: the tissue's fracture
//! toughness `J` (energy per area of new crack surface) times the area the blade's edge
//! sweeps through it (the fracture-mechanics view of cutting of Mahvash and Hayward, "Haptic
//! rendering of cutting: a fracture mechanics approach", Haptics-e 2(3), 2001). Over a step
//! the edge sweeps about `L d_across`: `L` the length of the edge inside the body now, and
//! `d_across` the part of the edge's motion across itself (a blade drawn along its own edge
//! sweeps nothing). The tool is held back against its motion `d` by `J L d_across / |d|`, so
//! the work it does over the step is the fracture energy of what it cut; the tissue takes
//! the opposite force where the edge passes through its surface (half at each crossing;
//! where the edge lies wholly inside, at the surface point nearest its middle), as a load of
//! the step. The resistance is measured on the bodies as the step begins (their surfaces as
//! the last step left them), before the cut stage: a cut landing in the step opens the
//! tissue the blade just went through. The load goes on the bodies the cut stage left. The tool's [`crate::contact::Tool::reaction_force`] includes the resistance; the
//! 1 kHz haptic loop's contact plane does not (a force against the motion is no surface,
//! and as one it would chatter with the hand's jitter). The loop renders the cut as a
//! friction across the edge instead ([`crate::haptics::CutModel`]): its breakaway force is
//! the tool's [`crate::contact::Tool::cutting_strength`], `J L` as this step measured it.
//!
//! A body's toughness is [`WorldBody::set_toughness`] (0, the default: no resistance), in
//! force per length of the scene's units (J/m^2 in a scene in metres). Liver: 164 +- 6 J/m^2
//! (bovine, from needle insertion; Gokgol, Basdogan and Canadinc, Med. Eng. Phys. 34(7),
//! 2012).
//!
//! Not modelled: the force before the tissue gives way (the deformation phase of Mahvash and
//! Hayward: the blade has no contact of its own), friction along the blade's faces, tissue
//! already cut (the edge is taken to cut whole tissue wherever it is inside the body, so
//! drawing it back through its own incision is resisted too), and the tissue's own motion
//! (the blade's motion in space is used, not relative to the tissue: tissue dragged along
//! with the blade is still pulled). The tissue's load sits on its surface, not along the
//! edge's crack front; a line through a surface edge exactly may be missed by both
//! triangles there (the piece's middle then decides).

use super::*;
use crate::contact::SurfaceCollider;

/// A point where a segment passes through a surface: its parameter along the segment, the
/// triangle and the point's barycentric weights in it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Crossing {
    pub t: f64,
    pub triangle: u32,
    pub weights: [f64; 3],
}

/// The part of the segment from `a` to `b` inside the closed surface `collider` (its current
/// positions): its length, with the points where it passes from outside to inside or back
/// into `crossings` (in order along it). The segment is split where it crosses triangles;
/// each piece is inside when its middle is (the sign of the distance to the surface, from
/// its pseudo-normals, so a line through an edge or a vertex of the surface does not
/// upset a count of crossings). A piece on the surface (in the plane of a cut's faces)
/// counts as inside.
pub(crate) fn segment_inside(
    collider: &SurfaceCollider,
    a: &Vec3,
    b: &Vec3,
    scratch: &mut Vec<u32>,
    crossings: &mut Vec<Crossing>,
) -> f64 {
    crossings.clear();
    let dir = b - a;
    let length = dir.norm();
    if length == 0.0 || !length.is_finite() {
        return 0.0;
    }
    let pad = Vec3::repeat(1e-9 * length);
    collider.triangles_in(&(a.inf(b) - pad), &(a.sup(b) + pad), scratch);
    let x = collider.positions();
    let mut hits: Vec<Crossing> = Vec::new();
    for &t in scratch.iter() {
        let [p0, p1, p2] = collider.triangles()[t as usize].map(|i| x[i as usize]);
        if let Some((s, w)) = segment_triangle(a, &dir, &p0, &p1, &p2) {
            hits.push(Crossing {
                t: s,
                triangle: t,
                weights: w,
            });
        }
    }
    hits.sort_by(|p, q| p.t.total_cmp(&q.t).then(p.triangle.cmp(&q.triangle)));
    // A crossing through an edge or a vertex of the surface is found in each triangle there.
    hits.dedup_by(|later, kept| later.t - kept.t <= 1e-12);
    let (lo, hi) = collider.bounds();
    let scale = (hi - lo).norm().max(length);
    let inside_at = |s: f64| {
        let p = a + dir * s;
        collider
            .closest(&p, f64::INFINITY)
            .is_some_and(|h| h.distance <= 1e-12 * scale)
    };
    let mut total = 0.0;
    let mut start = 0.0;
    let mut was: Option<bool> = None;
    for k in 0..=hits.len() {
        let end = hits.get(k).map_or(1.0, |h| h.t);
        if end > start {
            let inside = inside_at(0.5 * (start + end));
            if inside {
                total += (end - start) * length;
            }
            // The crossing at `start` separates pieces of different sides.
            if let Some(w) = was
                && w != inside
                && k > 0
            {
                crossings.push(hits[k - 1]);
            }
            was = Some(inside);
        }
        start = end;
    }
    total
}

/// Where the segment `a + s dir` (s in [0, 1]) meets triangle `(p0, p1, p2)`: `s` and the
/// point's barycentric weights (Moller and Trumbore's test); `None` when it misses or runs
/// parallel to the triangle's plane.
fn segment_triangle(
    a: &Vec3,
    dir: &Vec3,
    p0: &Vec3,
    p1: &Vec3,
    p2: &Vec3,
) -> Option<(f64, [f64; 3])> {
    let e1 = p1 - p0;
    let e2 = p2 - p0;
    let h = dir.cross(&e2);
    let det = e1.dot(&h);
    if det.abs() <= 1e-12 * dir.norm() * e1.norm() * e2.norm() {
        return None;
    }
    let inv = 1.0 / det;
    let s0 = a - p0;
    let u = inv * s0.dot(&h);
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s0.cross(&e1);
    let v = inv * dir.dot(&q);
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let s = inv * e2.dot(&q);
    (0.0..=1.0).contains(&s).then_some((s, [1.0 - u - v, u, v]))
}

/// A blade's pull on a body for this step (see [`cutting_resistance`]): the body's index,
/// where on its surface (a point where the edge crossed it, as the step began) and the
/// force there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutLoad {
    /// Index of the body (among those given to [`cutting_resistance`]).
    pub body: usize,
    /// The point, scene coordinates.
    pub point: Vec3,
    /// The force on the tissue there.
    pub force: Vec3,
}

/// Sets each tool's cutting resistance for this step (see the module docs), measured on the
/// bodies as the step begins (before the cut stage: a cut that lands now has opened the
/// tissue the blade just went through, and would hide it), and lists the opposite pull on
/// the tissue in `loads` (cleared first) for [`load_cutting`] after the cut stage. Zero for
/// a tool that is not a blade cutting, or that did not move. Sets each tool's cutting
/// strength too ([`Tool::cutting_strength`], the toughness times the length inside, whether
/// it moved or not): the haptic loop's breakaway force.
pub fn cutting_resistance<T: BorrowMut<Tool>, B: Borrow<WorldBody>>(
    tools: &mut [T],
    bodies: &[B],
    loads: &mut Vec<CutLoad>,
) {
    loads.clear();
    let (mut scratch, mut crossings) = (Vec::new(), Vec::new());
    for tool in tools.iter_mut() {
        let tool = tool.borrow_mut();
        let sweep = tool.blade_sweep().filter(|_| tool.cutting());
        let mut total = Vec3::zeros();
        let mut strength = 0.0;
        if let Some([(a0, b0), (a1, b1)]) = sweep
            && bodies.iter().any(|b| b.borrow().toughness > 0.0)
        {
            let motion = (a1 + b1 - a0 - b0) * 0.5;
            let (moved, edge) = (motion.norm(), (b1 - a1).norm());
            if edge > 0.0 {
                let along = (b1 - a1) / edge;
                // A blade at rest is measured too (its strength), but pushes nothing.
                let (across, dir) = if moved > 0.0 {
                    (
                        (motion - along * motion.dot(&along)).norm() / moved,
                        motion / moved,
                    )
                } else {
                    (0.0, Vec3::zeros())
                };
                for (i, body) in bodies.iter().enumerate() {
                    let body = body.borrow();
                    if body.toughness <= 0.0 {
                        continue;
                    }
                    let inside =
                        segment_inside(&body.collider, &a1, &b1, &mut scratch, &mut crossings);
                    let full = body.toughness * inside;
                    if full > 0.0 && full.is_finite() {
                        strength += full;
                    }
                    let force = full * across;
                    if !(force > 0.0 && force.is_finite()) {
                        continue;
                    }
                    total -= dir * force;
                    // Half at each crossing of its surface; where the edge crosses none, at
                    // the surface point nearest its middle.
                    let x = body.collider.positions();
                    let n = loads.len();
                    for c in &crossings {
                        let t = body.collider.triangles()[c.triangle as usize];
                        let point = (0..3).map(|k| x[t[k] as usize] * c.weights[k]).sum();
                        loads.push(CutLoad {
                            body: i,
                            point,
                            force: Vec3::zeros(),
                        });
                    }
                    if loads.len() == n {
                        let middle = (a1 + b1) * 0.5;
                        if let Some(h) = body.collider.closest(&middle, f64::INFINITY) {
                            loads.push(CutLoad {
                                body: i,
                                point: h.point,
                                force: Vec3::zeros(),
                            });
                        }
                    }
                    let share = dir * (force / (loads.len() - n).max(1) as f64);
                    for l in &mut loads[n..] {
                        l.force = share;
                    }
                }
            }
        }
        tool.set_cutting_resistance(total);
        tool.set_cutting_strength(strength);
    }
}

/// Loads the bodies with the pulls [`cutting_resistance`] listed, after the cut stage: each
/// at the surface point of its body nearest where it was measured (spread over that
/// triangle's nodes by the weights). A body the cut stage replaced keeps its index; a piece
/// it cut loose this step takes none.
pub fn load_cutting<B: BorrowMut<WorldBody>>(
    bodies: &mut [B],
    loads: &[CutLoad],
) -> Result<(), WorldError> {
    for l in loads {
        let Some(body) = bodies.get_mut(l.body) else {
            continue;
        };
        let body = body.borrow_mut();
        let Some(h) = body.collider.closest(&l.point, f64::INFINITY) else {
            continue;
        };
        let tri = body.collider.triangles()[h.triangle as usize];
        for (v, w) in tri.into_iter().zip(h.weights) {
            let node = body.collider.nodes()[v as usize] as usize;
            body.model
                .add_force(node, l.force * w)
                .map_err(|e| body.precision_err(e))?;
        }
    }
    Ok(())
}

impl WorldBody {
    /// Fracture toughness: energy per area of cut (force per length in the scene's units;
    /// see [`crate::world`]'s cutting resistance). 0 (the default): a blade cuts it freely.
    pub fn toughness(&self) -> f64 {
        self.toughness
    }

    /// Sets the fracture toughness (finite, >= 0); refused, naming the body, otherwise.
    pub fn set_toughness(&mut self, toughness: f64) -> Result<(), WorldError> {
        if !(toughness.is_finite() && toughness >= 0.0) {
            return Err(WorldError::Contact {
                name: self.label(),
                source: crate::contact::ContactError::BadParameter {
                    field: "toughness",
                    value: toughness,
                },
            });
        }
        self.toughness = toughness;
        Ok(())
    }
}
