//! Speed against error (every level and setting against a fine-step corotational FEM
//! reference) and step time against mesh size.

use std::path::Path;
use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::bench::{BenchBody, BenchMethod};
use soft_tissue_core::cage::CageDynamics;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::fem::FemIntegrator;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::msd::SpringStiffness;
use soft_tissue_core::precision::{BodySettings, Level, PreciseMethod as Method};
use soft_tissue_core::scenario::{CYLINDER_MSD, CageKind, ORGAN_FEM, Scene};
use soft_tissue_core::world::{Script, SoftTissueWorld, WorldBody, scene_bodies};

use super::{Res, median};
use crate::simulate::drive_tool;

/// Builds a scene's world after `edit` has changed every body's level settings.
pub(super) fn build_world(
    scene: &Scene,
    assets: &Path,
    edit: &dyn Fn(&mut BodySettings),
) -> Res<SoftTissueWorld> {
    let (mut config, bodies) = scene_bodies(scene, assets)?;
    let mut world = None;
    for mut b in bodies {
        edit(&mut b.settings);
        config.dt = b.settings.dt;
        let w = match &mut world {
            Some(w) => w,
            None => world.insert(SoftTissueWorld::new(config)?),
        };
        w.add_body(WorldBody::new(
            b.name,
            Arc::new(b.mesh),
            b.settings,
            b.heat,
        )?)?;
    }
    Ok(world.ok_or("the scene has no bodies")?)
}

/// One configuration of the sweep: a level, its method or cage, and a time step.
#[derive(Debug, Clone)]
pub(super) struct Config {
    pub label: String,
    /// The family a point is drawn with.
    pub family: &'static str,
    pub method: Method,
    /// Time integrator of the FEM methods.
    pub integrator: FemIntegrator,
    pub level: Level,
    pub cage: CageKind,
    /// How the cage moves (cage level only).
    pub cage_dynamics: CageDynamics,
    /// The MSD's springs fitted to the body's FEM material instead of the scene's constant.
    pub material_springs: bool,
    pub dt: f64,
}

/// The sweep's reference and its own convergence.
#[derive(Debug, Clone)]
pub(super) struct Reference {
    pub config: Config,
    /// The run at half the reference's step.
    pub halved: String,
    /// Largest node distance between the two over the run, % of the smallest dimension.
    pub halving_max_pct: f64,
    /// Mean over the run of their mean node distance, %.
    pub halving_mean_pct: f64,
}

/// A measured point of the sweep.
#[derive(Debug, Clone)]
pub(super) struct Point {
    pub config: Config,
    /// Median step time of the measured body, us.
    pub median_us: f64,
    /// Mean over the run of the mean node distance, % of the smallest dimension.
    pub mean_pct: f64,
    /// Largest node distance over the run, % of the smallest dimension.
    pub max_pct: f64,
    /// No other point is both faster and more accurate (by the largest distance).
    pub pareto: bool,
}

