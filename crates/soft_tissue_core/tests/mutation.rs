//! Deterministic mutation sweep (issue 21): every real-world mesh (the repository's
//! `assets/meshes`, the shared folder `../shared/meshes` beside the clone when present (its
//! absence fails the test under `SOFT_TISSUE_REQUIRE_SHARED=1`, as in CI), and
//! the folders named in `SOFT_TISSUE_MUTATION_DIRS`, separated by `:`), every scene in
//! `assets/scenes`, the script, recording and OBJ seeds of the fuzz targets (`fuzz/seeds`),
//! recordings sampled from those scripts, and the surface files (OBJ, STL, PLY, glTF and GLB
//! in `tests/fixtures` and `assets/meshes`; each surface read is then repaired) are read after seeded truncations, bit flips,
//! byte replacements and declared counts replaced by zero, negative and huge values. Each
//! read must return `Ok` or a typed error (a mesh error names the file), never panic and
//! never hang: a panic is caught and reported with the file and the mutation that caused it,
//! a file whose sweep takes longer than the guard fails the test naming the mutation under
//! way.
//!
//! Reproduce one failure: `support::Mutation` printed in the report, applied to the file
//! (`Mutation::apply`), read by the reader named with it. `SOFT_TISSUE_MUTATION_SCALE=10`
//! runs ten times as many mutations, `SOFT_TISSUE_MUTATION_SEED=N` other ones.

use soft_tissue_core::haptics::Recording;
use soft_tissue_core::mesh::io::{
    FormatError, MeshFormat, SurfaceMesh, parse_gltf, parse_obj, parse_ply, parse_stl,
    parse_tet_mesh,
};
use soft_tissue_core::mesh::tetrahedralize::repair;
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::Script;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

mod support;
use support::{Mutation, SweepSize, mutations};

/// Longest sweep of one input before it counts as a hang, times the scale (a test build with
/// overflow checks; the largest shared file takes a few seconds at scale 1).
const HANG_GUARD: Duration = Duration::from_secs(60);

#[derive(Debug, Clone, Copy)]
enum Reader {
    Mesh(MeshFormat),
    /// The surface readers, each followed by the mesher's repair of what it read (which
    /// must not panic either).
    Obj,
    Stl,
    Ply,
    Gltf,
    Scene,
    Script,
    Recording,
}

struct Input {
    name: String,
    bytes: Vec<u8>,
    reader: Reader,
    /// The unchanged input must read: not for files meant to be bad (`bad` or `broken` in the
    /// name) nor for the extra folders (which may hold surfaces, not volumes).
    must_read: bool,
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .collect();
    v.sort();
    v
}

fn input(path: &Path, reader: Reader) -> Input {
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    Input {
        bytes: std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
        must_read: !(name.contains("bad") || name.contains("broken")),
        name,
        reader,
    }
}

fn mesh_inputs(dir: &Path, must_read: bool, inputs: &mut Vec<Input>) -> usize {
    let before = inputs.len();
    for p in files(dir) {
        if let Some(f) = MeshFormat::from_path(&p)
            && f != MeshFormat::TetGen
        {
            let mut i = input(&p, Reader::Mesh(f));
            i.must_read &= must_read;
            inputs.push(i);
        }
    }
    inputs.len() - before
}

/// Reads `bytes`: the error message, or a note that it does not name the file.
fn read(reader: Reader, bytes: &[u8], name: &str) -> Result<(), String> {
    let text = || String::from_utf8_lossy(bytes);
    let named = |m: String| {
        if m.starts_with(name) {
            m
        } else {
            format!("error does not name the file: {m}")
        }
    };
    match reader {
        Reader::Mesh(f) => parse_tet_mesh(bytes, f, name)
            .map(drop)
            .map_err(|e| named(e.to_string())),
        Reader::Obj => surface(parse_obj(bytes, name), named),
        Reader::Stl => surface(parse_stl(bytes, name), named),
        Reader::Ply => surface(parse_ply(bytes, name), named),
        // A buffer in another file is answered with the unchanged `spheres.bin` of the
        // fixtures, any other name as missing (the mutations reach the JSON and the GLB
        // container).
        Reader::Gltf => surface(
            parse_gltf(bytes, name, &mut |uri| {
                let found = match uri {
                    "spheres.bin" => std::fs::read(repo().join("tests/fixtures/spheres.bin")),
                    _ => Err(std::io::ErrorKind::NotFound.into()),
                };
                found.map_err(|source| FormatError::Io {
                    file: uri.to_owned(),
                    source,
                })
            }),
            named,
        ),
        Reader::Scene => Scene::from_ron(&text(), name)
            .map(drop)
            .map_err(|e| e.to_string()),
        Reader::Script => Script::from_ron(&text(), name)
            .map(drop)
            .map_err(|e| e.to_string()),
        Reader::Recording => Recording::from_ron(&text(), name)
            .map(drop)
            .map_err(|e| e.to_string()),
    }
}

