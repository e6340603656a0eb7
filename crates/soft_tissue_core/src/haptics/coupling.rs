//! Virtual coupling: the simulated tool (a proxy of small mass) is tied to the device by a
//! spring-damper and pushed by the tissue's local contact model; the user feels the coupling
//! force. The proxy is integrated with implicit Euler at the haptic rate (unconditionally
//! stable for any coupling or tissue stiffness), the coupling damping is critical for the
//! proxy's mass, and the device force is clamped to the device's limit. A blade's cut acts
//! on the proxy as a friction across its edge ([`super::cutting`]).

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::cutting::{Bristle, CutModel};
use crate::Vec3;

/// The tissue as the haptic loop sees it between physics steps, linearised at the last one:
/// a plane through the touched surface with its outward normal, the penetration at the
/// linearisation point and a stiffness. Force at tool position `x`:
/// `stiffness * max(0, depth + (origin - x) . normal) * normal`. While the tool holds
/// tissue (`grab`), the tissue pulls as well as pushes: a spring to the anchor
/// `origin + depth * normal`, `stiffness * (anchor - x)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactModel {
    /// Whether a surface is near at all (no force otherwise).
    pub active: bool,
    /// Outward surface normal (the way the tissue pushes the tool), unit.
    pub normal: Vec3,
    /// Tool position at the linearisation.
    pub origin: Vec3,
    /// Penetration at `origin` (negative: the gap to the surface).
    pub depth: f64,
    /// Normal stiffness, force per length.
    pub stiffness: f64,
    /// The tool holds tissue: a bilateral spring instead of a one-sided plane.
    pub grab: bool,
    /// Physics step that produced it.
    pub step: u64,
    /// How far the proxy may lead `origin`, the tool position the physics last saw (scene
    /// units; 0: no limit). Between physics steps the proxy follows the device freely only
    /// this far, so however slowly the physics runs, the tool cannot cross a surface the
    /// physics has not yet seen ([`contact_model`](super::contact_model) sets half the
    /// tip's radius). When the physics stalls, the proxy waits for it and the device feels
    /// the coupling pulling it back, as with a wall.
    pub reach: f64,
}

/// Words of a [`ContactModel`] in the exchange.
pub(crate) const MODEL_WORDS: usize = 12;

impl ContactModel {
    /// No surface near the tool.
    pub const NONE: ContactModel = ContactModel {
        active: false,
        normal: Vec3::new(0.0, 1.0, 0.0),
        origin: Vec3::new(0.0, 0.0, 0.0),
        depth: 0.0,
        stiffness: 0.0,
        grab: false,
        step: 0,
        reach: 0.0,
    };

    /// Penetration at `x`.
    pub fn depth_at(&self, x: &Vec3) -> f64 {
        self.depth + (self.origin - x).dot(&self.normal)
    }

    /// Force of the tissue on a tool at `x` (without damping).
    pub fn force_at(&self, x: &Vec3) -> Vec3 {
        if !self.active {
            return Vec3::zeros();
        }
        if self.grab {
            return (self.origin + self.normal * self.depth - x) * self.stiffness;
        }
        let d = self.depth_at(x);
        if d <= 0.0 {
            Vec3::zeros()
        } else {
            self.normal * (self.stiffness * d)
        }
    }

    pub(crate) fn encode(&self) -> [f64; MODEL_WORDS] {
        [
            if self.active { 1.0 } else { 0.0 },
            self.normal.x,
            self.normal.y,
            self.normal.z,
            self.origin.x,
            self.origin.y,
            self.origin.z,
            self.depth,
            self.stiffness,
            if self.grab { 1.0 } else { 0.0 },
            self.step as f64,
            self.reach,
        ]
    }

    pub(crate) fn decode(w: &[f64; MODEL_WORDS]) -> Self {
        ContactModel {
            active: w[0] != 0.0,
            normal: Vec3::new(w[1], w[2], w[3]),
            origin: Vec3::new(w[4], w[5], w[6]),
            depth: w[7],
            stiffness: w[8],
            grab: w[9] != 0.0,
            step: w[10] as u64,
            reach: w[11],
        }
    }

