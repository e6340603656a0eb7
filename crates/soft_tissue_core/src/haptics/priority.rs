//! The scheduling priority of the haptic thread: what it asks for ([`HapticPriority`]) and
//! what the OS gave it ([`PriorityOutcome`]).
//!
//! A 1 kHz loop on a busy machine is late whenever the scheduler runs something else at its
//! deadline; under a real-time policy (Linux `SCHED_FIFO`) the thread preempts every
//! time-sharing thread as soon as its sleep ends. The request is applied inside the haptic
//! thread as it starts, so only that thread is raised: the physics (the thread that spawned
//! it, and the rayon workers it starts) stays at the normal policy. A refused request never
//! stops the loop: it falls back to the lowest nice value the OS allows, else to normal, and
//! the outcome says which and why.

use std::fmt;

/// The real-time level asked for by default: above the threaded interrupt handlers of a
/// PREEMPT_RT kernel (50) and below the kernel's own watchdog and migration threads (99).
pub const DEFAULT_REALTIME_LEVEL: u8 = 80;

/// Nice values tried, in order, when real time is refused (lower runs first; 0 is the
/// default). Unprivileged Linux processes may lower their nice value down to
/// `20 - RLIMIT_NICE`.
const FALLBACK_NICE: [i32; 3] = [-20, -10, -5];

/// The scheduling the haptic thread asks for when it starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HapticPriority {
    /// A real-time first-in-first-out policy (`SCHED_FIFO` on Linux and other Unixes) at this
    /// level, 1 to 99 (higher runs first). On Windows: the highest thread priority of the
    /// normal class. Needs a privilege on Linux (`CAP_SYS_NICE`, or an `RLIMIT_RTPRIO` of at
    /// least the level, e.g. `@audio - rtprio 95` in `/etc/security/limits.conf`); when the OS
    /// refuses, the thread takes the lowest nice value it may (-20, -10 or -5) or stays normal,
    /// and the outcome states the refusal.
    RealTime(u8),
    /// Leave the thread at the normal time-sharing policy it was started with (the same as
    /// the physics thread).
    Normal,
}

impl Default for HapticPriority {
    /// Real time at [`DEFAULT_REALTIME_LEVEL`] where the OS allows it.
    fn default() -> Self {
        HapticPriority::RealTime(DEFAULT_REALTIME_LEVEL)
    }
}

impl HapticPriority {
    /// Whether the level is one the setting accepts (1 to 99).
    pub fn is_valid(&self) -> bool {
        match *self {
            HapticPriority::RealTime(level) => (1..=99).contains(&level),
            HapticPriority::Normal => true,
        }
    }
}

impl fmt::Display for HapticPriority {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HapticPriority::RealTime(level) => write!(f, "real time {level}"),
            HapticPriority::Normal => write!(f, "normal"),
        }
    }
}

/// The scheduling a thread runs under, as read back from the OS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Scheduling {
    /// A real-time policy (`SCHED_FIFO`, `SCHED_RR`) at a static priority.
    RealTime {
        /// The policy's POSIX name.
        policy: &'static str,
        /// Its static priority.
        level: i32,
    },
    /// A time-sharing policy (`SCHED_OTHER`, `SCHED_BATCH`, `SCHED_IDLE`).
    TimeSharing {
        /// The policy's POSIX name.
        policy: &'static str,
        /// The thread's nice value, where the OS reports it (Linux).
        nice: Option<i32>,
    },
    /// What the OS reports in its own terms (Windows thread priorities, `SCHED_DEADLINE`),
    /// or why it could not be read.
    Other(String),
}

impl Scheduling {
    /// Whether this is a real-time policy.
    pub fn is_real_time(&self) -> bool {
        matches!(self, Scheduling::RealTime { .. })
    }
}