/// A surface reader's result, then the mesher's repair of the surface (its error is no
/// failure: a mutated surface may be beyond repair).
fn surface(
    read: Result<SurfaceMesh, FormatError>,
    named: impl Fn(String) -> String,
) -> Result<(), String> {
    let s = read.map_err(|e| named(e.to_string()))?;
    let _ = repair(&s);
    Ok(())
}

struct Outcome {
    runs: usize,
    failures: Vec<String>,
    /// The slowest read and its mutation.
    slowest: (Duration, Option<usize>),
}

/// Every mutation of `input`: panics and errors that do not name the file are failures.
fn sweep(input: &Input, list: &[Mutation], progress: &AtomicUsize) -> Outcome {
    let mut failures = Vec::new();
    let name = &input.name;
    match catch_unwind(AssertUnwindSafe(|| read(input.reader, &input.bytes, name))) {
        Ok(Err(e)) if input.must_read => failures.push(format!("{name} unchanged: {e}")),
        Err(_) => failures.push(format!("{name} unchanged: panicked")),
        _ => {}
    }
    let mut slowest = (Duration::ZERO, None);
    for (k, m) in list.iter().enumerate() {
        progress.store(k, Ordering::Relaxed);
        let bytes = m.apply(&input.bytes);
        let start = Instant::now();
        let result = catch_unwind(AssertUnwindSafe(|| read(input.reader, &bytes, name)));
        if start.elapsed() > slowest.0 {
            slowest = (start.elapsed(), Some(k));
        }
        match result {
            Err(_) => failures.push(format!("{name} ({:?}), {m}: panicked", input.reader)),
            Ok(Err(e)) if e.starts_with("error does not name") => {
                failures.push(format!("{name} ({:?}), {m}: {e}", input.reader))
            }
            Ok(_) => {}
        }
    }
    Outcome {
        runs: list.len() + 1,
        failures,
        slowest,
    }
}

