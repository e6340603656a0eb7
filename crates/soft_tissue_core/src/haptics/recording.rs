//! Recorded sessions: every device sample (time, position, buttons) of a haptic loop, saved as
//! RON, replayed exactly by [`super::ReplayDevice`], convertible to and from world scripts.

use std::path::Path;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::contact::ToolShape;
use crate::world::{Script, ScriptAction, ScriptEvent, Waypoint};

/// Button bit of the main button (grab).
pub const GRAB_BUTTON: u32 = 1;
/// Button bit of the second button (cautery).
pub const CAUTERY_BUTTON: u32 = 2;

/// Button bit: a grasper's jaws closed (released: open).
pub const JAWS_BUTTON: u32 = 4;

/// Button bit: a blade cuts (released: it does not).
pub const CUT_BUTTON: u32 = 8;

/// Most samples [`Recording::from_script`] makes (a day at 1 kHz is fewer).
pub const MAX_RECORDING_SAMPLES: usize = 100_000_000;

/// One device sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RecordedSample {
    /// Time since the session started, s.
    pub t: f64,
    /// Device position, scene units.
    pub position: [f64; 3],
    /// Button bits ([`GRAB_BUTTON`], [`CAUTERY_BUTTON`]).
    pub buttons: u32,
}

/// A recorded session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recording {
    /// Rate it was recorded at, Hz.
    pub rate_hz: f64,
    /// Samples in increasing time.
    pub samples: Vec<RecordedSample>,
    /// Whether recording stopped early because its buffer was full.
    pub truncated: bool,
}

/// A recording that cannot be read, written or used.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RecordingError {
    /// Reading or writing the file failed.
    #[error("{path}: {message}")]
    Io {
        /// File.
        path: String,
        /// What failed.
        message: String,
    },
    /// The file is not a recording.
    #[error("{path}: not a recording: {message}")]
    Parse {
        /// File.
        path: String,
        /// Parser message with position.
        message: String,
    },
    /// No samples.
    #[error("the recording has no samples")]
    Empty,
    /// A sampling rate that is not positive and finite.
    #[error("recording rate {rate_hz} Hz must be positive and finite")]
    BadRate {
        /// The rate, Hz.
        rate_hz: f64,
    },
    /// Sampling a script would take more than [`MAX_RECORDING_SAMPLES`] samples.
    #[error(
        "a recording of {seconds} s at {rate_hz} Hz would exceed {} samples",
        MAX_RECORDING_SAMPLES
    )]
    TooLong {
        /// Duration, s.
        seconds: f64,
        /// Rate, Hz.
        rate_hz: f64,
    },
    /// A sample is unusable.
    #[error("recording sample {sample}: {message}")]
    BadSample {
        /// Sample index.
        sample: usize,
        /// What is wrong.
        message: &'static str,
    },
}

impl Recording {
    /// An empty recording at `rate_hz` with room for `seconds` of samples (allocated now, so
    /// recording in the haptic loop never allocates).
    pub fn with_capacity(rate_hz: f64, seconds: f64) -> Self {
        let n = (rate_hz * seconds).clamp(0.0, 1e8).ceil() as usize;
        Recording {
            rate_hz,
            samples: Vec::with_capacity(n),
            truncated: false,
        }
    }

    /// Appends a sample if there is room (never reallocates); marks the recording truncated
    /// otherwise.
    pub fn push(&mut self, sample: RecordedSample) {
        if self.samples.len() < self.samples.capacity() {
            self.samples.push(sample);
        } else {
            self.truncated = true;
        }
    }

    /// Checks that there are samples, in increasing time, with finite numbers.
    pub fn validate(&self) -> Result<(), RecordingError> {
        if self.samples.is_empty() {
            return Err(RecordingError::Empty);
        }
        for (i, s) in self.samples.iter().enumerate() {
            if !s.t.is_finite() || !s.position.iter().all(|c| c.is_finite()) {
                return Err(RecordingError::BadSample {
                    sample: i,
                    message: "non-finite time or position",
                });
            }
            if i > 0 && s.t <= self.samples[i - 1].t {
                return Err(RecordingError::BadSample {
                    sample: i,
                    message: "time does not increase",
                });
            }
        }
        Ok(())
    }