impl fmt::Display for Scheduling {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Scheduling::RealTime { policy, level } => write!(f, "{policy} priority {level}"),
            Scheduling::TimeSharing {
                policy,
                nice: Some(n),
            } => write!(f, "{policy} nice {n}"),
            Scheduling::TimeSharing { policy, nice: None } => write!(f, "{policy}"),
            Scheduling::Other(s) => f.write_str(s),
        }
    }
}

/// What the haptic thread asked for and what it got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PriorityOutcome {
    /// The request (from [`super::HapticConfig::priority`]).
    pub requested: HapticPriority,
    /// The scheduling the thread runs under, read back from the OS after the request.
    pub obtained: Scheduling,
    /// Why the request was not granted as asked: the OS's answer to each refused attempt.
    /// `None` when it was granted (or nothing was asked).
    pub refused: Option<String>,
}

impl PriorityOutcome {
    /// Whether the thread got the real-time policy it asked for.
    pub fn is_real_time(&self) -> bool {
        self.obtained.is_real_time()
    }
}

impl fmt::Display for PriorityOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (asked {})", self.obtained, self.requested)?;
        if let Some(why) = &self.refused {
            write!(f, "; refused: {why}")?;
        }
        Ok(())
    }
}

/// The OS calls [`apply_with`] makes; separate so that the fallback can be tested with an
/// OS that refuses.
pub(crate) trait PriorityOs {
    /// Puts the calling thread under the real-time FIFO policy at `level`.
    fn set_real_time(&mut self, level: u8) -> Result<(), String>;
    /// Sets the calling thread's nice value (normal policy).
    fn set_nice(&mut self, nice: i32) -> Result<(), String>;
    /// The calling thread's scheduling.
    fn read(&self) -> Scheduling;
}

/// Lowers the calling thread to nice 10, for work beside the steps (a cut prepared in the
/// background) that should yield a core to the physics and the haptic loop but still get a
/// share of it (an idle-policy thread may get none while a step waits for it, and an
/// unprivileged process cannot raise it again). `Err` says why not.
pub(crate) fn background() -> Result<(), String> {
    SystemOs.set_nice(BACKGROUND_NICE)
}

/// The nice value of [`background`] work.
pub(crate) const BACKGROUND_NICE: i32 = 10;

/// Applies `request` to the calling thread and reads back what it got.
pub(crate) fn apply(request: HapticPriority) -> PriorityOutcome {
    apply_with(request, &mut SystemOs)
}

/// The calling thread's scheduling.
#[cfg(test)]
pub(crate) fn current() -> Scheduling {
    SystemOs.read()
}

pub(crate) fn apply_with(request: HapticPriority, os: &mut dyn PriorityOs) -> PriorityOutcome {
    let level = match request {
        HapticPriority::Normal => {
            return PriorityOutcome {
                requested: request,
                obtained: os.read(),
                refused: None,
            };
        }
        HapticPriority::RealTime(level) => level,
    };
    let mut refusals = Vec::new();
    match os.set_real_time(level) {
        Ok(()) => {}
        Err(e) => {
            refusals.push(format!("real time {level}: {e}"));
            for nice in FALLBACK_NICE {
                match os.set_nice(nice) {
                    Ok(()) => break,
                    Err(e) => refusals.push(format!("nice {nice}: {e}")),
                }
            }
        }
    }
    let obtained = os.read();
    // Off Unix the request is the OS's highest thread priority, which reads back in its own
    // terms: granted when the call succeeded.
    let granted = matches!(obtained, Scheduling::RealTime { level: l, .. } if l == i32::from(level))
        || (cfg!(not(unix)) && refusals.is_empty());
    if !granted && refusals.is_empty() {
        refusals.push(format!("the OS reports {obtained} after the request"));
    }
    PriorityOutcome {
        requested: request,
        obtained,
        refused: (!refusals.is_empty()).then(|| refusals.join("; ")),
    }
}

/// The OS through the `thread-priority` crate.
struct SystemOs;

