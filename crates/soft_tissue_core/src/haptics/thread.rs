//! The haptic thread: a fixed-rate loop (sleep, then spin to the deadline) that couples the
//! device to the tool proxy and renders the contact force and a blade's cut; and the
//! linearisation of a world's tool contact that the physics hands it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::coupling::{ContactModel, Coupling, CouplingParams, MODEL_WORDS, clamp};
use super::cutting::{CUT_WORDS, CutModel};
use super::exchange::SeqCell;
use super::passivity::DevicePort;
use super::priority::{self, HapticPriority, PriorityOutcome};
use super::recording::{RecordedSample, Recording};
use super::{HapticDevice, HapticError};
use crate::Vec3;
use crate::contact::Tool;
use crate::world::ContactState;

/// Maps device coordinates to the scene: `scene = offset + scale * device`; forces go back
/// as `device newtons = force_scale * scene force`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceMapping {
    /// Scene units per device unit.
    pub scale: f64,
    /// Scene position of the device origin.
    pub offset: Vec3,
    /// Device newtons per scene force unit.
    pub force_scale: f64,
}

impl Default for DeviceMapping {
    fn default() -> Self {
        DeviceMapping {
            scale: 1.0,
            offset: Vec3::zeros(),
            force_scale: 1.0,
        }
    }
}

/// Settings of the haptic loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HapticConfig {
    /// Loop rate, Hz (1000 for force feedback).
    pub rate_hz: f64,
    /// Virtual coupling gains (scene units).
    pub coupling: CouplingParams,
    /// Device to scene mapping (not applied to devices that report scene units).
    pub mapping: DeviceMapping,
    /// The loop sleeps until this long before a deadline, then spins, microseconds. Under a
    /// real-time policy the loop spins at most half the period, whatever this says: a
    /// real-time thread that never sleeps is stopped by the kernel's real-time throttling
    /// (Linux: for 50 ms of every second by default) and starves every other thread of its
    /// core; one that sleeps is woken on time anyway, as it preempts the normal threads.
    pub spin_us: f64,
    /// Seconds of device samples the session records (allocated up front).
    pub record_seconds: f64,
    /// Seconds of tick periods kept for the statistics (allocated up front).
    pub stats_seconds: f64,
    /// Cut-off of the low-pass filter on the device velocity, Hz.
    pub velocity_cutoff_hz: f64,
    /// Whether the passivity controller may add damping where the loop would give the hand
    /// energy ([`super::passivity`]; on by default: the filter's lag gives energy to hand
    /// motion above about 150 Hz without it).
    pub passivity: bool,
    /// Scheduling the thread asks for as it starts (default: real time where the OS allows
    /// it). Only the haptic thread is raised; the thread that spawns it keeps its own. What
    /// it got is [`HapticThread::priority`].
    pub priority: HapticPriority,
}

impl Default for HapticConfig {
    fn default() -> Self {
        HapticConfig {
            rate_hz: 1000.0,
            coupling: CouplingParams::default(),
            mapping: DeviceMapping::default(),
            spin_us: 300.0,
            record_seconds: 600.0,
            stats_seconds: 600.0,
            velocity_cutoff_hz: 40.0,
            passivity: true,
            priority: HapticPriority::default(),
        }
    }
}

impl HapticConfig {
    fn validate(&self) -> Result<(), HapticError> {
        let bad = |what, value, why| Err(HapticError::BadConfig { what, value, why });
        if !(self.rate_hz.is_finite() && (1.0..=20_000.0).contains(&self.rate_hz)) {
            return bad("rate_hz", self.rate_hz, "1 to 20000");
        }
        if !self.coupling.is_valid() {
            return bad(
                "coupling",
                self.coupling.stiffness,
                "stiffness, proxy mass and max force must be finite and > 0",
            );
        }
        if !(self.spin_us.is_finite() && (0.0..=1e6).contains(&self.spin_us)) {
            return bad("spin_us", self.spin_us, "0 to 1e6 (a second)");
        }
        for (what, v) in [
            ("record_seconds", self.record_seconds),
            ("stats_seconds", self.stats_seconds),
        ] {
            if !(v.is_finite() && (0.0..=86_400.0).contains(&v)) {
                return bad(what, v, "0 to 86400");
            }
        }
        if !(self.velocity_cutoff_hz.is_finite() && self.velocity_cutoff_hz > 0.0) {
            return bad("velocity_cutoff_hz", self.velocity_cutoff_hz, "> 0");
        }
        if let HapticPriority::RealTime(level) = self.priority
            && !self.priority.is_valid()
        {
            return bad("priority", f64::from(level), "real-time level 1 to 99");
        }
        let m = &self.mapping;
        let usable = m.scale.is_finite()
            && m.scale > 0.0
            && m.force_scale.is_finite()
            && m.force_scale > 0.0
            && m.offset.iter().all(|c| c.is_finite());
        if !usable {
            return bad("mapping", m.scale, "finite, scales > 0");
        }
        Ok(())
    }
}

