//! Tool scripts: a tool's path over time (waypoints, linearly interpolated) and actions at
//! given times (grab, release, cautery power). Scripts are RON files, so interactions can be
//! recorded and replayed; the paper's interactions are built in, placed from the scene's
//! bodies so they work for any mesh.

use serde::{Deserialize, Serialize};

use super::SoftTissueWorld;
use crate::Vec3;
use crate::contact::{ContactError, JawShape, Tool, ToolShape};

/// A tool pose at a time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Waypoint {
    /// Time, s.
    pub t: f64,
    /// Tip position, scene units.
    pub position: [f64; 3],
    /// Shaft axis (from the tip backward).
    pub axis: [f64; 3],
    /// Turn about the shaft axis, degrees (a grasper's jaws close along the tool frame's x:
    /// with no turn, the x the shortest turn from +y to the axis leaves).
    #[serde(default)]
    pub roll_deg: f64,
}

/// Something the tool does.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ScriptAction {
    /// Grab the surface under the tip.
    Grab,
    /// Let go.
    Release,
    /// Set the electrocautery power, W (0 turns it off).
    Cautery(f64),
    /// Move a grasper's jaws toward this opening, scene units (0 closes them; beyond the
    /// widest opens them fully).
    Jaws(f64),
    /// Turn a blade's cutting on or off (the surface its edge sweeps while on cuts).
    Cut(bool),
}

impl ScriptAction {
    /// Does it to `tool`.
    pub fn apply(&self, tool: &mut Tool) -> Result<(), ContactError> {
        match *self {
            ScriptAction::Grab => tool.grab(),
            ScriptAction::Release => tool.release(),
            ScriptAction::Cautery(w) => tool.set_cautery(w)?,
            ScriptAction::Jaws(w) => tool.set_opening(w)?,
            ScriptAction::Cut(on) => tool.set_cutting(on)?,
        }
        Ok(())
    }
}

/// An action at a time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScriptEvent {
    /// Time, s.
    pub t: f64,
    /// What happens.
    pub action: ScriptAction,
}

/// A scripted tool (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Script {
    /// Name.
    pub name: String,
    /// Tool tip.
    pub tool: ToolShape,
    /// Path, in increasing time; the pose holds before the first and after the last.
    pub waypoints: Vec<Waypoint>,
    /// Actions, in increasing time.
    pub events: Vec<ScriptEvent>,
}

/// A script that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ScriptError {
    /// The RON text does not parse.
    #[error("{file}: {source}")]
    Ron {
        /// File.
        file: String,
        /// Parser error with position.
        source: Box<ron::error::SpannedError>,
    },
    /// Something in the script is out of range.
    #[error("script `{script}`: {message}")]
    Invalid {
        /// Script name.
        script: String,
        /// What is wrong.
        message: String,
    },
    /// No built-in script by that name.
    #[error(
        "no built-in script `{0}` (poke-a, push-a-into-b, poke-liver, cauterize-liver, poke, poke:BODY, grasp-spleen, grasp:BODY, cut-liver, cut:BODY)"
    )]
    Unknown(String),
    /// The scene lacks a body the built-in script needs.
    #[error("script `{script}` needs {needed} in the scene")]
    MissingBody {
        /// Script.
        script: String,
        /// What it needs, in words (`a body named `Liver``, `another organ`): no body of the
        /// scene has it, so there is no body to name.
        needed: String,
    },
}

impl Script {
    /// Parses a RON script and validates it.
    pub fn from_ron(text: &str, file: &str) -> Result<Script, ScriptError> {
        let s: Script = ron::from_str(text).map_err(|e| ScriptError::Ron {
            file: file.into(),
            source: Box::new(e),
        })?;
        s.validate()?;
        Ok(s)
    }

    /// RON text of the script.
    pub fn to_ron(&self) -> String {
        ron::ser::to_string_pretty(self, ron::ser::PrettyConfig::default())
            .unwrap_or_else(|e| format!("// serialisation failed: {e}"))
    }

