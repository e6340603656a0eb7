//! Step-time statistics. Real time is decided by the worst step, not the mean: every place
//! that reports timings (the `soft-tissue` benchmark, `simulate`, the report, the plugin's
//! inspector) gives the median, the 99th percentile and the largest of the whole step and of
//! each stage, from these types.
//!
//! Percentiles are nearest-rank: the `q` quantile of `n` sorted samples is the sample of rank
//! `ceil(q n)` (so the 99th percentile of 100 samples is the 99th smallest, and the maximum is
//! the 100th).

use serde::{Deserialize, Serialize};

/// Wall time of each stage of one step, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    /// The cut stage: the bodies cutting blades crossed since the last step, cut and
    /// rebuilt (next to nothing when no blade cuts).
    pub cut_us: f64,
    /// `prepare`: tool velocities, surfaces gathered.
    pub prepare_us: f64,
    /// `detect_contacts`: who is touched at the start of the step.
    pub detect_us: f64,
    /// `switch_precision`.
    pub switch_us: f64,
    /// `step_solvers`: every body's free motion (its own step) and heat.
    pub solve_us: f64,
    /// The contact problem of `solve_contacts`: detection on the moved positions, assembly
    /// of the bodies' compliances and the projected Gauss-Seidel solve, all rounds.
    pub contact_us: f64,
    /// The bodies' corrections by the contact forces in `solve_contacts` (each body's own
    /// solve), all rounds.
    pub correct_us: f64,
    /// `writeback`.
    pub writeback_us: f64,
    /// Of `cut_us`, the time the step waited for cuts prepared in the background to be done
    /// (or prepared them, where their thread had not started), all landings of the step,
    /// whatever they came to. Not a stage of its own: not in [`StageTimes::values`].
    #[serde(default)]
    pub cut_wait_us: f64,
}

impl StageTimes {
    /// Stage names, in the order of [`StageTimes::values`].
    pub const NAMES: [&'static str; 8] = [
        "cut",
        "prepare",
        "detect",
        "switch",
        "solve",
        "contact",
        "correct",
        "writeback",
    ];

    /// Sum of the stages.
    pub fn total_us(&self) -> f64 {
        self.values().iter().sum()
    }

    /// The stages in the order of [`StageTimes::NAMES`].
    pub fn values(&self) -> [f64; 8] {
        [
            self.cut_us,
            self.prepare_us,
            self.detect_us,
            self.switch_us,
            self.solve_us,
            self.contact_us,
            self.correct_us,
            self.writeback_us,
        ]
    }

    /// Contact: the detection at the start of the step and the contact problem (detection
    /// after the motion, assembly, solve).
    pub fn contact_total_us(&self) -> f64 {
        self.detect_us + self.contact_us
    }

    /// The solvers: the bodies' free motion and their contact corrections (both are the
    /// bodies' own solves).
    pub fn solvers_us(&self) -> f64 {
        self.solve_us + self.correct_us
    }
}

/// Median, 99th percentile, largest and mean of a set of durations, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeStats {
    /// Number of samples.
    pub count: usize,
    /// Smallest.
    pub min_us: f64,
    /// Median (nearest rank).
    pub median_us: f64,
    /// 99th percentile (nearest rank).
    pub p99_us: f64,
    /// Largest.
    pub max_us: f64,
    /// Mean.
    pub mean_us: f64,
}

/// The `q` quantile of sorted samples, nearest rank (`q` in [0, 1]).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

impl TimeStats {
    /// Statistics of `samples` (any order; not-a-number samples sort last). All zero when
    /// there are none.
    pub fn of(samples: &[f64]) -> Self {
        let mut sorted = samples.to_vec();
        Self::of_sorted_in_place(&mut sorted)
    }

    /// Statistics of `samples`, sorting them in place (no copy).
    pub fn of_sorted_in_place(samples: &mut [f64]) -> Self {
        samples.sort_by(f64::total_cmp);
        let count = samples.len();
        if count == 0 {
            return TimeStats::default();
        }
        TimeStats {
            count,
            min_us: samples[0],
            median_us: quantile(samples, 0.5),
            p99_us: quantile(samples, 0.99),
            max_us: samples[count - 1],
            mean_us: samples.iter().sum::<f64>() / count as f64,
        }
    }

    /// Samples above `budget_us`, from the sorted samples `of` was given (for
    /// [`StageRecorder::over_budget`]).
    fn over(sorted: &[f64], budget_us: f64) -> usize {
        sorted.len() - sorted.partition_point(|&x| x <= budget_us)
    }
}

