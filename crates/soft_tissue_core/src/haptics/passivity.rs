//! The device port of the haptic loop: the device velocity the coupling's damper sees, and a
//! time-domain passivity observer and controller on the force the hand feels.
//!
//! The coupling's damper acts on the device velocity through a low-pass filter (a real
//! device's position is noisy); above about 150 Hz of hand motion at the default 40 Hz
//! cut-off the filter lags by more than a quarter period, and with each tick's force held
//! over the next tick (as a device renders it) the loop then gives the hand energy, with or
//! without tissue (docs/haptics.md). A device given energy by its loop can buzz or run away.
//!
//! The observer and controller are Hannaford and Ryu's ("Time-domain passivity control of
//! haptic interfaces", IEEE Trans. Robotics and Automation 18(1), 2002): the observer sums
//! the energy the loop has taken from the hand, each tick's rendered force over the device
//! motion it was held for; before a force is written, the energy it would take over the
//! next tick is predicted from the last tick's motion, and where the sum would fall below
//! zero a damper on the unfiltered device velocity takes the difference (a force against the
//! motion, so it only ever takes energy). Energy taken earlier is forgotten with a time
//! constant ([`PASSIVITY_MEMORY_S`]), so a loop that absorbed a lot while the hand pushed
//! into tissue does not spend that credit later by giving energy for seconds; the
//! controller acts only while the loop would give energy, and a loop that takes energy tick
//! by tick (a stroke, a press, a rest) feels exactly the coupling.
//!
//! Where the hand's motion has content near the loop's Nyquist rate, a tick's motion does
//! not predict the next one's, and a damper on it gives energy itself (measured: up to 27
//! times what the loop gave without it). The controller's damping is therefore weighed by
//! its own record: what its damping took over what it expected to take, both summed with
//! the observer's memory; where it took nothing it stands aside (and the loop is then no
//! more passive than without it).

use super::coupling::{Coupling, clamp};
use crate::Vec3;

/// Seconds over which energy the loop took from the hand is forgotten (time constant).
pub const PASSIVITY_MEMORY_S: f64 = 0.02;

/// The energy below which the controller's record counts for little, as a share of the
/// energy the coupling's spring holds at the force limit: a controller that stood aside
/// (its record faded with [`PASSIVITY_MEMORY_S`]) trusts itself again after some 0.3 s.
const TRUST_PRIOR: f64 = 1e-9;

/// Most damping the controller adds, as a multiple of the coupling's own (critical)
/// damping: a hand that barely moves while the observer is short of energy would otherwise
/// ask for an arbitrarily large damper (the shortfall is then carried to the next ticks).
pub const PASSIVITY_MAX_DAMPING: f64 = 20.0;

/// The device side of one haptic loop: velocity filter, passivity observer and controller.
#[derive(Debug, Clone)]
pub struct DevicePort {
    /// Low-pass weight of each tick's finite-difference velocity.
    alpha: f64,
    /// Whether the controller acts (the observer always runs).
    passivity: bool,
    /// Device position last tick.
    last: Option<Vec3>,
    /// Filtered device velocity (what the coupling's damper sees).
    velocity: Vec3,
    /// Force rendered last tick, scene units.
    force: Vec3,
    /// The controller's force last tick, and the energy it expected that force to take.
    added: Vec3,
    expected_now: f64,
    /// Energy the controller expected to take, and took, the past forgotten like the
    /// observer's.
    expected: f64,
    realized: f64,
    /// Share of the most damping the controller may add now: what its damping took over
    /// what it expected to (see the module docs).
    trust: f64,
    /// Energy the loop has taken from the hand (observer), forgetting the past.
    energy: f64,
    /// Energy the controller's damping took from the hand, summed (negative where it gave).
    dissipated: f64,
    /// Ticks the controller acted in.
    active_ticks: u64,
}

impl DevicePort {
    /// A port for a loop at `rate_hz` filtering the device velocity at `cutoff_hz`; with
    /// `passivity` the controller acts.
    pub fn new(rate_hz: f64, cutoff_hz: f64, passivity: bool) -> Self {
        let h = 1.0 / rate_hz;
        let rc = 1.0 / (2.0 * std::f64::consts::PI * cutoff_hz);
        DevicePort {
            alpha: h / (h + rc),
            passivity,
            last: None,
            velocity: Vec3::zeros(),
            force: Vec3::zeros(),
            added: Vec3::zeros(),
            expected_now: 0.0,
            expected: 0.0,
            realized: 0.0,
            trust: 1.0,
            energy: 0.0,
            dissipated: 0.0,
            active_ticks: 0,
        }
    }

