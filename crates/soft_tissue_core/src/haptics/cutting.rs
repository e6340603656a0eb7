//! The cut as the haptic loop renders it: a friction across the blade's edge.
//!
//! The physics holds a cutting blade back by the work of fracture of what it cuts: the
//! tissue's toughness `J` times the area its edge sweeps, so pushing the edge across itself
//! costs `J L` per distance (`L` the length of the edge inside tissue) and drawing it along
//! itself nothing (`world::cut_force`, after Mahvash and Hayward, "Haptic rendering of
//! cutting: a fracture mechanics approach", Haptics-e 2(3), 2001). That is a dry friction
//! acting across the edge with breakaway force `J L`: the physics hands the loop the edge's
//! direction and `J L` ([`CutModel`], from [`cut_model`]) at each step, and the loop renders
//! it with the bristle (elasto-plastic) friction of Hayward and Armstrong ("A new
//! computational model of friction applied to haptic rendering", Experimental Robotics VI,
//! LNCIS 250, 2000): the proxy is tied across the edge to an anchor by a spring of
//! [`CutModel::stiffness`]; while the spring's force is below `J L` the anchor stays
//! (stick: the proxy's motion across the edge stretches the spring); beyond, the anchor
//! follows the proxy at the spring's full stretch `J L / stiffness` (slip: the force is
//! `J L` against the motion across the edge, whatever the speed). Along the edge the spring
//! has no component. The work the slipping friction takes is `J L` times the distance slid
//! across the edge, the physics' fracture energy over the same motion; the force is the
//! across part of it (the physics puts the same work on the blade's whole motion, `J L
//! sin(angle) ` against it: on a stroke across the edge the two are the same force).
//!
//! Why a bristle and not a force against the velocity (Coulomb, or a plane against the
//! motion, which a review found chattering with the hand's jitter): below the breakaway the
//! force is a spring's, so a hand trembling around a point feels a spring that follows its
//! tremor smoothly instead of the full force flipping sign every tick; the spring stores at
//! most `J L^2 / (2 stiffness)` and the anchor only moves to release it, so the friction
//! gives back nothing it did not store (passive); and unlike Dahl's model the anchor does not
//! creep under small oscillations below the breakaway (Hayward and Armstrong's point).
//!
//! In the loop the bristle acts on the tool proxy inside the implicit step (as the contact
//! model does): a trial step with the spring and its critical damping for the proxy's mass
//! (stick); if it would stretch the spring past `J L / stiffness`, the step is taken again
//! with the constant force `J L` against the trial stretch instead (slip), and the anchor is
//! dragged along. The device feels it through the coupling. A new model fades in over
//! [`CouplingParams::blend_ticks`](super::CouplingParams::blend_ticks) (its breakaway force
//! blended with the last one's); a new edge direction only ever shortens the stretch (it is
//! projected onto the new plane across the edge and held within the new stick distance).

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::HapticError;
use crate::Vec3;
use crate::contact::Tool;

/// A blade's cut as the haptic loop renders it between physics steps (see the module docs):
/// a friction across the edge whose breakaway force is `strength`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CutModel {
    /// Whether the blade cuts tissue (no force otherwise).
    pub active: bool,
    /// The blade's edge direction, unit (motion along it is free).
    pub edge: Vec3,
    /// Breakaway force: the toughness times the edge's length inside tissue, `J L`, as the
    /// physics' last step measured it ([`Tool::cutting_strength`]); scene force units.
    pub strength: f64,
    /// The bristle's spring, force per length (scene units): the proxy moves
    /// `strength / stiffness` across the edge before the blade slips on.
    pub stiffness: f64,
}

/// Words of a [`CutModel`] in the exchange.
pub(crate) const CUT_WORDS: usize = 6;

impl CutModel {
    /// Not cutting.
    pub const NONE: CutModel = CutModel {
        active: false,
        edge: Vec3::new(0.0, 1.0, 0.0),
        strength: 0.0,
        stiffness: 0.0,
    };