    /// Writes the recording as RON.
    pub fn save(&self, path: &Path) -> Result<(), RecordingError> {
        let text =
            ron::ser::to_string_pretty(self, ron::ser::PrettyConfig::default()).map_err(|e| {
                RecordingError::Io {
                    path: path.display().to_string(),
                    message: e.to_string(),
                }
            })?;
        std::fs::write(path, text).map_err(|e| RecordingError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// Reads and validates a RON recording.
    pub fn load(path: &Path) -> Result<Self, RecordingError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| RecordingError::Io {
            path: name.clone(),
            message: e.to_string(),
        })?;
        Self::from_ron(&text, &name)
    }

    /// Parses and validates a RON recording; `name` names it in messages.
    pub fn from_ron(text: &str, name: &str) -> Result<Self, RecordingError> {
        let r: Recording = ron::from_str(text).map_err(|e| RecordingError::Parse {
            path: name.to_owned(),
            message: e.to_string(),
        })?;
        r.validate()?;
        Ok(r)
    }

    /// Samples `script` at `rate_hz` over its duration plus `tail` seconds: positions from its
    /// path, buttons from its actions (grab sets [`GRAB_BUTTON`], release clears it, a
    /// cautery power above zero sets [`CAUTERY_BUTTON`]). A rate that is not positive and
    /// finite, or more than [`MAX_RECORDING_SAMPLES`] samples (a script ending far in the future), is an
    /// error.
    pub fn from_script(script: &Script, rate_hz: f64, tail: f64) -> Result<Self, RecordingError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(RecordingError::BadRate { rate_hz });
        }
        let end = script.end_time() + tail.max(0.0);
        let count = (end * rate_hz).floor();
        if !(count.is_finite() && count < MAX_RECORDING_SAMPLES as f64) {
            return Err(RecordingError::TooLong {
                seconds: end,
                rate_hz,
            });
        }
        let n = count.max(0.0) as usize + 1;
        let mut r = Recording {
            rate_hz,
            samples: Vec::with_capacity(n),
            truncated: false,
        };
        let mut buttons = 0u32;
        let mut next_event = 0;
        // A blade grabs nothing (its first button cuts when played on a device).
        let blade = matches!(script.tool, ToolShape::Blade { .. });
        for k in 0..n {
            let t = k as f64 / rate_hz;
            while next_event < script.events.len() && script.events[next_event].t <= t {
                match script.events[next_event].action {
                    ScriptAction::Grab | ScriptAction::Release if blade => {}
                    ScriptAction::Grab => buttons |= GRAB_BUTTON,
                    ScriptAction::Release => buttons &= !GRAB_BUTTON,
                    ScriptAction::Cautery(w) if w > 0.0 => buttons |= CAUTERY_BUTTON,
                    ScriptAction::Cautery(_) => buttons &= !CAUTERY_BUTTON,
                    ScriptAction::Jaws(w) if w <= 0.0 => buttons |= JAWS_BUTTON,
                    ScriptAction::Jaws(_) => buttons &= !JAWS_BUTTON,
                    ScriptAction::Cut(true) => buttons |= CUT_BUTTON,
                    ScriptAction::Cut(false) => buttons &= !CUT_BUTTON,
                }
                next_event += 1;
            }
            let (p, _) = script.pose_at(t);
            r.samples.push(RecordedSample {
                t,
                position: [p.x, p.y, p.z],
                buttons,
            });
        }
        Ok(r)
    }

    /// A world script of this session: a waypoint every `every` samples (and the last),
    /// with a fixed tool `axis`, and an action at every button change (cautery at
    /// `cautery_watts`), for `soft-tissue simulate --script`.
    pub fn to_script(
        &self,
        name: &str,
        tool: ToolShape,
        axis: [f64; 3],
        cautery_watts: f64,
        every: usize,
    ) -> Script {
        let every = every.max(1);
        let n = self.samples.len();
        let mut waypoints = Vec::with_capacity(n / every + 2);
        let mut events = Vec::new();
        let mut last_buttons = 0u32;
        for (i, s) in self.samples.iter().enumerate() {
            if i % every == 0 || i + 1 == n {
                waypoints.push(Waypoint {
                    t: s.t,
                    position: s.position,
                    axis,
                    roll_deg: 0.0,
                });
            }
            let changed = s.buttons ^ last_buttons;
            // A blade cuts with the first button (as the plugin's haptic tool does) or the
            // cut button; it grabs nothing.
            let blade = matches!(tool, ToolShape::Blade { .. });
            let cutting = |b: u32| b & (GRAB_BUTTON | CUT_BUTTON) != 0;
            if blade && cutting(s.buttons) != cutting(last_buttons) {
                events.push(ScriptEvent {
                    t: s.t,
                    action: ScriptAction::Cut(cutting(s.buttons)),
                });
            }
            if changed & GRAB_BUTTON != 0 && !blade {
                events.push(ScriptEvent {
                    t: s.t,
                    action: if s.buttons & GRAB_BUTTON != 0 {
                        ScriptAction::Grab
                    } else {
                        ScriptAction::Release
                    },
                });
            }
            if changed & CAUTERY_BUTTON != 0 {
                let w = if s.buttons & CAUTERY_BUTTON != 0 {
                    cautery_watts
                } else {
                    0.0
                };
                events.push(ScriptEvent {
                    t: s.t,
                    action: ScriptAction::Cautery(w),
                });
            }
            if let (true, ToolShape::Grasper { max_opening, .. }) =
                (changed & JAWS_BUTTON != 0, tool)
            {
                events.push(ScriptEvent {
                    t: s.t,
                    action: ScriptAction::Jaws(if s.buttons & JAWS_BUTTON != 0 {
                        0.0
                    } else {
                        max_opening
                    }),
                });
            }
            last_buttons = s.buttons;
        }
        Script {
            name: name.to_owned(),
            tool,
            waypoints,
            events,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCRIPT: &str = "(name: \"poke\", tool: Sphere(radius: 0.5), \
        waypoints: [(t: 0.0, position: (0.0, 1.0, 0.0), axis: (0.0, 1.0, 0.0)), \
                    (t: T_END, position: (0.0, 0.0, 0.0), axis: (0.0, 1.0, 0.0))], \
        events: [(t: 0.1, action: Grab), (t: 0.2, action: Cautery(30.0)), \
                 (t: 0.3, action: Release), (t: 0.4, action: Cautery(0.0))])";

    fn script(end: &str) -> Script {
        Script::from_ron(&SCRIPT.replace("T_END", end), "poke.ron").unwrap()
    }

    #[test]
    fn a_sampled_script_round_trips_through_ron() {
        let r = Recording::from_script(&script("0.5"), 100.0, 0.1).unwrap();
        assert_eq!(r.samples.len(), 61);
        assert_eq!(r.samples[25].buttons, GRAB_BUTTON | CAUTERY_BUTTON);
        assert_eq!(r.samples[45].buttons, 0);
        let text = ron::ser::to_string(&r).unwrap();
        assert_eq!(Recording::from_ron(&text, "r.ron").unwrap(), r);
    }

    #[test]
    fn a_script_ending_far_away_or_a_bad_rate_is_an_error_not_a_panic() {
        // Once a panic (the sample count overflowed) or an allocation of exabytes.
        for end in ["1e20", "1e300", "2e5"] {
            let e = Recording::from_script(&script(end), 1000.0, 1.0).unwrap_err();
            assert!(matches!(e, RecordingError::TooLong { .. }), "{e}");
            assert!(e.to_string().contains("would exceed"), "{e}");
        }
        for rate in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = Recording::from_script(&script("0.5"), rate, 1.0).unwrap_err();
            assert!(matches!(e, RecordingError::BadRate { .. }), "{e}");
        }
    }

    #[test]
    fn unreadable_recordings_are_typed_errors_naming_the_file() {
        let e = Recording::from_ron("(rate_hz: 1000.0, samples: [", "r.ron").unwrap_err();
        assert!(matches!(e, RecordingError::Parse { .. }), "{e}");
        assert!(e.to_string().starts_with("r.ron: not a recording"), "{e}");
        let e = Recording::from_ron(
            "(rate_hz: 1000.0, truncated: false, samples: [\
             (t: 0.0, position: (0.0, 0.0, 0.0), buttons: 0),\
             (t: 0.0, position: (0.0, 0.0, 0.0), buttons: 0)])",
            "r.ron",
        )
        .unwrap_err();
        assert_eq!(
            e,
            RecordingError::BadSample {
                sample: 1,
                message: "time does not increase"
            }
        );
    }
}
