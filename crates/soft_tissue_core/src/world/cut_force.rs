//! The force a blade feels as it cuts: the work of fracture.
//!
//! Cutting soft tissue costs the energy of the crack it makes: the tissue's fracture
//! toughness `J` (energy per area of new crack surface) times the area the blade's edge
//! sweeps through it (the fracture-mechanics view of cutting of Mahvash and Hayward, "Haptic
//! rendering of cutting: a fracture mechanics approach", Haptics-e 2(3), 2001). Over a step
//! the edge sweeps, through the tissue, about `L m_across`: `L` the length of the edge inside
//! the body now, and `m_across` the part across the edge of its motion `m` relative to the
//! tissue (a blade drawn along its own edge, or carried along with the tissue, sweeps
//! nothing). The tool is held back against that relative motion by `J L m_across / |m|`, so
//! the work done against it over the motion relative to the tissue is the fracture energy of
//! what it cut; the tissue takes the opposite force where the edge passes through its
//! surface (each piece of the edge inside, its share: half at each of its two crossings, all
//! at the one of a piece that ends inside; where the edge lies wholly inside, at the surface
//! point nearest its middle), as a load of the step. The resistance is measured on the
//! bodies as the step begins (their surfaces as the last step left them), before the cut
//! stage: a cut landing in the step opens the tissue the blade just went through. The load goes on the
//! bodies the cut stage left. The tool's [`crate::contact::Tool::reaction_force`] includes
//! the resistance; the 1 kHz haptic loop's contact plane does not (a force against the
//! motion is no surface, and as one it would chatter with the hand's jitter). The loop
//! renders the cut as a friction across the edge instead ([`crate::haptics::CutModel`]): its
//! breakaway force is the tool's [`crate::contact::Tool::cutting_strength`], `J L` as this
//! step measured it.
//!
//! The relative motion is taken piece by piece of the edge inside a body: the blade's motion
//! over the step at the piece's middle (from the edge as the step began to the edge now),
//! less the body's own motion over the last step: the mean motion of its contact surface
//! (where the last step left it, less where it was as that step began). A body carried as a
//! whole with the blade in it (a free organ moving, a piece falling with the blade) is not
//! cut; for a body moving steadily its mean motion is its velocity times the step; for one
//! that did not move (asleep, or just made by a cut or reset), none. The tissue's motion
//! where the edge is was tried and dropped: it is the last step's, and the pull acts as a
//! load of the next step, so on soft tissue the pull dragged the tissue past the blade, the
//! relative motion turned, and with it the force, in 8 of 16 steps of a 0.5 m/s stroke
//! through a held 20 kPa block, shaking the nodes beside the cut by 1-2 mm (never with the
//! mean motion). Tissue dragged along locally with the blade is therefore still pulled; the
//! stick of tissue moving with the blade would need the pull solved inside the step (as
//! contact friction is). A relative motion under `1e-9` of the edge's length counts as none
//! (the rounding of positions that moved together), so a blade carried with the tissue
//! feels nothing though its strength is still `J L`.
//!
//! A body's toughness is [`WorldBody::set_toughness`] (0, the default: no resistance), in
//! force per length of the scene's units (J/m^2 in a scene in metres). Liver: 164 +- 6 J/m^2
//! (bovine, from needle insertion; Gokgol, Basdogan and Canadinc, Med. Eng. Phys. 34(7),
//! 2012).
//!
//! Not modelled: the force before the tissue gives way (the deformation phase of Mahvash and
//! Hayward: the blade has no contact of its own), friction along the blade's faces, and
//! tissue already cut (the edge is taken to cut whole tissue wherever it is inside the body,
//! so drawing it back through its own incision is resisted too), the tissue's local motion
//! (above) and a body's turning as a whole (its mean motion is a translation). The tissue's
//! load sits on its surface, not along the edge's crack front; a line through a surface
//! edge exactly may be missed by both triangles
//! there (the piece's middle then decides).

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

