//! What a run's steps cost, for `simulate` and the report: the whole step and each stage
//! (median, 99th percentile, largest), the steps where some body is precise, each body's
//! precise steps and its up- and down-switch steps against them, contact against the solvers,
//! and the steps over a budget.

use serde::Serialize;
use soft_tissue_core::precision::Level;
use soft_tissue_core::timing::{StageRecorder, StageTimes, TimeStats};
use soft_tissue_core::world::SoftTissueWorld;

/// One body's step costs: its solver step, plus its up-switch when it rose this step.
#[derive(Debug, Default, Clone)]
struct BodyRecord {
    precise: Vec<f64>,
    up: Vec<f64>,
    down: Vec<f64>,
    cg: CgSummary,
}

/// A body's iterative solves over a run (corotational FEM, implicit MSD).
#[derive(Debug, Default, Clone, Copy, Serialize)]
pub struct CgSummary {
    /// Steps with an iterative solve.
    pub solves: usize,
    /// Most iterations of one solve.
    pub max_iterations: u32,
    /// Mean iterations.
    pub mean_iterations: f64,
    /// Solves that stopped at the iteration cap above their tolerance.
    pub not_converged: usize,
    /// Largest final relative residual.
    pub worst_residual: f64,
}

/// Records every step of a run.
#[derive(Debug, Clone)]
pub struct RunRecorder {
    stages: StageRecorder,
    precise_steps: Vec<f64>,
    bodies: Vec<BodyRecord>,
    contact_us: f64,
    solve_us: f64,
}

/// A body's step costs over a run.
#[derive(Debug, Clone, Serialize)]
pub struct BodyCosts {
    /// Body name.
    pub name: String,
    /// Its steps at the precise level that were not switches.
    pub precise: TimeStats,
    /// Its up-switch steps: the switch in the switch stage plus the first precise step.
    pub up_switch: TimeStats,
    /// Its down-switch steps: the last precise step plus the switch.
    pub down_switch: TimeStats,
    /// The costliest switch step over the median precise step (`None` without both).
    pub worst_switch_ratio: Option<f64>,
    /// Its iterative solves.
    pub cg: CgSummary,
}

/// A run's step costs (see the module docs).
#[derive(Debug, Clone, Serialize)]
pub struct RunCosts {
    /// The whole step.
    pub step: TimeStats,
    /// Each stage.
    pub stages: std::collections::BTreeMap<&'static str, TimeStats>,
    /// Whole steps where some body was precise (or switched).
    pub precise_step: TimeStats,
    /// The largest whole step over the median of `precise_step` (`None` when no body was ever
    /// precise).
    pub worst_over_precise_median: Option<f64>,
    /// Contact (the start-of-step detection and the contact problem: detection after the
    /// motion, assembly, solve) over the solvers (the bodies' free motion and their contact
    /// corrections), summed over the run.
    pub contact_over_solve: Option<f64>,
    /// Steps over 1 ms.
    pub steps_over_1ms: usize,
    /// Steps over 10 ms.
    pub steps_over_10ms: usize,
    /// Every body.
    pub bodies: Vec<BodyCosts>,
}

impl RunRecorder {
    /// A recorder for `bodies` bodies, room for `steps` steps.
    pub fn new(bodies: usize, steps: usize) -> Self {
        RunRecorder {
            stages: StageRecorder::with_capacity(steps),
            precise_steps: Vec::with_capacity(steps),
            bodies: vec![BodyRecord::default(); bodies],
            contact_us: 0.0,
            solve_us: 0.0,
        }
    }

    /// Records the step `world` just ran.
    pub fn record(&mut self, world: &SoftTissueWorld) {
        let times: StageTimes = world.stage_times();
        self.stages.push(&times);
        self.contact_us += times.contact_total_us();
        self.solve_us += times.solvers_us();
        let mut any_precise = false;
        // Pieces a cut made are recorded from the step they appear.
        if self.bodies.len() < world.bodies().len() {
            self.bodies
                .resize(world.bodies().len(), BodyRecord::default());
        }
        for (rec, b) in self.bodies.iter_mut().zip(world.bodies()) {
            let d = b.diagnostics();
            let cost = d.switch_us + d.step_us;
            if let Some(cg) = d.cg {
                let c = &mut rec.cg;
                c.mean_iterations += f64::from(cg.iterations);
                c.solves += 1;
                c.max_iterations = c.max_iterations.max(cg.iterations);
                c.not_converged += usize::from(!cg.converged);
                if cg.relative_residual.is_nan() || cg.relative_residual > c.worst_residual {
                    c.worst_residual = cg.relative_residual;
                }
            }
            match d.switched {
                Some(s) if s.to == Level::Precise => {
                    rec.up.push(cost);
                    any_precise = true;
                }
                Some(_) => {
                    rec.down.push(cost);
                    any_precise = true;
                }
                None if d.level == Level::Precise => {
                    rec.precise.push(cost);
                    any_precise = true;
                }
                None => {}
            }
        }
        if any_precise {
            self.precise_steps.push(times.total_us());
        }
    }

    /// Statistics of the steps recorded; `names` are the bodies' names.
    pub fn costs<'a>(&self, names: impl IntoIterator<Item = &'a str>) -> RunCosts {
        let summary = self.stages.summary();
        let precise_step = TimeStats::of(&self.precise_steps);
        let bodies = self
            .bodies
            .iter()
            .zip(names)
            .map(|(r, name)| {
                let precise = TimeStats::of(&r.precise);
                let up_switch = TimeStats::of(&r.up);
                let down_switch = TimeStats::of(&r.down);
                let worst = up_switch.max_us.max(down_switch.max_us);
                let mut cg = r.cg;
                cg.mean_iterations /= cg.solves.max(1) as f64;
                BodyCosts {
                    name: name.to_owned(),
                    cg,
                    worst_switch_ratio: (precise.count > 0
                        && up_switch.count + down_switch.count > 0)
                        .then(|| worst / precise.median_us),
                    precise,
                    up_switch,
                    down_switch,
                }
            })
            .collect();
        RunCosts {
            step: summary.step,
            stages: StageTimes::NAMES
                .iter()
                .copied()
                .zip(summary.stages)
                .collect(),
            worst_over_precise_median: (precise_step.count > 0)
                .then(|| summary.step.max_us / precise_step.median_us),
            precise_step,
            contact_over_solve: (self.solve_us > 0.0).then(|| self.contact_us / self.solve_us),
            steps_over_1ms: self.stages.over_budget(1000.0),
            steps_over_10ms: self.stages.over_budget(10_000.0),
            bodies,
        }
    }
}

/// `median / p99 / max` in microseconds, for tables.
pub fn triple(t: &TimeStats) -> String {
    if t.count == 0 {
        return "-".into();
    }
    format!("{:.0} / {:.0} / {:.0}", t.median_us, t.p99_us, t.max_us)
}
