//! Kinematic tools: a probe (sphere or capsule) that pokes, picks (an exact grab) and
//! cauterizes, and a grasper whose two jaws hold tissue by normal force and friction.

use nalgebra::{Point3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::ContactError;
use super::rigid::{Friction, Pose, RigidShape, pose_along};
use crate::Vec3;

/// The shape of one jaw of a grasper, in the jaw's frame: the jaw runs from the tool tip back
/// along the shaft (+y) and closes along the tool's jaw direction (x).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum JawShape {
    /// A rod: a capsule of `radius` around a segment of `length` along the shaft.
    Capsule {
        /// Radius, scene units.
        radius: f64,
        /// Length along the shaft, scene units.
        length: f64,
    },
    /// A flat jaw: a box `thickness` across (along the closing direction), `width` wide and
    /// `length` long.
    Box {
        /// Extent along the closing direction.
        thickness: f64,
        /// Extent across the shaft, perpendicular to the closing direction.
        width: f64,
        /// Extent along the shaft.
        length: f64,
    },
}

impl JawShape {
    /// Half the jaw's extent along the closing direction (its centre sits this far outside
    /// the gap between the jaws).
    fn half_thickness(&self) -> f64 {
        match *self {
            JawShape::Capsule { radius, .. } => radius,
            JawShape::Box { thickness, .. } => 0.5 * thickness,
        }
    }

    /// The jaw as a rigid shape and its frame relative to the jaw's centre line at the tip.
    fn shape(&self) -> (RigidShape, Vec3) {
        match *self {
            JawShape::Capsule { radius, length } => {
                (RigidShape::Capsule { radius, length }, Vec3::zeros())
            }
            JawShape::Box {
                thickness,
                width,
                length,
            } => (
                RigidShape::Box {
                    half_extents: Vec3::new(0.5 * thickness, 0.5 * length, 0.5 * width),
                },
                Vec3::new(0.0, 0.5 * length, 0.0),
            ),
        }
    }
}

/// Shape of a tool.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ToolShape {
    /// A ball of `radius` centred at the tool position.
    Sphere {
        /// Radius, scene units.
        radius: f64,
    },
    /// A capsule of `radius` around the segment from the tool position along the tool axis
    /// for `length` (the shaft behind the tip).
    Capsule {
        /// Radius, scene units.
        radius: f64,
        /// Segment length, scene units.
        length: f64,
    },
    /// Two parallel jaws on either side of the shaft, along the tool's jaw direction, their
    /// inner surfaces [`Tool::opening`] apart (from 0, closed, to `max_opening`). A parallel
    /// gripper's kinematics: the jaws stay parallel as they close.
    Grasper {
        /// Each jaw's shape.
        jaw: JawShape,
        /// Widest opening, scene units.
        max_opening: f64,
    },
    /// A scalpel's edge: the segment from the tool position along the tool axis for
    /// `length`. While cutting is on ([`Tool::set_cutting`]) the surface it sweeps between
    /// two steps cuts the bodies it crosses; it takes no part in contact (a sharp edge
    /// parts tissue rather than pushing it).
    Blade {
        /// Edge length, scene units.
        length: f64,
    },
}

impl ToolShape {
    /// Radius of the tip (a sphere's or capsule's radius; half a grasper jaw's thickness).
    pub fn radius(&self) -> f64 {
        match *self {
            ToolShape::Sphere { radius } | ToolShape::Capsule { radius, .. } => radius,
            ToolShape::Grasper { jaw, .. } => jaw.half_thickness(),
            ToolShape::Blade { .. } => 0.0,
        }
    }