/// What the haptic loop publishes every tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ToolSample {
    /// Tool proxy position, scene units: where the physics should put the tool.
    pub position: Vec3,
    /// Tool proxy velocity.
    pub velocity: Vec3,
    /// Device position in the scene.
    pub device: Vec3,
    /// Force rendered on the device, N.
    pub force: Vec3,
    /// Device buttons.
    pub buttons: u32,
    /// Ticks so far.
    pub tick: u64,
}

const TOOL_WORDS: usize = 14;

impl ToolSample {
    fn encode(&self) -> [f64; TOOL_WORDS] {
        let v = |a: &Vec3| [a.x, a.y, a.z];
        let mut w = [0.0; TOOL_WORDS];
        w[0..3].copy_from_slice(&v(&self.position));
        w[3..6].copy_from_slice(&v(&self.velocity));
        w[6..9].copy_from_slice(&v(&self.device));
        w[9..12].copy_from_slice(&v(&self.force));
        w[12] = f64::from(self.buttons);
        w[13] = self.tick as f64;
        w
    }

    fn decode(w: &[f64; TOOL_WORDS]) -> Self {
        let v = |i: usize| Vec3::new(w[i], w[i + 1], w[i + 2]);
        ToolSample {
            position: v(0),
            velocity: v(3),
            device: v(6),
            force: v(9),
            buttons: w[12] as u32,
            tick: w[13] as u64,
        }
    }
}

/// Words the physics hands the loop each step: a contact model, then a cut model (one
/// write, so the loop never mixes two steps' models).
const HANDOVER_WORDS: usize = MODEL_WORDS + CUT_WORDS;

fn handover(contact: &ContactModel, cut: &CutModel) -> [f64; HANDOVER_WORDS] {
    let mut w = [0.0; HANDOVER_WORDS];
    w[..MODEL_WORDS].copy_from_slice(&contact.encode());
    w[MODEL_WORDS..].copy_from_slice(&cut.encode());
    w
}

fn handed_over(w: &[f64; HANDOVER_WORDS]) -> (ContactModel, CutModel) {
    (
        ContactModel::decode(&std::array::from_fn(|i| w[i])),
        CutModel::decode(&std::array::from_fn(|i| w[MODEL_WORDS + i])),
    )
}

/// State shared by the haptic thread and the physics.
#[derive(Debug)]
pub struct HapticShared {
    tool: SeqCell<TOOL_WORDS>,
    model: SeqCell<HANDOVER_WORDS>,
    stop: AtomicBool,
    ticks: AtomicU64,
}

impl HapticShared {
    /// The tool as of the last haptic tick.
    pub fn tool(&self) -> ToolSample {
        ToolSample::decode(&self.tool.read().0)
    }

    /// Hands the loop a new contact model, and no cut ([`CutModel::NONE`]). Call from one
    /// thread only (the physics).
    pub fn publish_model(&self, model: &ContactModel) {
        self.model.write(handover(model, &CutModel::NONE));
    }

    /// Hands the loop a new contact model and a blade's cut model together (from the same
    /// physics step). Call from one thread only (the physics). A cut model that is not
    /// valid ([`CutModel::validate`]) is refused and nothing is handed over.
    pub fn publish(&self, model: &ContactModel, cut: &CutModel) -> Result<(), HapticError> {
        cut.validate()?;
        self.model.write(handover(model, cut));
        Ok(())
    }