    /// Whether every number is finite and the normal unit (a model that is not is ignored).
    pub fn is_valid(&self) -> bool {
        let reach_ok = self.reach.is_finite()
            && self.reach >= 0.0
            && (self.reach == 0.0 || self.origin.iter().all(|c| c.is_finite()));
        reach_ok
            && (!self.active
                || self.normal.iter().all(|c| c.is_finite())
                    && (self.normal.norm() - 1.0).abs() < 1e-6
                    && self.origin.iter().all(|c| c.is_finite())
                    && self.depth.is_finite()
                    && self.stiffness.is_finite()
                    && self.stiffness >= 0.0)
    }
}

/// Gains of the virtual coupling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CouplingParams {
    /// Coupling spring, force per length (scene units).
    pub stiffness: f64,
    /// Mass of the tool proxy (scene units). The coupling damping is critical for it:
    /// `2 sqrt(stiffness * mass)`; contact damping likewise for the tissue stiffness.
    pub proxy_mass: f64,
    /// Largest force sent to the device (scene units; the device's limit, mapped).
    pub max_force: f64,
    /// Haptic ticks over which a new contact model fades in (smooths the force across
    /// physics steps; 0: switch at once). Keep it at most the physics step in ticks (10 for
    /// a 100 Hz physics at 1 kHz): a model arriving before the last one has fully faded in
    /// replaces what remains of the one before.
    pub blend_ticks: u32,
}

impl Default for CouplingParams {
    fn default() -> Self {
        CouplingParams {
            stiffness: 400.0,
            proxy_mass: 0.05,
            max_force: 8.0,
            blend_ticks: 8,
        }
    }
}

impl CouplingParams {
    /// Critical damping of the coupling for the proxy's mass.
    pub fn damping(&self) -> f64 {
        2.0 * (self.stiffness * self.proxy_mass).sqrt()
    }

    /// Whether the gains are usable.
    pub fn is_valid(&self) -> bool {
        self.stiffness.is_finite()
            && self.stiffness > 0.0
            && self.proxy_mass.is_finite()
            && self.proxy_mass > 0.0
            && self.max_force.is_finite()
            && self.max_force > 0.0
    }
}

/// The proxy and the contact models it feels (the old one fading out, the new one in), and
/// a blade's cut (likewise).
#[derive(Debug, Clone)]
pub struct Coupling {
    params: CouplingParams,
    x: Vec3,
    v: Vec3,
    old: ContactModel,
    new: ContactModel,
    blend: u32,
    cut_old: CutModel,
    cut_new: CutModel,
    cut_blend: u32,
    bristle: Bristle,
}

impl Coupling {
    /// A proxy at rest at `position`.
    pub fn new(params: CouplingParams, position: Vec3) -> Self {
        Coupling {
            params,
            x: position,
            v: Vec3::zeros(),
            old: ContactModel::NONE,
            new: ContactModel::NONE,
            blend: params.blend_ticks,
            cut_old: CutModel::NONE,
            cut_new: CutModel::NONE,
            cut_blend: params.blend_ticks,
            bristle: Bristle::default(),
        }
    }

    /// The gains.
    pub fn params(&self) -> &CouplingParams {
        &self.params
    }

    /// Proxy position.
    pub fn position(&self) -> Vec3 {
        self.x
    }

    /// Proxy velocity.
    pub fn velocity(&self) -> Vec3 {
        self.v
    }

    /// The newest contact model.
    pub fn model(&self) -> &ContactModel {
        &self.new
    }

    /// Hands over a new contact model; it fades in over `blend_ticks` ticks.
    pub fn set_model(&mut self, model: ContactModel) {
        if !model.is_valid() {
            return;
        }
        // Mid-blend, what remains of the older model is dropped (blends are kept shorter
        // than a physics step, see `blend_ticks`).
        self.old = self.new;
        self.new = model;
        self.blend = 0;
    }

    /// Hands over a new cut model (with the contact model of the same physics step); its
    /// breakaway force fades in over `blend_ticks` ticks. An invalid one is ignored.
    pub fn set_cut(&mut self, cut: CutModel) {
        if cut.validate().is_err() {
            return;
        }
        self.cut_old = self.cut_now();
        self.cut_new = cut;
        self.cut_blend = 0;
    }

    /// The newest cut model.
    pub fn cut(&self) -> &CutModel {
        &self.cut_new
    }

    /// The cut as the proxy feels it this tick (the models blended).
    pub fn cut_now(&self) -> CutModel {
        CutModel::blend(&self.cut_old, &self.cut_new, self.ratio(self.cut_blend))
    }