#[cfg(unix)]
fn os_text(e: thread_priority::Error) -> String {
    match e {
        thread_priority::Error::OS(code) => std::io::Error::from_raw_os_error(code).to_string(),
        other => other.to_string(),
    }
}

#[cfg(unix)]
impl PriorityOs for SystemOs {
    fn set_real_time(&mut self, level: u8) -> Result<(), String> {
        use thread_priority::{
            RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue,
            ThreadSchedulePolicy, set_thread_priority_and_policy, thread_native_id,
        };
        let value = ThreadPriorityValue::try_from(level).map_err(|e| e.to_string())?;
        set_thread_priority_and_policy(
            thread_native_id(),
            ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
        )
        .map_err(os_text)
    }

    fn set_nice(&mut self, nice: i32) -> Result<(), String> {
        use thread_priority::{
            NormalThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
            set_thread_priority_and_policy, thread_native_id,
        };
        // The crate takes nice values as a 0..=99 scale (99: nice -20); find the value that
        // maps onto `nice` with its formula, trunc(39 * (1 - p / 99)) - 20.
        let value = (0u8..=99)
            .rev()
            .find(|&p| (39.0 * (1.0 - f32::from(p) / 99.0)) as i32 - 20 == nice)
            .ok_or_else(|| format!("nice {nice} has no thread-priority value"))?;
        let value = ThreadPriorityValue::try_from(value).map_err(|e| e.to_string())?;
        set_thread_priority_and_policy(
            thread_native_id(),
            ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Other),
        )
        .map_err(os_text)
    }

    fn read(&self) -> Scheduling {
        use thread_priority::{
            NormalThreadSchedulePolicy as N, RealtimeThreadSchedulePolicy as R,
            ThreadSchedulePolicy as P, thread_native_id, thread_schedule_policy_param,
        };
        match thread_schedule_policy_param(thread_native_id()) {
            Ok((P::Realtime(policy), params)) => {
                let policy = match policy {
                    R::Fifo => "SCHED_FIFO",
                    R::RoundRobin => "SCHED_RR",
                    #[cfg(all(
                        any(target_os = "linux", target_os = "android"),
                        not(target_arch = "wasm32")
                    ))]
                    R::Deadline => return Scheduling::Other("SCHED_DEADLINE".into()),
                    #[cfg(target_os = "vxworks")]
                    R::Sporadic => return Scheduling::Other("SCHED_SPORADIC".into()),
                };
                Scheduling::RealTime {
                    policy,
                    level: params.sched_priority,
                }
            }
            Ok((P::Normal(policy), _)) => Scheduling::TimeSharing {
                policy: match policy {
                    N::Other => "SCHED_OTHER",
                    #[cfg(any(target_os = "linux", target_os = "android"))]
                    N::Batch => "SCHED_BATCH",
                    #[cfg(any(target_os = "linux", target_os = "android"))]
                    N::Idle => "SCHED_IDLE",
                },
                nice: current_nice(),
            },
            Err(e) => Scheduling::Other(format!("unknown ({})", os_text(e))),
        }
    }
}

/// The calling thread's nice value: field 19 of `/proc/thread-self/stat` (the fields after
/// the parenthesised command name, which may itself hold spaces).
#[cfg(unix)]
fn current_nice() -> Option<i32> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    let after_name = stat.get(stat.rfind(')')? + 1..)?;
    // Fields from the third (state) on; nice is the nineteenth.
    after_name.split_whitespace().nth(16)?.parse().ok()
}

#[cfg(not(unix))]
impl PriorityOs for SystemOs {
    fn set_real_time(&mut self, _level: u8) -> Result<(), String> {
        thread_priority::ThreadPriority::Max
            .set_for_current()
            .map_err(|e| e.to_string())
    }

    fn set_nice(&mut self, nice: i32) -> Result<(), String> {
        Err(format!("no nice value {nice} on this OS"))
    }

