//! The report's real-time budget: per scene, the whole step's median, 99th percentile and
//! largest, each stage, the up- and down-switch steps against each body's precise step, and
//! the steps over a 1 ms and a 10 ms budget; and the organs all precise against the sum of
//! their solver steps.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::json;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::precision::Level;
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::{Script, SoftTissueWorld};

use super::{Json, Res};
use crate::realtime::{RunCosts, RunRecorder, triple};
use crate::simulate::{drive_tool, load_scene};

/// Runs `scene` under the built-in `script` `runs` times for `steps` steps (every body pinned to `pin`
/// if given) on `threads` threads (`None`: the report's default): the costs of all steps,
/// the bodies' tetrahedra and the last run's `state_hash`.
fn measure(
    scene: &Scene,
    script: &str,
    steps: usize,
    runs: usize,
    pin: Option<Level>,
    assets: &Path,
    threads: Option<usize>,
) -> Res<(RunCosts, Vec<usize>, u64)> {
    let mut recorder = None;
    let mut names = Vec::new();
    let mut tets = Vec::new();
    let mut hash = 0;
    for _ in 0..runs {
        let mut world = SoftTissueWorld::from_scene(scene, assets)?;
        if let Some(n) = threads {
            world.set_threads(n)?;
        }
        if let Some(level) = pin {
            for b in world.bodies_mut() {
                b.model_mut().pin(Some(level))?;
            }
        }
        let s = Script::builtin(script, &world)?;
        let ti = world.add_tool(Tool::new(s.name.clone(), s.tool)?);
        let dt = world.config().dt;
        let rec =
            recorder.get_or_insert_with(|| RunRecorder::new(world.bodies().len(), steps * runs));
        names = world.bodies().iter().map(|b| b.name().to_owned()).collect();
        tets = world
            .bodies()
            .iter()
            .map(|b| b.mesh().tet_count())
            .collect();
        for k in 0..steps {
            let t = (k + 1) as f64 * dt;
            drive_tool(&mut world, &s, ti, t, dt)?;
            world.step_fixed()?;
            rec.record(&world);
        }
        hash = world.state_hash();
    }
    let rec = recorder.ok_or("no runs")?;
    Ok((rec.costs(names.iter().map(String::as_str)), tets, hash))
}

fn ratio(r: Option<f64>) -> String {
    r.map_or("-".into(), |r| format!("{r:.2}"))
}