    /// Checks times increase, values are finite, the tool is valid and axes are not zero.
    pub fn validate(&self) -> Result<(), ScriptError> {
        let bad = |message: String| ScriptError::Invalid {
            script: self.name.clone(),
            message,
        };
        crate::contact::Tool::new(self.name.clone(), self.tool).map_err(|e| bad(e.to_string()))?;
        if self.waypoints.is_empty() {
            return Err(bad("at least one waypoint is needed".into()));
        }
        let mut last = f64::NEG_INFINITY;
        for (i, w) in self.waypoints.iter().enumerate() {
            let finite = w.t.is_finite() && w.position.iter().chain(&w.axis).all(|x| x.is_finite());
            if !finite {
                return Err(bad(format!("waypoint {i} is not finite")));
            }
            if Vec3::from(w.axis).norm() == 0.0 {
                return Err(bad(format!("waypoint {i} has a zero axis")));
            }
            if w.t < last {
                return Err(bad(format!("waypoint {i} (t = {}) goes back in time", w.t)));
            }
            if !w.roll_deg.is_finite() {
                return Err(bad(format!("waypoint {i}: roll_deg is not finite")));
            }
            last = w.t;
        }
        let mut last = f64::NEG_INFINITY;
        for (i, e) in self.events.iter().enumerate() {
            if !e.t.is_finite() || e.t < last {
                return Err(bad(format!("event {i} (t = {}) is not in time order", e.t)));
            }
            if let ScriptAction::Cautery(w) = e.action
                && !(w.is_finite() && w >= 0.0)
            {
                return Err(bad(format!("event {i}: cautery power {w} must be >= 0")));
            }
            if let ScriptAction::Jaws(w) = e.action {
                if !matches!(self.tool, ToolShape::Grasper { .. }) {
                    return Err(bad(format!("event {i}: `Jaws` needs a grasper tool")));
                }
                if !(w.is_finite() && w >= 0.0) {
                    return Err(bad(format!("event {i}: jaw opening {w} must be >= 0")));
                }
            }
            if let ScriptAction::Cut(true) = e.action
                && !matches!(self.tool, ToolShape::Blade { .. })
            {
                return Err(bad(format!("event {i}: `Cut(true)` needs a blade tool")));
            }
            last = e.t;
        }
        Ok(())
    }

    /// Tool pose at time `t` (linear between waypoints).
    pub fn pose_at(&self, t: f64) -> (Vec3, Vec3) {
        let w = &self.waypoints;
        let pose = |w: &Waypoint| (Vec3::from(w.position), Vec3::from(w.axis));
        if t <= w[0].t {
            return pose(&w[0]);
        }
        for pair in w.windows(2) {
            let (a, b) = (&pair[0], &pair[1]);
            if t <= b.t {
                let s = if b.t > a.t {
                    (t - a.t) / (b.t - a.t)
                } else {
                    1.0
                };
                let (pa, aa) = pose(a);
                let (pb, ab) = pose(b);
                let axis = aa * (1.0 - s) + ab * s;
                let axis = if axis.norm() > 0.0 { axis } else { ab };
                return (pa * (1.0 - s) + pb * s, axis);
            }
        }
        pose(&w[w.len() - 1])
    }