/// Statistics of the whole step and of each stage over a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageStats {
    /// The whole step.
    pub step: TimeStats,
    /// Each stage, in the order of [`StageTimes::NAMES`].
    pub stages: [TimeStats; 8],
}

impl StageStats {
    /// The statistics of the stage named `name` (see [`StageTimes::NAMES`]).
    pub fn stage(&self, name: &str) -> Option<&TimeStats> {
        StageTimes::NAMES
            .iter()
            .position(|&n| n == name)
            .map(|k| &self.stages[k])
    }
}

/// Records the stage times of every step of a run (or of the last `window` steps) and
/// summarises them on request: recording costs a push per stage, the sorting happens only
/// when someone asks.
#[derive(Debug, Clone, Default)]
pub struct StageRecorder {
    whole: Vec<f64>,
    stages: [Vec<f64>; 8],
    window: Option<usize>,
    next: usize,
}

impl StageRecorder {
    /// Keeps every step; room for `capacity` steps is reserved.
    pub fn with_capacity(capacity: usize) -> Self {
        StageRecorder {
            whole: Vec::with_capacity(capacity),
            stages: std::array::from_fn(|_| Vec::with_capacity(capacity)),
            window: None,
            next: 0,
        }
    }

    /// Keeps the last `window` steps (at least one) in a ring, for a live display.
    pub fn windowed(window: usize) -> Self {
        let mut r = Self::with_capacity(window.max(1));
        r.window = Some(window.max(1));
        r
    }

    /// Records one step.
    pub fn push(&mut self, times: &StageTimes) {
        let values = times.values();
        match self.window {
            Some(w) if self.whole.len() == w => {
                let k = self.next;
                self.whole[k] = times.total_us();
                for (s, v) in self.stages.iter_mut().zip(values) {
                    s[k] = v;
                }
                self.next = (k + 1) % w;
            }
            _ => {
                self.whole.push(times.total_us());
                for (s, v) in self.stages.iter_mut().zip(values) {
                    s.push(v);
                }
            }
        }
    }

    /// Steps recorded (at most the window).
    pub fn len(&self) -> usize {
        self.whole.len()
    }

    /// Whether nothing was recorded.
    pub fn is_empty(&self) -> bool {
        self.whole.is_empty()
    }

    /// Forgets every step.
    pub fn clear(&mut self) {
        self.whole.clear();
        for s in &mut self.stages {
            s.clear();
        }
        self.next = 0;
    }

    /// Whole-step times as recorded (ring order when windowed).
    pub fn whole_steps(&self) -> &[f64] {
        &self.whole
    }

    /// Statistics of the recorded steps (allocates: call it to report, not in a step).
    pub fn summary(&self) -> StageStats {
        StageStats {
            step: TimeStats::of(&self.whole),
            stages: std::array::from_fn(|k| TimeStats::of(&self.stages[k])),
        }
    }

    /// Steps whose whole time exceeded `budget_us`.
    pub fn over_budget(&self, budget_us: f64) -> usize {
        let mut sorted = self.whole.clone();
        sorted.sort_by(f64::total_cmp);
        TimeStats::over(&sorted, budget_us)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_quantiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = TimeStats::of(&v);
        assert_eq!(
            (s.min_us, s.median_us, s.p99_us, s.max_us),
            (1.0, 50.0, 99.0, 100.0)
        );
        assert_eq!(s.mean_us, 50.5);
        let s = TimeStats::of(&[3.0]);
        assert_eq!((s.median_us, s.p99_us, s.max_us), (3.0, 3.0, 3.0));
        assert_eq!(TimeStats::of(&[]), TimeStats::default());
        // One slow step in 1000 is above the 99th percentile, not below.
        let mut v = vec![1.0; 999];
        v.push(50.0);
        let s = TimeStats::of(&v);
        assert_eq!((s.p99_us, s.max_us), (1.0, 50.0));
    }

    #[test]
    fn the_recorder_summarises_stages_and_keeps_a_window() {
        let mut r = StageRecorder::windowed(3);
        for k in 1..=5 {
            let k = f64::from(k);
            r.push(&StageTimes {
                detect_us: k,
                solve_us: 10.0 * k,
                ..StageTimes::default()
            });
        }
        assert_eq!(r.len(), 3);
        let s = r.summary();
        // Steps 3, 4, 5 are left.
        assert_eq!(s.stage("detect").unwrap().min_us, 3.0);
        assert_eq!(s.stage("solve").unwrap().max_us, 50.0);
        assert_eq!(s.step.median_us, 44.0);
        assert_eq!(r.over_budget(40.0), 2);
        assert!(s.stage("nothing").is_none());
    }
}
