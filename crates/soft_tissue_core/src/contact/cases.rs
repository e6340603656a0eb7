//! Contact cases with closed forms or laws to check against, run by the tests and by the
//! report (`soft-tissue report`, its contact section): Coulomb's incline, Hertz's sphere on
//! an elastic half-space, Newton's third law at rest, a grasp held by friction, organs at
//! rest on a table.

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion};

use super::{ContactConfig, Friction, Obstacle, RigidShape, Tool, ToolShape};
use crate::Vec3;
use crate::boundary::Boundary;
use crate::material::{FemParams, PAPER_CAGE_MSD};
use crate::mesh::TetMesh;
use crate::mesh::generate::block;
use crate::precision::{BodySettings, Level, PreciseMethod};
use crate::scenario::Scene;
use crate::world::{Script, SoftTissueWorld, WorldBody, WorldConfig, WorldError};

/// A block on an incline (see [`incline`]).
#[derive(Debug, Clone)]
pub struct InclineRun {
    /// The block's centroid along the slope (downhill), every step from the start.
    pub track: Vec<f64>,
    /// Step, s.
    pub dt: f64,
    /// Deepest penetration into the incline over the run.
    pub penetration: f64,
    /// The block's edge and smallest dimension.
    pub size: f64,
    /// Smallest dimension (thickness).
    pub thickness: f64,
}

impl InclineRun {
    /// Largest distance of the centroid from where it was at `from` seconds, over the rest.
    pub fn drift_after(&self, from: f64) -> f64 {
        let k = (from / self.dt).round() as usize;
        self.track[k..]
            .iter()
            .map(|s| (s - self.track[k]).abs())
            .fold(0.0, f64::max)
    }

    /// Least-squares acceleration along the slope from `from` seconds on (a parabola fit).
    pub fn acceleration_after(&self, from: f64) -> f64 {
        let k0 = (from / self.dt).round() as usize;
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut b = Vec3::zeros();
        for (k, s) in self.track[k0..].iter().enumerate() {
            let t = k as f64 * self.dt;
            let phi = Vec3::new(1.0, t, t * t);
            a += phi * phi.transpose();
            b += phi * *s;
        }
        a.lu().solve(&b).map_or(f64::NAN, |c| 2.0 * c.z)
    }
}

/// Coulomb's incline: a stiff corotational block (0.2 x 0.1 x 0.2 m, 2 kg, 100 kPa) set on a
/// rigid plane tilted by `angle_deg` under gravity, both surfaces with friction `mu`, run for
/// `seconds` at 5 ms. Closed form: it sticks for `tan(angle) < mu` and slides with
/// acceleration `g (sin - mu cos)` otherwise.
pub fn incline(angle_deg: f64, mu: f64, seconds: f64) -> Result<InclineRun, WorldError> {
    let theta = angle_deg.to_radians();
    let (size, thickness) = (0.2, 0.1);
    let base = block(Vec3::zeros(), Vec3::new(size, thickness, size), [4, 2, 4])
        .map_err(|e| mesh_error("incline block", e))?;
    let turn = Rotation3::from_axis_angle(&Vec3::z_axis(), theta);
    let config = WorldConfig {
        dt: 0.005,
        contact: ContactConfig::for_scale(thickness),
    };
    // Turned with the slope and set on it (a hair above the contact skin).
    let lift = config.contact.thickness * 1.01;
    let positions: Vec<Vec3> = base
        .positions()
        .iter()
        .map(|p| turn * (p + Vec3::new(-0.5 * size, lift, -0.5 * size)))
        .collect();
    let tets = base.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let mesh = TetMesh::new(positions, tets).map_err(|e| mesh_error("incline block", e))?;
    let fem = FemParams {
        young_modulus: 1e5,
        poisson_ratio: 0.3,
        mass: 2.0,
        damping: 0.0,
    };
    let mut s = BodySettings::new(fem, PAPER_CAGE_MSD, config.dt);
    s.gravity = Vec3::new(0.0, -9.81, 0.0);
    // Measured at its precise level throughout.
    s.policy.min_precise_steps = u32::MAX;
    let mut world = SoftTissueWorld::new(config)?;
    let mut body = WorldBody::new("block", Arc::new(mesh), s, None)?;
    body.set_friction(Friction::new(mu))?;
    world.add_body(body)?;
    let slope = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vec3::z_axis(), theta),
    );
    let incline = Obstacle::new("incline", RigidShape::Plane, slope, Friction::new(mu)).map_err(
        |source| WorldError::Contact {
            name: "incline".into(),
            source,
        },
    )?;
    world.add_obstacle(incline)?;
    let down = -(turn * Vec3::x());
    let centroid = |w: &SoftTissueWorld| -> f64 {
        let x = w.bodies()[0].model().node_positions();
        x.iter().sum::<Vec3>().dot(&down) / x.len() as f64
    };
    let steps = (seconds / config.dt).round() as usize;
    let mut track = Vec::with_capacity(steps + 1);
    track.push(centroid(&world));
    let mut penetration: f64 = 0.0;
    for _ in 0..steps {
        world.step_fixed()?;
        penetration = penetration.max(world.bodies()[0].diagnostics().max_penetration);
        track.push(centroid(&world));
    }
    Ok(InclineRun {
        track,
        dt: config.dt,
        penetration,
        size,
        thickness,
    })
}

