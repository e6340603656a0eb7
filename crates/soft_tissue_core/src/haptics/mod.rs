//! Haptics: force feedback at 1 kHz, independent of the render and physics rates.
//!
//! - [`HapticDevice`]: read a pose and buttons, write a force, report workspace and force
//!   limits. [`NullDevice`], [`VirtualDevice`] (driven from another thread, e.g. by the mouse
//!   through a [`VirtualDeviceHandle`]) and [`ReplayDevice`] (plays a [`Recording`]).
//! - [`HapticThread`]: a dedicated thread ticking at the configured rate (sleep, then spin to
//!   the deadline). Each tick reads the device, advances the virtual coupling
//!   ([`coupling::Coupling`]: tool proxy, spring-damper to the device, critical damping,
//!   implicit Euler), evaluates the tissue's local [`ContactModel`] that the physics handed
//!   over at its last step and a cutting blade's friction across its edge ([`CutModel`]:
//!   breakaway at the toughness times the edge's length in tissue, [`cutting`]), clamps and
//!   writes the force, publishes the tool pose and records
//!   the device sample. The physics reads the tool with [`HapticShared::tool`] and publishes
//!   models with [`HapticShared::publish_model`] (with a cut: [`HapticShared::publish`]);
//!   both go through lock-free sequence cells
//!   ([`exchange::SeqCell`]), so a stalled physics step never stalls the haptic loop, and the
//!   loop does not allocate. The thread asks for real-time scheduling ([`HapticPriority`],
//!   default `SCHED_FIFO` 80 where the OS allows it, else the lowest nice value allowed, else
//!   normal) and [`HapticThread::priority`] says what it got ([`PriorityOutcome`]); the
//!   physics thread that spawns it stays at normal priority.
//! - [`Recording`]: every device sample of a session; saved as RON, replayed exactly by
//!   [`ReplayDevice`], turned into a world [`crate::world::Script`] with
//!   [`Recording::to_script`] (and built from one with [`Recording::from_script`]).
//! - [`contact_model`]: the linearisation of a world's tool contact for the loop.
//! - `haply::HaplyInverse3` (feature `haply`): a Haply Inverse3 through the Haply Inverse
//!   Service.
//!
//! Units are the scene's; a real device maps its workspace into the scene with
//! [`DeviceMapping`].

pub mod coupling;
pub mod cutting;
pub mod exchange;
#[cfg(feature = "haply")]
pub mod haply;
pub mod passivity;
pub(crate) mod priority;
mod recording;
mod thread;

pub use coupling::{ContactModel, CouplingParams};
pub use cutting::{CutModel, cut_model};
pub use passivity::DevicePort;
pub use priority::{DEFAULT_REALTIME_LEVEL, HapticPriority, PriorityOutcome, Scheduling};
pub use recording::{
    CAUTERY_BUTTON, CUT_BUTTON, GRAB_BUTTON, JAWS_BUTTON, MAX_RECORDING_SAMPLES, RecordedSample,
    Recording, RecordingError,
};
pub use thread::{
    DeviceMapping, HapticConfig, HapticRun, HapticShared, HapticThread, ToolSample, contact_model,
};

use std::sync::Arc;

use crate::Vec3;
use exchange::SeqCell;
use thiserror::Error;

/// Errors of the haptic devices and loop.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HapticError {
    /// The device failed (disconnected, refused a command).
    #[error("haptic device `{device}`: {message}")]
    Device {
        /// Device name.
        device: String,
        /// What happened.
        message: String,
    },
    /// A setting is out of range.
    #[error("haptic setting `{what}` = {value} is out of range ({why})")]
    BadConfig {
        /// Which setting.
        what: &'static str,
        /// Its value.
        value: f64,
        /// The valid range.
        why: &'static str,
    },
    /// A model handed to the loop is unusable (a number not finite, out of range).
    #[error("haptic model `{what}` = {value} is out of range ({why})")]
    BadModel {
        /// Which number.
        what: &'static str,
        /// Its value.
        value: f64,
        /// The valid range.
        why: &'static str,
    },
    /// The haptic thread could not be started or panicked.
    #[error("haptic thread: {0}")]
    Thread(String),
}

/// What a device reports each tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DeviceState {
    /// Handle position, device units.
    pub position: Vec3,
    /// Button bits (bit 0: the main button, grab; bit 1: the second, cautery).
    pub buttons: u32,
}

/// What a device can do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceLimits {
    /// Lower corner of the workspace, device units.
    pub workspace_min: Vec3,
    /// Upper corner of the workspace, device units.
    pub workspace_max: Vec3,
    /// Largest force it renders, N.
    pub max_force: f64,
}

impl DeviceLimits {
    /// No workspace bound (a software device) and a force limit, N.
    pub fn unbounded(max_force: f64) -> Self {
        DeviceLimits {
            workspace_min: Vec3::repeat(f64::NEG_INFINITY),
            workspace_max: Vec3::repeat(f64::INFINITY),
            max_force,
        }
    }
}