    /// One tick with the device at `device` (scene units), `h` seconds after the last: steps
    /// the coupling and returns the force on the hand, scene units, within the coupling's
    /// force limit.
    pub fn tick(&mut self, coupling: &mut Coupling, device: &Vec3, h: f64) -> Vec3 {
        let moved = self.last.map_or(Vec3::zeros(), |l| device - l);
        if self.last.is_some() {
            self.velocity += (moved / h - self.velocity) * self.alpha;
        }
        self.last = Some(*device);
        // What the last force took from the hand over the motion it was held for; energy
        // taken or given more than the memory ago fades (credit and debt alike).
        let forget = (-h / PASSIVITY_MEMORY_S).exp();
        self.energy = (self.energy - self.force.dot(&moved)) * forget;
        // How far the controller's last damping took what it expected to take (it does
        // not where the motion turned within the tick).
        let took = -self.added.dot(&moved);
        self.dissipated += took;
        let p = coupling.params();
        let prior = TRUST_PRIOR * p.max_force * p.max_force / p.stiffness;
        self.expected = self.expected * forget + self.expected_now;
        self.realized = self.realized * forget + took;
        self.trust = ((self.realized + prior) / (self.expected + prior)).clamp(0.0, 1.0);
        if !self.trust.is_finite() {
            self.trust = 0.0;
        }
        self.expected_now = 0.0;
        self.added = Vec3::zeros();
        let max_force = p.max_force;
        let mut f = coupling.step(device, &self.velocity, h);
        if self.passivity {
            // The next tick's motion, predicted as the last one's.
            let v = moved / h;
            let vv = v.norm_squared();
            let predicted = self.energy - f.dot(&v) * h;
            if predicted < 0.0 && vv > 0.0 {
                let most = self.trust * PASSIVITY_MAX_DAMPING * coupling.params().damping();
                let damping = (-predicted / (h * vv)).min(most);
                if damping > 0.0 {
                    let damped = clamp(f - v * damping, max_force);
                    self.active_ticks += 1;
                    self.added = damped - f;
                    self.expected_now = -(damped - f).dot(&v) * h;
                    f = damped;
                }
            }
        }
        self.force = f;
        f
    }

    /// The filtered device velocity the coupling's damper saw this tick.
    pub fn velocity(&self) -> Vec3 {
        self.velocity
    }

    /// The observer's energy: what the loop has taken from the hand, the past forgotten
    /// with [`PASSIVITY_MEMORY_S`] (negative: it has given energy the controller has yet to
    /// take back).
    pub fn energy(&self) -> f64 {
        self.energy
    }

    /// Energy the controller's damping has taken from the hand over the motion each of its
    /// forces was held for (negative where it gave: motion that turned within the tick).
    pub fn dissipated(&self) -> f64 {
        self.dissipated
    }

    /// Ticks the controller added damping in.
    pub fn active_ticks(&self) -> u64 {
        self.active_ticks
    }

    /// The force the device rendered this tick, scene units, where it is not the one
    /// [`DevicePort::tick`] returned (clamped to a device limit below the coupling's): the
    /// observer counts the energy of what the hand felt.
    pub fn rendered(&mut self, force: Vec3) {
        self.force = force;
    }