    /// The cut's friction on the proxy now (the bristle's spring; zero when not cutting).
    pub fn cutting_force(&self) -> Vec3 {
        self.bristle.force(&self.cut_now())
    }

    /// Weight of the new model this tick.
    fn weight(&self) -> f64 {
        self.ratio(self.blend)
    }

    /// How far a blend that has run `ticks` is.
    fn ratio(&self, ticks: u32) -> f64 {
        if self.params.blend_ticks == 0 {
            1.0
        } else {
            (f64::from(ticks) / f64::from(self.params.blend_ticks)).min(1.0)
        }
    }

    /// Tissue force on the proxy now (blended models, without damping).
    pub fn contact_force(&self) -> Vec3 {
        let w = self.weight();
        self.old.force_at(&self.x) * (1.0 - w) + self.new.force_at(&self.x) * w
    }

    /// Advances the proxy by `h` seconds toward the device at `device` moving at
    /// `device_velocity`; returns the force for the device (clamped to the limit).
    pub fn step(&mut self, device: &Vec3, device_velocity: &Vec3, h: f64) -> Vec3 {
        let p = self.params;
        let (kc, bc, m) = (p.stiffness, p.damping(), p.proxy_mass);
        let w = self.weight();
        // Implicit Euler on m dv/dt = kc (xd - x) + bc (vd - v) + sum_i w_i f_i(x, v),
        // each touching model linearised: f_i = (K d_i(x) - b_i v.n) n, df/dx = -K n n^T.
        let mut a = Matrix3::identity() * (m + h * bc + h * h * kc);
        let mut rhs = self.v * m + (kc * (device - self.x) + device_velocity * bc) * h;
        for (model, wi) in [(&self.old, 1.0 - w), (&self.new, w)] {
            if wi <= 0.0 || !model.active {
                continue;
            }
            let k = model.stiffness;
            let b = 2.0 * (k * m).sqrt();
            if model.grab {
                // f = K (anchor - x) - b v: the same implicit form in all three directions.
                a += Matrix3::identity() * (wi * (h * h * k + h * b));
                rhs += model.force_at(&self.x) * (wi * h);
                continue;
            }
            let d = model.depth_at(&self.x);
            if d <= 0.0 {
                continue;
            }
            let n = model.normal;
            // Damping grows with the penetration (Hunt and Crossley) over the first quarter of
            // the depth at which the force reaches the device limit, so touching the surface
            // does not step the force.
            let ramp = 0.25 * p.max_force / k.max(f64::MIN_POSITIVE);
            let b = b * (d / ramp).min(1.0);
            a += n * n.transpose() * (wi * (h * h * k + h * b));
            rhs += n * (wi * h * k * d);
        }
        // A blade's cut: a friction across its edge (stuck or slipping, see `cutting`).
        let cut = self.cut_now();
        let v = self.bristle.solve(&cut, &a, &rhs, h, m);
        let before = self.x;
        self.v = v;
        self.x += v * h;
        self.keep_within_reach();
        self.bristle.follow(&cut, &(self.x - before));
        if self.blend < p.blend_ticks {
            self.blend += 1;
        }
        if self.cut_blend < p.blend_ticks {
            self.cut_blend += 1;
        }
        let f = (self.x - device) * kc + (self.v - device_velocity) * bc;
        clamp(f, p.max_force)
    }

    /// Holds the proxy within the newest model's reach of the tool the physics last saw,
    /// dropping the velocity that would carry it farther.
    fn keep_within_reach(&mut self) {
        let reach = self.new.reach;
        if reach <= 0.0 {
            return;
        }
        let lead = self.x - self.new.origin;
        let d = lead.norm();
        if d > reach {
            let u = lead / d;
            self.x = self.new.origin + u * reach;
            let out = self.v.dot(&u);
            if out > 0.0 {
                self.v -= u * out;
            }
        }
    }

    /// Puts the proxy at `position`, at rest (a reset, or a jump of the device).
    pub fn teleport(&mut self, position: Vec3) {
        self.x = position;
        self.v = Vec3::zeros();
        // The cut's anchor comes along: no stretch.
        self.bristle = Bristle::default();
    }
}