fn mesh_error(what: &str, e: impl std::fmt::Display) -> WorldError {
    WorldError::Mesh {
        body: what.into(),
        message: e.to_string(),
    }
}

/// Hertz's contact (see [`hertz`]).
#[derive(Debug, Clone, Copy)]
pub struct HertzRun {
    /// Tetrahedra of the quarter block.
    pub tets: usize,
    /// Mesh spacing under the sphere, as a fraction of the contact radius `sqrt(R d)`.
    pub spacing: f64,
    /// Growth of the cells away from the sphere.
    pub growth: f64,
    /// The force on the sphere (the whole block's: four times the quarter's).
    pub force: f64,
    /// Hertz's closed form, `4/3 E / (1 - nu^2) sqrt(R) d^1.5`.
    pub hertz: f64,
    /// Deepest penetration into the sphere at the end.
    pub penetration: f64,
}

/// The three meshes of the Hertz case, coarse to fine: spacing under the sphere (in contact
/// radii) and growth of the cells away from it.
pub const HERTZ_MESHES: [(f64, f64); 3] = [(0.5, 1.3), (0.35, 1.2), (0.25, 1.13)];

/// Hertz: a rigid frictionless sphere of radius 1 pressed 0.075 deep into an elastic block
/// (linear FEM, E 1, nu 0.3) standing for a half-space: a quarter of a 16 x 16 x 16 block by
/// symmetry (the two symmetry planes hold their normal component, the bottom is fixed),
/// graded from `spacing` times the contact radius under the sphere, cells growing by
/// `growth` (a mesh converges when both fall: the cells' size over their distance from the
/// contact is what the far field's error follows). The sphere goes down in 20 steps and
/// holds for 5; the step is long (1000 s) so that each is the static answer.
pub fn hertz(spacing: f64, growth: f64) -> Result<HertzRun, WorldError> {
    hertz_at(spacing, growth, Level::Precise)
}

