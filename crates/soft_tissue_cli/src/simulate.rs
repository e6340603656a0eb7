//! `soft-tissue simulate`: a scene run headless under a scripted tool.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use crate::realtime::{RunRecorder, triple};
use serde_json::json;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::precision::Level;
use soft_tissue_core::scenario::{PreciseMethod, Scene};
use soft_tissue_core::world::{Script, SoftTissueWorld};

#[derive(Args)]
pub struct SimulateArgs {
    /// `cylinders`, `organs` (the paper's scenes), `organs-fine` (liver, stomach and spleen
    /// generated at 2.8k-4.8k tetrahedra each), `organs-large` (the four organs at 4.9k-8.3k
    /// tetrahedra each, `assets/scenes/organs-large.scene.ron`) or a scene RON file.
    #[arg(long)]
    scene: String,
    /// Built-in script (`poke-a`, `push-a-into-b`, `poke-liver`, `cauterize-liver`) or a
    /// script RON file. Without one, nothing touches the bodies.
    #[arg(long)]
    script: Option<String>,
    /// Fixed steps to run.
    #[arg(long)]
    steps: usize,
    /// One JSON object per step on stdout, then a summary object.
    #[arg(long)]
    json: bool,
    /// Folder the scene's mesh files are relative to.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Adds this many resting copies of the scene's last body, laid out in a grid beside the
    /// scene (to measure how the cost grows with bodies nobody touches).
    #[arg(long, default_value_t = 0)]
    resting: usize,
    /// Write the script used (built-in ones included) to this RON file, for replay.
    #[arg(long)]
    save_script: Option<PathBuf>,
    /// Run a shadow precise simulation beside every body's cage level and report the
    /// distance between the two (the cage level's error). Each body's step time then
    /// includes its shadow's step.
    #[arg(long)]
    shadow: bool,
    /// Level of every body: `auto` (switch on contact and rest), or pinned to `precise` or
    /// `cage` for the whole run (to measure the all-precise cost, or with `--shadow` the
    /// cage level's error, on any scene).
    #[arg(long, value_enum, default_value_t = LevelArg::Auto)]
    level: LevelArg,
    /// Threads the world steps on (0: every available core). The final state (its
    /// `state_hash`) is the same for every count.
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Let the scene's mesh paths leave the assets folder (absolute paths, `..`).
    #[arg(long)]
    allow_outside_assets: bool,
    /// Steps a cut is prepared for on a thread of its own before it lands (0: within the
    /// step the blade crossed the body; see `CutOptions::background_steps`).
    #[arg(long, default_value_t = 0)]
    cut_background_steps: u32,
    /// A cut prepared in the background lands at the first step its thread is done by, once
    /// due, instead of that step waiting for it (`CutOptions::land_when_ready`: no step
    /// waits, but the run depends on the machine's speed; `state_hash` may differ from run
    /// to run).
    #[arg(long)]
    cut_land_when_ready: bool,
    /// Step in real time: each step starts one step's time after the last (as an app's
    /// fixed step does; a cut prepared in the background then has that time); a step more
    /// than a step late starts the schedule again from then (no catching up back to back).
    /// Step times count the steps' work, not the waits between them.
    #[arg(long)]
    real_time: bool,
}

/// `--level`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LevelArg {
    /// Contact raises a body, rest lowers it.
    Auto,
    /// Every body pinned to its precise method.
    Precise,
    /// Every body pinned to its cage.
    Cage,
}

impl LevelArg {
    /// The pin it sets (`None` for `auto`).
    pub fn pin(self) -> Option<Level> {
        match self {
            LevelArg::Auto => None,
            LevelArg::Precise => Some(Level::Precise),
            LevelArg::Cage => Some(Level::Cage),
        }
    }
}