    /// The bristle's stiffness [`cut_model`] is given by the plugin (and `haptics-bench`),
    /// as a multiple of the coupling's stiffness (chosen by measurement: see
    /// `docs/haptics.md`, "The cut in the loop").
    pub const STIFFNESS_PER_COUPLING: f64 = 4.0;

    /// A cut along `edge` (any length, normalised) with breakaway force `strength` (>= 0)
    /// and bristle stiffness `stiffness` (> 0); a zero strength is a model that renders
    /// nothing. Every number must be finite: refused with [`HapticError::BadModel`]
    /// otherwise.
    pub fn new(edge: Vec3, strength: f64, stiffness: f64) -> Result<Self, HapticError> {
        let length = edge.norm();
        if !(length.is_finite() && length > 0.0) {
            return Err(bad("edge", length, "a finite, non-zero direction"));
        }
        let model = CutModel {
            active: true,
            edge: edge / length,
            strength,
            stiffness,
        };
        model.validate()?;
        Ok(model)
    }

    /// Checks the model: an active one needs a unit, finite edge, a finite strength >= 0 and
    /// a finite stiffness > 0; an inactive one anything finite.
    pub fn validate(&self) -> Result<(), HapticError> {
        if !self.active {
            let finite = self.edge.iter().all(|c| c.is_finite())
                && self.strength.is_finite()
                && self.stiffness.is_finite();
            return if finite {
                Ok(())
            } else {
                Err(bad("inactive model", f64::NAN, "finite numbers"))
            };
        }
        let n = self.edge.norm();
        if !(n.is_finite() && (n - 1.0).abs() < 1e-6) {
            return Err(bad("edge", n, "a unit direction"));
        }
        if !(self.strength.is_finite() && self.strength >= 0.0) {
            return Err(bad("strength", self.strength, "finite and >= 0"));
        }
        if !(self.stiffness.is_finite() && self.stiffness > 0.0) {
            return Err(bad("stiffness", self.stiffness, "finite and > 0"));
        }
        Ok(())
    }

    /// Whether it renders a force at all.
    pub fn renders(&self) -> bool {
        self.active && self.strength > 0.0
    }

    /// How far the proxy moves across the edge before it slips: `strength / stiffness`.
    pub fn stick(&self) -> f64 {
        if self.renders() {
            self.strength / self.stiffness
        } else {
            0.0
        }
    }

    /// The part of `v` across the edge.
    pub fn across(&self, v: &Vec3) -> Vec3 {
        v - self.edge * v.dot(&self.edge)
    }

    pub(crate) fn encode(&self) -> [f64; CUT_WORDS] {
        [
            if self.active { 1.0 } else { 0.0 },
            self.edge.x,
            self.edge.y,
            self.edge.z,
            self.strength,
            self.stiffness,
        ]
    }

    pub(crate) fn decode(w: &[f64; CUT_WORDS]) -> Self {
        CutModel {
            active: w[0] != 0.0,
            edge: Vec3::new(w[1], w[2], w[3]),
            strength: w[4],
            stiffness: w[5],
        }
    }

    /// `old` fading out and `new` fading in at weight `w` of the new: the breakaway forces
    /// blended, the edge and stiffness of the newer one that cuts.
    pub(crate) fn blend(old: &CutModel, new: &CutModel, w: f64) -> CutModel {
        let strength = |m: &CutModel| if m.renders() { m.strength } else { 0.0 };
        let base = if new.renders() { new } else { old };
        let blended = (1.0 - w) * strength(old) + w * strength(new);
        if !base.renders() || blended <= 0.0 {
            return CutModel::NONE;
        }
        CutModel {
            strength: blended,
            ..*base
        }
    }
}

fn bad(what: &'static str, value: f64, why: &'static str) -> HapticError {
    HapticError::BadModel { what, value, why }
}