/// [`hertz`] with the block held at `level`: at the cage level (a box cage) it meets the
/// sphere with its precise model's compliance and keeps what its cage cannot show as a dent
/// (see [`crate::precision::LeveledModel::contact_compliance`]).
pub fn hertz_at(spacing: f64, growth: f64, level: Level) -> Result<HertzRun, WorldError> {
    let (radius, depth, e, nu): (f64, f64, f64, f64) = (1.0, 0.075, 1.0, 0.3);
    let a = (radius * depth).sqrt();
    let (half, height) = (16.0, 16.0);
    // Graded coordinates from 0: cells from spacing * a, growing by 1.25, to the far side.
    let graded = |length: f64| -> Vec<f64> {
        let mut c = vec![0.0];
        let mut h = spacing * a;
        while *c.last().unwrap() < length {
            let next = (c.last().unwrap() + h).min(length);
            if length - next < 0.3 * h {
                c.push(length);
                break;
            }
            c.push(next);
            h *= growth;
        }
        c
    };
    let xs = graded(half);
    let ys = graded(height);
    let (nx, ny) = (xs.len() - 1, ys.len() - 1);
    let grid = block(Vec3::zeros(), Vec3::new(1.0, 1.0, 1.0), [nx, ny, nx])
        .map_err(|e| mesh_error("Hertz block", e))?;
    let positions: Vec<Vec3> = grid
        .positions()
        .iter()
        .map(|p| {
            let i = (p.x * nx as f64).round() as usize;
            let j = (p.y * ny as f64).round() as usize;
            let k = (p.z * nx as f64).round() as usize;
            // Finest at the top (y = height), where the sphere presses.
            Vec3::new(xs[i], height - ys[ny - j], xs[k])
        })
        .collect();
    let tets = grid.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let mesh = TetMesh::new(positions, tets).map_err(|e| mesh_error("Hertz block", e))?;
    let fixed = mesh
        .positions()
        .iter()
        .enumerate()
        .filter_map(|(n, p)| {
            let mask = [p.x == 0.0, p.y == 0.0, p.z == 0.0];
            let mask = if p.y == 0.0 { [true; 3] } else { mask };
            mask.iter().any(|&m| m).then_some((n, mask))
        })
        .collect();
    let fem = FemParams {
        young_modulus: e,
        poisson_ratio: nu,
        mass: 1.0,
        damping: 0.0,
    };
    let dt = 1000.0;
    let mut s = BodySettings::new(fem, PAPER_CAGE_MSD, dt);
    s.precise = PreciseMethod::LinearFem;
    s.boundary = Boundary {
        fixed,
        anchors: Vec::new(),
    };
    s.policy.min_precise_steps = u32::MAX;
    let config = WorldConfig {
        dt,
        contact: ContactConfig {
            tolerance: 1e-6,
            max_rounds: 6,
            max_sweeps: 2000,
            ..ContactConfig::for_scale(a)
        },
    };
    let tet_count = mesh.tet_count();
    let mut world = SoftTissueWorld::new(config)?;
    let mut body = WorldBody::new("block", Arc::new(mesh), s, None)?;
    body.model_mut()
        .pin(Some(level))
        .map_err(|e| mesh_error("Hertz block", e))?;
    world.add_body(body)?;
    let mut tool = Tool::new("sphere", ToolShape::Sphere { radius }).map_err(|source| {
        WorldError::Contact {
            name: "sphere".into(),
            source,
        }
    })?;
    tool.set_friction(Friction::FRICTIONLESS)
        .map_err(|source| WorldError::Contact {
            name: "sphere".into(),
            source,
        })?;
    let t = world.add_tool(tool);
    let (load, hold) = (20, 5);
    for k in 1..=load + hold {
        let d = depth * (k.min(load) as f64 / load as f64);
        world.tools_mut()[t]
            .set_position(Vec3::new(0.0, height + radius - d, 0.0))
            .map_err(|source| WorldError::Contact {
                name: "sphere".into(),
                source,
            })?;
        world.step_fixed()?;
    }
    let force = 4.0 * world.tools()[t].reaction_force().y;
    let hertz = 4.0 / 3.0 * e / (1.0 - nu * nu) * radius.sqrt() * depth.powf(1.5);
    Ok(HertzRun {
        tets: tet_count,
        spacing,
        growth,
        force,
        hertz,
        penetration: world.bodies()[0].diagnostics().max_penetration,
    })
}

/// Newton's third law at rest (see [`balance`]).
#[derive(Debug, Clone, Copy)]
pub struct BalanceRun {
    /// The force on the tool (its contacts' sum).
    pub tool: Vec3,
    /// The force of the anchors on the body.
    pub anchors: Vec3,
    /// Largest node speed at the end, in the body's smallest dimension per second.
    pub speed: f64,
    /// Whether the body was at its precise level at the end.
    pub precise: bool,
}