/// `cylinders` and `organs` are read from `<assets>/scenes/<name>.scene.ron` (the scenario files),
/// falling back to the built-in definitions when that file is absent; anything else is a RON
/// file path.
pub(crate) fn load_scene(name: &str, assets: &Path) -> Result<Scene, String> {
    let (path, builtin) = match name {
        "cylinders" => (
            assets.join("scenes/cylinders.scene.ron"),
            Some(Scene::paper_cylinders(
                PreciseMethod::LinearFem,
                PreciseMethod::LinearFem,
            )),
        ),
        "organs" => (
            assets.join("scenes/organs.scene.ron"),
            Some(Scene::paper_organs()),
        ),
        "organs-fine" => (PathBuf::new(), Some(Scene::fine_organs())),
        "grasp" => (PathBuf::new(), Some(Scene::grasp())),
        "stack" => (PathBuf::new(), Some(Scene::organ_stack())),
        "organs-large" => (
            assets.join("scenes/organs-large.scene.ron"),
            Some(Scene::large_organs()),
        ),
        _ => (PathBuf::from(name), None),
    };
    match (std::fs::read_to_string(&path), builtin) {
        (Ok(text), _) => {
            Scene::from_ron(&text, &path.display().to_string()).map_err(|e| e.to_string())
        }
        (Err(_), Some(scene)) => Ok(scene),
        (Err(e), None) => Err(format!("{}: {e}", path.display())),
    }
}

pub(crate) fn add_resting_copies(scene: &mut Scene, n: usize, world: &SoftTissueWorld) {
    let Some(last) = scene.bodies.last().cloned() else {
        return;
    };
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let mut ext = [0.0f64; 3];
    for b in world.bodies() {
        let (l, h) = b.collider().bounds();
        for k in 0..3 {
            lo[k] = lo[k].min(l[k]);
            hi[k] = hi[k].max(h[k]);
        }
    }
    if let Some(b) = world.bodies().last() {
        let (l, h) = b.collider().bounds();
        for k in 0..3 {
            ext[k] = h[k] - l[k];
        }
    }
    let spacing = 1.5 * ext[0].max(ext[2]).max(1e-6);
    let per_row = 16;
    for k in 0..n {
        let mut spec = last.clone();
        spec.name = format!("{} copy {}", last.name, k + 1);
        spec.placement.translation[0] += hi[0] - lo[0] + spacing * (1 + k % per_row) as f64;
        spec.placement.translation[2] += spacing * (k / per_row) as f64;
        scene.bodies.push(spec);
    }
}

fn level_name(world: &SoftTissueWorld, i: usize) -> &'static str {
    world.bodies()[i].diagnostics().running()
}

/// Puts tool `ti` where `script` has it at time `t` and applies the script's events of the
/// step ending at `t`.
pub(crate) fn drive_tool(
    world: &mut SoftTissueWorld,
    script: &Script,
    ti: usize,
    t: f64,
    dt: f64,
) -> Result<(), Box<dyn std::error::Error>> {
    let (p, r) = script.pose_rotation_at(t);
    let tl = &mut world.tools_mut()[ti];
    tl.set_pose_rotation(p, r)?;
    for e in script.events_in(t - dt, t) {
        e.action.apply(tl)?;
    }
    Ok(())
}

/// Body `i`'s heat (`None` without a heat field): the largest temperature of the run, the
/// burnt volumes at the electrodes' scale, the spots now, the heat step's time.
fn heat_summary(
    world: &SoftTissueWorld,
    i: usize,
    hottest: f64,
    heat_us: &[f64],
) -> Option<serde_json::Value> {
    let h = world.bodies()[i].heat()?;
    let v = h.burn_volumes();
    Some(json!({
        "largest_temperature_c": hottest.max(h.max_temperature()),
        "coagulated_mm3": v.coagulated * 1e9,
        "charred_mm3": v.charred * 1e9,
        "vaporized_mm3": v.vaporized * 1e9,
        "spots": h.spot_count(),
        "heat_us": soft_tissue_core::timing::TimeStats::of(heat_us),
    }))
}

/// What cuts did to body `i` (`None` if it was never cut): its cut faces and their area,
/// the pieces its uncut body is in now, their volume change, the smallest dihedral angle
/// of its tetrahedra, whether its surface is closed.
fn cut_summary(world: &SoftTissueWorld, i: usize) -> Option<serde_json::Value> {
    let b = &world.bodies()[i];
    let r = b.cut_record()?;
    let family: Vec<_> = world
        .bodies()
        .iter()
        .filter(|o| o.cut_record().is_some_and(|c| c.origin == r.origin))
        .collect();
    let volume: f64 = family.iter().map(|o| o.mesh().volume()).sum();
    Some(json!({
        "origin": r.origin,
        "cuts": r.cuts,
        "cut_faces": r.surface_faces.len(),
        "cut_area": r.area,
        "pieces": family.len(),
        "volume_change_pct": 100.0 * (volume - r.origin_volume) / r.origin_volume,
        "smallest_dihedral_deg": r.smallest_dihedral_deg,
        "closed": r.closed,
    }))
}