/// The cut model of a blade after a world step, for the haptic loop: its edge as the step
/// left it and its [`Tool::cutting_strength`] as the breakaway force, with the bristle
/// spring `stiffness` (e.g. [`CutModel::STIFFNESS_PER_COUPLING`] times the coupling's);
/// [`CutModel::NONE`] for a tool that is not a blade cutting tissue. A stiffness that is not
/// finite and > 0 is refused ([`HapticError::BadModel`]), as is a strength that is not
/// finite.
pub fn cut_model(tool: &Tool, stiffness: f64) -> Result<CutModel, HapticError> {
    if !(stiffness.is_finite() && stiffness > 0.0) {
        return Err(bad("stiffness", stiffness, "finite and > 0"));
    }
    let strength = tool.cutting_strength();
    if !strength.is_finite() {
        return Err(bad("strength", strength, "finite and >= 0"));
    }
    match tool.blade_sweep() {
        Some([_, (a, b)]) if tool.cutting() && strength > 0.0 => {
            CutModel::new(b - a, strength, stiffness)
        }
        _ => Ok(CutModel::NONE),
    }
}

/// The bristle's stretch: the proxy's offset from its anchor across the edge.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Bristle {
    z: Vec3,
    /// The stiffness the stretch was held at (0: none yet).
    k: f64,
}

impl Bristle {
    /// The bristle's force on the proxy now.
    pub(crate) fn force(&self, cut: &CutModel) -> Vec3 {
        if cut.renders() {
            -self.z * cut.stiffness
        } else {
            Vec3::zeros()
        }
    }

    /// Holds the stretch across `cut`'s edge and within its stick distance (a new model, or
    /// a blended breakaway force that fell): it only ever shortens. Nothing without a cut.
    fn settle(&mut self, cut: &CutModel) {
        if !cut.renders() {
            self.z = Vec3::zeros();
            self.k = 0.0;
            return;
        }
        // A new stiffness keeps the force, not the stretch: a stiffer spring at the same
        // stretch would hold more energy than was put in (and could give it to the hand).
        if self.k > 0.0 && self.k != cut.stiffness {
            self.z *= self.k / cut.stiffness;
        }
        self.k = cut.stiffness;
        self.z = cut.across(&self.z);
        let (n, stick) = (self.z.norm(), cut.stick());
        if n > stick {
            self.z *= stick / n;
        }
    }

    /// The proxy moved by `moved`: the spring stretches by its part across the edge, and the
    /// anchor is dragged along where that passes the stick distance (slip).
    pub(crate) fn follow(&mut self, cut: &CutModel, moved: &Vec3) {
        self.z += moved;
        self.settle(cut);
    }

    /// The proxy's velocity for an implicit Euler step of `h` of
    /// `a v = rhs + h f_cut(x + h v, v)`, `a` and `rhs` holding the proxy's mass, the
    /// coupling and the contact (see [`super::coupling::Coupling::step`]): first as stuck
    /// (the spring and its critical damping for `mass`), and if that stretches the spring
    /// past the stick distance, again with the breakaway force against the trial stretch
    /// (slip).
    pub(crate) fn solve(
        &mut self,
        cut: &CutModel,
        a: &Matrix3<f64>,
        rhs: &Vec3,
        h: f64,
        mass: f64,
    ) -> Vec3 {
        self.settle(cut);
        if !cut.renders() {
            return solve3(a, rhs);
        }
        let e = cut.edge;
        let across = Matrix3::identity() - e * e.transpose();
        let k = cut.stiffness;
        let b = 2.0 * (k * mass).sqrt();
        // Stuck: f = -k (z + h P v) - b P v.
        let stuck = solve3(
            &(a + across * (h * h * k + h * b)),
            &(rhs - self.z * (h * k)),
        );
        let trial = self.z + across * stuck * h;
        let stretch = trial.norm();
        if stretch <= cut.stick() {
            return stuck;
        }
        // Slipping: the breakaway force against the way the spring was pulled.
        solve3(a, &(rhs - trial * (h * cut.strength / stretch)))
    }
}

/// `a^-1 rhs`, zero where `a` is singular or the answer not finite.
pub(crate) fn solve3(a: &Matrix3<f64>, rhs: &Vec3) -> Vec3 {
    a.try_inverse()
        .map(|inv| inv * rhs)
        .filter(|v| v.iter().all(|c| c.is_finite()))
        .unwrap_or_else(Vec3::zeros)
}
