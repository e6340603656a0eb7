//! `soft-tissue haptics-bench`: a scene stepped in real time on this thread while the haptic
//! thread replays a recorded session at 1 kHz, coupling the replayed device to the tool and
//! rendering the contact force from the model each physics step hands over. Prints the haptic
//! loop's period distribution, missed deadlines and force continuity, and the scheduling the
//! haptic thread got (real time where the OS allows it; this thread, the physics, stays
//! normal).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use serde_json::json;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::contact::ToolShape;
use soft_tissue_core::haptics::{
    ContactModel, CutModel, DEFAULT_REALTIME_LEVEL, HapticConfig, HapticError, HapticPriority,
    HapticThread, Recording, ReplayDevice, Scheduling, contact_model, cut_model,
};
use soft_tissue_core::world::{Script, SoftTissueWorld};

use crate::simulate::load_scene;

use soft_tissue_core::haptics::{
    CAUTERY_BUTTON as CAUTERY, CUT_BUTTON as CUT, GRAB_BUTTON as GRAB,
};

#[derive(Args)]
pub struct HapticsBenchArgs {
    /// `cylinders`, `organs` or a scene RON file.
    #[arg(long, default_value = "organs")]
    scene: String,
    /// Wall-clock seconds to run.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Session to replay: a recording RON file; without one, the built-in script
    /// (`--script`) sampled at the haptic rate.
    #[arg(long)]
    replay: Option<PathBuf>,
    /// Built-in script or script RON file used when no recording is given.
    #[arg(long, default_value = "cauterize-liver")]
    script: String,
    /// Electrocautery power while the second button is held, W.
    #[arg(long, default_value_t = 10.0)]
    cautery_watts: f64,
    /// Save the session the haptic thread recorded (RON) here.
    #[arg(long)]
    record: Option<PathBuf>,
    /// Save the recorded session as a `simulate --script` RON file here (a waypoint every
    /// 10 ms).
    #[arg(long)]
    save_script: Option<PathBuf>,
    /// The haptic thread sleeps until this long before each deadline, then spins,
    /// microseconds. The default spins the whole period (a dedicated core, as haptic loops
    /// usually run) at normal priority; under real time the loop spins at most half the
    /// period (a real-time thread that never sleeps is throttled by the kernel). 300 sleeps
    /// most of it (gentler on a shared machine, more jitter at normal priority).
    #[arg(long, default_value_t = 1000.0)]
    spin_us: f64,
    /// Scheduling of the haptic thread: `realtime` (SCHED_FIFO at level 80 where the OS
    /// allows it, else the lowest nice value allowed, else normal), `realtime:LEVEL` (1 to 99)
    /// or `normal` (as the physics thread).
    #[arg(long, default_value = "realtime", value_parser = parse_priority)]
    priority: HapticPriority,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Folder the scene's mesh files are relative to.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Steps a cut is prepared for on a thread of its own before it lands (0: within the
    /// step the blade crossed the body). A blade cuts while the cut button is held (or the
    /// first button, as the plugin's haptic tool does).
    #[arg(long, default_value_t = 4)]
    cut_background_steps: u32,
    /// Turn the loop's passivity controller off (`HapticConfig::passivity`), to compare.
    #[arg(long)]
    no_passivity: bool,
}

/// What `haptics-bench` refuses in the tool its `--script` gives.
#[derive(Debug)]
pub enum HapticsBenchError {
    /// The blade's edge is too short for the haptic loop to find its direction (its length
    /// squared is below the smallest normal number, or its two ends are one point).
    BladeEdge {
        /// The `--script` value.
        script: String,
        /// The blade's length, scene units.
        length: f64,
        /// What the haptic loop refused.
        why: HapticError,
    },
    /// The cut model of a step could not be made from the blade as the step left it.
    CutModel {
        /// The `--script` value.
        script: String,
        /// The physics step (1-based).
        step: u64,
        /// What the haptic loop refused.
        why: HapticError,
    },
}

impl std::fmt::Display for HapticsBenchError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HapticsBenchError::BladeEdge {
                script,
                length,
                why,
            } => write!(
                f,
                "--script `{script}`: the blade's edge (length {length:e}) is too short for \
                 the haptic loop to render a cut across it ({why}); give the blade a longer \
                 edge"
            ),
            HapticsBenchError::CutModel { script, step, why } => write!(
                f,
                "--script `{script}`: step {step}: the blade's cut model could not be made \
                 ({why})"
            ),
        }
    }
}

impl std::error::Error for HapticsBenchError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            HapticsBenchError::BladeEdge { why, .. } | HapticsBenchError::CutModel { why, .. } => {
                Some(why)
            }
        }
    }
}

