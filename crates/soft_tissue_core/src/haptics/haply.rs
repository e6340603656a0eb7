//! A Haply Inverse3 (with or without a VerseGrip handle) as a [`HapticDevice`], through the
//! Haply Inverse Service and its maintained Rust client, the `haply` crate (feature `haply`).
//!
//! The service speaks WebSocket and the client is async (tokio), which has no place in the
//! 1 kHz loop. So a bridge thread owns a small single-threaded tokio runtime and the
//! connection: it streams the device state into a lock-free [`SeqCell`] and sends the latest
//! force from another one. The haptic loop's `read` and `write_force` only touch those cells
//! (no allocation, no lock, no await). If the bridge stops hearing from the service for
//! longer than [`HaplyConfig::stale_after`], `read` fails and the loop ends, which writes a
//! zero force; dropping the device sends a zero force and closes the session.
//!
//! Positions are the Inverse3 cursor in the service's frame (metres); map them into the
//! scene with the loop's [`DeviceMapping`](super::DeviceMapping). Buttons: VerseGrip button
//! or wireless VerseGrip button `a` is [`GRAB_BUTTON`], button `b` is [`CAUTERY_BUTTON`].
//!
//! Not tested on hardware here (no device on the CI machine); the tests cover the typed
//! errors when no service answers.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use haply::HaplyDevice;
use haply::device_model::{Force, ForceInput, ServiceData};

use super::exchange::SeqCell;
use super::{CAUTERY_BUTTON, DeviceLimits, DeviceState, GRAB_BUTTON, HapticDevice, HapticError};
use crate::Vec3;

/// Where the service is and what the device may do.
#[derive(Debug, Clone, PartialEq)]
pub struct HaplyConfig {
    /// The service's HTTP address (Haply's default: `http://localhost:10001`).
    pub http_url: String,
    /// The service's WebSocket address (Haply's default: `ws://localhost:10001/`).
    pub ws_url: String,
    /// Which Inverse3 (its device id); `None`: the first one the service lists.
    pub device_id: Option<String>,
    /// Largest force sent, N. Conservative by default: set it to your device's continuous
    /// force rating.
    pub max_force: f64,
    /// Workspace in the service's frame, metres (used by the loop's mapping checks).
    pub workspace_min: Vec3,
    /// Upper corner of the workspace, metres.
    pub workspace_max: Vec3,
    /// How long to wait for the connection and the first state.
    pub connect_timeout: Duration,
    /// A state older than this stops the loop (the service or the cable went away).
    pub stale_after: Duration,
}

impl Default for HaplyConfig {
    fn default() -> Self {
        HaplyConfig {
            http_url: "http://localhost:10001".into(),
            ws_url: "ws://localhost:10001/".into(),
            device_id: None,
            max_force: 3.0,
            workspace_min: Vec3::repeat(-0.2),
            workspace_max: Vec3::repeat(0.2),
            connect_timeout: Duration::from_secs(5),
            stale_after: Duration::from_millis(250),
        }
    }
}

/// Words of the state cell: position (3), buttons.
const STATE_WORDS: usize = 4;

/// What the bridge thread shares with the device handle.
#[derive(Debug)]
struct Bridge {
    state: SeqCell<STATE_WORDS>,
    force: SeqCell<3>,
    stop: AtomicBool,
    failed: AtomicBool,
    error: std::sync::Mutex<String>,
}

impl Bridge {
    fn fail(&self, message: String) {
        if let Ok(mut e) = self.error.lock() {
            *e = message;
        }
        self.failed.store(true, Ordering::Release);
    }
}

/// A Haply Inverse3 through the Inverse Service (see the module docs).
#[derive(Debug)]
pub struct HaplyInverse3 {
    name: String,
    config: HaplyConfig,
    bridge: Arc<Bridge>,
    thread: Option<JoinHandle<()>>,
    last_writes: u64,
    last_fresh: Instant,
}