/// A force-feedback device (see the module docs).
pub trait HapticDevice: Send {
    /// Name, for errors and reports.
    fn name(&self) -> &str;
    /// Workspace and force limits.
    fn limits(&self) -> DeviceLimits;
    /// The pose and buttons at `time` seconds since the loop started.
    fn read(&mut self, time: f64) -> Result<DeviceState, HapticError>;
    /// Renders `force` (N, already clamped to the limit).
    fn write_force(&mut self, force: Vec3) -> Result<(), HapticError>;
    /// Whether positions are already scene units (the loop's [`DeviceMapping`] is then not
    /// applied): true for the software devices.
    fn in_scene_units(&self) -> bool {
        false
    }
}

/// A device that stays where it was put and renders nothing.
#[derive(Debug, Clone)]
pub struct NullDevice {
    state: DeviceState,
}

impl NullDevice {
    /// Held at `position`, no button.
    pub fn new(position: Vec3) -> Self {
        NullDevice {
            state: DeviceState {
                position,
                buttons: 0,
            },
        }
    }
}

impl HapticDevice for NullDevice {
    fn name(&self) -> &str {
        "null"
    }
    fn in_scene_units(&self) -> bool {
        true
    }
    fn limits(&self) -> DeviceLimits {
        DeviceLimits::unbounded(f64::INFINITY)
    }
    fn read(&mut self, _time: f64) -> Result<DeviceState, HapticError> {
        Ok(self.state)
    }
    fn write_force(&mut self, _force: Vec3) -> Result<(), HapticError> {
        Ok(())
    }
}

/// A software device whose handle is moved from another thread (the mouse in the example
/// apps); the last rendered force can be read back (to draw it, or to test). Positions set
/// through the handle arrive in jumps (a mouse moves once per frame); the device follows them
/// with a first-order lag (time constant [`VirtualDevice::SMOOTHING`]) as a hand would, so
/// the coupling sees a finite device velocity.
#[derive(Debug)]
pub struct VirtualDevice {
    shared: Arc<VirtualShared>,
    limits: DeviceLimits,
    smoothing: f64,
    current: Option<(f64, Vec3)>,
    hand: Option<f64>,
    last_force: Vec3,
}

#[derive(Debug)]
struct VirtualShared {
    /// Position x, y, z and buttons.
    input: SeqCell<4>,
    /// Last force x, y, z.
    force: SeqCell<3>,
}

/// Moves a [`VirtualDevice`] and reads its force; cheap to clone, usable from any thread.
#[derive(Debug, Clone)]
pub struct VirtualDeviceHandle(Arc<VirtualShared>);

impl VirtualDevice {
    /// Default time constant of the lag behind the handle, s.
    pub const SMOOTHING: f64 = 0.012;

    /// The same device with another lag time constant (0: follow the handle at once).
    pub fn with_smoothing(mut self, seconds: f64) -> Self {
        self.smoothing = if seconds.is_finite() {
            seconds.max(0.0)
        } else {
            0.0
        };
        self
    }

    /// The same device held by a hand that stops pushing against the rendered force once
    /// it reaches `strength` N, as a user who feels the wall does: the device keeps following
    /// the handle sideways and backward but not deeper. Without it (the default) the device
    /// always reaches the handle, like a hand of unlimited strength, and a mouse pushed far
    /// beyond a surface drives the tool through soft tissue. A strength at or above the
    /// device's force limit never stops it (the force is clamped to the limit).
    pub fn with_hand(mut self, strength: f64) -> Self {
        self.hand = (strength.is_finite() && strength > 0.0).then_some(strength);
        self
    }

    /// A virtual device at `position` with a force limit (N), and its handle.
    pub fn new(position: Vec3, max_force: f64) -> (Self, VirtualDeviceHandle) {
        let shared = Arc::new(VirtualShared {
            input: SeqCell::new([position.x, position.y, position.z, 0.0]),
            force: SeqCell::new([0.0; 3]),
        });
        (
            VirtualDevice {
                shared: shared.clone(),
                limits: DeviceLimits::unbounded(max_force),
                smoothing: Self::SMOOTHING,
                current: None,
                hand: None,
                last_force: Vec3::zeros(),
            },
            VirtualDeviceHandle(shared),
        )
    }
}

impl VirtualDeviceHandle {
    /// Moves the handle and sets the buttons. One thread should drive a given device.
    pub fn set(&self, position: Vec3, buttons: u32) {
        self.0
            .input
            .write([position.x, position.y, position.z, f64::from(buttons)]);
    }

    /// The force the device rendered last.
    pub fn force(&self) -> Vec3 {
        let (f, _) = self.0.force.read();
        Vec3::new(f[0], f[1], f[2])
    }
}