/// The sweep's configurations around the paper's step `dt`.
pub(super) fn configs(quick: bool, dt: f64) -> Vec<Config> {
    let precise = |method, family, dt: f64| Config {
        label: format!("{family} dt {dt}"),
        family,
        method,
        integrator: FemIntegrator::BackwardEuler,
        level: Level::Precise,
        cage: CageKind::BoundingBox,
        cage_dynamics: CageDynamics::Calibrated,
        material_springs: false,
        dt,
    };
    let cage = |kind, name: &str, dt: f64| Config {
        label: format!("cage {name} dt {dt}"),
        family: "cage",
        method: Method::CorotationalFem,
        integrator: FemIntegrator::BackwardEuler,
        level: Level::Cage,
        cage: kind,
        cage_dynamics: CageDynamics::Calibrated,
        material_springs: false,
        dt,
    };
    // The paper's cage MSD instead of the calibrated dynamics.
    let paper_cage = |kind, name: &str, dt: f64| Config {
        label: format!("cage {name} paper dt {dt}"),
        family: "cage (paper)",
        cage_dynamics: CageDynamics::Paper,
        ..cage(kind, name, dt)
    };
    // The MSD with springs fitted to the material.
    let material = |method, family, dt: f64| Config {
        material_springs: true,
        ..precise(method, family, dt)
    };
    let co = Method::CorotationalFem;
    let pf = Method::PrefactoredFem;
    let li = Method::LinearFem;
    let rk4 = Method::MsdRk4;
    let implicit = Method::MsdImplicit;
    let msd_bdf2 = Method::MsdBdf2;
    // The FEM methods with the second-order integrator.
    let bdf2 = |method, family, dt: f64| Config {
        integrator: FemIntegrator::Bdf2,
        ..precise(method, family, dt)
    };
    if quick {
        return vec![
            precise(co, "FEM corotational", dt),
            bdf2(co, "FEM corotational BDF2", dt),
            precise(pf, "FEM corotational prefactored", dt),
            precise(li, "FEM linear", dt),
            bdf2(li, "FEM linear BDF2", dt),
            precise(implicit, "MSD implicit", dt),
            material(implicit, "MSD implicit material", dt),
            cage(CageKind::BoundingBox, "box", dt),
            paper_cage(CageKind::BoundingBox, "box", dt),
        ];
    }
    let mut v = Vec::new();
    for s in [1.0, 2.0, 4.0] {
        v.push(precise(co, "FEM corotational", dt * s));
    }
    for s in [1.0, 2.0, 4.0] {
        v.push(bdf2(co, "FEM corotational BDF2", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(precise(pf, "FEM corotational prefactored", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(precise(li, "FEM linear", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(bdf2(li, "FEM linear BDF2", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(precise(rk4, "MSD RK4", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(precise(implicit, "MSD implicit", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(precise(msd_bdf2, "MSD BDF2", dt * s));
    }
    for s in [1.0, 2.0] {
        v.push(material(implicit, "MSD implicit material", dt * s));
    }
    v.push(material(msd_bdf2, "MSD BDF2 material", dt));
    for s in [1.0, 2.0] {
        v.push(cage(CageKind::BoundingBox, "box", dt * s));
    }
    v.push(paper_cage(CageKind::BoundingBox, "box", dt));
    v.push(paper_cage(
        CageKind::Fitted { vertices: 128 },
        "fitted 128",
        dt,
    ));
    for n in [32, 64, 128] {
        v.push(cage(
            CageKind::Fitted { vertices: n },
            &format!("fitted {n}"),
            dt,
        ));
    }
    v
}

/// The configurations whose family contains `family` (all without it), each family at the
/// steps `scales` times `dt` when given (its first configuration rescaled), as listed
/// otherwise.
pub(super) fn select(
    configs: Vec<Config>,
    family: Option<&str>,
    scales: Option<&[f64]>,
    dt: f64,
) -> Res<Vec<Config>> {
    let chosen: Vec<Config> = configs
        .into_iter()
        .filter(|c| family.is_none_or(|f| c.family.contains(f)))
        .collect();
    if chosen.is_empty() {
        return Err(format!("no setting's family contains {:?}", family.unwrap_or("")).into());
    }
    let Some(scales) = scales else {
        return Ok(chosen);
    };
    if let Some(s) = scales.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        return Err(format!("--sweep-scales: {s} is not a positive step multiple").into());
    }
    let mut out = Vec::new();
    let mut seen: Vec<&'static str> = Vec::new();
    for c in &chosen {
        // A family's first setting, once per cage shape.
        if seen.contains(&c.family) && c.level == Level::Precise {
            continue;
        }
        if out
            .iter()
            .any(|o: &Config| o.family == c.family && o.cage == c.cage && o.dt == dt * scales[0])
        {
            continue;
        }
        seen.push(c.family);
        for &s in scales {
            let step = dt * s;
            let base = c
                .label
                .rsplit_once(" dt ")
                .map_or(c.label.as_str(), |(l, _)| l);
            out.push(Config {
                label: format!("{base} dt {step}"),
                dt: step,
                ..c.clone()
            });
        }
    }
    Ok(out)
}

/// Positions of the first body after each step of a run of `duration` seconds at `config`,
/// every body held at the config's level; also the first body's median step time, us.
fn trajectory(
    scene: &Scene,
    assets: &Path,
    script: &str,
    config: &Config,
    duration: f64,
    cg: Option<(f64, u32)>,
) -> Res<(Vec<Vec<Vec3>>, f64)> {
    let mut world = build_world(scene, assets, &|s: &mut BodySettings| {
        s.precise = config.method;
        s.fem_integrator = config.integrator;
        s.cage = config.cage;
        s.cage_dynamics = config.cage_dynamics;
        if config.material_springs {
            s.msd_spring_stiffness = SpringStiffness::Material {
                young_modulus: s.fem.young_modulus,
                poisson_ratio: s.fem.poisson_ratio,
            };
        }
        s.dt = config.dt;
    })?;
    for b in world.bodies_mut() {
        if let Some((tol, cap)) = cg {
            b.model_mut().set_precise_cg(tol, cap)?;
        }
        b.model_mut().pin(Some(config.level))?;
    }
    let s = Script::builtin(script, &world)?;
    let ti = world.add_tool(Tool::new(s.name.clone(), s.tool)?);
    let dt = config.dt;
    let steps = (duration / dt).round() as usize;
    let mut out = Vec::with_capacity(steps);
    let mut times = Vec::with_capacity(steps);

    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        drive_tool(&mut world, &s, ti, t, dt)?;
        world.step_fixed()?;
        let b = &world.bodies()[0];
        times.push(b.diagnostics().step_us);
        out.push(b.model().node_positions().to_vec());
    }
    Ok((out, median(&times).unwrap_or(0.0)))
}

/// Runs every configuration of `scene` under `script` for `duration` seconds and
/// measures its first body against corotational FEM with BDF2 at a tenth of the paper's step
/// with a tight CG tolerance. `progress` is called before each run.
pub(super) fn speed_against_error(
    scene: &Scene,
    assets: &Path,
    script: &str,
    configs: &[Config],
    duration: f64,
    progress: &mut dyn FnMut(&str),
) -> Res<(Reference, Vec<Point>)> {
    // A tenth of the paper's organ step, whatever steps the settings take (their order of
    // convergence is measured down to a quarter of it); its own convergence is measured below.
    let base = ORGAN_FEM.dt;
    let reference = Config {
        label: format!("reference: FEM corotational BDF2 dt {}", base / 10.0),
        family: "reference",
        method: Method::CorotationalFem,
        // Second order: at a tenth of the step its own time error is about a hundredth of
        // the settings' (backward Euler's would be a tenth of theirs, as large as BDF2's
        // error at the sweep's step).
        integrator: FemIntegrator::Bdf2,
        level: Level::Precise,
        cage: CageKind::BoundingBox,
        cage_dynamics: CageDynamics::Calibrated,
        material_springs: false,
        dt: base / 10.0,
    };
    progress(&reference.label);
    let (refs, _) = trajectory(
        scene,
        assets,
        script,
        &reference,
        duration,
        Some((1e-8, 200)),
    )?;
    let scale = {
        let w = build_world(scene, assets, &|_| {})?;
        w.bodies()[0].model().smallest_dimension()
    };
    // The reference's own convergence: the same run at half its step, compared at the
    // reference's times.
    let half = Config {
        label: format!("FEM corotational BDF2 dt {}", reference.dt / 2.0),
        dt: reference.dt / 2.0,
        ..reference.clone()
    };
    progress(&format!("reference check: {}", half.label));
    let (halved, _) = trajectory(scene, assets, script, &half, duration, Some((1e-8, 200)))?;
    let (halving_mean, halving_max) = gap(refs
        .iter()
        .enumerate()
        .map_while(|(k, r)| Some((r.as_slice(), halved.get(2 * k + 1)?.as_slice()))));
    let reference = Reference {
        halving_max_pct: 100.0 * halving_max / scale,
        halving_mean_pct: 100.0 * halving_mean / scale,
        halved: half.label,
        config: reference,
    };
    let mut points = Vec::with_capacity(configs.len());
    for c in configs {
        progress(&c.label);
        let (traj, median_us) = trajectory(scene, assets, script, c, duration, None)?;
        let (mean, max) = gap(traj.iter().enumerate().map(|(k, x)| {
            let t = (k + 1) as f64 * c.dt;
            let j = ((t / reference.config.dt).round() as usize).clamp(1, refs.len()) - 1;
            (x.as_slice(), refs[j].as_slice())
        }));
        points.push(Point {
            config: c.clone(),
            median_us,
            mean_pct: 100.0 * mean / scale,
            max_pct: 100.0 * max / scale,
            pareto: false,
        });
    }
    for i in 0..points.len() {
        let (t, e) = (points[i].median_us, points[i].max_pct);
        points[i].pareto = !points
            .iter()
            .any(|q| q.median_us <= t && q.max_pct <= e && (q.median_us < t || q.max_pct < e));
    }
    Ok((reference, points))
}

/// Over pairs of node sets (the same nodes in two runs at one time): the mean of their mean
/// node distance, and the largest node distance.
fn gap<'a>(pairs: impl Iterator<Item = (&'a [Vec3], &'a [Vec3])>) -> (f64, f64) {
    let (mut sum, mut max, mut n) = (0.0f64, 0.0f64, 0usize);
    for (a, b) in pairs {
        let mut s = 0.0;
        for (p, q) in a.iter().zip(b) {
            let d = (p - q).norm();
            s += d;
            max = max.max(d);
        }
        sum += s / a.len().max(1) as f64;
        n += 1;
    }
    (sum / n.max(1) as f64, max)
}

/// One row of the mesh-size scaling.
#[derive(Debug, Clone)]
pub(super) struct SizeRow {
    pub resolution: f64,
    pub nodes: usize,
    pub tets: usize,
    pub surface: usize,
    /// Median step per method (same order as [`SIZE_METHODS`]), us, on one thread, or the
    /// error that stopped the method (building its body or stepping it).
    pub median_us: Vec<Result<f64, String>>,
    /// The same on every available core (`None` on a one-core machine).
    pub median_all_us: Vec<Option<Result<f64, String>>>,
    /// Matrix and factor bytes of the FEM methods (`None` for the others).
    pub matrix_bytes: Vec<Option<usize>>,
}

/// The methods of the mesh-size scaling.
pub(super) const SIZE_METHODS: [BenchMethod; 6] = [
    BenchMethod::FemLinear,
    BenchMethod::FemCorotational,
    BenchMethod::FemCorotationalPrefactored,
    BenchMethod::MsdImplicit,
    BenchMethod::CageBox,
    BenchMethod::CageFitted,
];

/// The exponent `p` of the least-squares fit `time = a tets^p` (log-log) over the rows where
/// the method ran; `None` with fewer than two.
pub(super) fn growth_exponent(rows: &[SizeRow], method: usize, all: bool) -> Option<f64> {
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|r| {
            let t = if all {
                r.median_all_us[method].as_ref()?.as_ref().ok()?
            } else {
                r.median_us[method].as_ref().ok()?
            };
            (*t > 0.0).then(|| ((r.tets as f64).ln(), t.ln()))
        })
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Step time against mesh size: the generated liver at several resolutions under the bench
/// load (`soft-tissue bench`'s swinging force, organ FEM parameters), median of `steps` steps,
/// on one thread and in `threads` (when it has more than one).
pub(super) fn mesh_size(
    resolutions: &[f64],
    steps: usize,
    threads: &soft_tissue_core::parallel::Threads,
    progress: &mut dyn FnMut(&str),
) -> Res<Vec<SizeRow>> {
    let mut rows = Vec::with_capacity(resolutions.len());
    for &r in resolutions {
        progress(&format!("mesh size: liver at resolution {r}"));
        let mesh = Organ::Liver.generate(r)?;
        let mut row = SizeRow {
            resolution: r,
            nodes: mesh.node_count(),
            tets: mesh.tet_count(),
            surface: mesh.surface().vertices().len(),
            median_us: Vec::with_capacity(SIZE_METHODS.len()),
            median_all_us: Vec::with_capacity(SIZE_METHODS.len()),
            matrix_bytes: Vec::with_capacity(SIZE_METHODS.len()),
        };
        for m in SIZE_METHODS {
            let build = || {
                BenchBody::new(
                    &mesh,
                    m,
                    (&ORGAN_FEM.params, ORGAN_FEM.dt),
                    (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
                    false,
                    64,
                )
            };
            let mut bytes = None;
            let measured = build().and_then(|mut b| {
                bytes = b.matrix_bytes();
                b.run(m, &mesh, steps / 10, steps)
            });
            row.median_us
                .push(measured.map(|r| r.median_us).map_err(|e| e.to_string()));
            row.matrix_bytes.push(bytes);
            let all = (threads.count() > 1).then(|| {
                build()
                    .and_then(|mut b| threads.run(|| b.run(m, &mesh, steps / 10, steps)))
                    .map(|r| r.median_us)
                    .map_err(|e| e.to_string())
            });
            row.median_all_us.push(all);
        }
        rows.push(row);
    }
    Ok(rows)
}