/// A part of a segment inside a surface: its parameters along the segment (`from < to`) and
/// the crossings where it enters and leaves (`None` where it reaches an end of the segment
/// lying inside).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Piece {
    pub from: f64,
    pub to: f64,
    pub ends: [Option<Crossing>; 2],
}

/// Room [`segment_inside`] and [`cutting_resistance`] reuse from call to call.
#[derive(Debug, Default)]
pub(crate) struct SegmentScratch {
    triangles: Vec<u32>,
    hits: Vec<Crossing>,
    pieces: Vec<Piece>,
}

thread_local! {
    /// [`cutting_resistance`]'s room on this thread: a step measures without allocating once
    /// it has measured as many crossings before.
    static SCRATCH: std::cell::RefCell<SegmentScratch> = std::cell::RefCell::default();
}

/// The part of the segment from `a` to `b` inside the closed surface `collider` (its current
/// positions): its length, with its pieces inside into `pieces` (in order along it, each
/// with the points where it passes from outside to inside or back). The segment is split
/// where it crosses triangles; each piece is inside when its middle is (the sign of the
/// distance to the surface, from its pseudo-normals, so a line through an edge or a vertex
/// of the surface does not upset a count of crossings). A piece on the surface (in the plane
/// of a cut's faces) counts as inside. Adjacent inside pieces are one piece.
pub(crate) fn segment_inside(
    collider: &SurfaceCollider,
    a: &Vec3,
    b: &Vec3,
    triangles: &mut Vec<u32>,
    hits: &mut Vec<Crossing>,
    pieces: &mut Vec<Piece>,
) -> f64 {
    pieces.clear();
    hits.clear();
    let dir = b - a;
    let length = dir.norm();
    if length == 0.0 || !length.is_finite() {
        return 0.0;
    }
    let pad = Vec3::repeat(1e-9 * length);
    collider.triangles_in(&(a.inf(b) - pad), &(a.sup(b) + pad), triangles);
    let x = collider.positions();
    for &t in triangles.iter() {
        let [p0, p1, p2] = collider.triangles()[t as usize].map(|i| x[i as usize]);
        if let Some((s, w)) = segment_triangle(a, &dir, &p0, &p1, &p2) {
            hits.push(Crossing {
                t: s,
                triangle: t,
                weights: w,
            });
        }
    }
    hits.sort_unstable_by(|p, q| p.t.total_cmp(&q.t).then(p.triangle.cmp(&q.triangle)));
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
    // The crossing at `start` (none at the segment's own start).
    let mut at_start: Option<Crossing> = None;
    let mut was_inside = false;
    for k in 0..=hits.len() {
        let end = hits.get(k).map_or(1.0, |h| h.t);
        if end > start {
            let inside = inside_at(0.5 * (start + end));
            if inside {
                total += (end - start) * length;
                let leave = hits.get(k).copied();
                match pieces.last_mut() {
                    // Inside on both sides of the crossing at `start`: one piece.
                    Some(p) if was_inside => {
                        p.to = end;
                        p.ends[1] = leave;
                    }
                    _ => pieces.push(Piece {
                        from: start,
                        to: end,
                        ends: [at_start, leave],
                    }),
                }
            }
            was_inside = inside;
        }
        at_start = hits.get(k).copied();
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

/// A motion of the blade relative to the tissue under this share of the edge's length counts
/// as none: the rounding of positions that moved together (a blade carried with the tissue).
const STILL: f64 = 1e-9;

/// Sets each tool's cutting resistance for this step (see the module docs), measured on the
/// bodies as the step begins (before the cut stage: a cut that lands now has opened the
/// tissue the blade just went through, and would hide it), and lists the opposite pull on
/// the tissue in `loads` (cleared first) for [`load_cutting`] after the cut stage. Zero for
/// a tool that is not a blade cutting, or that did not move relative to the tissue. Sets
/// each tool's cutting strength too ([`Tool::cutting_strength`], the toughness times the
/// length inside, whether it moved or not): the haptic loop's breakaway force.
pub fn cutting_resistance<T: BorrowMut<Tool>, B: Borrow<WorldBody>>(
    tools: &mut [T],
    bodies: &[B],
    loads: &mut Vec<CutLoad>,
) {
    loads.clear();
    SCRATCH.with_borrow_mut(|scratch| {
        for tool in tools.iter_mut() {
            let tool = tool.borrow_mut();
            let (total, strength) = match tool.blade_sweep().filter(|_| tool.cutting()) {
                Some(sweep) if bodies.iter().any(|b| b.borrow().toughness > 0.0) => {
                    resist(sweep, bodies, scratch, loads)
                }
                _ => (Vec3::zeros(), 0.0),
            };
            tool.set_cutting_resistance(total);
            tool.set_cutting_strength(strength);
        }
    });
}

/// One blade's resistance and cutting strength (see [`cutting_resistance`]), from its edge
/// at the start of the step and now; its pulls on the bodies go onto `loads`.
fn resist<B: Borrow<WorldBody>>(
    [(a0, b0), (a1, b1)]: [(Vec3, Vec3); 2],
    bodies: &[B],
    scratch: &mut SegmentScratch,
    loads: &mut Vec<CutLoad>,
) -> (Vec3, f64) {
    let mut total = Vec3::zeros();
    let mut strength = 0.0;
    let edge = (b1 - a1).norm();
    if !(edge > 0.0 && edge.is_finite()) {
        return (total, strength);
    }
    let along = (b1 - a1) / edge;
    let SegmentScratch {
        triangles,
        hits,
        pieces,
    } = scratch;
    for (i, body) in bodies.iter().enumerate() {
        let body = body.borrow();
        if body.toughness <= 0.0 {
            continue;
        }
        let inside = segment_inside(&body.collider, &a1, &b1, triangles, hits, pieces);
        let full = body.toughness * inside;
        if !(full > 0.0 && full.is_finite()) {
            continue;
        }
        strength += full;
        let x = body.collider.positions();
        let surface = body.collider.triangles();
        // The tissue's motion: its surface's mean motion over the last step (now less as
        // that step began; see the module docs for why not the motion where the edge is).
        let (mut carried, mut counted) = (Vec3::zeros(), 0usize);
        for (xv, sv) in x.iter().zip(&body.start) {
            carried += xv - sv;
            counted += 1;
        }
        let tissue = carried / counted.max(1) as f64;
        for p in pieces.iter() {
            let middle = 0.5 * (p.from + p.to);
            let length = (p.to - p.from) * edge;
            // The blade's motion at the piece's middle; the pull at the piece's ends on the
            // surface (half at each; a piece that crosses the surface nowhere, the edge
            // wholly inside, at the surface point nearest its middle).
            let blade = (a1 - a0) * (1.0 - middle) + (b1 - b0) * middle;
            let n = loads.len();
            for c in p.ends.iter().flatten() {
                let t = surface[c.triangle as usize];
                let point = (0..3).map(|k| x[t[k] as usize] * c.weights[k]).sum();
                loads.push(CutLoad {
                    body: i,
                    point,
                    force: Vec3::zeros(),
                });
            }
            if loads.len() == n
                && let Some(h) = body
                    .collider
                    .closest(&(a1 + (b1 - a1) * middle), f64::INFINITY)
            {
                loads.push(CutLoad {
                    body: i,
                    point: h.point,
                    force: Vec3::zeros(),
                });
            }
            let points = loads.len() - n;
            let relative = blade - tissue;
            let moved = relative.norm();
            let across = (relative - along * relative.dot(&along)).norm();
            let force = body.toughness * length * across / moved;
            if !(moved > STILL * edge && force > 0.0 && force.is_finite()) {
                loads.truncate(n);
                continue;
            }
            let dir = relative / moved;
            total -= dir * force;
            let share = dir * (force / points.max(1) as f64);
            for l in &mut loads[n..] {
                l.force = share;
            }
        }
    }
    (total, strength)
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