/// Refuses a blade whose edge the haptic loop cannot render a cut across: the cut model of
/// its edge along the script's starting axis, with the bench's bristle `stiffness`, must be
/// valid (a length whose square underflows has no direction to speak of).
fn check_blade(script: &Script, option: &str, stiffness: f64) -> Result<(), HapticsBenchError> {
    let ToolShape::Blade { length } = script.tool else {
        return Ok(());
    };
    let (_, axis) = script.pose_at(0.0);
    CutModel::new(axis.normalize() * length, 0.0, stiffness)
        .map(|_| ())
        .map_err(|why| HapticsBenchError::BladeEdge {
            script: option.to_owned(),
            length,
            why,
        })
}

fn parse_priority(text: &str) -> Result<HapticPriority, String> {
    let level = match text {
        "normal" => return Ok(HapticPriority::Normal),
        "realtime" => DEFAULT_REALTIME_LEVEL,
        _ => match text.strip_prefix("realtime:").map(str::parse::<u8>) {
            Some(Ok(level)) => level,
            _ => {
                return Err(format!(
                    "`{text}`: expected `realtime`, `realtime:LEVEL` (1 to 99) or `normal`"
                ));
            }
        },
    };
    let p = HapticPriority::RealTime(level);
    if p.is_valid() {
        Ok(p)
    } else {
        Err(format!("`{text}`: the real-time level must be 1 to 99"))
    }
}