impl HaplyInverse3 {
    /// Connects to the service, picks the device and waits for its first state.
    ///
    /// Errors: a setting out of range ([`HapticError::BadConfig`]); no service at the
    /// address, no Inverse3, the named device missing or no state within
    /// `connect_timeout` ([`HapticError::Device`], naming the address).
    pub fn connect(config: HaplyConfig) -> Result<Self, HapticError> {
        if !(config.max_force.is_finite() && config.max_force > 0.0) {
            return Err(HapticError::BadConfig {
                what: "max_force",
                value: config.max_force,
                why: "a positive force in N",
            });
        }
        if config.stale_after.is_zero() {
            return Err(HapticError::BadConfig {
                what: "stale_after",
                value: 0.0,
                why: "a positive duration",
            });
        }
        let name = format!("Haply Inverse3 at {}", config.ws_url);
        let bridge = Arc::new(Bridge {
            state: SeqCell::new([0.0; STATE_WORDS]),
            force: SeqCell::new([0.0; 3]),
            stop: AtomicBool::new(false),
            failed: AtomicBool::new(false),
            error: std::sync::Mutex::new(String::new()),
        });
        let (ready_tx, ready_rx) = mpsc::channel::<Result<String, String>>();
        let thread = {
            let bridge = bridge.clone();
            let config = config.clone();
            std::thread::Builder::new()
                .name("haply-bridge".into())
                .spawn(move || run_bridge(&config, &bridge, ready_tx))
                .map_err(|e| HapticError::Thread(format!("starting the Haply bridge: {e}")))?
        };
        let device = |message: String| HapticError::Device {
            device: name.clone(),
            message,
        };
        match ready_rx.recv_timeout(config.connect_timeout) {
            Ok(Ok(id)) => Ok(HaplyInverse3 {
                name: format!("Haply Inverse3 {id} at {}", config.ws_url),
                config,
                bridge,
                thread: Some(thread),
                last_writes: 0,
                last_fresh: Instant::now(),
            }),
            Ok(Err(message)) => {
                let _ = thread.join();
                Err(device(message))
            }
            Err(_) => {
                bridge.stop.store(true, Ordering::Release);
                // The bridge may be stuck in a connect; it exits when that returns.
                Err(device(format!(
                    "no state within {:.1} s",
                    config.connect_timeout.as_secs_f64()
                )))
            }
        }
    }
}

/// The Inverse3 of `data` with `id` (or the first), its cursor and the handle's buttons.
fn extract(data: &ServiceData, id: Option<&str>) -> Option<(String, [f64; STATE_WORDS])> {
    let inv = match id {
        Some(id) => data.inverse3.iter().find(|d| d.device_id == id)?,
        None => data.inverse3.first()?,
    };
    let p = inv.state.cursor_position?;
    let mut buttons = 0u32;
    if let Some(b) = data
        .wireless_verse_grip
        .first()
        .and_then(|g| g.state.buttons)
    {
        if b.a {
            buttons |= GRAB_BUTTON;
        }
        if b.b {
            buttons |= CAUTERY_BUTTON;
        }
    } else if let Some(true) = data.verse_grip.first().and_then(|g| g.state.button) {
        buttons |= GRAB_BUTTON;
    }
    Some((
        inv.device_id.clone(),
        [
            f64::from(p.x),
            f64::from(p.y),
            f64::from(p.z),
            f64::from(buttons),
        ],
    ))
}

fn run_bridge(config: &HaplyConfig, bridge: &Bridge, ready: mpsc::Sender<Result<String, String>>) {
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            let _ = ready.send(Err(format!("starting the async runtime: {e}")));
            return;
        }
    };
    runtime.block_on(async {
        let mut device = match HaplyDevice::new(&config.http_url, &config.ws_url).await {
            Ok(d) => d,
            Err(e) => {
                let _ = ready.send(Err(format!("connecting to {}: {e}", config.http_url)));
                return;
            }
        };
        let mut id = None;
        let mut ready = Some(ready);
        let zero = Force {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        };
        while !bridge.stop.load(Ordering::Acquire) {
            let data = match device.read_state().await {
                Ok(d) => d,
                Err(e) => {
                    let message = format!("reading the state: {e}");
                    match ready.take() {
                        Some(r) => {
                            let _ = r.send(Err(message));
                        }
                        None => bridge.fail(message),
                    }
                    break;
                }
            };
            let Some((device_id, words)) = extract(&data, config.device_id.as_deref()) else {
                if ready.is_some() && !data.inverse3.is_empty() && config.device_id.is_some() {
                    let listed: Vec<&str> =
                        data.inverse3.iter().map(|d| d.device_id.as_str()).collect();
                    if let Some(r) = ready.take() {
                        let _ = r.send(Err(format!(
                            "no Inverse3 `{}` (the service lists {listed:?})",
                            config.device_id.as_deref().unwrap_or_default()
                        )));
                    }
                    break;
                }
                tokio::time::sleep(Duration::from_millis(1)).await;
                continue;
            };
            bridge.state.write(words);
            if let Some(r) = ready.take() {
                let _ = r.send(Ok(device_id.clone()));
            }
            let (f, _) = bridge.force.read();
            let forces = Force {
                x: f[0] as f32,
                y: f[1] as f32,
                z: f[2] as f32,
            };
            let sent = device
                .update_force(
                    vec![ForceInput {
                        device_id: device_id.clone(),
                        forces,
                    }],
                    Some(true),
                    Some(true),
                )
                .await;
            if let Err(e) = sent {
                bridge.fail(format!("sending the force: {e}"));
                break;
            }
            id = Some(device_id);
        }
        if let Some(device_id) = id {
            let _ = device
                .update_force(
                    vec![ForceInput {
                        device_id,
                        forces: zero,
                    }],
                    Some(true),
                    Some(true),
                )
                .await;
        }
        let _ = device.shutdown().await;
    });
}