/// Newton's third law at rest: the paper's liver alone (anchored to its rest shape, as in the
/// organs scene), a ball a tenth of its smallest dimension pressed a quarter of that
/// dimension into its top over a second and held for `seconds` more. At rest the force on
/// the tool and the anchors' reaction on the body must be equal and opposite.
pub fn balance(assets: &Path, seconds: f64) -> Result<BalanceRun, WorldError> {
    let mut scene = Scene::paper_organs();
    scene.bodies.retain(|b| b.name == "Liver");
    let mut world = SoftTissueWorld::from_scene(&scene, assets)?;
    let (lo, hi) = world.bodies()[0].collider().bounds();
    let small = (hi - lo).min();
    let r = 0.1 * small;
    let centre = (lo + hi) / 2.0;
    let top = world.bodies()[0]
        .collider()
        .positions()
        .iter()
        .filter(|p| (p.xz() - centre.xz()).norm() < 0.15 * small)
        .map(|p| p.y)
        .fold(f64::NEG_INFINITY, f64::max);
    let tool = Tool::new("ball", ToolShape::Sphere { radius: r }).map_err(|source| {
        WorldError::Contact {
            name: "ball".into(),
            source,
        }
    })?;
    let t = world.add_tool(tool);
    let start = Vec3::new(centre.x, top + r + 0.05 * small, centre.z);
    let pressed = Vec3::new(centre.x, top + r - 0.25 * small, centre.z);
    let dt = world.config().dt;
    let steps = ((1.0 + seconds) / dt).round() as usize;
    for k in 1..=steps {
        let s = (k as f64 * dt).min(1.0);
        world.tools_mut()[t]
            .set_position(start * (1.0 - s) + pressed * s)
            .map_err(|source| WorldError::Contact {
                name: "ball".into(),
                source,
            })?;
        world.step_fixed()?;
    }
    let b = world.bodies()[0].model();
    let precise = b.level() == Level::Precise;
    Ok(BalanceRun {
        tool: world.tools()[t].reaction_force(),
        anchors: b.precise().anchor_force(),
        speed: b.precise().max_speed() / small,
        precise,
    })
}

/// A grasp (see [`grasp`]).
#[derive(Debug, Clone, Copy)]
pub struct GraspRun {
    /// How high the surface the jaws held when the lift began rose by 4.5 s (the mean of
    /// those vertices).
    pub lifted: f64,
    /// How high the spleen's centroid rose over the same time (less than the hold: the
    /// spleen hangs from the jaws).
    pub centroid_rose: f64,
    /// How high the grasper lifted.
    pub lift: f64,
    /// The largest normal force on a jaw while holding.
    pub squeeze: f64,
    /// Deepest penetration of the spleen into anything over the run.
    pub penetration: f64,
    /// The spleen's smallest dimension.
    pub smallest: f64,
}

