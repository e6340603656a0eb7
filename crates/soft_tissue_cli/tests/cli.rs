//! The `soft-tissue` binary end to end: JSON output, exit codes, conversion, generation.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_soft-tissue"))
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs the binary and returns its stdout, failing the test with stderr on a non-zero exit.
fn run_ok(args: &[&std::ffi::OsStr]) -> Vec<u8> {
    let out = bin().args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("st-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn info_json_has_the_documented_fields() {
    let fixture = root().join("tests/fixtures/block_v41_binary.msh");
    let stdout = run_ok(&[
        "mesh".as_ref(),
        "info".as_ref(),
        "--json".as_ref(),
        fixture.as_os_str(),
    ]);
    let v: serde_json::Value = serde_json::from_slice(&stdout).unwrap();
    assert_eq!(v["nodes"], 36);
    assert_eq!(v["tets"], 72);
    assert_eq!(v["components"], 1);
    // A 3 x 2 x 2 block of cubes: 2 * (6 + 6 + 4) quads, 2 triangles each.
    assert_eq!(v["surface_triangles"], 64);
    assert!(v["volume"].as_f64().unwrap() > 0.5);
    assert_eq!(v["bbox_min"].as_array().unwrap().len(), 3);
    assert_eq!(v["bbox_max"].as_array().unwrap().len(), 3);
    let warnings = v["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("skipped"))
    );
}

#[test]
fn bad_input_exits_non_zero_with_the_error() {
    let dir = tmp("bad");
    let f = dir.join("broken.msh");
    std::fs::write(
        &f,
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n2\n1 0 0 0\n",
    )
    .unwrap();
    let out = bin().args(["mesh", "info"]).arg(&f).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("broken.msh") && err.contains("line"), "{err}");
    let out = bin()
        .args(["mesh", "info", "does-not-exist.vtk"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    // A resolution too fine for memory is refused by a message, not a panic (exit 101).
    let generate = bin()
        .args(["mesh", "generate", "liver", "--resolution", "1e19", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let bench = bin()
        .args(["bench", "--generated", "liver", "--resolution", "1e30"])
        .args(["--method", "fem-linear", "--steps", "1"])
        .output()
        .unwrap();
    for out in [generate, bench] {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("lattice"), "{err}");
    }
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn convert_and_generate() {
    let dir = tmp("conv");
    run_ok(&[
        "mesh".as_ref(),
        "generate".as_ref(),
        "spleen".as_ref(),
        "--out".as_ref(),
        dir.as_os_str(),
    ]);
    let vtk = dir.join("spleen.vtk");
    for target in ["spleen.msh", "spleen.vtu", "spleen.node", "spleen.obj"] {
        let out = dir.join(target);
        run_ok(&[
            "mesh".as_ref(),
            "convert".as_ref(),
            "--binary".as_ref(),
            vtk.as_os_str(),
            out.as_os_str(),
        ]);
    }
    // Converted volume files describe the same mesh.
    let info = |p: PathBuf| -> serde_json::Value {
        serde_json::from_slice(&run_ok(&[
            "mesh".as_ref(),
            "info".as_ref(),
            "--json".as_ref(),
            p.as_os_str(),
        ]))
        .unwrap()
    };
    let a = info(vtk);
    for f in ["spleen.msh", "spleen.vtu", "spleen.ele"] {
        let b = info(dir.join(f));
        for key in [
            "nodes",
            "tets",
            "surface_triangles",
            "volume",
            "bbox_min",
            "bbox_max",
        ] {
            assert_eq!(a[key], b[key], "{f}: {key}");
        }
    }
    let out = bin()
        .args(["mesh", "generate", "kidney", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown body 'kidney'"));
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn simulate_json_lines_and_script_replay() {
    let assets = root().join("assets");
    let dir = tmp("simulate");
    let saved = dir.join("poke-a.ron");
    let args = |script: &std::path::Path| {
        vec![
            "simulate".into(),
            "--scene".into(),
            "cylinders".into(),
            "--script".into(),
            script.as_os_str().to_owned(),
            "--steps".into(),
            "40".into(),
            "--json".into(),
            "--assets".into(),
            assets.as_os_str().to_owned(),
        ]
    };
    let mut first: Vec<std::ffi::OsString> = args(Path::new("poke-a"));
    first.extend(["--save-script".into(), saved.as_os_str().to_owned()]);
    let refs: Vec<&std::ffi::OsStr> = first.iter().map(|s| s.as_os_str()).collect();
    let out = String::from_utf8(run_ok(&refs)).unwrap();
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 41);
    for (k, l) in lines[..40].iter().enumerate() {
        assert_eq!(l["step"], k + 1);
        assert!(l["t"].as_f64().unwrap() > 0.0);
        let bodies = l["bodies"].as_array().unwrap();
        assert_eq!(bodies.len(), 2);
        for b in bodies {
            assert!(["cage", "fem", "msd"].contains(&b["level"].as_str().unwrap()));
            assert!(b["step_us"].as_f64().unwrap() >= 0.0);
            assert!(b["max_displacement"].as_f64().unwrap().is_finite());
            assert!(b["switch_jump"].is_null() || b["switch_jump"].as_f64().is_some());
            assert!(b["contacts"].as_u64().is_some());
            assert!(b["name"].is_string());
        }
    }
    // The tool reaches A at 0.5 s (step 25): A rises, B does not.
    assert_eq!(lines[39]["bodies"][0]["level"], "fem");
    assert_eq!(lines[39]["bodies"][1]["level"], "cage");
    let summary = &lines[40];
    assert_eq!(summary["summary"], true);
    assert_eq!(summary["steps"], 40);
    // The saved script replays to the same states.
    let replay = String::from_utf8(run_ok(
        &args(&saved)
            .iter()
            .map(|s| s.as_os_str())
            .collect::<Vec<_>>(),
    ))
    .unwrap();
    let strip = |s: &str| -> Vec<String> {
        s.lines()
            .take(40)
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                let b = &v["bodies"];
                format!(
                    "{} {} {}",
                    v["step"], b[0]["max_displacement"], b[0]["level"]
                )
            })
            .collect()
    };
    assert_eq!(strip(&out), strip(&replay));
    // A missing scene file is an error naming it.
    let bad = bin()
        .args(["simulate", "--scene", "no-such.ron", "--steps", "1"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("no-such.ron"));
}

#[test]
fn simulate_reports_the_cage_error_against_a_shadow() {
    let assets = root().join("assets");
    let out = run_ok(&[
        "simulate".as_ref(),
        "--scene".as_ref(),
        "cylinders".as_ref(),
        "--script".as_ref(),
        "poke-a".as_ref(),
        "--steps".as_ref(),
        "900".as_ref(),
        "--json".as_ref(),
        "--shadow".as_ref(),
        "--assets".as_ref(),
        assets.as_os_str(),
    ]);
    let out = String::from_utf8(out).unwrap();
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let mut precise_then_cage = false;
    for l in &lines[..900] {
        for b in l["bodies"].as_array().unwrap() {
            // A shadow gap exists exactly while the body is at its cage.
            let at_cage = b["level"] == "cage";
            assert_eq!(b["shadow_error_ratio"].is_number(), at_cage, "{b}");
            precise_then_cage |= !at_cage;
        }
    }
    assert!(precise_then_cage, "poke-a should raise model A");
    let summary = &lines[900];
    for b in summary["bodies"].as_array().unwrap() {
        let worst = b["worst_shadow_error_ratio"].as_f64().unwrap();
        let mean = b["mean_shadow_error_ratio"].as_f64().unwrap();
        // The paper's bound for the cage against FEM: 4 % of the smallest dimension.
        assert!(worst.is_finite() && worst < 0.04, "{b}");
        assert!(mean <= worst, "{b}");
    }
}

#[test]
fn haptics_bench_reports_records_and_its_session_replays_as_a_script() {
    let dir = tmp("haptics");
    let rec = dir.join("session.ron");
    let script = dir.join("session.script.ron");
    let assets = root().join("assets");
    let stdout = run_ok(&[
        "haptics-bench".as_ref(),
        "--scene".as_ref(),
        "cylinders".as_ref(),
        "--script".as_ref(),
        "poke-a".as_ref(),
        "--seconds".as_ref(),
        "1.5".as_ref(),
        "--spin-us".as_ref(),
        "300".as_ref(),
        "--json".as_ref(),
        "--assets".as_ref(),
        assets.as_os_str(),
        "--record".as_ref(),
        rec.as_os_str(),
        "--save-script".as_ref(),
        script.as_os_str(),
    ]);
    let v: serde_json::Value = serde_json::from_slice(&stdout).unwrap();
    for key in [
        "period_p50_us",
        "period_p99_us",
        "period_p999_us",
        "period_max_us",
        "missed_deadlines",
        "max_force_step",
        "machine",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    let ticks = v["ticks"].as_u64().unwrap();
    assert!(ticks > 0);
    // The priority the haptic thread asked for (real time by default) and what it got: the
    // level asked, or a stated refusal.
    let p = &v["haptic_priority"];
    assert_eq!(p["requested"]["real_time"], 80, "{p}");
    if p["real_time"].as_bool().unwrap() {
        assert_eq!(p["obtained"]["level"], 80, "{p}");
        assert!(p["refused"].is_null(), "{p}");
    } else {
        assert!(!p["refused"].as_str().unwrap().is_empty(), "{p}");
    }
    // The force never exceeds the coupling's clamp (8 scene units).
    assert!(v["max_force"].as_f64().unwrap() <= 8.0 + 1e-9);
    // The recording holds one sample per tick, in increasing time at the haptic rate.
    let r = soft_tissue_core::haptics::Recording::load(&rec).unwrap();
    assert_eq!(r.samples.len() as u64, ticks);
    assert!((r.samples[1].t - r.samples[0].t - 1e-3).abs() < 1e-12);
    // The session, as a script, drives `simulate`.
    let out = run_ok(&[
        "simulate".as_ref(),
        "--scene".as_ref(),
        "cylinders".as_ref(),
        "--assets".as_ref(),
        assets.as_os_str(),
        "--script".as_ref(),
        script.as_os_str(),
        "--steps".as_ref(),
        "20".as_ref(),
    ]);
    assert!(!out.is_empty());
    // A bad duration is refused with a message.
    let out = bin()
        .args(["haptics-bench", "--seconds=0"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--seconds"));
}

#[cfg(target_os = "linux")]
#[test]
fn haptics_bench_names_the_priority_and_keeps_normal_when_asked() {
    let assets = root().join("assets");
    let stdout = run_ok(&[
        "haptics-bench".as_ref(),
        "--scene".as_ref(),
        "cylinders".as_ref(),
        "--script".as_ref(),
        "poke-a".as_ref(),
        "--seconds".as_ref(),
        "0.3".as_ref(),
        "--spin-us".as_ref(),
        "300".as_ref(),
        "--priority".as_ref(),
        "normal".as_ref(),
        "--assets".as_ref(),
        assets.as_os_str(),
    ]);
    let text = String::from_utf8_lossy(&stdout);
    let line = text
        .lines()
        .find(|l| l.starts_with("haptic thread priority: "))
        .unwrap_or_else(|| panic!("no priority line in {text}"));
    assert!(line.contains("SCHED_OTHER"), "{line}");
    assert!(line.contains("(asked normal)"), "{line}");
    assert!(!line.contains("refused"), "{line}");
    // Levels outside 1 to 99 and unknown words are refused with a message naming the flag.
    for bad in ["realtime:0", "realtime:100", "fast"] {
        let out = bin()
            .args(["haptics-bench", "--priority", bad])
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--priority") && err.contains(bad), "{err}");
    }
}

#[test]
fn simulate_ends_quietly_when_its_reader_stops() {
    // `simulate --json | head -1`: the pipe closes after one line; the run must end without a
    // panic and with success.
    use std::io::{BufRead, BufReader};
    let mut child = bin()
        .args(["simulate", "--scene", "cylinders", "--script", "poke-a"])
        .args(["--steps", "400", "--json", "--assets"])
        .arg(root().join("assets"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let mut first = String::new();
    BufReader::new(stdout).read_line(&mut first).unwrap();
    assert!(first.starts_with('{'), "{first}");
    // The reader is dropped here: the pipe is closed.
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(!err.contains("panicked"), "{err}");
}

/// A scene file naming a mesh outside the assets folder is refused (the body and the path
/// named) unless `--allow-outside-assets` is given.
#[test]
fn simulate_keeps_mesh_paths_inside_the_assets_folder() {
    let dir = tmp("outside");
    let assets = root().join("assets");
    let text = std::fs::read_to_string(assets.join("scenes/organs.scene.ron")).unwrap();
    let liver = assets.join("meshes/liver.vtk").canonicalize().unwrap();
    let scene = dir.join("outside.scene.ron");
    std::fs::write(
        &scene,
        text.replace(
            "\"meshes/liver.vtk\"",
            &format!("{:?}", liver.display().to_string()),
        ),
    )
    .unwrap();
    let run = |allow: bool| {
        let mut cmd = bin();
        cmd.args(["simulate", "--steps", "2", "--threads", "1", "--scene"])
            .arg(&scene)
            .arg("--assets")
            .arg(&assets);
        if allow {
            cmd.arg("--allow-outside-assets");
        }
        cmd.output().unwrap()
    };
    let refused = run(false);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{err}");
    assert!(
        err.contains("Liver") && err.contains("assets folder"),
        "{err}"
    );
    let allowed = run(true);
    assert!(
        allowed.status.success(),
        "{}",
        String::from_utf8_lossy(&allowed.stderr)
    );
    std::fs::remove_dir_all(dir).ok();
}

/// `mesh tetrahedralize --max-distance`: the paper-sized liver's boundary meshed to within
/// 1 % of its diagonal both ways, the walls and every try in the JSON; with a cap below
/// what 0.1 % takes, the command stops at the cap and says so; the flag refuses a spacing
/// beside it.
#[test]
fn tetrahedralize_to_a_distance_reports_its_tries_and_its_cap() {
    let dir = tmp("distance");
    let obj = dir.join("liver.obj");
    let vtk = root().join("assets/meshes/liver.vtk");
    run_ok(&[
        "mesh".as_ref(),
        "convert".as_ref(),
        vtk.as_os_str(),
        obj.as_os_str(),
    ]);
    let out = dir.join("liver.vtu");
    let mesh = |extra: &[&str]| -> serde_json::Value {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "mesh".as_ref(),
            "tetrahedralize".as_ref(),
            obj.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--json".as_ref(),
        ];
        args.extend(extra.iter().map(std::ffi::OsStr::new));
        serde_json::from_slice(&run_ok(&args)).unwrap()
    };
    let v = mesh(&["--max-distance", "1"]);
    let r = &v["report"];
    let worst = r["mesh_to_surface"]
        .as_f64()
        .unwrap()
        .max(r["surface_to_mesh"].as_f64().unwrap())
        / r["bbox_diagonal"].as_f64().unwrap();
    assert!(worst <= 0.01, "{v}");
    let volume = r["volume"].as_f64().unwrap() / r["enclosed_volume"].as_f64().unwrap() - 1.0;
    assert!(volume.abs() <= 0.03, "{v}");
    assert_eq!(v["search"]["reached"], true, "{v}");
    assert!(v["search"]["shortfall"].is_null(), "{v}");
    let tries = v["search"]["tries"].as_array().unwrap();
    assert_eq!(tries.last().unwrap()["tets"], r["tets"], "{v}");
    let walls = &v["search"]["walls"]["walls"];
    assert!(
        walls["thin"].as_f64().unwrap() > 0.0
            && walls["thin"].as_f64().unwrap() <= walls["median"].as_f64().unwrap(),
        "{v}"
    );
    // The written mesh is the one reported.
    let info: serde_json::Value = serde_json::from_slice(&run_ok(&[
        "mesh".as_ref(),
        "info".as_ref(),
        "--json".as_ref(),
        out.as_os_str(),
    ]))
    .unwrap();
    assert_eq!(info["tets"], r["tets"]);

    let v = mesh(&["--max-distance", "0.1", "--max-tets", "2000"]);
    assert_eq!(v["search"]["reached"], false, "{v}");
    let short = v["search"]["shortfall"].as_str().unwrap();
    assert!(short.contains("cap of 2000 tetrahedra"), "{short}");
    assert!(short.contains("walls as thin as"), "{short}");
    let tries = v["search"]["tries"].as_array().unwrap();
    assert!(
        tries.iter().all(|t| t["tets"].as_u64().unwrap() <= 2400),
        "{v}"
    );

    let refused = bin()
        .args(["mesh", "tetrahedralize"])
        .arg(&obj)
        .arg("--out")
        .arg(&out)
        .args(["--max-distance", "1", "--edge-length", "0.1"])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--edge-length"));
    std::fs::remove_dir_all(dir).ok();
}