impl HapticDevice for VirtualDevice {
    fn name(&self) -> &str {
        "virtual"
    }
    fn in_scene_units(&self) -> bool {
        true
    }
    fn limits(&self) -> DeviceLimits {
        self.limits
    }
    fn read(&mut self, time: f64) -> Result<DeviceState, HapticError> {
        let (w, _) = self.shared.input.read();
        let target = Vec3::new(w[0], w[1], w[2]);
        let mut position = match self.current {
            Some((t0, p)) if self.smoothing > 0.0 && time > t0 => {
                let a = 1.0 - (-(time - t0) / self.smoothing).exp();
                p + (target - p) * a
            }
            Some((t0, p)) if self.smoothing > 0.0 && time <= t0 => p,
            _ => target,
        };
        if let (Some(strength), Some((_, p))) = (self.hand, self.current) {
            let f = self.last_force.norm();
            if f >= strength {
                // The hand stops pushing: no motion against the force.
                let n = self.last_force / f;
                let against = (position - p).dot(&n);
                if against < 0.0 {
                    position -= n * against;
                }
            }
        }
        self.current = Some((time, position));
        Ok(DeviceState {
            position,
            buttons: w[3] as u32,
        })
    }
    fn write_force(&mut self, force: Vec3) -> Result<(), HapticError> {
        self.last_force = force;
        self.shared.force.write([force.x, force.y, force.z]);
        Ok(())
    }
}

/// Plays a [`Recording`]: positions interpolated linearly between samples (exactly the
/// recorded ones at the recorded times), buttons as last recorded; holds the last sample
/// after the end.
#[derive(Debug, Clone)]
pub struct ReplayDevice {
    recording: Recording,
    cursor: usize,
    max_force: f64,
}

impl ReplayDevice {
    /// A device replaying `recording` (which must not be empty) with a force limit (N).
    pub fn new(recording: Recording, max_force: f64) -> Result<Self, RecordingError> {
        recording.validate()?;
        Ok(ReplayDevice {
            recording,
            cursor: 0,
            max_force,
        })
    }

    /// The recorded state at `time` (see the type docs).
    pub fn state_at(&mut self, time: f64) -> DeviceState {
        let s = &self.recording.samples;
        // Samples are in increasing time; the cursor only moves back on a rewind.
        if self.cursor >= s.len() || s[self.cursor].t > time {
            self.cursor = 0;
        }
        while self.cursor + 1 < s.len() && s[self.cursor + 1].t <= time {
            self.cursor += 1;
        }
        let a = &s[self.cursor];
        let pa = Vec3::from(a.position);
        if time <= a.t || self.cursor + 1 == s.len() {
            return DeviceState {
                position: pa,
                buttons: a.buttons,
            };
        }
        let b = &s[self.cursor + 1];
        let w = (time - a.t) / (b.t - a.t);
        DeviceState {
            position: pa + (Vec3::from(b.position) - pa) * w,
            buttons: a.buttons,
        }
    }
}

impl HapticDevice for ReplayDevice {
    fn name(&self) -> &str {
        "replay"
    }
    fn in_scene_units(&self) -> bool {
        true
    }
    fn limits(&self) -> DeviceLimits {
        DeviceLimits::unbounded(self.max_force)
    }
    fn read(&mut self, time: f64) -> Result<DeviceState, HapticError> {
        Ok(self.state_at(time))
    }
    fn write_force(&mut self, _force: Vec3) -> Result<(), HapticError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_virtual_hand_stops_pushing_at_its_strength_but_still_moves_sideways() {
        let (device, handle) = VirtualDevice::new(Vec3::zeros(), 8.0);
        let mut device = device.with_hand(2.0);
        assert_eq!(device.read(0.0).unwrap().position, Vec3::zeros());
        handle.set(Vec3::new(1.0, -1.0, 0.0), 0);
        // The tissue pushes back (+y) with 3 N, above the hand's 2 N: no deeper, but sideways.
        device.write_force(Vec3::new(0.0, 3.0, 0.0)).unwrap();
        let p = device.read(0.1).unwrap().position;
        assert_eq!(p.y, 0.0);
        assert!(p.x > 0.99, "{p}");
        // Below its strength the hand pushes on toward the handle.
        device.write_force(Vec3::new(0.0, 1.0, 0.0)).unwrap();
        let q = device.read(0.2).unwrap().position;
        assert!(q.y < -0.99, "{q}");
        // Pulled back by the user (handle above), the device follows whatever the force.
        device.write_force(Vec3::new(0.0, 7.0, 0.0)).unwrap();
        handle.set(Vec3::new(1.0, 0.5, 0.0), 0);
        let r = device.read(0.3).unwrap().position;
        assert!(r.y > 0.49, "{r}");
        // Without a hand the device always reaches the handle.
        let (free, handle) = VirtualDevice::new(Vec3::zeros(), 8.0);
        let mut free = free.with_smoothing(0.0);
        handle.set(Vec3::new(0.0, -1.0, 0.0), 0);
        free.write_force(Vec3::new(0.0, 8.0, 0.0)).unwrap();
        assert_eq!(free.read(0.0).unwrap().position.y, -1.0);
    }
}