    /// Starts again from a device at rest (the coupling moved elsewhere): the filter, the
    /// observer and the controller's record (the counts `dissipated` and `active_ticks`
    /// go on).
    pub fn reset(&mut self) {
        self.last = None;
        self.velocity = Vec3::zeros();
        self.force = Vec3::zeros();
        self.added = Vec3::zeros();
        self.expected_now = 0.0;
        self.expected = 0.0;
        self.realized = 0.0;
        self.trust = 1.0;
        self.energy = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::super::coupling::{ContactModel, CouplingParams};
    use super::*;

    const H: f64 = 1e-3;

    /// A hand `hand(t)` on a loop touching a tissue plane (stiffness `k`, its surface at
    /// y = 0) for `ticks`: the forces, the work each tick's force does on the hand over the
    /// next tick (as a device renders it), summed, and the port.
    fn run(
        passivity: bool,
        k: f64,
        ticks: usize,
        hand: &impl Fn(f64) -> Vec3,
    ) -> (Vec<Vec3>, f64, DevicePort) {
        let params = CouplingParams::default();
        let mut coupling = Coupling::new(params, hand(0.0));
        coupling.set_model(ContactModel {
            active: true,
            normal: Vec3::new(0.0, 1.0, 0.0),
            origin: Vec3::zeros(),
            depth: 0.0,
            stiffness: k,
            grab: false,
            step: 1,
            reach: 0.0,
        });
        let mut port = DevicePort::new(1.0 / H, 40.0, passivity);
        let at = |i: usize| hand(i as f64 * H);
        let f: Vec<Vec3> = (0..ticks)
            .map(|i| port.tick(&mut coupling, &at(i), H))
            .collect();
        let held = (0..ticks - 1).map(|i| f[i].dot(&(at(i + 1) - at(i)))).sum();
        (f, held, port)
    }

    /// A hand pressed 2 mm into stiff tissue, shaking in all three directions at several
    /// frequencies at once, each +-0.03 mm.
    fn shaking(frequencies: &'static [f64]) -> impl Fn(f64) -> Vec3 {
        move |t: f64| {
            let mut x = Vec3::new(0.0, -2e-3, 0.0);
            for (j, hz) in frequencies.iter().enumerate() {
                let w = 2.0 * std::f64::consts::PI * hz;
                let phase = 0.7 * j as f64;
                x += Vec3::new(
                    (w * t + phase).sin(),
                    (w * t + 2.0 * phase).cos(),
                    (w * t - phase).sin(),
                ) * 3e-5;
            }
            x
        }
    }

    /// Shaking at 60, 130 and 190 Hz: without the controller the loop gives the hand energy
    /// (the velocity filter's lag); with it the hand gets none over the run.
    #[test]
    fn a_shaking_hand_gets_no_energy_with_the_controller() {
        let hand = shaking(&[60.0, 130.0, 190.0]);
        let ticks = 5000;
        let (_, without, _) = run(false, 2000.0, ticks, &hand);
        let (f, with, port) = run(true, 2000.0, ticks, &hand);
        println!(
            "work on the hand: {without:.3e} without the controller, {with:.3e} with it \
             (it acted in {} of {ticks} ticks and took {:.3e})",
            port.active_ticks(),
            port.dissipated()
        );
        assert!(without > 0.0, "the case this is for: {without}");
        assert!(with <= 0.0, "{with}");
        assert!(f.iter().all(|f| f.iter().all(|c| c.is_finite())));
    }

    /// Shaking with content up to 250 and 420 Hz (near the 500 Hz a 1 kHz loop can see),
    /// where a tick's motion does not predict the next one's: a damper on it would give
    /// energy, so the controller stands aside but for the tries its record's fading allows,
    /// and the hand gets at most 2 % more than without it (without the weighting by its
    /// record: up to 27 times more).
    #[test]
    fn near_the_loop_rate_the_controller_does_little_harm() {
        for frequencies in [
            &[60.0, 130.0, 190.0, 250.0][..],
            &[60.0, 130.0, 190.0, 250.0, 330.0, 420.0][..],
        ] {
            let hand = shaking(frequencies);
            let ticks = 5000;
            let (_, without, _) = run(false, 2000.0, ticks, &hand);
            let (_, with, port) = run(true, 2000.0, ticks, &hand);
            println!(
                "up to {} Hz: {without:.4e} without the controller, {with:.4e} with it (it took \
                 {:.3e})",
                frequencies.last().unwrap(),
                port.dissipated()
            );
            assert!(
                with <= without + 0.02 * without.abs(),
                "{with} against {without}"
            );
        }
    }

    /// A hand pushing slowly and steadily into the tissue: the loop takes energy tick by
    /// tick and the controller never acts (the forces are the coupling's to the bit).
    #[test]
    fn a_loop_that_takes_energy_feels_exactly_the_coupling() {
        let hand = |t: f64| Vec3::new(0.01 * t, -0.005 * t, 0.0);
        let (without, _, _) = run(false, 2000.0, 2000, &hand);
        let (with, held, port) = run(true, 2000.0, 2000, &hand);
        assert_eq!(port.active_ticks(), 0);
        assert!(held < 0.0);
        for (a, b) in with.iter().zip(&without) {
            for c in 0..3 {
                assert_eq!(a[c].to_bits(), b[c].to_bits());
            }
        }
    }
}