    /// The last contact model published.
    pub fn model(&self) -> ContactModel {
        handed_over(&self.model.read().0).0
    }

    /// The last cut model published.
    pub fn cut_model(&self) -> CutModel {
        handed_over(&self.model.read().0).1
    }

    /// Ticks run so far.
    pub fn ticks(&self) -> u64 {
        self.ticks.load(Ordering::Acquire)
    }
}

/// Statistics of a finished haptic session.
#[derive(Debug, Clone, PartialEq)]
pub struct HapticRun {
    /// Ticks run.
    pub ticks: u64,
    /// Measured period of every tick after the first (up to `stats_seconds`), microseconds.
    pub periods_us: Vec<f32>,
    /// Ticks that began more than a tenth of a period after their deadline.
    pub missed: u64,
    /// Largest change of the device force between two ticks, N.
    pub max_force_step: f64,
    /// Largest change of the device force on a tick that adopted a new contact model, N.
    pub max_force_step_on_model: f64,
    /// Change of the device force at every tick (up to `stats_seconds`), N.
    pub force_steps: Vec<f32>,
    /// Largest device force, N.
    pub max_force: f64,
    /// The device samples (scene units).
    pub recording: Recording,
    /// Why the loop ended early, if a device call failed.
    pub device_error: Option<HapticError>,
    /// The scheduling the thread asked for and got.
    pub priority: PriorityOutcome,
    /// The spin the loop used before each deadline, microseconds: [`HapticConfig::spin_us`],
    /// at most half the period under real time.
    pub spin_us: f64,
    /// Ticks the passivity controller added damping in.
    pub passivity_ticks: u64,
    /// Energy the passivity controller's damping took from the hand over the motion each of
    /// its forces was held for, scene units (force times length; negative where it gave).
    pub passivity_dissipated: f64,
}

impl HapticRun {
    /// The `q` quantile (0..1) of the tick periods, microseconds (`None` without periods).
    pub fn period_quantile(&self, q: f64) -> Option<f64> {
        quantile(&self.periods_us, q)
    }

    /// The `q` quantile (0..1) of the per-tick force changes, N.
    pub fn force_step_quantile(&self, q: f64) -> Option<f64> {
        quantile(&self.force_steps, q)
    }
}