/// The section (see the module docs). Returns the organs' all-precise whole step over the sum
/// of their solver steps.
pub(super) fn budget_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    quick: bool,
    step: &mut dyn FnMut(&str),
) -> Res<Vec<(String, RunCosts)>> {
    let (steps, runs) = if quick { (300, 1) } else { (700, 3) };
    let scenes: Vec<(String, Scene, &str)> = vec![
        (
            "cylinders".into(),
            load_scene("cylinders", assets)?,
            "poke-a",
        ),
        ("organs".into(), load_scene("organs", assets)?, "poke-liver"),
        ("organs-fine".into(), Scene::fine_organs(), "poke-liver"),
        (
            "organs-large".into(),
            load_scene("organs-large", assets)?,
            "poke-liver",
        ),
    ];
    writeln!(
        md,
        "## Real-time budget\n\n\
         Real time is decided by the worst step. Each scene runs its built-in script {runs} \
         time(s) for {steps} steps (`soft-tissue simulate --scene S --script X --steps {steps}` \
         runs one); all steps together: the whole step and each stage (median / 99th \
         percentile / largest, us), the steps over a 1 ms and a 10 ms budget, contact (the \
         start-of-step detection and the contact problem: detection after the motion, assembly, \
         solve) against the solvers (the bodies' free motion and contact corrections; sums over \
         the run), and the largest step against the \
         median of the steps where some body is precise. `organs-fine` is the organs scene at \
         real-mesh sizes (liver, stomach and spleen generated at 1.5, 2 and 2 times the \
         paper's resolution); `organs-large` the four organs at segmentation sizes \
         (`assets/scenes/organs-large.scene.ron`, the prefactored corotational model).\n"
    )?;
    writeln!(
        md,
        "| scene (tetrahedra) | whole step | steps with a precise body | largest / their median \
         | over 1 ms | over 10 ms | contact / solve |\n|---|---|---|---|---|---|---|"
    )?;
    let mut measured = Vec::new();
    let mut stage_rows = Vec::new();
    for (name, scene, script) in &scenes {
        step(&format!("real-time budget: {name}"));
        let (costs, tets, _) = measure(scene, script, steps, runs, None, assets, None)?;
        writeln!(
            md,
            "| {name} ({}) | {} | {} | {} | {} | {} | {} |",
            tets.iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(" + "),
            triple(&costs.step),
            triple(&costs.precise_step),
            ratio(costs.worst_over_precise_median),
            costs.steps_over_1ms,
            costs.steps_over_10ms,
            ratio(costs.contact_over_solve),
        )?;
        stage_rows.push(StageRow::new(name, "step", &costs.step));
        for (stage, t) in &costs.stages {
            stage_rows.push(StageRow::new(name, stage, t));
        }
        measured.push((name.clone(), costs));
    }
    writeln!(
        md,
        "\nStages, median / p99 / largest us:\n\n| scene | prepare | detect | switch | solve | \
         contact | correct | writeback |\n|---|---|---|---|---|---|---|---|"
    )?;
    for (name, costs) in &measured {
        let cell = |s: &str| costs.stages.get(s).map_or("-".into(), triple);
        writeln!(
            md,
            "| {name} | {} | {} | {} | {} | {} | {} | {} |",
            cell("prepare"),
            cell("detect"),
            cell("switch"),
            cell("solve"),
            cell("contact"),
            cell("correct"),
            cell("writeback")
        )?;
    }
    writeln!(
        md,
        "\nSwitch steps against each body's precise steps (a body's cost in the step: its \
         up-switch in the switch stage plus its solver step), median / p99 / largest us; the \
         ratio is the costliest switch step over the median precise step:\n\n\
         | scene | body | precise steps | up-switch steps | down-switch steps | ratio | CG \
         max iterations (stopped at the cap) |\n|---|---|---|---|---|---|---|"
    )?;
    for (name, costs) in &measured {
        for b in costs.bodies.iter().filter(|b| b.precise.count > 0) {
            writeln!(
                md,
                "| {name} | {} | {} | {} | {} | {} | {} ({}) |",
                b.name,
                triple(&b.precise),
                triple(&b.up_switch),
                triple(&b.down_switch),
                ratio(b.worst_switch_ratio),
                b.cg.max_iterations,
                b.cg.not_converged
            )?;
        }
    }
    // The organs with every body held at its precise level: the whole step against the
    // solvers' sum.
    step("real-time budget: organs all precise");
    let organs = &scenes[1].1;
    let (precise, _, _) = measure(
        organs,
        "poke-liver",
        steps,
        runs,
        Some(Level::Precise),
        assets,
        None,
    )?;
    let solve = precise.stages.get("solve").map_or(0.0, |t| t.mean_us);
    let over_solvers = (solve > 0.0).then(|| precise.step.mean_us / solve);
    writeln!(
        md,
        "\nThe organs with every body held at its precise level (`simulate --level precise`): \
         whole step {} us (mean {:.0}), solvers {:.0} us (mean), whole over solvers {}; \
         contact / solve {}.\n",
        triple(&precise.step),
        precise.step.mean_us,
        solve,
        ratio(over_solvers),
        ratio(precise.contact_over_solve),
    )?;
    // The same runs on one thread and on every core (at least two, so the final states are
    // compared on any machine; CI fails when they differ): the speed-up and the final states.
    let cores = soft_tissue_core::parallel::available_cores().max(2);
    let mut threads_rows = Vec::new();
    writeln!(
        md,
        "One thread against {cores} (`simulate --level precise --threads 1` and \
         `--threads {cores}`), every body held precise, the same script and steps, run in \
         alternation ({} rounds); times of the first round, speed-ups of the mean and the \
         median whole step as the median over the rounds, and whether every round's final \
         states' `state_hash` agree:\n\n\
         | scene | 1 thread median / mean us | {cores} threads median / mean us | speed-up \
         mean / median | same state |\n|---|---|---|---|---|",
        runs.max(3)
    )?;
    for k in [1, 3] {
        let (name, scene, script) = &scenes[k];
        step(&format!(
            "real-time budget: {name} on 1 and {cores} threads"
        ));
        // One and every core in alternation, one run each per round, so the machine's
        // drift between minutes does not fall on one side; the speed-ups are the median
        // over the rounds.
        let (mut mean_ratios, mut median_ratios) = (Vec::new(), Vec::new());
        let (mut one_step, mut all_step, mut same) = (None, None, true);
        let mut hash = 0;
        for _ in 0..runs.max(3) {
            let one = measure(
                scene,
                script,
                steps,
                1,
                Some(Level::Precise),
                assets,
                Some(1),
            )?;
            let all = measure(
                scene,
                script,
                steps,
                1,
                Some(Level::Precise),
                assets,
                Some(cores),
            )?;
            mean_ratios.push(one.0.step.mean_us / all.0.step.mean_us);
            median_ratios.push(one.0.step.median_us / all.0.step.median_us);
            same &= one.2 == all.2;
            hash = one.2;
            one_step.get_or_insert(one.0.step);
            all_step.get_or_insert(all.0.step);
        }
        let (one_step, all_step) = (one_step.ok_or("no runs")?, all_step.ok_or("no runs")?);
        let mean = super::median(&mean_ratios).unwrap_or(0.0);
        let median = super::median(&median_ratios).unwrap_or(0.0);
        writeln!(
            md,
            "| {name} | {:.0} / {:.0} | {:.0} / {:.0} | {mean:.2} / {median:.2} | {} ({hash:016x}) |",
            one_step.median_us,
            one_step.mean_us,
            all_step.median_us,
            all_step.mean_us,
            if same { "yes" } else { "**no**" },
        )?;
        threads_rows.push(json!({
            "scene": name, "threads": cores, "rounds": mean_ratios.len(),
            "one_thread_first_round": one_step, "all_threads_first_round": all_step,
            "speedup_mean": mean, "speedup_median": median,
            "speedup_mean_per_round": mean_ratios, "speedup_median_per_round": median_ratios,
            "same_state": same,
            "state_hash": format!("{hash:016x}"),
        }));
    }
    writeln!(md)?;
    // Long form: one row per scene and stage (the Markdown shows them wide).
    super::write_file(
        out,
        "realtime_budget.csv",
        &super::table::csv_text(&stage_rows)?,
    )?;
    js.insert(
        "realtime_budget".into(),
        json!({
            "steps_per_run": steps,
            "runs": runs,
            "scenes": measured.iter().map(|(n, c)| json!({"scene": n, "costs": c})).collect::<Vec<_>>(),
            "organs_all_precise": precise,
            "organs_all_precise_over_solvers": over_solvers,
            "threads": threads_rows,
        }),
    );
    measured.push(("organs (all precise)".into(), precise));
    Ok(measured)
}

/// A scene's step or one of its stages over the run, us.
#[derive(serde::Serialize)]
struct StageRow {
    scene: String,
    stage: String,
    median_us: f64,
    p99_us: f64,
    max_us: f64,
    mean_us: f64,
}

impl StageRow {
    fn new(scene: &str, stage: &str, t: &soft_tissue_core::timing::TimeStats) -> Self {
        StageRow {
            scene: scene.into(),
            stage: stage.into(),
            median_us: t.median_us,
            p99_us: t.p99_us,
            max_us: t.max_us,
            mean_us: t.mean_us,
        }
    }
}

impl super::ReportRow for StageRow {
    const MD_HEAD: &'static [&'static str] = &["scene", "stage", "median us", "p99 us", "max us"];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.scene.clone(),
            self.stage.clone(),
            format!("{:.1}", self.median_us),
            format!("{:.1}", self.p99_us),
            format!("{:.1}", self.max_us),
        ]
    }
}