/// The grasp scene ([`Scene::grasp`]) with the spleen's and the grasper's friction `mu`, the
/// built-in `grasp-spleen` script: how far what the jaws held rose when the grasper lifted 5
/// cm (it slips out when friction cannot hold it).
pub fn grasp(mu: f64, assets: &Path) -> Result<GraspRun, WorldError> {
    let mut scene = Scene::grasp();
    for b in &mut scene.bodies {
        b.friction = Some(Friction::new(mu));
    }
    let mut world = SoftTissueWorld::from_scene(&scene, assets)?;
    let script =
        Script::builtin("grasp-spleen", &world).map_err(|e| mesh_error("grasp-spleen", e))?;
    let mut tool = Tool::new("grasper", script.tool).map_err(|source| WorldError::Contact {
        name: "grasper".into(),
        source,
    })?;
    tool.set_friction(Friction::new(mu))
        .map_err(|source| WorldError::Contact {
            name: "grasper".into(),
            source,
        })?;
    let t = world.add_tool(tool);
    let dt = world.config().dt;
    let centroid = |w: &SoftTissueWorld| -> f64 {
        let x = w.bodies()[0].model().node_positions();
        x.iter().map(|p| p.y).sum::<f64>() / x.len() as f64
    };
    let smallest = world.bodies()[0].model().smallest_dimension();
    let (mut squeeze, mut penetration): (f64, f64) = (0.0, 0.0);
    let lift_starts = (2.0 / dt).round() as usize;
    let steps = (4.5 / dt).round() as usize;
    let mut held: Vec<u32> = Vec::new();
    let (mut centroid_before, mut held_before) = (0.0, 0.0);
    let held_height = |w: &SoftTissueWorld, held: &[u32]| -> f64 {
        let x = w.bodies()[0].collider().positions();
        held.iter().map(|&v| x[v as usize].y).sum::<f64>() / held.len().max(1) as f64
    };
    for k in 1..=steps {
        let time = k as f64 * dt;
        let (p, r) = script.pose_rotation_at(time);
        let tl = &mut world.tools_mut()[t];
        tl.set_pose_rotation(p, r)
            .map_err(|source| WorldError::Contact {
                name: "grasper".into(),
                source,
            })?;
        for e in script.events_in(time - dt, time) {
            e.action.apply(tl).map_err(|source| WorldError::Contact {
                name: "grasper".into(),
                source,
            })?;
        }
        world.step_fixed()?;
        let jaws = world.tools()[t].jaw_forces();
        squeeze = squeeze.max(jaws[0].min(jaws[1]));
        penetration = penetration.max(world.bodies()[0].diagnostics().max_penetration);
        if k == lift_starts {
            // What the jaws hold as the lift begins.
            held = world
                .contacts()
                .solved_rows()
                .iter()
                .filter(|r| matches!(r.other, super::Counterpart::Tool { .. }) && r.force.x > 0.0)
                .flat_map(|r| r.a.terms().map(|(v, _)| v).collect::<Vec<_>>())
                .collect();
            held.sort_unstable();
            held.dedup();
            centroid_before = centroid(&world);
            held_before = held_height(&world, &held);
        }
    }
    Ok(GraspRun {
        lifted: held_height(&world, &held) - held_before,
        centroid_rose: centroid(&world) - centroid_before,
        lift: 0.05,
        squeeze,
        penetration,
        smallest,
    })
}

/// Organs at rest on a table (see [`stack`]).
#[derive(Debug, Clone)]
pub struct StackRun {
    /// Seconds until every body was back at its cage (`None`: not within the run).
    pub settled_at: Option<f64>,
    /// Up-switches after every body was at its cage.
    pub rose_after: u64,
    /// Deepest penetration of each body over the run, as a fraction of its smallest dimension.
    pub penetration: Vec<f64>,
    /// Body names.
    pub names: Vec<String>,
}

/// The organ stack ([`Scene::organ_stack`]): run `seconds`; when does every body come back to
/// its cage, and does any rise again after that.
pub fn stack(assets: &Path, seconds: f64) -> Result<StackRun, WorldError> {
    let scene = Scene::organ_stack();
    let mut world = SoftTissueWorld::from_scene(&scene, assets)?;
    let dt = world.config().dt;
    let n = world.bodies().len();
    let mut settled_at = None;
    let mut rose_after = 0;
    let mut penetration = vec![0.0f64; n];
    let steps = (seconds / dt).round() as usize;
    for k in 1..=steps {
        world.step_fixed()?;
        for (i, b) in world.bodies().iter().enumerate() {
            let d = b.diagnostics();
            penetration[i] = penetration[i].max(d.max_penetration / b.model().smallest_dimension());
            if settled_at.is_some()
                && let Some(s) = d.switched
                && s.to == Level::Precise
            {
                rose_after += 1;
            }
        }
        if settled_at.is_none()
            && world
                .bodies()
                .iter()
                .all(|b| b.model().level() == Level::Cage)
        {
            settled_at = Some(k as f64 * dt);
        }
    }
    Ok(StackRun {
        settled_at,
        rose_after,
        penetration,
        names: world
            .bodies()
            .iter()
            .map(|b| b.name().to_string())
            .collect(),
    })
}