    fn read(&self) -> Scheduling {
        match thread_priority::get_current_thread_priority() {
            Ok(p) => Scheduling::Other(format!("thread priority {p:?}")),
            Err(e) => Scheduling::Other(format!("unknown ({e})")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An OS that refuses real time, and nice values below `floor`.
    struct Refusing {
        floor: i32,
        nice: i32,
        fifo_calls: u32,
    }

    impl PriorityOs for Refusing {
        fn set_real_time(&mut self, _level: u8) -> Result<(), String> {
            self.fifo_calls += 1;
            Err("Operation not permitted (os error 1)".into())
        }
        fn set_nice(&mut self, nice: i32) -> Result<(), String> {
            if nice < self.floor {
                Err("Permission denied (os error 13)".into())
            } else {
                self.nice = nice;
                Ok(())
            }
        }
        fn read(&self) -> Scheduling {
            Scheduling::TimeSharing {
                policy: "SCHED_OTHER",
                nice: Some(self.nice),
            }
        }
    }

    #[test]
    fn a_refused_request_falls_back_to_the_lowest_nice_allowed_and_says_why() {
        let mut os = Refusing {
            floor: -10,
            nice: 0,
            fifo_calls: 0,
        };
        let out = apply_with(HapticPriority::RealTime(80), &mut os);
        assert_eq!(os.fifo_calls, 1);
        assert_eq!(
            out.obtained,
            Scheduling::TimeSharing {
                policy: "SCHED_OTHER",
                nice: Some(-10)
            }
        );
        assert!(!out.is_real_time());
        let why = out.refused.as_deref().unwrap();
        assert!(
            why.contains("real time 80: Operation not permitted"),
            "{why}"
        );
        assert!(why.contains("nice -20: Permission denied"), "{why}");
        assert!(!why.contains("nice -10"), "{why}");
        let text = out.to_string();
        assert!(
            text.starts_with("SCHED_OTHER nice -10 (asked real time 80)"),
            "{text}"
        );
    }

    #[test]
    fn with_nothing_allowed_the_thread_stays_normal_and_lists_every_refusal() {
        let mut os = Refusing {
            floor: 0,
            nice: 0,
            fifo_calls: 0,
        };
        let out = apply_with(HapticPriority::RealTime(10), &mut os);
        assert_eq!(
            out.obtained,
            Scheduling::TimeSharing {
                policy: "SCHED_OTHER",
                nice: Some(0)
            }
        );
        let why = out.refused.unwrap();
        for attempt in ["real time 10", "nice -20", "nice -10", "nice -5"] {
            assert!(why.contains(attempt), "{attempt} missing from {why}");
        }
    }

    #[test]
    fn normal_asks_nothing_of_the_os() {
        let mut os = Refusing {
            floor: 0,
            nice: 3,
            fifo_calls: 0,
        };
        let out = apply_with(HapticPriority::Normal, &mut os);
        assert_eq!(os.fifo_calls, 0);
        assert_eq!(out.refused, None);
        assert_eq!(
            out.obtained,
            Scheduling::TimeSharing {
                policy: "SCHED_OTHER",
                nice: Some(3)
            }
        );
    }

    #[test]
    fn levels_outside_1_to_99_are_not_valid() {
        assert!(!HapticPriority::RealTime(0).is_valid());
        assert!(!HapticPriority::RealTime(100).is_valid());
        assert!(HapticPriority::RealTime(1).is_valid());
        assert!(HapticPriority::RealTime(99).is_valid());
        assert!(HapticPriority::Normal.is_valid());
        assert_eq!(
            HapticPriority::default(),
            HapticPriority::RealTime(DEFAULT_REALTIME_LEVEL)
        );
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn the_nice_value_is_read_from_proc() {
        // This test thread runs at the process's nice value (0 unless started under `nice`).
        let n = current_nice().expect("/proc/thread-self/stat has a nice field");
        assert!((-20..=19).contains(&n), "{n}");
    }
}