    /// Checks the dimensions; the error names the tool and the field.
    pub fn validate(&self, tool: &str) -> Result<(), ContactError> {
        let bad = |what: &'static str, value: f64| ContactError::BadTool {
            tool: tool.into(),
            what,
            value,
        };
        let positive = |what, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(what, v))
            }
        };
        match *self {
            ToolShape::Sphere { radius } => positive("radius (must be > 0)", radius),
            ToolShape::Capsule { radius, length } => {
                positive("radius (must be > 0)", radius)?;
                if !(length.is_finite() && length >= 0.0) {
                    return Err(bad("capsule length (must be >= 0)", length));
                }
                Ok(())
            }
            ToolShape::Grasper { jaw, max_opening } => {
                match jaw {
                    JawShape::Capsule { radius, length } => {
                        positive("jaw radius (must be > 0)", radius)?;
                        positive("jaw length (must be > 0)", length)?;
                    }
                    JawShape::Box {
                        thickness,
                        width,
                        length,
                    } => {
                        positive("jaw thickness (must be > 0)", thickness)?;
                        positive("jaw width (must be > 0)", width)?;
                        positive("jaw length (must be > 0)", length)?;
                    }
                }
                positive("grasper max_opening (must be > 0)", max_opening)
            }
            ToolShape::Blade { length } => positive("blade length (must be > 0)", length),
        }
    }

    /// Number of rigid parts in contact (1, 2 for a grasper, none for a blade).
    pub fn parts(&self) -> usize {
        match self {
            ToolShape::Grasper { .. } => 2,
            ToolShape::Blade { .. } => 0,
            _ => 1,
        }
    }
}

/// A surface node held by a pick tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grip {
    /// Body index.
    pub body: u32,
    /// Node of that body.
    pub node: u32,
    /// Surface vertex of that body (collider index).
    pub vertex: u32,
    /// Node position minus tool position when grabbed, in the tool's frame (it turns with
    /// the tool).
    pub offset: Vec3,
}

/// A cautery electrode's radius by default, m (1 mm).
pub const DEFAULT_ELECTRODE_RADIUS: f64 = 1e-3;

/// A kinematic tool: pokes (always), picks (after [`Tool::grab`]), cauterizes (with power
/// set) and, as a grasper, holds by squeezing. The caller sets its pose each step; the step
/// returns the contact force on it (the sum of its contacts' forces).
#[derive(Debug, Clone)]
pub struct Tool {
    name: String,
    shape: ToolShape,
    position: Vec3,
    rotation: UnitQuaternion<f64>,
    /// The parts' poses at the start of the step (their motion over the step drives
    /// friction).
    last_parts: [Pose; 2],
    last_position: Option<Vec3>,
    velocity: Vec3,
    cautery_watts: f64,
    electrode_radius: Option<f64>,
    grab_requested: bool,
    grips: Vec<Grip>,
    reaction: Vec3,
    /// The normal force each jaw took in the last step (grasper).
    jaw_force: [f64; 2],
    contacts: u32,
    friction: Friction,
    opening: f64,
    target_opening: f64,
    jaw_speed: f64,
    grip_limit: f64,
    /// A blade's cutting is on.
    cutting: bool,
    /// The tissue's resistance to the blade's cut over the last step.
    resistance: Vec3,
    /// The force it takes to push a cutting blade's edge across itself, as the last step
    /// found it (toughness times the edge's length inside, summed over the bodies).
    strength: f64,
}

impl Tool {
    /// A tool at the origin pointing along +y (shaft upward), idle; a grasper starts fully
    /// open.
    pub fn new(name: impl Into<String>, shape: ToolShape) -> Result<Self, ContactError> {
        let name = name.into();
        shape.validate(&name)?;
        let open = match shape {
            ToolShape::Grasper { max_opening, .. } => max_opening,
            _ => 0.0,
        };
        let mut t = Tool {
            name,
            shape,
            position: Vec3::zeros(),
            rotation: UnitQuaternion::identity(),
            last_parts: [Pose::identity(); 2],
            last_position: None,
            velocity: Vec3::zeros(),
            cautery_watts: 0.0,
            electrode_radius: Some(DEFAULT_ELECTRODE_RADIUS),
            grab_requested: false,
            grips: Vec::new(),
            reaction: Vec3::zeros(),
            jaw_force: [0.0; 2],
            contacts: 0,
            friction: Friction::default(),
            opening: open,
            target_opening: open,
            jaw_speed: 2.0 * open,
            grip_limit: f64::INFINITY,
            cutting: false,
            resistance: Vec3::zeros(),
            strength: 0.0,
        };
        t.last_parts = [t.part_pose(0), t.part_pose(1)];
        Ok(t)
    }

    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Shape.
    pub fn shape(&self) -> ToolShape {
        self.shape
    }