    /// Tool tip position and frame orientation at time `t`: the shortest turn from +y to the
    /// axis of [`Script::pose_at`], then the roll (linear between waypoints) about it.
    pub fn pose_rotation_at(&self, t: f64) -> (Vec3, nalgebra::UnitQuaternion<f64>) {
        let (p, axis) = self.pose_at(t);
        let w = &self.waypoints;
        let roll = if t <= w[0].t {
            w[0].roll_deg
        } else {
            w.windows(2)
                .find(|p| t <= p[1].t)
                .map(|p| {
                    let s = if p[1].t > p[0].t {
                        (t - p[0].t) / (p[1].t - p[0].t)
                    } else {
                        1.0
                    };
                    p[0].roll_deg * (1.0 - s) + p[1].roll_deg * s
                })
                .unwrap_or(w[w.len() - 1].roll_deg)
        };
        let base = crate::contact::pose_along(Vec3::zeros(), axis.normalize()).rotation;
        let turn = nalgebra::UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(axis),
            roll.to_radians(),
        );
        (p, turn * base)
    }

    /// Events with `t0 < t <= t1`.
    pub fn events_in(&self, t0: f64, t1: f64) -> impl Iterator<Item = &ScriptEvent> {
        self.events.iter().filter(move |e| e.t > t0 && e.t <= t1)
    }

    /// Time of the last waypoint or event.
    pub fn end_time(&self) -> f64 {
        let w = self.waypoints.last().map_or(0.0, |w| w.t);
        let e = self.events.last().map_or(0.0, |e| e.t);
        w.max(e)
    }

    /// A built-in script placed from `world`'s bodies:
    /// - `poke-a` (paper Table II): a ball pushes model A from the front (along z, past model
    ///   B), holds, and withdraws at 2.5 s.
    /// - `push-a-into-b` (Table III): a ball pushes the top of A toward B until A presses B,
    ///   holds, withdraws at 3 s.
    /// - `poke-liver` (Table IV): a ball presses down on the top of the liver above the point
    ///   where it is closest to another organ, holds, withdraws at 3 s.
    /// - `cauterize-liver`: a capsule touches the liver's top and cauterizes at 30 W for 2 s.
    /// - `poke` (any scene) and `poke:BODY`: a ball a tenth of the body's smallest dimension
    ///   across presses down on the top of the first body (or the one named) near the middle
    ///   of its footprint, 30 % of that dimension deep, holds, withdraws at 3 s.
    /// - `grasp-spleen` and `grasp:BODY` (any scene): an open grasper (box jaws) comes down
    ///   over the body (the spleen, or the one named) with its jaws across its narrower
    ///   horizontal extent, closes to half of it from 1 s, lifts by a third of the
    ///   body's height (`grasp-spleen`: 0.05 scene units, 5 cm in a scene in metres) from 2 s
    ///   to 3 s, holds until 4.5 s, and opens.
    /// - `cut-liver` and `cut:BODY` (any scene): a scalpel (a blade edge pointing up from
    ///   its tip) goes into the body (the liver, or the one named) from beside it, its tip
    ///   40 % of the body's height below its top, and cuts across its whole length along x
    ///   from 0.5 s to 2 s (an incision that does not go through: the body stays one piece),
    ///   then stops cutting and leaves upward.
    pub fn builtin(name: &str, world: &SoftTissueWorld) -> Result<Script, ScriptError> {
        match name {
            "cut-liver" => cut_script(world, name, "Liver"),
            cut if cut.starts_with("cut:") => cut_script(world, name, &cut["cut:".len()..]),
            "poke-a" => {
                // From the front (-z), so A is pushed along z, past B rather than into it.
                let a = body_box(world, name, "Model A")?;
                let r = 0.08 * a.extent.y;
                let y = a.lo.y + 0.75 * a.extent.y;
                let depth = 0.15 * a.extent.z;
                let contact = Vec3::new(a.center.x, y, a.lo.z - r);
                let start = contact - Vec3::z() * 0.2 * a.extent.z;
                Ok(push_script(
                    name,
                    r,
                    -Vec3::z(),
                    start,
                    contact,
                    contact + Vec3::z() * depth,
                    [0.5, 1.5, 2.0, 2.5],
                ))
            }
            "push-a-into-b" => {
                let a = body_box(world, name, "Model A")?;
                let b = body_box(world, name, "Model B")?;
                let dir = (b.center - a.center).normalize();
                let r = 0.08 * a.extent.y;
                let y = a.lo.y + 0.85 * a.extent.y;
                let contact = Vec3::new(a.center.x, y, a.center.z) - dir * (0.5 * a.extent.x + r);
                let gap = (b.lo.x - a.hi.x).max(0.0);
                let depth = gap + 0.2 * a.extent.x;
                let start = contact - dir * 0.2 * a.extent.x;
                Ok(push_script(
                    name,
                    r,
                    -dir,
                    start,
                    contact,
                    contact + dir * depth,
                    [0.5, 2.0, 2.5, 3.0],
                ))
            }
            "poke-liver" => {
                let liver = world
                    .body_index("Liver")
                    .map_err(|_| ScriptError::MissingBody {
                        script: name.into(),
                        needed: "a body named `Liver`".into(),
                    })?;
                // The liver surface point closest to another organ.
                let lp = world.bodies()[liver].collider().positions();
                let mut best: Option<(f64, Vec3)> = None;
                for (i, other) in world.bodies().iter().enumerate() {
                    if i == liver {
                        continue;
                    }
                    for q in other.collider().positions() {
                        for p in lp {
                            let d = (q - p).norm_squared();
                            if best.is_none_or(|(bd, _)| d < bd) {
                                best = Some((d, *p));
                            }
                        }
                    }
                }
                let Some((_, p)) = best else {
                    return Err(ScriptError::MissingBody {
                        script: name.into(),
                        needed: "another organ".into(),
                    });
                };
                // Press down (-y) on the top of the liver above that point, so the liver is
                // pushed onto what lies under and beside it.
                let bb = crate::mesh::Aabb::from_points(lp.iter()).ok_or_else(|| {
                    ScriptError::MissingBody {
                        script: name.into(),
                        needed: "a body named `Liver` with a surface".into(),
                    }
                })?;
                let small = bb.smallest_dimension();
                let near = 0.15 * small;
                let top = lp
                    .iter()
                    .filter(|x| ((*x - p).xz()).norm() < near)
                    .map(|x| x.y)
                    .fold(p.y, f64::max);
                let r = 0.1 * small;
                let contact = Vec3::new(p.x, top + r, p.z);
                let start = contact + Vec3::y() * 0.2 * small;
                let pushed = contact - Vec3::y() * 0.3 * small;
                Ok(push_script(
                    name,
                    r,
                    Vec3::y(),
                    start,
                    contact,
                    pushed,
                    [0.5, 2.0, 2.5, 3.0],
                ))
            }
            "cauterize-liver" => {
                let l = body_box(world, name, "Liver")?;
                let lp = world.bodies()[l.index].collider().positions();
                // The highest liver vertex.
                let top = lp
                    .iter()
                    .copied()
                    .fold(l.center, |a, b| if b.y > a.y { b } else { a });
                let r = 0.04 * l.extent.y;
                let contact = top + Vec3::y() * r;
                let press = contact - Vec3::y() * 0.5 * r;
                let start = contact + Vec3::y() * 0.2 * l.extent.y;
                let mut s = push_script(
                    name,
                    r,
                    Vec3::y(),
                    start,
                    contact,
                    press,
                    [0.5, 0.8, 2.8, 3.2],
                );
                s.tool = ToolShape::Capsule {
                    radius: r,
                    length: 0.5 * l.extent.y,
                };
                s.events = vec![
                    ScriptEvent {
                        t: 0.8,
                        action: ScriptAction::Cautery(30.0),
                    },
                    ScriptEvent {
                        t: 2.8,
                        action: ScriptAction::Cautery(0.0),
                    },
                ];
                Ok(s)
            }
            "grasp-spleen" => grasp_script(world, name, "Spleen", Some(0.05)),
            grasp if grasp.starts_with("grasp:") => {
                grasp_script(world, name, &grasp["grasp:".len()..], None)
            }
            poke if poke == "poke" || poke.starts_with("poke:") => {
                // Any scene: press down (-y) on the top of a body (the first, or the one
                // named after `poke:`) near the middle of its footprint, 30 % of its smallest
                // dimension deep, then withdraw.
                let target = match poke.strip_prefix("poke:") {
                    Some(body) => body_box(world, name, body)?,
                    None => {
                        let first =
                            world
                                .bodies()
                                .first()
                                .ok_or_else(|| ScriptError::MissingBody {
                                    script: name.into(),
                                    needed: "a body".into(),
                                })?;
                        body_box(world, name, first.name())?
                    }
                };
                let points = world.bodies()[target.index].collider().positions();
                let small = target.extent.min();
                let middle = |x: &Vec3, reach: f64| {
                    ((x - target.center).xz()).norm() <= reach * target.extent.xz().norm()
                };
                let top = [0.1, 0.25, 1.0]
                    .into_iter()
                    .find_map(|reach| {
                        points
                            .iter()
                            .filter(|x| middle(x, reach))
                            .copied()
                            .reduce(|a, b| if b.y > a.y { b } else { a })
                    })
                    .unwrap_or(target.center);
                let r = 0.1 * small;
                let contact = top + Vec3::y() * r;
                Ok(push_script(
                    name,
                    r,
                    Vec3::y(),
                    contact + Vec3::y() * 0.2 * small,
                    contact,
                    contact - Vec3::y() * 0.3 * small,
                    [0.5, 2.0, 2.5, 3.0],
                ))
            }
            other => Err(ScriptError::Unknown(other.into())),
        }
    }
}