impl HapticDevice for HaplyInverse3 {
    fn name(&self) -> &str {
        &self.name
    }

    fn limits(&self) -> DeviceLimits {
        DeviceLimits {
            workspace_min: self.config.workspace_min,
            workspace_max: self.config.workspace_max,
            max_force: self.config.max_force,
        }
    }

    fn read(&mut self, _time: f64) -> Result<DeviceState, HapticError> {
        if self.bridge.failed.load(Ordering::Acquire) {
            let message = self
                .bridge
                .error
                .lock()
                .map(|e| e.clone())
                .unwrap_or_else(|_| "the bridge failed".into());
            return Err(HapticError::Device {
                device: self.name.clone(),
                message,
            });
        }
        let (w, writes) = self.bridge.state.read();
        let now = Instant::now();
        if writes != self.last_writes {
            self.last_writes = writes;
            self.last_fresh = now;
        } else if now - self.last_fresh > self.config.stale_after {
            return Err(HapticError::Device {
                device: self.name.clone(),
                message: format!(
                    "no new state for {:.0} ms",
                    (now - self.last_fresh).as_secs_f64() * 1e3
                ),
            });
        }
        Ok(DeviceState {
            position: Vec3::new(w[0], w[1], w[2]),
            buttons: w[3] as u32,
        })
    }

    fn write_force(&mut self, force: Vec3) -> Result<(), HapticError> {
        let f = super::coupling::clamp(force, self.config.max_force);
        self.bridge.force.write([f.x, f.y, f.z]);
        Ok(())
    }
}

impl Drop for HaplyInverse3 {
    fn drop(&mut self) {
        self.bridge.force.write([0.0; 3]);
        self.bridge.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_service_is_a_typed_error_naming_the_address() {
        // Nothing listens on port 9 (discard) of the loopback here.
        let config = HaplyConfig {
            http_url: "http://127.0.0.1:9".into(),
            ws_url: "ws://127.0.0.1:9/".into(),
            connect_timeout: Duration::from_secs(10),
            ..HaplyConfig::default()
        };
        match HaplyInverse3::connect(config) {
            Err(HapticError::Device { device, message }) => {
                assert!(device.contains("ws://127.0.0.1:9/"), "{device}");
                assert!(!message.is_empty());
            }
            Err(e) => panic!("unexpected error {e}"),
            Ok(d) => panic!("connected to {}", d.name()),
        }
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        let bad = HaplyConfig {
            max_force: f64::NAN,
            ..HaplyConfig::default()
        };
        assert!(matches!(
            HaplyInverse3::connect(bad),
            Err(HapticError::BadConfig {
                what: "max_force",
                ..
            })
        ));
        let bad = HaplyConfig {
            stale_after: Duration::ZERO,
            ..HaplyConfig::default()
        };
        assert!(matches!(
            HaplyInverse3::connect(bad),
            Err(HapticError::BadConfig {
                what: "stale_after",
                ..
            })
        ));
    }

    #[test]
    fn state_is_read_from_the_first_or_the_named_inverse3_with_grip_buttons() {
        let json = r#"{
            "session_id": 1,
            "inverse3": [
                {"device_id": "A1", "state": {"cursor_position": {"x": 0.1, "y": 0.2, "z": 0.3},
                  "mode": "idle"},
                 "status": {"calibrated": true, "in_use": true, "power_supply": true,
                  "ready": true, "started": true}},
                {"device_id": "B2", "state": {"cursor_position": {"x": -0.1, "y": 0.0, "z": 0.05},
                  "mode": "idle"},
                 "status": {"calibrated": true, "in_use": true, "power_supply": true,
                  "ready": true, "started": true}}
            ],
            "wireless_verse_grip": [
                {"device_id": "G", "state": {"buttons": {"a": false, "b": true}},
                 "status": {"ready": true, "connected": true, "awake": true}}
            ]
        }"#;
        let data: ServiceData = match serde_json::from_str(json) {
            Ok(d) => d,
            Err(e) => panic!("the service's state format changed: {e}"),
        };
        let (id, w) = extract(&data, None).unwrap();
        assert_eq!(id, "A1");
        assert!((w[0] - 0.1).abs() < 1e-7 && (w[2] - 0.3).abs() < 1e-7);
        assert_eq!(w[3] as u32, CAUTERY_BUTTON);
        let (id, w) = extract(&data, Some("B2")).unwrap();
        assert_eq!(id, "B2");
        assert!((w[0] + 0.1).abs() < 1e-7);
        assert!(extract(&data, Some("C3")).is_none());
    }
}