pub fn haptics_bench(args: &HapticsBenchArgs) -> Result<(), Box<dyn std::error::Error>> {
    if !(args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= 3600.0) {
        return Err(format!("--seconds {} must be in (0, 3600]", args.seconds).into());
    }
    let scene = load_scene(&args.scene, &args.assets)?;
    let mut world = SoftTissueWorld::from_scene(&scene, &args.assets)?;
    let script = if args.script.ends_with(".ron") {
        let text =
            std::fs::read_to_string(&args.script).map_err(|e| format!("{}: {e}", args.script))?;
        Script::from_ron(&text, &args.script)?
    } else {
        Script::builtin(&args.script, &world)?
    };
    let recording = match &args.replay {
        Some(path) => Recording::load(path)?,
        None => Recording::from_script(&script, 1000.0, 1.0)?,
    };
    let (_, axis) = script.pose_at(0.0);
    let tool = world.add_tool(Tool::new("haptic tool", script.tool)?);
    world.set_cut_options(soft_tissue_core::mesh::cut::CutOptions {
        background_steps: args.cut_background_steps,
        ..Default::default()
    })?;
    let blade = matches!(script.tool, ToolShape::Blade { .. });
    // Whole steps while the blade cuts or a cut is being prepared.
    let mut cutting_us = Vec::new();
    let dt = world.config().dt;
    // Scene-unit gains: the coupling is about as stiff as the organs' surface under the
    // tool; the proxy mass keeps the coupling's natural frequency at ~90 Hz (well resolved
    // at 1 kHz).
    let config = HapticConfig {
        record_seconds: args.seconds + 1.0,
        stats_seconds: args.seconds + 1.0,
        spin_us: args.spin_us,
        priority: args.priority,
        passivity: !args.no_passivity,
        ..HapticConfig::default()
    };
    let nominal = config.coupling.stiffness;
    let cut_stiffness = CutModel::STIFFNESS_PER_COUPLING * nominal;
    check_blade(&script, &args.script, cut_stiffness)?;
    let max_force = config.coupling.max_force;
    let thread = HapticThread::spawn(Box::new(ReplayDevice::new(recording, max_force)?), config)?;
    let shared = thread.shared().clone();
    let mut model = ContactModel::NONE;
    let mut step_us = Vec::with_capacity((args.seconds / dt).ceil() as usize + 1);
    let mut behind = 0u64;
    let mut last_buttons = 0u32;
    let start = Instant::now();
    let mut k: u64 = 0;
    let result = (|| -> Result<(), Box<dyn std::error::Error>> {
        while start.elapsed().as_secs_f64() < args.seconds {
            // Real time: step k runs when the wall clock reaches k dt.
            let due = start + Duration::from_secs_f64(k as f64 * dt);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            } else if now - due > Duration::from_secs_f64(dt) {
                behind += 1;
            }
            let sample = shared.tool();
            let t = world.tools_mut();
            t[tool].set_pose(sample.position, axis)?;
            let changed = sample.buttons ^ last_buttons;
            if blade {
                if changed & (GRAB | CUT) != 0 {
                    t[tool].set_cutting(sample.buttons & (GRAB | CUT) != 0)?;
                }
            } else if changed & GRAB != 0 {
                if sample.buttons & GRAB != 0 {
                    t[tool].grab();
                } else {
                    t[tool].release();
                }
            }
            if changed & CAUTERY != 0 {
                let w = if sample.buttons & CAUTERY != 0 {
                    args.cautery_watts
                } else {
                    0.0
                };
                t[tool].set_cautery(w)?;
            }
            last_buttons = sample.buttons;
            let cutting = world.cuts_in_flight() > 0 || world.tools()[tool].cutting();
            let t0 = Instant::now();
            world.step_fixed()?;
            step_us.push(t0.elapsed().as_secs_f64() * 1e6);
            if cutting {
                cutting_us.push(t0.elapsed().as_secs_f64() * 1e6);
            }
            model = contact_model(
                &world.tools()[tool],
                tool as u32,
                world.contacts(),
                &model,
                nominal,
                world.step_count(),
            );
            let cut = cut_model(&world.tools()[tool], cut_stiffness).map_err(|why| {
                HapticsBenchError::CutModel {
                    script: args.script.clone(),
                    step: k + 1,
                    why,
                }
            })?;
            shared.publish(&model, &cut)?;
            k += 1;
        }
        Ok(())
    })();
    let run = thread.stop()?;
    result?;
    if let Some(path) = &args.record {
        run.recording.save(path)?;
    }
    if let Some(path) = &args.save_script {
        let s = run.recording.to_script(
            "haptic session",
            script.tool,
            [axis.x, axis.y, axis.z],
            args.cautery_watts,
            10,
        );
        std::fs::write(path, s.to_ron()).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if let Some(e) = &run.device_error {
        return Err(e.to_string().into());
    }
    let q = |p: f64| run.period_quantile(p).unwrap_or(f64::NAN);
    let (p50, p99, p999, max) = (q(0.5), q(0.99), q(0.999), q(1.0));
    let mut sorted = step_us.clone();
    sorted.sort_unstable_by(f64::total_cmp);
    let physics_median = sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN);
    let physics_max = sorted.last().copied().unwrap_or(f64::NAN);
    let cutting = soft_tissue_core::timing::TimeStats::of(&cutting_us);
    let cuts = world
        .bodies()
        .iter()
        .filter_map(|b| b.cut_record())
        .map(|r| r.cuts)
        .max()
        .unwrap_or(0);
    let machine = crate::bench::machine();
    let rate = run.ticks as f64 / args.seconds;
    let target_met = p99 <= 1100.0;
    if args.json {
        let v = json!({
            "scene": args.scene,
            "seconds": args.seconds,
            "ticks": run.ticks,
            "rate_hz": rate,
            "period_p50_us": p50,
            "period_p99_us": p99,
            "period_p999_us": p999,
            "period_max_us": max,
            "missed_deadlines": run.missed,
            "max_force_step": run.max_force_step,
            "max_force_step_on_new_model": run.max_force_step_on_model,
            "force_step_p99": run.force_step_quantile(0.99),
            "max_force": run.max_force,
            "passivity": !args.no_passivity,
            "passivity_ticks": run.passivity_ticks,
            "passivity_dissipated": run.passivity_dissipated,
            "physics_steps": k,
            "physics_dt": dt,
            "physics_step_median_us": physics_median,
            "physics_step_max_us": physics_max,
            "physics_steps_late": behind,
            "physics_steps_while_cutting": cutting_us.len(),
            "physics_step_while_cutting_us": cutting,
            "cut_background_steps": args.cut_background_steps,
            "most_cuts_of_one_body": cuts,
            "recorded_samples": run.recording.samples.len(),
            "haptic_priority": priority_json(&run.priority),
            "spin_us": run.spin_us,
            "target_p99_le_1100_us": target_met,
            "machine": machine,
        });
        println!("{v}");
    } else {
        println!(
            "haptic loop: {} ticks in {:.1} s ({rate:.1} Hz); period p50 {p50:.1} us, p99 {p99:.1} us, \
             p99.9 {p999:.1} us, max {max:.1} us; missed deadlines {} ({:.3} %)",
            run.ticks,
            args.seconds,
            run.missed,
            100.0 * run.missed as f64 / run.ticks.max(1) as f64
        );
        println!(
            "haptic thread priority: {}; spin before each deadline {:.0} us",
            run.priority, run.spin_us
        );
        println!(
            "force: max {:.4}; change per tick: p99 {:.5}, largest {:.5}, largest on a tick that \
             took a new contact model {:.5} (scene units, clamp {max_force})",
            run.max_force,
            run.force_step_quantile(0.99).unwrap_or(f64::NAN),
            run.max_force_step,
            run.max_force_step_on_model
        );
        println!(
            "passivity controller: damping added in {} ticks, {:.3e} taken from the hand \
             (scene units)",
            run.passivity_ticks, run.passivity_dissipated
        );
        println!(
            "physics: {k} steps of {dt} s in real time, median {physics_median:.0} us, max {physics_max:.0} us, \
             {behind} late by more than a step"
        );
        if !cutting_us.is_empty() {
            println!(
                "physics while cutting: {} steps, median / p99 / max us {} ({}); a body cut {cuts} times",
                cutting_us.len(),
                crate::realtime::triple(&cutting),
                if args.cut_background_steps > 0 {
                    format!(
                        "cuts prepared on a thread of their own, landing {} steps later",
                        args.cut_background_steps
                    )
                } else {
                    "cuts made within the step".into()
                }
            );
        }
        println!(
            "target p99 <= 1100 us: {}; machine: {}, {} cores, {} build",
            if target_met { "met" } else { "MISSED" },
            machine["cpu"].as_str().unwrap_or("?"),
            machine["cores"],
            machine["profile"].as_str().unwrap_or("?")
        );
    }
    Ok(())
}