    /// Tip position.
    pub fn position(&self) -> Vec3 {
        self.position
    }

    /// Unit shaft axis (from the tip backward): the tool frame's +y.
    pub fn axis(&self) -> Vec3 {
        self.rotation * Vec3::y()
    }

    /// Orientation of the tool frame (+y the shaft axis, +x the grasper's closing
    /// direction).
    pub fn rotation(&self) -> UnitQuaternion<f64> {
        self.rotation
    }

    /// Velocity over the last step.
    pub fn velocity(&self) -> Vec3 {
        self.velocity
    }

    /// Sets the pose for the next step: tip position and shaft axis (any length but zero);
    /// the frame turns from +y to the axis the shortest way.
    pub fn set_pose(&mut self, position: Vec3, axis: Vec3) -> Result<(), ContactError> {
        let len = axis.norm();
        if !(len.is_finite() && len > 0.0) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "axis (zero or not finite)",
                value: len,
            });
        }
        let rotation = pose_along(Vec3::zeros(), axis / len).rotation;
        self.set_pose_rotation(position, rotation)
    }

    /// Sets the pose for the next step: tip position and the tool frame's orientation.
    pub fn set_pose_rotation(
        &mut self,
        position: Vec3,
        rotation: UnitQuaternion<f64>,
    ) -> Result<(), ContactError> {
        if !position.iter().all(|x| x.is_finite()) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "position (not finite)",
                value: position.norm(),
            });
        }
        if !rotation.coords.iter().all(|x| x.is_finite()) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "rotation (not finite)",
                value: rotation.coords.norm(),
            });
        }
        self.position = position;
        self.rotation = rotation;
        Ok(())
    }

    /// Moves the tip keeping the orientation.
    pub fn set_position(&mut self, position: Vec3) -> Result<(), ContactError> {
        self.set_pose_rotation(position, self.rotation)
    }

    /// Electrocautery power delivered while touching, W (0 turns it off).
    pub fn set_cautery(&mut self, watts: f64) -> Result<(), ContactError> {
        if !(watts.is_finite() && watts >= 0.0) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "cautery power (must be >= 0)",
                value: watts,
            });
        }
        self.cautery_watts = watts;
        Ok(())
    }

    /// Cautery power, W.
    pub fn cautery_watts(&self) -> f64 {
        self.cautery_watts
    }

    /// The cautery electrode's radius, m: its heat is modelled at that scale by a sub-grid
    /// spot at the contact (see [`crate::heat::HeatField::add_electrode`]). `None` spreads
    /// the power over the pressed mesh nodes instead (the coarse field only, as before the
    /// sub-grid model). Default [`DEFAULT_ELECTRODE_RADIUS`].
    pub fn set_electrode_radius(&mut self, radius: Option<f64>) -> Result<(), ContactError> {
        if let Some(r) = radius
            && !crate::heat::ELECTRODE_RADIUS_RANGE.contains(&r)
        {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "electrode radius (must be from 1e-5 to 0.05 m)",
                value: r,
            });
        }
        self.electrode_radius = radius;
        Ok(())
    }

    /// The cautery electrode's radius, m (`None`: nodal heating).
    pub fn electrode_radius(&self) -> Option<f64> {
        self.electrode_radius
    }

    /// The tool's surface friction.
    pub fn friction(&self) -> &Friction {
        &self.friction
    }

    /// Sets the tool's surface friction (refused, naming the tool and field, when invalid).
    pub fn set_friction(&mut self, friction: Friction) -> Result<(), ContactError> {
        friction.validate(&self.name)?;
        self.friction = friction;
        Ok(())
    }

    /// A grasper's current opening (the gap between its jaws), scene units; 0 for other
    /// tools.
    pub fn opening(&self) -> f64 {
        self.opening
    }

    /// The opening the jaws move toward.
    pub fn target_opening(&self) -> f64 {
        self.target_opening
    }

    /// Moves a grasper's jaws toward `opening` (clamped to 0..max_opening) at the jaw speed;
    /// refused for other tools or a non-finite value.
    pub fn set_opening(&mut self, opening: f64) -> Result<(), ContactError> {
        let ToolShape::Grasper { max_opening, .. } = self.shape else {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "opening (only a grasper has jaws)",
                value: opening,
            });
        };
        if !opening.is_finite() {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "opening (not finite)",
                value: opening,
            });
        }
        self.target_opening = opening.clamp(0.0, max_opening);
        Ok(())
    }

    /// Closes a grasper (target opening 0).
    pub fn close(&mut self) -> Result<(), ContactError> {
        self.set_opening(0.0)
    }

    /// Opens a grasper fully.
    pub fn open(&mut self) -> Result<(), ContactError> {
        self.set_opening(f64::INFINITY)
    }

    /// How fast the jaws open and close, scene units per second (default: the widest
    /// opening in half a second).
    pub fn set_jaw_speed(&mut self, speed: f64) -> Result<(), ContactError> {
        if !(speed.is_finite() && speed > 0.0) {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "jaw speed (must be > 0)",
                value: speed,
            });
        }
        self.jaw_speed = speed;
        Ok(())
    }

    /// The squeeze at which closing jaws stop closing further: when either jaw's normal
    /// force reached it in the last step, the opening holds (default: no limit, the jaws go
    /// where they are told).
    pub fn set_grip_limit(&mut self, force: f64) -> Result<(), ContactError> {
        if force.is_nan() || force <= 0.0 {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "grip force limit (must be > 0)",
                value: force,
            });
        }
        self.grip_limit = force;
        Ok(())
    }

    /// Normal force on each jaw in the last step (grasper; the tip's in the first entry
    /// otherwise).
    pub fn jaw_forces(&self) -> [f64; 2] {
        self.jaw_force
    }

    /// Grabs the surface under the tip at the next contact stage (nodes within the tip
    /// radius plus the tool margin of the nearest body).
    pub fn grab(&mut self) {
        self.grab_requested = true;
    }

    /// Lets go of whatever is held.
    pub fn release(&mut self) {
        self.grab_requested = false;
        self.grips.clear();
    }

    /// Whether a grab is waiting for the next contact stage.
    pub fn grab_requested(&self) -> bool {
        self.grab_requested
    }

    /// Nodes held.
    pub fn grips(&self) -> &[Grip] {
        &self.grips
    }

    /// Force of the tissue on the tool over the last step: the sum of the contact forces of
    /// its contacts (and grips) as the step's contact solve balanced them, and a blade's
    /// cutting resistance ([`Tool::cutting_resistance`]).
    pub fn reaction_force(&self) -> Vec3 {
        self.reaction + self.resistance
    }

    /// The contact part of [`Tool::reaction_force`]: the forces of its contacts and grips as
    /// the step's contact solve balanced them, without a blade's cutting resistance.
    pub fn contact_force(&self) -> Vec3 {
        self.reaction
    }

    /// The tissue's resistance to a blade's cut over the last step (against its motion: the
    /// work of fracture of what it cut, see `world::cut_force`); zero for other tools.
    pub fn cutting_resistance(&self) -> Vec3 {
        self.resistance
    }

    /// Sets the cutting resistance of this step (the world's cut stage).
    pub(crate) fn set_cutting_resistance(&mut self, force: Vec3) {
        self.resistance = force;
    }

    /// The force it takes to push a cutting blade's edge straight across itself, as the last
    /// step found it: each body's toughness times the length of the edge inside it, summed
    /// (`J L`; the largest [`Tool::cutting_resistance`] can be, reached when the blade moves
    /// straight across its edge). Found whether or not the blade moved over the step, so a
    /// blade resting in tissue reports what it will take to move it; zero for other tools,
    /// with cutting off, or outside tissue. The 1 kHz haptic loop renders it as the
    /// breakaway force of a friction ([`crate::haptics::CutModel`]).
    pub fn cutting_strength(&self) -> f64 {
        self.strength
    }

    /// Sets the cutting strength of this step (the world's cut stage).
    pub(crate) fn set_cutting_strength(&mut self, strength: f64) {
        self.strength = strength;
    }

    /// Contacts of the last step's solve (points with a force, or within the margin).
    pub fn contact_count(&self) -> u32 {
        self.contacts
    }

    /// Core segment (tip, back end) of a probe; a grasper's shaft line over its jaw length.
    pub fn core(&self) -> (Vec3, Vec3) {
        match self.shape {
            ToolShape::Sphere { .. } => (self.position, self.position),
            ToolShape::Capsule { length, .. } | ToolShape::Blade { length } => {
                (self.position, self.position + self.axis() * length)
            }
            ToolShape::Grasper { jaw, .. } => {
                let length = match jaw {
                    JawShape::Capsule { length, .. } | JawShape::Box { length, .. } => length,
                };
                (self.position, self.position + self.axis() * length)
            }
        }
    }

    /// Part `k` (0, or 0 and 1 for a grasper) as a rigid shape.
    pub fn part_shape(&self, k: usize) -> RigidShape {
        match self.shape {
            ToolShape::Sphere { radius } => RigidShape::Sphere { radius },
            ToolShape::Capsule { radius, length } => RigidShape::Capsule { radius, length },
            // No part of a blade is in contact; its edge as a capsule of no radius.
            ToolShape::Blade { length } => RigidShape::Capsule {
                radius: 0.0,
                length,
            },
            ToolShape::Grasper { jaw, .. } => {
                let _ = k;
                jaw.shape().0
            }
        }
    }

    /// Where part `k` is now.
    pub fn part_pose(&self, k: usize) -> Pose {
        let base = Pose::from_parts(Translation3::from(self.position), self.rotation);
        match self.shape {
            ToolShape::Grasper { jaw, .. } => {
                let side = if k == 0 { 1.0 } else { -1.0 };
                let (_, centre) = jaw.shape();
                let offset =
                    Vec3::new(side * (0.5 * self.opening + jaw.half_thickness()), 0.0, 0.0)
                        + centre;
                base * Translation3::from(offset)
            }
            _ => base,
        }
    }

    /// Where part `k` was at the start of the step.
    pub fn last_part_pose(&self, k: usize) -> Pose {
        self.last_parts[k.min(1)]
    }

    /// How far the tool's material point now at `p` (on part `k`) moved over the step.
    pub fn point_motion(&self, k: usize, p: &Vec3) -> Vec3 {
        let now = self.part_pose(k);
        let local = now.inverse_transform_point(&Point3::from(*p));
        p - self.last_part_pose(k).transform_point(&local).coords
    }

    /// Bounds of the tool grown by `grow`.
    pub fn bounds(&self, grow: f64) -> (Vec3, Vec3) {
        let mut out = (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY));
        for k in 0..self.shape.parts() {
            let (lo, hi) = super::rigid::world_bounds(&self.part_shape(k), &self.part_pose(k));
            out = (out.0.inf(&lo), out.1.sup(&hi));
        }
        let g = Vec3::repeat(grow);
        (out.0 - g, out.1 + g)
    }

    /// Start of a step of `dt`: the velocity from the pose change, the jaws moved toward
    /// their target (not further closed once the grip limit was reached), the force and
    /// contacts cleared. The parts' poses before the move are kept for friction.
    pub fn begin_step(&mut self, dt: f64) {
        self.velocity = match self.last_position {
            Some(last) if dt > 0.0 => (self.position - last) / dt,
            _ => Vec3::zeros(),
        };
        if self.last_position.is_none() {
            // The first step: the tool appears where it is, it did not move there.
            self.keep_last_pose();
        }
        self.last_position = Some(self.position);
        if let ToolShape::Grasper { .. } = self.shape {
            let squeezed = self.jaw_force.iter().any(|f| *f >= self.grip_limit);
            let step = self.jaw_speed * dt;
            let delta = (self.target_opening - self.opening).clamp(-step, step);
            if !(delta < 0.0 && squeezed) {
                self.opening += delta;
            }
        }
        self.reaction = Vec3::zeros();
        self.jaw_force = [0.0; 2];
        self.contacts = 0;
    }

    /// Records where the parts are, as the start of the next step (the contact stage calls it
    /// at the end of a step, before the caller sets the next pose).
    pub fn keep_last_pose(&mut self) {
        self.last_parts = [self.part_pose(0), self.part_pose(1)];
    }

    /// Replaces the grips, a pending grab kept (a cut moves the grips to the nodes of the
    /// cut bodies).
    pub fn set_grips(&mut self, grips: Vec<Grip>) {
        self.grips = grips;
    }

    /// Sets the grips (the contact stage's answer to a grab).
    pub fn take_grips(&mut self, grips: Vec<Grip>) {
        self.grab_requested = false;
        self.grips = grips;
    }

    /// Adds to the contact force of this step; `normal` is the part of it along the contact
    /// normals, counted on part `part`.
    pub fn add_reaction(&mut self, force: Vec3, part: usize, normal: f64) {
        self.reaction += force;
        self.jaw_force[part.min(1)] += normal;
    }

    /// Drops the force summed so far this step (a failed contact stage).
    pub fn clear_reaction(&mut self) {
        self.reaction = Vec3::zeros();
        self.jaw_force = [0.0; 2];
    }

    /// Counts contacts.
    pub fn add_contacts(&mut self, n: u32) {
        self.contacts += n;
    }

    /// Turns a blade's cutting on or off (only a [`ToolShape::Blade`] cuts).
    pub fn set_cutting(&mut self, on: bool) -> Result<(), ContactError> {
        if !matches!(self.shape, ToolShape::Blade { .. }) && on {
            return Err(ContactError::BadTool {
                tool: self.name.clone(),
                what: "cutting (only a blade cuts)",
                value: 1.0,
            });
        }
        self.cutting = on;
        Ok(())
    }

    /// Whether the tool is a blade with cutting on.
    pub fn cutting(&self) -> bool {
        self.cutting
    }

    /// The edge a blade had at the start of the step and has now (each as its two ends);
    /// `None` for other tools and before a first step (the two are equal when it did not
    /// move).
    pub fn blade_sweep(&self) -> Option<[(Vec3, Vec3); 2]> {
        let ToolShape::Blade { length } = self.shape else {
            return None;
        };
        self.last_position?;
        let edge = |p: &Pose| {
            (
                p.transform_point(&Point3::origin()).coords,
                p.transform_point(&Point3::new(0.0, length, 0.0)).coords,
            )
        };
        Some([edge(&self.last_parts[0]), edge(&self.part_pose(0))])
    }

    /// Back to idle at the origin (no grips, no cautery, a grasper open).
    pub fn reset(&mut self) {
        let fresh = Tool::new(self.name.clone(), self.shape).expect("validated when built");
        let friction = self.friction;
        *self = fresh;
        self.friction = friction;
    }
}