struct BodyBox {
    index: usize,
    lo: Vec3,
    hi: Vec3,
    center: Vec3,
    extent: Vec3,
}

fn body_box(world: &SoftTissueWorld, script: &str, body: &str) -> Result<BodyBox, ScriptError> {
    let i = world
        .body_index(body)
        .map_err(|_| ScriptError::MissingBody {
            script: script.into(),
            needed: format!("a body named `{body}`"),
        })?;
    let (lo, hi) = world.bodies()[i].collider().bounds();
    Ok(BodyBox {
        index: i,
        lo,
        hi,
        center: (lo + hi) / 2.0,
        extent: hi - lo,
    })
}

/// See [`Script::builtin`]'s `cut:BODY`.
fn cut_script(world: &SoftTissueWorld, name: &str, body: &str) -> Result<Script, ScriptError> {
    let b = body_box(world, name, body)?;
    let margin = 0.1 * b.extent.x;
    let tip_y = b.hi.y - 0.4 * b.extent.y;
    let start = Vec3::new(b.lo.x - margin, tip_y, b.center.z);
    let end = Vec3::new(b.hi.x + margin, tip_y, b.center.z);
    let away = end + Vec3::y() * 1.2 * b.extent.y;
    let w = |t: f64, p: Vec3| Waypoint {
        t,
        position: p.into(),
        axis: Vec3::y().into(),
        roll_deg: 0.0,
    };
    Ok(Script {
        name: name.into(),
        tool: ToolShape::Blade {
            length: 0.8 * b.extent.y,
        },
        waypoints: vec![w(0.0, start), w(0.5, start), w(2.0, end), w(2.5, away)],
        events: vec![
            ScriptEvent {
                t: 0.5,
                action: ScriptAction::Cut(true),
            },
            ScriptEvent {
                t: 2.0,
                action: ScriptAction::Cut(false),
            },
        ],
    })
}