pub fn simulate(args: &SimulateArgs) -> Result<(), Box<dyn std::error::Error>> {
    let mut scene = load_scene(&args.scene, &args.assets)?;
    let build_start = Instant::now();
    let options = soft_tissue_core::world::SceneOptions {
        allow_outside_assets: args.allow_outside_assets,
    };
    let mut world = SoftTissueWorld::from_scene_with(&scene, &args.assets, options)?;
    if args.resting > 0 {
        add_resting_copies(&mut scene, args.resting, &world);
        world = SoftTissueWorld::from_scene_with(&scene, &args.assets, options)?;
    }
    world.set_threads(args.threads)?;
    if args.shadow {
        for b in world.bodies_mut() {
            b.set_shadow(true)?;
        }
    }
    if let Some(level) = args.level.pin() {
        for b in world.bodies_mut() {
            let name = b.name().to_owned();
            b.model_mut()
                .pin(Some(level))
                .map_err(|e| format!("body `{name}`: pinning to {level:?}: {e}"))?;
        }
    }
    let build_s = build_start.elapsed().as_secs_f64();
    let script = match &args.script {
        None => None,
        Some(s) if s.ends_with(".ron") => {
            let text = std::fs::read_to_string(s).map_err(|e| format!("{s}: {e}"))?;
            Some(Script::from_ron(&text, s)?)
        }
        Some(s) => Some(Script::builtin(s, &world)?),
    };
    if let (Some(path), Some(s)) = (&args.save_script, &script) {
        std::fs::write(path, s.to_ron()).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let tool = match &script {
        Some(s) => Some(world.add_tool(Tool::new(s.name.clone(), s.tool)?)),
        None => None,
    };
    world.set_cut_options(soft_tissue_core::mesh::cut::CutOptions {
        background_steps: args.cut_background_steps,
        land_when_ready: args.cut_land_when_ready,
        ..Default::default()
    })?;
    let dt = world.config().dt;
    let nb = world.bodies().len();
    // The whole run's steps, kept for the statistics (allocated before the first step).
    let mut recorder = RunRecorder::new(nb, args.steps.min(1 << 24));
    let mut precise_steps = vec![0u64; nb];
    let mut body_us = vec![0.0f64; nb];
    let mut worst_jump = vec![0.0f64; nb];
    let mut worst_shadow = vec![0.0f64; nb];
    let mut shadow_sum = vec![(0.0f64, 0u64); nb];
    let mut worst_penetration = vec![0.0f64; nb];
    let mut hottest = vec![f64::NEG_INFINITY; nb];
    let mut heat_us: Vec<Vec<f64>> = vec![Vec::new(); nb];
    let mut most_contacts = vec![0u32; nb];
    let mut contact_rounds = (0u64, 0u32, 0u64, 0u32);
    // Each cut that changed a body: (mesh change, bodies built, landing), microseconds.
    let mut seen: Vec<u64> = world.bodies().iter().map(|b| b.id()).collect();
    let mut cut_costs: Vec<(f64, f64, f64)> = Vec::new();
    // Steps that waited for a cut prepared in the background (its landing, whatever it came
    // to), and how long.
    let mut cut_waits: Vec<f64> = Vec::new();
    // Whole steps while a blade cuts or a cut is being prepared.
    let mut cutting_steps: Vec<f64> = Vec::new();
    let period = std::time::Duration::from_secs_f64(dt);
    let mut due = std::time::Instant::now();
    for k in 0..args.steps {
        let t = (k + 1) as f64 * dt;
        if args.real_time {
            // Each step one period after the last; a step more than a period late is not
            // caught up with steps back to back (an app drops that time, as Bevy's fixed
            // step caps its steps per frame): the schedule starts again from now.
            let now = std::time::Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            } else if now - due > period {
                due = now;
            }
            due += period;
        }
        if let (Some(s), Some(ti)) = (&script, tool) {
            drive_tool(&mut world, s, ti, t, dt)?;
        }
        let cutting =
            world.cuts_in_flight() > 0 || tool.is_some_and(|ti| world.tools()[ti].cutting());
        world.step_fixed()?;
        let st = world.stage_times();
        recorder.record(&world);
        if cutting {
            cutting_steps.push(st.total_us());
        }
        if st.cut_wait_us > 0.0 {
            cut_waits.push(st.cut_wait_us);
        }
        // A cut may have changed bodies and added some (the pieces that came loose).
        {
            let mut this_step: Vec<(f64, f64, f64)> = Vec::new();
            for b in world.bodies() {
                if let (false, Some(r)) = (seen.contains(&b.id()), b.cut_record()) {
                    seen.push(b.id());
                    let c = (r.mesh_us, r.build_us, r.land_us);
                    if !this_step.contains(&c) {
                        this_step.push(c);
                    }
                }
            }
            cut_costs.extend(this_step);
        }
        let nb = world.bodies().len();
        if precise_steps.len() < nb {
            precise_steps.resize(nb, 0);
            body_us.resize(nb, 0.0);
            worst_jump.resize(nb, 0.0);
            worst_shadow.resize(nb, 0.0);
            shadow_sum.resize(nb, (0.0, 0));
            worst_penetration.resize(nb, 0.0);
            hottest.resize(nb, f64::NEG_INFINITY);
            heat_us.resize(nb, Vec::new());
            most_contacts.resize(nb, 0);
        }
        for (i, b) in world.bodies().iter().enumerate() {
            let d = b.diagnostics();
            if d.level == Level::Precise {
                precise_steps[i] += 1;
            }
            body_us[i] += d.step_us + d.switch_us;
            if let Some(s) = d.switched {
                worst_jump[i] = worst_jump[i].max(s.jump_ratio);
            }
            if let Some(e) = d.shadow {
                worst_shadow[i] = worst_shadow[i].max(e.max_ratio);
                shadow_sum[i].0 += e.mean / b.model().smallest_dimension();
                shadow_sum[i].1 += 1;
            }
            worst_penetration[i] = worst_penetration[i].max(d.max_penetration);
            if let Some(t) = d.max_temperature {
                hottest[i] = hottest[i].max(t);
                heat_us[i].push(d.heat_us);
            }
            most_contacts[i] = most_contacts[i].max(d.contacts);
        }
        let cs = world.contacts().stats();
        contact_rounds.0 += u64::from(cs.rounds);
        contact_rounds.1 = contact_rounds.1.max(cs.rounds);
        contact_rounds.2 += u64::from(cs.sweeps);
        contact_rounds.3 = contact_rounds.3.max(cs.rows);
        if args.json {
            let bodies: Vec<_> = world
                .bodies()
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    let d = b.diagnostics();
                    json!({
                        "name": b.name(),
                        "level": level_name(&world, i),
                        "step_us": d.step_us,
                        "switch_us": d.switch_us,
                        "cg_iterations": d.cg.map(|c| c.iterations),
                        "cg_residual": d.cg.map(|c| c.relative_residual),
                        "cg_converged": d.cg.map(|c| c.converged),
                        "max_displacement": d.max_displacement,
                        "switch_jump": d.switched.map(|s| s.jump),
                        "switch_jump_ratio": d.switched.map(|s| s.jump_ratio),
                        "contacts": d.contacts,
                        "max_penetration": d.max_penetration,
                        "max_temperature": d.max_temperature,
                        "shadow_error_ratio": d.shadow.map(|e| e.max_ratio),
                    })
                })
                .collect();
            let tool_json = tool.map(|ti| {
                let tl = &world.tools()[ti];
                json!({
                    "position": tl.position().as_slice(),
                    "force": tl.reaction_force().as_slice(),
                    "contacts": tl.contact_count(),
                    "opening": tl.opening(),
                    "jaw_forces": tl.jaw_forces(),
                })
            });
            let line = json!({
                "step": k + 1,
                "t": t,
                "step_us": st.total_us(),
                "stages": {
                    "cut_us": st.cut_us,
                    "prepare_us": st.prepare_us,
                    "detect_us": st.detect_us,
                    "switch_us": st.switch_us,
                    "solve_us": st.solve_us,
                    "contact_us": st.contact_us,
                    "correct_us": st.correct_us,
                    "writeback_us": st.writeback_us,
                },
                "contact": {
                    "rows": cs.rows,
                    "active": cs.active,
                    "rounds": cs.rounds,
                    "sweeps": cs.sweeps,
                    "sliding": cs.sliding,
                    "max_penetration": cs.max_penetration,
                },
                "bodies": bodies,
                "tool": tool_json,
            });
            // A reader that stops early (`| head`) ends the run quietly, not with a panic.
            if let Err(e) = writeln!(std::io::stdout().lock(), "{line}") {
                if e.kind() == std::io::ErrorKind::BrokenPipe {
                    return Ok(());
                }
                return Err(e.into());
            }
        }
    }
    let names: Vec<String> = world.bodies().iter().map(|b| b.name().to_owned()).collect();
    let costs = recorder.costs(names.iter().map(String::as_str));
    let n = args.steps.max(1) as f64;
    let bodies: Vec<_> = world
        .bodies()
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let c = &costs.bodies[i];
            json!({
                "name": b.name(),
                "final_level": level_name(&world, i),
                "switches": b.model().switch_count(),
                "precise_steps": precise_steps[i],
                "max_switch_jump_ratio": worst_jump[i],
                "mean_step_us": body_us[i] / n,
                "precise_step": c.precise,
                "up_switch": c.up_switch,
                "down_switch": c.down_switch,
                "worst_switch_over_precise_median": c.worst_switch_ratio,
                "cg": c.cg,
                "worst_shadow_error_ratio": args.shadow.then_some(worst_shadow[i]),
                "mean_shadow_error_ratio": args.shadow.then(|| {
                    shadow_sum[i].0 / shadow_sum[i].1.max(1) as f64
                }),
                "max_penetration": worst_penetration[i],
                "max_penetration_ratio": worst_penetration[i] / b.model().smallest_dimension(),
                "max_contacts": most_contacts[i],
                "cut": cut_summary(&world, i),
                "heat": heat_summary(&world, i, hottest[i], &heat_us[i]),
            })
        })
        .collect();
    let mean_stage = |name: &str| costs.stages.get(name).map_or(0.0, |t| t.mean_us);
    let stages = json!({
        "cut_us": mean_stage("cut"),
        "prepare_us": mean_stage("prepare"),
        "detect_us": mean_stage("detect"),
        "switch_us": mean_stage("switch"),
        "solve_us": mean_stage("solve"),
        "contact_us": mean_stage("contact"),
        "correct_us": mean_stage("correct"),
        "writeback_us": mean_stage("writeback"),
    });
    if args.json {
        println!(
            "{}",
            json!({
                "summary": true,
                "scene": scene.name,
                "script": script.as_ref().map(|s| s.name.clone()),
                "steps": args.steps,
                "dt": dt,
                "body_count": world.bodies().len(),
                "level": format!("{:?}", args.level).to_lowercase(),
                "build_s": build_s,
                "mean_step_us": costs.step.mean_us,
                "median_step_us": costs.step.median_us,
                "max_step_us": costs.step.max_us,
                "mean_stage_us": stages,
                "step": costs.step,
                "stage": costs.stages,
                "precise_step": costs.precise_step,
                "worst_over_precise_median": costs.worst_over_precise_median,
                "contact_over_solve": costs.contact_over_solve,
                "contact_rounds_mean": contact_rounds.0 as f64 / n,
                "contact_rounds_max": contact_rounds.1,
                "contact_sweeps_mean": contact_rounds.2 as f64 / n,
                "contact_rows_max": contact_rounds.3,
                "steps_over_1ms": costs.steps_over_1ms,
                "steps_over_10ms": costs.steps_over_10ms,
                "cuts": cut_costs.len(),
                "cut_mesh_us": soft_tissue_core::timing::TimeStats::of(
                    &cut_costs.iter().map(|c| c.0).collect::<Vec<_>>()
                ),
                "cut_build_us": soft_tissue_core::timing::TimeStats::of(
                    &cut_costs.iter().map(|c| c.1).collect::<Vec<_>>()
                ),
                "cut_land_us": soft_tissue_core::timing::TimeStats::of(
                    &cut_costs.iter().map(|c| c.2).collect::<Vec<_>>()
                ),
                "cut_wait_us": soft_tissue_core::timing::TimeStats::of(&cut_waits),
                "cut_background_steps": args.cut_background_steps,
                "cut_land_when_ready": args.cut_land_when_ready,
                "real_time": args.real_time,
                "steps_while_cutting": cutting_steps.len(),
                "step_while_cutting_us": soft_tissue_core::timing::TimeStats::of(&cutting_steps),
                "state_hash": format!("{:016x}", world.state_hash()),
                "threads": world.threads().count(),
                "bodies": bodies,
            })
        );
    } else {
        println!(
            "scene {} ({} bodies, built in {:.2} s), script {}, {} steps of {} s",
            scene.name,
            nb,
            build_s,
            script.as_ref().map_or("none", |s| s.name.as_str()),
            args.steps,
            dt
        );
        println!(
            "threads {}, state_hash {:016x}",
            world.threads().count(),
            world.state_hash()
        );
        println!(
            "step time (wall clock, this machine), median / p99 / max us: {} (mean {:.1}); steps with a precise body {}; worst step / their median {}",
            triple(&costs.step),
            costs.step.mean_us,
            triple(&costs.precise_step),
            costs
                .worst_over_precise_median
                .map_or("-".into(), |r| format!("{r:.2}"))
        );
        println!(
            "stages, median / p99 / max us: {}",
            costs
                .stages
                .iter()
                .map(|(k, t)| format!("{k} {}", triple(t)))
                .collect::<Vec<_>>()
                .join(", ")
        );
        println!(
            "contact (detect + contact problem) / solvers (free motion + corrections): {}; steps over 1 ms: {}, over 10 ms: {}",
            costs
                .contact_over_solve
                .map_or("-".into(), |r| format!("{r:.3}")),
            costs.steps_over_1ms,
            costs.steps_over_10ms
        );
        println!(
            "{:<24} {:>6} {:>9} {:>14} {:>11} {:>9} {:>20} {:>20} {:>20} {:>8}",
            "body",
            "final",
            "switches",
            "precise steps",
            "max jump %",
            "mean us",
            "precise med/p99/max",
            "up-switch med/p99/max",
            "down-sw. med/p99/max",
            "sw/prec"
        );
        for (i, b) in world.bodies().iter().enumerate().take(12) {
            let c = &costs.bodies[i];
            println!(
                "{:<24} {:>6} {:>9} {:>14} {:>11.3} {:>9.1} {:>20} {:>20} {:>20} {:>8}",
                b.name(),
                level_name(&world, i),
                b.model().switch_count(),
                precise_steps[i],
                100.0 * worst_jump[i],
                body_us[i] / n,
                triple(&c.precise),
                triple(&c.up_switch),
                triple(&c.down_switch),
                c.worst_switch_ratio
                    .map_or("-".into(), |r| format!("{r:.2}"))
            );
        }
        if nb > 12 {
            println!("... {} more bodies", nb - 12);
        }
        println!(
            "contact solve: rounds mean {:.2} max {}, sweeps mean {:.1}, rows max {}",
            contact_rounds.0 as f64 / n,
            contact_rounds.1,
            contact_rounds.2 as f64 / n,
            contact_rounds.3
        );
        for (i, b) in world.bodies().iter().enumerate().take(12) {
            println!(
                "{:<24} largest penetration {:.3e} ({:.4} % of its smallest dimension), most contacts {}",
                b.name(),
                worst_penetration[i],
                100.0 * worst_penetration[i] / b.model().smallest_dimension(),
                most_contacts[i]
            );
        }
        for c in costs.bodies.iter().filter(|c| c.cg.not_converged > 0) {
            println!(
                "warning: {}: {} of {} iterative solves stopped at the iteration cap ({} iterations), worst relative residual {:.2e}",
                c.name, c.cg.not_converged, c.cg.solves, c.cg.max_iterations, c.cg.worst_residual
            );
        }
        if !cut_costs.is_empty() {
            let mesh: Vec<f64> = cut_costs.iter().map(|c| c.0).collect();
            let build: Vec<f64> = cut_costs.iter().map(|c| c.1).collect();
            let land: Vec<f64> = cut_costs.iter().map(|c| c.2).collect();
            println!(
                "cuts that changed a body: {}; per cut, median / p99 / max us: mesh change {}, bodies built {} ({}), landing in its step {}; steps that waited for a cut's thread (any landing): {}, median / p99 / max us {}",
                cut_costs.len(),
                triple(&soft_tissue_core::timing::TimeStats::of(&mesh)),
                triple(&soft_tissue_core::timing::TimeStats::of(&build)),
                if args.cut_background_steps > 0 {
                    format!(
                        "on a thread of their own, landing {} steps later ({} for a carve){}",
                        args.cut_background_steps,
                        args.cut_background_steps
                            .saturating_mul(soft_tissue_core::mesh::cut::CARVE_STEPS_FACTOR),
                        if args.cut_land_when_ready {
                            ", or once ready"
                        } else {
                            ""
                        }
                    )
                } else {
                    "within the step".to_string()
                },
                triple(&soft_tissue_core::timing::TimeStats::of(&land)),
                cut_waits.len(),
                triple(&soft_tissue_core::timing::TimeStats::of(&cut_waits)),
            );
            println!(
                "steps while cutting ({}{}): {}, median / p99 / max us {}",
                if args.real_time {
                    "in real time"
                } else {
                    "back to back"
                },
                if args.cut_background_steps > 0 {
                    ", cuts in the background"
                } else {
                    ""
                },
                cutting_steps.len(),
                triple(&soft_tissue_core::timing::TimeStats::of(&cutting_steps)),
            );
        }
        for (i, b) in world.bodies().iter().enumerate().take(12) {
            if let Some(h) = heat_summary(&world, i, hottest[i], &heat_us[i]) {
                println!(
                    "{:<24} heat: largest {:.1} C, coagulated {:.2} mm^3, charred {:.2} mm^3, vaporized {:.2} mm^3 (sub-grid), spots {}; heat step median / p99 / max us {}",
                    b.name(),
                    h["largest_temperature_c"].as_f64().unwrap_or(f64::NAN),
                    h["coagulated_mm3"].as_f64().unwrap_or(f64::NAN),
                    h["charred_mm3"].as_f64().unwrap_or(f64::NAN),
                    h["vaporized_mm3"].as_f64().unwrap_or(f64::NAN),
                    h["spots"],
                    triple(&soft_tissue_core::timing::TimeStats::of(&heat_us[i])),
                );
            }
        }
        for (i, b) in world.bodies().iter().enumerate().take(12) {
            if let Some(c) = cut_summary(&world, i) {
                println!(
                    "{:<24} cut: {} cut faces, area {:.4e}, {} pieces of `{}` (volume change {:.2e} %), smallest dihedral {:.2} deg, surface {}",
                    b.name(),
                    c["cut_faces"],
                    c["cut_area"].as_f64().unwrap_or(f64::NAN),
                    c["pieces"],
                    c["origin"].as_str().unwrap_or(""),
                    c["volume_change_pct"].as_f64().unwrap_or(f64::NAN),
                    c["smallest_dihedral_deg"].as_f64().unwrap_or(f64::NAN),
                    if c["closed"] == true {
                        "closed"
                    } else {
                        "OPEN"
                    },
                );
            }
        }
        if args.shadow {
            println!(
                "cage level against its shadow precise simulation (surface distance, % of the smallest dimension):"
            );
            for (i, b) in world.bodies().iter().enumerate().take(12) {
                let (sum, count) = shadow_sum[i];
                println!(
                    "{:<24} mean {:>8.3} %  worst {:>8.3} %  over {count} cage steps",
                    b.name(),
                    100.0 * sum / count.max(1) as f64,
                    100.0 * worst_shadow[i],
                );
            }
        }
    }
    Ok(())
}