/// `f` with its magnitude limited to `max` (direction kept; non-finite gives zero).
pub fn clamp(f: Vec3, max: f64) -> Vec3 {
    let n = f.norm();
    if !n.is_finite() {
        Vec3::zeros()
    } else if n > max {
        f * (max / n)
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: f64 = 1e-3;

    fn params() -> CouplingParams {
        CouplingParams {
            stiffness: 400.0,
            proxy_mass: 0.05,
            max_force: 1e9,
            blend_ticks: 0,
        }
    }

    #[test]
    fn a_released_proxy_returns_critically_damped_without_overshoot() {
        // Device held at the origin, proxy released 0.1 away: the continuous solution is
        // x(t) = x0 (1 + w t) e^(-w t), w = sqrt(k / m); implicit Euler at 1 kHz follows it
        // within its first-order error and never crosses zero (no oscillation, no growth).
        let p = params();
        let omega = (p.stiffness / p.proxy_mass).sqrt();
        let x0 = 0.1;
        let mut c = Coupling::new(p, Vec3::new(x0, 0.0, 0.0));
        let mut worst: f64 = 0.0;
        let mut last = x0;
        for k in 1..=2000 {
            c.step(&Vec3::zeros(), &Vec3::zeros(), H);
            let x = c.position().x;
            let t = k as f64 * H;
            let exact = x0 * (1.0 + omega * t) * (-omega * t).exp();
            worst = worst.max((x - exact).abs());
            assert!(x >= 0.0, "overshoot at tick {k}: {x}");
            assert!(x <= last + 1e-15, "grew at tick {k}");
            last = x;
        }
        // First-order error, O(w h) of the amplitude: w h = 0.089 here.
        assert!(worst < 0.1 * x0, "{worst}");
        assert!(last < 1e-6 * x0);
    }

    #[test]
    fn pressing_into_tissue_settles_at_the_series_spring_force() {
        // Device 0.02 below a surface of stiffness K: the proxy settles where
        // kc (D - s) = K s, and the device feels kc K / (kc + K) * D.
        let p = params();
        let stiffness = 1600.0;
        let model = ContactModel {
            active: true,
            normal: Vec3::new(0.0, 1.0, 0.0),
            origin: Vec3::zeros(),
            depth: 0.0,
            stiffness,
            grab: false,
            step: 1,
            reach: 0.0,
        };
        let mut c = Coupling::new(p, Vec3::zeros());
        c.set_model(model);
        let device = Vec3::new(0.0, -0.02, 0.0);
        let mut f = Vec3::zeros();
        for _ in 0..5000 {
            f = c.step(&device, &Vec3::zeros(), H);
        }
        let kc = p.stiffness;
        let want = kc * stiffness / (kc + stiffness) * 0.02;
        assert!((f.y - want).abs() < 1e-9 * want, "{} vs {want}", f.y);
        assert!(f.x.abs() < 1e-12 && f.z.abs() < 1e-12);
        let s = kc * 0.02 / (kc + stiffness);
        assert!((c.position().y + s).abs() < 1e-9);
    }

    #[test]
    fn held_tissue_pulls_back_like_a_spring_in_series() {
        // Grabbed tissue anchored at the origin, device pulled 0.03 away sideways: the device
        // feels the series spring kc K / (kc + K) * 0.03 back toward the anchor.
        let p = params();
        let stiffness = 600.0;
        let mut c = Coupling::new(p, Vec3::zeros());
        c.set_model(ContactModel {
            active: true,
            normal: Vec3::new(0.0, 1.0, 0.0),
            origin: Vec3::zeros(),
            depth: 0.0,
            stiffness,
            grab: true,
            step: 1,
            reach: 0.0,
        });
        let device = Vec3::new(0.03, 0.0, 0.0);
        let mut f = Vec3::zeros();
        for _ in 0..5000 {
            f = c.step(&device, &Vec3::zeros(), H);
        }
        let want = -p.stiffness * stiffness / (p.stiffness + stiffness) * 0.03;
        assert!((f.x - want).abs() < 1e-9 * want.abs(), "{} vs {want}", f.x);
    }

    #[test]
    fn stiff_tissue_and_a_shaking_device_stay_bounded() {
        // Tissue 1000 times stiffer than the coupling and a device shaken at 40 Hz into it
        // for ten seconds: the proxy's energy never exceeds what the device puts in.
        let p = params();
        let model = ContactModel {
            active: true,
            normal: Vec3::new(0.0, 0.0, 1.0),
            origin: Vec3::zeros(),
            depth: 0.0,
            stiffness: 1000.0 * p.stiffness,
            grab: false,
            step: 1,
            reach: 0.0,
        };
        let mut c = Coupling::new(p, Vec3::zeros());
        c.set_model(model);
        let mut max_speed: f64 = 0.0;
        for k in 0..10_000 {
            let t = k as f64 * H;
            let w = 2.0 * std::f64::consts::PI * 40.0;
            let d = Vec3::new(0.0, 0.0, -0.01 - 0.01 * (w * t).sin());
            let dv = Vec3::new(0.0, 0.0, -0.01 * w * (w * t).cos());
            let f = c.step(&d, &dv, H);
            assert!(f.iter().all(|x| x.is_finite()));
            max_speed = max_speed.max(c.velocity().norm());
        }
        // The device's own peak speed is 0.01 w = 2.5: the proxy, held by a far stiffer
        // surface, moves much less.
        assert!(max_speed < 2.6, "{max_speed}");
        assert!(c.position().z > -0.001, "the stiff surface holds the proxy");
    }

    #[test]
    fn device_force_is_clamped_and_models_blend_in() {
        let mut p = params();
        p.max_force = 2.0;
        p.blend_ticks = 10;
        let mut c = Coupling::new(p, Vec3::zeros());
        // Far from the proxy: the spring force would be 400 * 1 = 400.
        let f = c.step(&Vec3::new(1.0, 0.0, 0.0), &Vec3::zeros(), H);
        assert!((f.norm() - 2.0).abs() < 1e-12);
        assert!(f.x < 0.0, "pulls the device back toward the proxy");
        assert_eq!(clamp(Vec3::new(f64::NAN, 0.0, 0.0), 1.0), Vec3::zeros());
        // A model that appears with the proxy inside: its force rises over ten ticks.
        let mut c = Coupling::new(p, Vec3::zeros());
        c.set_model(ContactModel {
            active: true,
            normal: Vec3::new(0.0, 1.0, 0.0),
            origin: Vec3::zeros(),
            depth: 0.001,
            stiffness: 1000.0,
            grab: false,
            step: 1,
            reach: 0.0,
        });
        let mut last = 0.0;
        for _ in 0..10 {
            let now = c.contact_force().y;
            assert!(now >= last);
            last = now;
            c.step(&c.position(), &Vec3::zeros(), H);
        }
        // A broken model is ignored.
        let before = c.contact_force();
        c.set_model(ContactModel {
            active: true,
            normal: Vec3::new(f64::NAN, 0.0, 0.0),
            ..ContactModel::NONE
        });
        assert_eq!(c.contact_force(), before);
    }

    #[test]
    fn the_proxy_waits_for_the_physics_within_its_reach() {
        // The device jumps 1.0 away while the physics last saw the tool at the origin with a
        // reach of 0.1: the proxy stops at 0.1 (the tool cannot skip a surface the physics has
        // not seen), at rest, and the device feels the coupling spring over the remaining
        // 0.9. Each later physics step lets it advance one reach more.
        let p = params();
        let mut c = Coupling::new(p, Vec3::zeros());
        let seen = |x: f64, step| ContactModel {
            origin: Vec3::new(x, 0.0, 0.0),
            reach: 0.1,
            step,
            ..ContactModel::NONE
        };
        c.set_model(seen(0.0, 1));
        let device = Vec3::new(1.0, 0.0, 0.0);
        let mut f = Vec3::zeros();
        for _ in 0..2000 {
            f = c.step(&device, &Vec3::zeros(), H);
            assert!(c.position().x <= 0.1 + 1e-15);
        }
        assert!((c.position().x - 0.1).abs() < 1e-12);
        assert!(c.velocity().norm() < 1e-12);
        assert!((f.x + p.stiffness * 0.9).abs() < 1e-6, "{f}");
        for step in 2..=12 {
            c.set_model(seen(c.position().x, step));
            for _ in 0..200 {
                c.step(&device, &Vec3::zeros(), H);
            }
        }
        // Ten steps of 0.1 reach the device, which the proxy then follows freely.
        assert!((c.position().x - 1.0).abs() < 1e-6, "{}", c.position());
        // A model without reach (0) sets no limit; a negative or non-finite one is refused.
        assert!(ContactModel::NONE.is_valid());
        assert!(
            !ContactModel {
                reach: -1.0,
                ..ContactModel::NONE
            }
            .is_valid()
        );
        assert!(
            !ContactModel {
                reach: f64::NAN,
                ..ContactModel::NONE
            }
            .is_valid()
        );
    }
}