/// Approach, push in, hold, withdraw: waypoints at `start` (t = 0), `contact` (times[0]),
/// `pushed` (times[1]), hold until times[2], back at `start` at times[3].
fn push_script(
    name: &str,
    radius: f64,
    axis: Vec3,
    start: Vec3,
    contact: Vec3,
    pushed: Vec3,
    times: [f64; 4],
) -> Script {
    let w = |t: f64, p: Vec3| Waypoint {
        t,
        position: p.into(),
        axis: axis.into(),
        roll_deg: 0.0,
    };
    Script {
        name: name.into(),
        tool: ToolShape::Sphere { radius },
        waypoints: vec![
            w(0.0, start),
            w(times[0], contact),
            w(times[1], pushed),
            w(times[2], pushed),
            w(times[3], start),
        ],
        events: Vec::new(),
    }
}

/// The grasp of [`Script::builtin`]'s `grasp:BODY` (`lift`: how high, default a third of the
/// body's height).
fn grasp_script(
    world: &SoftTissueWorld,
    script: &str,
    body: &str,
    lift: Option<f64>,
) -> Result<Script, ScriptError> {
    let b = body_box(world, script, body)?;
    // Jaws across the narrower horizontal extent: x (no roll) or z (a quarter turn).
    let (across, roll) = if b.extent.x <= b.extent.z {
        (b.extent.x, 0.0)
    } else {
        (b.extent.z, 90.0)
    };
    let along = b.extent.x.max(b.extent.z);
    let lift = lift.unwrap_or(b.extent.y / 3.0);
    let tip = Vec3::new(b.center.x, b.lo.y + 0.2 * b.extent.y, b.center.z);
    let above = tip + Vec3::y() * 1.2 * b.extent.y;
    let lifted = tip + Vec3::y() * lift;
    let w = |t: f64, p: Vec3| Waypoint {
        t,
        position: p.into(),
        axis: [0.0, 1.0, 0.0],
        roll_deg: roll,
    };
    Ok(Script {
        name: script.into(),
        tool: ToolShape::Grasper {
            jaw: JawShape::Box {
                thickness: 0.1 * across,
                width: 0.4 * along,
                length: 0.7 * b.extent.y,
            },
            max_opening: 1.3 * across,
        },
        waypoints: vec![
            w(0.0, above),
            w(1.0, tip),
            w(2.0, tip),
            w(3.0, lifted),
            w(4.5, lifted),
        ],
        events: vec![
            ScriptEvent {
                t: 1.0,
                action: ScriptAction::Jaws(0.5 * across),
            },
            ScriptEvent {
                t: 4.5,
                action: ScriptAction::Jaws(1.3 * across),
            },
        ],
    })
}