/// The priority outcome as JSON: what was asked, the policy and level (or nice value) the
/// OS reports, and the refusals.
fn priority_json(p: &soft_tissue_core::haptics::PriorityOutcome) -> serde_json::Value {
    let requested = match p.requested {
        HapticPriority::RealTime(level) => json!({ "real_time": level }),
        HapticPriority::Normal => json!("normal"),
    };
    let obtained = match &p.obtained {
        Scheduling::RealTime { policy, level } => json!({ "policy": policy, "level": level }),
        Scheduling::TimeSharing { policy, nice } => json!({ "policy": policy, "nice": nice }),
        Scheduling::Other(s) => json!({ "policy": s }),
    };
    json!({
        "requested": requested,
        "obtained": obtained,
        "real_time": p.is_real_time(),
        "refused": p.refused,
        "text": p.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::FromArgMatches;

    fn blade_script(length: f64) -> String {
        format!(
            "(name: \"tiny\", tool: Blade(length: {length:e}), \
             waypoints: [(t: 0.0, position: (0.0, 0.0, 0.0), axis: (0.0, 2.0, 0.0))], \
             events: [(t: 0.0, action: Cut(true))])"
        )
    }

    /// A blade whose edge has no direction the haptic loop can find (its length squared
    /// below the smallest normal number, or zero) is refused by name and length; one of a
    /// sane length passes.
    #[test]
    fn a_blade_too_short_for_the_haptic_loop_is_refused_by_name() {
        let stiffness =
            CutModel::STIFFNESS_PER_COUPLING * HapticConfig::default().coupling.stiffness;
        for length in [1e-160, 1e-170] {
            let script = Script::from_ron(&blade_script(length), "tiny.ron").unwrap();
            let e = check_blade(&script, "tiny.ron", stiffness).unwrap_err();
            assert!(
                matches!(e, HapticsBenchError::BladeEdge { length: l, .. } if l == length),
                "{e:?}"
            );
            let text = e.to_string();
            assert!(
                text.contains("--script `tiny.ron`") && text.contains(&format!("{length:e}")),
                "{text}"
            );
        }
        let script = Script::from_ron(&blade_script(1e-3), "short.ron").unwrap();
        assert!(check_blade(&script, "short.ron", stiffness).is_ok());
    }

    /// The bench refuses it before it runs: the error is the typed one (was the haptic
    /// loop's `edge` out of range, from the middle of the run, naming no option).
    #[test]
    fn haptics_bench_refuses_a_blade_too_short_before_it_runs() {
        let dir = std::env::temp_dir().join(format!("st-hb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("tiny.ron");
        std::fs::write(&file, blade_script(1e-160)).unwrap();
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
        let command = HapticsBenchArgs::augment_args(clap::Command::new("haptics-bench"));
        let mut argv: Vec<std::ffi::OsString> = "haptics-bench --scene cylinders --seconds 1 \
             --spin-us 300 --priority normal"
            .split_whitespace()
            .map(Into::into)
            .collect();
        argv.extend(["--script".into(), file.clone().into_os_string()]);
        argv.extend(["--assets".into(), assets.into_os_string()]);
        let matches = command.try_get_matches_from(argv).unwrap();
        let args = HapticsBenchArgs::from_arg_matches(&matches).unwrap();
        let e = haptics_bench(&args).expect_err("the bench ran with a blade it cannot render");
        let typed = e.downcast_ref::<HapticsBenchError>();
        assert!(
            matches!(typed, Some(HapticsBenchError::BladeEdge { .. })),
            "{e}"
        );
        assert!(e.to_string().contains("--script"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