fn quantile(values: &[f32], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut p = values.to_vec();
    p.sort_unstable_by(f32::total_cmp);
    let i = ((p.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    Some(f64::from(p[i]))
}

/// A running haptic loop; stopping it (or dropping it) ends the thread cleanly and leaves the
/// device with zero force.
#[derive(Debug)]
pub struct HapticThread {
    shared: Arc<HapticShared>,
    handle: Option<JoinHandle<HapticRun>>,
    priority: PriorityOutcome,
}

impl HapticThread {
    /// Starts the loop on its own thread. The tool proxy starts at the device's first pose.
    /// The thread applies [`HapticConfig::priority`] to itself before its first tick and this
    /// returns once it has (a refused priority is no error: see [`HapticThread::priority`]).
    pub fn spawn(
        mut device: Box<dyn HapticDevice>,
        config: HapticConfig,
    ) -> Result<Self, HapticError> {
        config.validate()?;
        let mapping = if device.in_scene_units() {
            DeviceMapping::default()
        } else {
            config.mapping
        };
        let first = device.read(0.0)?;
        let start = mapping.offset + first.position * mapping.scale;
        let shared = Arc::new(HapticShared {
            tool: SeqCell::new(
                ToolSample {
                    position: start,
                    device: start,
                    buttons: first.buttons,
                    ..ToolSample::default()
                }
                .encode(),
            ),
            model: SeqCell::new(handover(&ContactModel::NONE, &CutModel::NONE)),
            stop: AtomicBool::new(false),
            ticks: AtomicU64::new(0),
        });
        let thread_shared = shared.clone();
        let (applied, outcome) = std::sync::mpsc::sync_channel(1);
        let handle = std::thread::Builder::new()
            .name("soft-tissue-haptics".into())
            .spawn(move || {
                let priority = priority::apply(config.priority);
                // The spawner waits for this; it only fails if the spawner is gone.
                let _ = applied.send(priority.clone());
                run(device, config, mapping, start, &thread_shared, priority)
            })
            .map_err(|e| HapticError::Thread(e.to_string()))?;
        let priority = match outcome.recv() {
            Ok(p) => p,
            Err(_) => {
                // The thread ended before it reported: it panicked.
                let _ = handle.join();
                return Err(HapticError::Thread(
                    "the haptic thread ended before it started ticking".into(),
                ));
            }
        };
        Ok(HapticThread {
            shared,
            handle: Some(handle),
            priority,
        })
    }

    /// The scheduling the thread asked for and got (policy and priority read back from the
    /// OS, or why the request was refused).
    pub fn priority(&self) -> &PriorityOutcome {
        &self.priority
    }

    /// The state shared with the loop.
    pub fn shared(&self) -> &Arc<HapticShared> {
        &self.shared
    }

    /// Stops the loop, waits for the thread and returns its statistics and recording.
    pub fn stop(mut self) -> Result<HapticRun, HapticError> {
        self.shared.stop.store(true, Ordering::Release);
        let handle = self.handle.take().expect("joined only here or on drop");
        handle
            .join()
            .map_err(|_| HapticError::Thread("the haptic thread panicked".into()))
    }
}

impl Drop for HapticThread {
    fn drop(&mut self) {
        if let Some(h) = self.handle.take() {
            self.shared.stop.store(true, Ordering::Release);
            let _ = h.join();
        }
    }
}

/// Sleeps until `spin` before `deadline`, then spins to it.
fn wait_until(deadline: Instant, spin: Duration) {
    let now = Instant::now();
    if deadline > now + spin {
        std::thread::sleep(deadline - now - spin);
    }
    while Instant::now() < deadline {
        std::hint::spin_loop();
    }
}

fn run(
    mut device: Box<dyn HapticDevice>,
    config: HapticConfig,
    mapping: DeviceMapping,
    start_position: Vec3,
    shared: &HapticShared,
    priority: PriorityOutcome,
) -> HapticRun {
    let h = 1.0 / config.rate_hz;
    let period = Duration::from_secs_f64(h);
    let late = period / 10;
    let mut spin = Duration::from_secs_f64(config.spin_us * 1e-6);
    if priority.is_real_time() {
        spin = spin.min(period / 2);
    }
    let limit = device.limits().max_force;
    let mut out = HapticRun {
        ticks: 0,
        periods_us: Vec::with_capacity((config.stats_seconds * config.rate_hz).ceil() as usize),
        missed: 0,
        max_force_step: 0.0,
        max_force_step_on_model: 0.0,
        force_steps: Vec::with_capacity((config.stats_seconds * config.rate_hz).ceil() as usize),
        max_force: 0.0,
        recording: Recording::with_capacity(config.rate_hz, config.record_seconds),
        device_error: None,
        priority,
        spin_us: spin.as_secs_f64() * 1e6,
        passivity_ticks: 0,
        passivity_dissipated: 0.0,
    };
    let mut coupling = Coupling::new(config.coupling, start_position);
    let mut port = DevicePort::new(config.rate_hz, config.velocity_cutoff_hz, config.passivity);
    let mut model_writes = 0u64;
    let mut last_force = Vec3::zeros();
    let start = Instant::now();
    let mut deadline = start;
    let mut last_tick: Option<Instant> = None;
    let mut k: u64 = 0;
    while !shared.stop.load(Ordering::Acquire) {
        wait_until(deadline, spin);
        let now = Instant::now();
        if let Some(l) = last_tick
            && out.periods_us.len() < out.periods_us.capacity()
        {
            out.periods_us.push((now - l).as_secs_f64() as f32 * 1e6);
        }
        last_tick = Some(now);
        if now > deadline + late {
            out.missed += 1;
        }
        // Device time is the tick count: a replay sees the same times whatever the jitter.
        let t = k as f64 * h;
        let state = match device.read(t) {
            Ok(s) => s,
            Err(e) => {
                out.device_error = Some(e);
                break;
            }
        };
        let x_device = mapping.offset + state.position * mapping.scale;
        let (words, writes) = shared.model.read();
        let new_model = writes != model_writes;
        if new_model {
            model_writes = writes;
            let (contact, cut) = handed_over(&words);
            coupling.set_model(contact);
            coupling.set_cut(cut);
        }
        let f_scene = port.tick(&mut coupling, &x_device, h);
        out.passivity_ticks = port.active_ticks();
        out.passivity_dissipated = port.dissipated();
        let force = clamp(f_scene * mapping.force_scale, limit);
        port.rendered(force / mapping.force_scale);
        let change = (force - last_force).norm();
        out.max_force_step = out.max_force_step.max(change);
        if new_model {
            out.max_force_step_on_model = out.max_force_step_on_model.max(change);
        }
        if out.force_steps.len() < out.force_steps.capacity() {
            out.force_steps.push(change as f32);
        }
        out.max_force = out.max_force.max(force.norm());
        last_force = force;
        if let Err(e) = device.write_force(force) {
            out.device_error = Some(e);
            break;
        }
        k += 1;
        shared.tool.write(
            ToolSample {
                position: coupling.position(),
                velocity: coupling.velocity(),
                device: x_device,
                force,
                buttons: state.buttons,
                tick: k,
            }
            .encode(),
        );
        shared.ticks.store(k, Ordering::Release);
        out.recording.push(RecordedSample {
            t,
            position: [x_device.x, x_device.y, x_device.z],
            buttons: state.buttons,
        });
        deadline += period;
        // Far behind (the thread was descheduled): skip the lost ticks instead of bursting.
        if now > deadline + period {
            deadline = now + period;
        }
    }
    out.ticks = k;
    if out.device_error.is_none()
        && let Err(e) = device.write_force(Vec3::zeros())
    {
        out.device_error = Some(e);
    }
    out
}

/// The local contact model of tool `tool_index` after a world step, for the haptic loop:
/// the plane of the touched surface (normal from the tissue's reaction, or from the nearest
/// contacts within the margin when not touching), the penetration that gives the measured
/// force at the stiffness estimate, and that estimate: a secant between successive physics
/// steps, smoothed (one tenth of each new secant) and kept within a factor four of
/// `nominal_stiffness`. `grab`: the tool
/// holds tissue.
pub fn contact_model(
    tool: &Tool,
    tool_index: u32,
    contacts: &ContactState,
    previous: &ContactModel,
    nominal_stiffness: f64,
    step: u64,
) -> ContactModel {
    let x = tool.position();
    // The proxy may lead this pose by half the tip's radius: the physics pushed the surface
    // out of the tip at this pose, so at the next pose the tip's centre is still on the
    // outer side of every surface it touches (a whole radius could put the centre on the
    // surface, where the push-out direction flips and the tool slips through).
    let reach = 0.5 * tool.shape().radius();
    // The contact forces only: a blade's cutting resistance pushes against its motion, not
    // out of a surface, and as a plane it would chatter with the hand's jitter.
    let reaction = tool.contact_force();
    let f = reaction.norm();
    let grab = !tool.grips().is_empty();
    let mut stiffness = if previous.active && previous.stiffness > 0.0 {
        previous.stiffness
    } else {
        nominal_stiffness
    };
    if f > 0.0 && f.is_finite() {
        let n = reaction / f;
        // Secant: how much more force for how much deeper, since the last step.
        if previous.active && !previous.grab && !grab {
            let f_prev = previous.stiffness * previous.depth.max(0.0);
            let deeper = (previous.origin - x).dot(&n);
            if deeper.abs() > 1e-9 && previous.depth > 0.0 {
                let secant = (f - f_prev) / deeper;
                if secant.is_finite() && secant > 0.0 {
                    stiffness = 0.9 * stiffness + 0.1 * secant;
                }
            }
        }
        stiffness = stiffness.clamp(0.25 * nominal_stiffness, 4.0 * nominal_stiffness);
        return ContactModel {
            active: true,
            normal: n,
            origin: x,
            depth: f / stiffness,
            stiffness,
            grab,
            step,
            reach,
        };
    }
    // Not pushing: the nearest contact within the margin gives the plane and the gap.
    let near = contacts
        .tool_contacts
        .iter()
        .filter(|c| c.tool == tool_index)
        .max_by(|a, b| a.depth.total_cmp(&b.depth));
    match near {
        Some(c) if c.normal.iter().all(|v| v.is_finite()) && c.normal.norm() > 0.0 => {
            ContactModel {
                active: true,
                // The contact normal points from the tool into the tissue.
                normal: -c.normal.normalize(),
                origin: x,
                depth: c.depth.min(0.0),
                stiffness: stiffness.clamp(0.25 * nominal_stiffness, 4.0 * nominal_stiffness),
                grab: false,
                step,
                reach,
            }
        }
        _ => ContactModel {
            step,
            origin: x,
            reach,
            ..ContactModel::NONE
        },
    }
}

#[cfg(test)]
mod tests {
    use super::super::{NullDevice, ReplayDevice, VirtualDevice};
    use super::*;

    fn quick() -> HapticConfig {
        HapticConfig {
            record_seconds: 5.0,
            stats_seconds: 5.0,
            ..HapticConfig::default()
        }
    }

    #[test]
    fn the_loop_ticks_without_physics_and_stops_cleanly() {
        let thread =
            HapticThread::spawn(Box::new(NullDevice::new(Vec3::new(0.0, 1.0, 0.0))), quick())
                .unwrap();
        let shared = thread.shared().clone();
        // Nobody publishes a model (a stalled physics): the loop keeps ticking.
        let t0 = shared.ticks();
        std::thread::sleep(Duration::from_millis(60));
        let t1 = shared.ticks();
        assert!(t1 > t0 + 10, "ticks {t0} -> {t1}");
        let run = thread.stop().unwrap();
        assert!(run.ticks >= t1);
        assert_eq!(run.device_error, None);
        assert_eq!(run.recording.samples.len() as u64, run.ticks);
        assert_eq!(run.periods_us.len() as u64, run.ticks - 1);
        // Stopped: no more ticks.
        let after = shared.ticks();
        std::thread::sleep(Duration::from_millis(10));
        assert_eq!(shared.ticks(), after);
        assert_eq!(shared.tool().position, Vec3::new(0.0, 1.0, 0.0));
    }

    #[test]
    fn a_published_model_pushes_the_device_back_and_drop_zeroes_the_force() {
        let (device, handle) = VirtualDevice::new(Vec3::zeros(), 5.0);
        let thread = HapticThread::spawn(Box::new(device), quick()).unwrap();
        // The surface is at y = 0, the device 2 cm below it.
        thread.shared().publish_model(&ContactModel {
            active: true,
            normal: Vec3::new(0.0, 1.0, 0.0),
            origin: Vec3::zeros(),
            depth: 0.0,
            stiffness: 400.0,
            grab: false,
            step: 1,
            reach: 0.0,
        });
        handle.set(Vec3::new(0.0, -0.02, 0.0), 0);
        let deadline = Instant::now() + Duration::from_secs(5);
        let want = 400.0 * 400.0 / 800.0 * 0.02;
        loop {
            let f = handle.force();
            if (f.y - want).abs() < 1e-3 * want {
                break;
            }
            assert!(Instant::now() < deadline, "force {f:?}, want {want}");
            std::thread::sleep(Duration::from_millis(5));
        }
        assert!(thread.shared().tool().position.y < 0.0);
        drop(thread);
        assert_eq!(
            handle.force(),
            Vec3::zeros(),
            "the device is left with no force"
        );
    }

    #[test]
    fn replay_reproduces_the_recorded_session_exactly() {
        // Record a session driven by a moving virtual device, then replay it: the replay
        // device returns the recorded samples bit for bit at their times.
        let (device, handle) = VirtualDevice::new(Vec3::zeros(), 5.0);
        let thread = HapticThread::spawn(Box::new(device), quick()).unwrap();
        for i in 0..40 {
            handle.set(Vec3::new(0.001 * i as f64, 0.0, 0.0), (i / 20) as u32);
            std::thread::sleep(Duration::from_millis(1));
        }
        let run = thread.stop().unwrap();
        let rec = run.recording;
        assert!(rec.samples.len() > 10);
        let mut replay = ReplayDevice::new(rec.clone(), 5.0).unwrap();
        for s in &rec.samples {
            let st = replay.state_at(s.t);
            assert_eq!(st.position, Vec3::from(s.position));
            assert_eq!(st.buttons, s.buttons);
        }
        // And through a second haptic loop: it reads the same samples in the same order.
        let thread = HapticThread::spawn(
            Box::new(ReplayDevice::new(rec.clone(), 5.0).unwrap()),
            quick(),
        )
        .unwrap();
        while thread.shared().ticks() < rec.samples.len() as u64 {
            std::thread::sleep(Duration::from_millis(2));
        }
        let again = thread.stop().unwrap().recording;
        assert_eq!(&again.samples[..rec.samples.len()], &rec.samples[..]);
    }

    #[test]
    fn normal_priority_leaves_the_thread_at_the_normal_policy_and_says_so() {
        let thread = HapticThread::spawn(
            Box::new(NullDevice::new(Vec3::zeros())),
            HapticConfig {
                priority: HapticPriority::Normal,
                ..quick()
            },
        )
        .unwrap();
        let p = thread.priority().clone();
        assert_eq!(p.requested, HapticPriority::Normal);
        assert_eq!(p.refused, None);
        assert!(!p.is_real_time(), "{p}");
        #[cfg(target_os = "linux")]
        assert_eq!(
            p.obtained,
            // The spawning thread's policy and nice value, inherited unchanged.
            priority::current(),
            "{p}"
        );
        let run = thread.stop().unwrap();
        assert_eq!(run.priority, p, "the run's statistics carry the outcome");
        assert!((run.spin_us - 300.0).abs() < 1e-6, "{}", run.spin_us);
    }

    #[test]
    fn real_time_raises_the_haptic_thread_only_or_states_the_refusal() {
        let before = priority::current();
        let thread = HapticThread::spawn(
            Box::new(NullDevice::new(Vec3::zeros())),
            HapticConfig {
                priority: HapticPriority::RealTime(42),
                spin_us: 1000.0,
                ..quick()
            },
        )
        .unwrap();
        let p = thread.priority().clone();
        assert_eq!(p.requested, HapticPriority::RealTime(42));
        match (&p.obtained, &p.refused) {
            // Granted (a privileged process, as on the CI machine): the level asked.
            (priority::Scheduling::RealTime { level, .. }, None) => assert_eq!(*level, 42),
            // Refused: the OS's reason, and the loop runs all the same.
            (_, Some(why)) => assert!(why.contains("real time 42"), "{p}"),
            _ => panic!("real time neither obtained nor refused: {p}"),
        }
        // The spawning thread (the physics) keeps its own scheduling.
        assert_eq!(priority::current(), before);
        let shared = thread.shared().clone();
        while shared.ticks() < 5 {
            std::thread::sleep(Duration::from_millis(1));
        }
        let run = thread.stop().unwrap();
        assert_eq!(run.priority, p);
        // Under real time the loop sleeps at least half of every period.
        let want = if p.is_real_time() { 500.0 } else { 1000.0 };
        assert!(
            (run.spin_us - want).abs() < 1e-6,
            "{} vs {want}",
            run.spin_us
        );
    }

    #[test]
    fn bad_settings_are_refused() {
        let mut c = quick();
        c.rate_hz = 0.0;
        assert!(matches!(
            HapticThread::spawn(Box::new(NullDevice::new(Vec3::zeros())), c),
            Err(HapticError::BadConfig {
                what: "rate_hz",
                ..
            })
        ));
        let mut c = quick();
        c.coupling.proxy_mass = -1.0;
        assert!(matches!(
            HapticThread::spawn(Box::new(NullDevice::new(Vec3::zeros())), c),
            Err(HapticError::BadConfig {
                what: "coupling",
                ..
            })
        ));
        // A spin too long for a `Duration` is refused, not a panic in the thread.
        let c = HapticConfig {
            spin_us: 1e30,
            ..quick()
        };
        assert!(matches!(
            HapticThread::spawn(Box::new(NullDevice::new(Vec3::zeros())), c),
            Err(HapticError::BadConfig {
                what: "spin_us",
                ..
            })
        ));
        for level in [0, 100] {
            let c = HapticConfig {
                priority: HapticPriority::RealTime(level),
                ..quick()
            };
            assert!(matches!(
                HapticThread::spawn(Box::new(NullDevice::new(Vec3::zeros())), c),
                Err(HapticError::BadConfig {
                    what: "priority",
                    ..
                })
            ));
        }
    }
}