/// A line on the test's standard error that `cargo test` shows even when the test passes
/// (the print macros' output is captured).
fn loud(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// `SOFT_TISSUE_MUTATION_SCALE` (a whole number, 1 by default) multiplies every count for a
/// longer local sweep.
fn scale() -> usize {
    let v = std::env::var("SOFT_TISSUE_MUTATION_SCALE").unwrap_or_default();
    if v.is_empty() {
        return 1;
    }
    v.parse()
        .unwrap_or_else(|_| panic!("SOFT_TISSUE_MUTATION_SCALE={v}: expected a whole number"))
}

/// `SOFT_TISSUE_MUTATION_SEED` (a whole number) changes every mutation; the default keeps the
/// sweep the same from run to run.
fn base_seed() -> u64 {
    let v = std::env::var("SOFT_TISSUE_MUTATION_SEED").unwrap_or_default();
    if v.is_empty() {
        return 0x5EED_0000;
    }
    v.parse()
        .unwrap_or_else(|_| panic!("SOFT_TISSUE_MUTATION_SEED={v}: expected a whole number"))
}

fn size_for(len: usize, scale: usize) -> SweepSize {
    // Large files parse slowly in the test build: fewer mutations, the same kinds.
    let big = len > 100_000;
    SweepSize {
        truncations: scale * if big { 100 } else { 400 },
        bit_flips: scale * if big { 250 } else { 1500 },
        replacements: scale * if big { 250 } else { 1500 },
        integers: scale * if big { 40 } else { 160 },
    }
}

/// Scripts sampled into recordings (RON, as `Recording::save` writes them): the recording
/// inputs made by the code itself.
fn recordings_of(scripts: &[Input]) -> Vec<Input> {
    scripts
        .iter()
        .map(|s| {
            let script = Script::from_ron(&String::from_utf8_lossy(&s.bytes), &s.name)
                .unwrap_or_else(|e| panic!("{e}"));
            let r = Recording::from_script(&script, 20.0, 0.2).unwrap_or_else(|e| panic!("{e}"));
            let text = ron::ser::to_string_pretty(&r, ron::ser::PrettyConfig::default()).unwrap();
            Input {
                name: format!("recording of {}", s.name),
                bytes: text.into_bytes(),
                reader: Reader::Recording,
                must_read: true,
            }
        })
        .collect()
}

#[test]
fn no_reader_panics_or_hangs_on_mutated_real_files() {
    let root = repo();
    let mut inputs = Vec::new();
    let own = mesh_inputs(&root.join("assets/meshes"), true, &mut inputs);
    assert!(own > 0, "no meshes in assets/meshes");
    let shared = root.join("../shared/meshes");
    if let Some(shared) = support::shared_folder(
        &shared,
        "mutation sweep of the shared real-world meshes",
        support::shared_meshes_required(),
    ) {
        let n = mesh_inputs(shared, true, &mut inputs);
        eprintln!(
            "mutation sweep: {n} shared meshes from {}",
            shared.display()
        );
    }
    for dir in std::env::var("SOFT_TISSUE_MUTATION_DIRS")
        .unwrap_or_default()
        .split(':')
        .filter(|d| !d.is_empty())
    {
        let n = mesh_inputs(Path::new(dir), false, &mut inputs);
        eprintln!("mutation sweep: {n} meshes from {dir} (SOFT_TISSUE_MUTATION_DIRS)");
    }
    for p in files(&root.join("assets/scenes")) {
        inputs.push(input(&p, Reader::Scene));
    }
    let seeds = root.join("fuzz/seeds");
    let scripts: Vec<Input> = files(&seeds.join("script"))
        .iter()
        .map(|p| input(p, Reader::Script))
        .collect();
    assert!(!scripts.is_empty(), "no script seeds");
    inputs.extend(recordings_of(&scripts));
    inputs.extend(scripts);
    for p in files(&seeds.join("recording")) {
        inputs.push(input(&p, Reader::Recording));
    }
    for p in files(&seeds.join("obj")) {
        inputs.push(input(&p, Reader::Obj));
    }
    // The surface files the tests read back against other writers (meshio, trimesh,
    // pygltflib), and the STL and glTF in `assets/meshes`.
    let fixtures = root.join("tests/fixtures");
    for (file, reader) in [
        ("sphere.obj", Reader::Obj),
        ("sphere_ascii.stl", Reader::Stl),
        ("sphere_binary.stl", Reader::Stl),
        ("sphere_ascii.ply", Reader::Ply),
        ("sphere_binary.ply", Reader::Ply),
        ("sphere.glb", Reader::Gltf),
        ("spheres.gltf", Reader::Gltf),
        ("spheres_embedded.gltf", Reader::Gltf),
    ] {
        inputs.push(input(&fixtures.join(file), reader));
    }
    inputs.push(input(&root.join("assets/meshes/sphere.stl"), Reader::Stl));

    let (scale, seed) = (scale(), base_seed());
    let files = inputs.len();
    let mut total = 0;
    let mut failures = Vec::new();
    for (i, input) in inputs.into_iter().enumerate() {
        let list = Arc::new(mutations(
            &input.bytes,
            seed.wrapping_add(i as u64),
            size_for(input.bytes.len(), scale),
        ));
        let progress = Arc::new(AtomicUsize::new(0));
        let (tx, rx) = mpsc::channel();
        let input = Arc::new(input);
        let worker = {
            let (input, list, progress) = (input.clone(), list.clone(), progress.clone());
            std::thread::spawn(move || {
                let start = Instant::now();
                let outcome = sweep(&input, &list, &progress);
                let _ = tx.send((outcome, start.elapsed()));
            })
        };
        let guard = HANG_GUARD * scale as u32;
        match rx.recv_timeout(guard) {
            Ok((outcome, took)) => {
                let (time, k) = outcome.slowest;
                eprintln!(
                    "mutation sweep: {:>5} reads of {} ({} bytes) in {:.1} s, slowest {:.1} ms ({})",
                    outcome.runs,
                    input.name,
                    input.bytes.len(),
                    took.as_secs_f64(),
                    time.as_secs_f64() * 1e3,
                    k.map_or("none".into(), |k| list[k].to_string())
                );
                total += outcome.runs;
                failures.extend(outcome.failures);
                worker.join().unwrap();
            }
            Err(_) => {
                let k = progress.load(Ordering::Relaxed);
                panic!(
                    "{} ({:?}): the sweep took over {} s (a hang?), at mutation {k}: {}",
                    input.name,
                    input.reader,
                    guard.as_secs(),
                    list[k]
                );
            }
        }
    }
    loud(&format!(
        "mutation sweep: {total} reads of {files} inputs (seed {seed}, scale {scale})"
    ));
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// The mutations themselves: reproducible from the seed and what they claim to be.
#[test]
fn mutations_are_reproducible_and_as_described() {
    let text = b"$Nodes\n12\n1 0.5 -3 2e5\n$EndNodes\n<Piece NumberOfPoints=\"8\">\n";
    let size = SweepSize {
        truncations: 10,
        bit_flips: 5,
        replacements: 5,
        integers: 8,
    };
    let a = mutations(text, 7, size);
    assert_eq!(a, mutations(text, 7, size));
    assert_ne!(a, mutations(text, 8, size));
    // Integers: the count, the node number, -3 and the quoted 8 (not 0.5, 2e5 or a word).
    let ints: Vec<&[u8]> = support::integers(text)
        .into_iter()
        .map(|(s, e)| &text[s..e])
        .collect();
    assert_eq!(ints, [&b"12"[..], b"1", b"-3", b"8"]);
    let huge = Mutation::Count {
        start: 7,
        end: 9,
        value: "18446744073709551616",
    };
    assert!(a.contains(&huge));
    assert!(
        String::from_utf8(huge.apply(text))
            .unwrap()
            .starts_with("$Nodes\n18446744073709551616\n1 0.5")
    );
    assert_eq!(Mutation::Truncate(3).apply(text), b"$No");
    assert_eq!(Mutation::FlipBit { byte: 0, bit: 0 }.apply(text)[0], b'%');
}
