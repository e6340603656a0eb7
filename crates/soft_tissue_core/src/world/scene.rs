//! Building a world from a [`Scene`]: meshes read or generated, placed, bodies configured.

use std::path::Path;
use std::sync::Arc;

use nalgebra::Rotation3;

use super::{SoftTissueWorld, WorldBody, WorldConfig, WorldError};
use crate::Vec3;
use crate::contact::{ContactConfig, Friction, MeshShape, Obstacle, RigidShape};
use crate::heat::HeatBoundary;
use crate::material::{FemParams, MsdParams};
use crate::mesh::TetMesh;
use crate::mesh::io::read_tet_mesh;
use crate::precision::BodySettings;
use crate::scenario::{
    BodySpec, CYLINDER_FEM, CYLINDER_MSD, MeshSource, ObstacleShape, ObstacleSpec, Placement, Scene,
};

/// `mesh` rotated (XYZ Euler angles in degrees: about x, then y, then z) and translated.
pub fn placed_mesh(mesh: &TetMesh, placement: &Placement) -> Result<TetMesh, String> {
    let [rx, ry, rz] = placement.rotation_deg.map(f64::to_radians);
    let r = Rotation3::from_euler_angles(rx, ry, rz);
    let t = Vec3::from(placement.translation);
    if !t
        .iter()
        .chain(placement.rotation_deg.iter())
        .all(|x| x.is_finite())
    {
        return Err("placement is not finite".into());
    }
    if !(placement.scale.is_finite() && placement.scale > 0.0) {
        return Err(format!(
            "placement scale {} must be positive and finite",
            placement.scale
        ));
    }
    let scale = placement.scale;
    let positions = mesh
        .positions()
        .iter()
        .map(|p| r * (p * scale) + t)
        .collect();
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    TetMesh::new(positions, tets).map_err(|e| e.to_string())
}

/// How a scene's files are found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SceneOptions {
    /// Let mesh paths leave the assets folder (absolute paths, `..`). Off by default: a scene
    /// file from elsewhere reads only what lies under the folder it is given.
    pub allow_outside_assets: bool,
}

/// Reads (relative to `assets`, and inside it) or generates the body's mesh and places it.
pub fn load_mesh(spec: &BodySpec, assets: &Path) -> Result<TetMesh, WorldError> {
    load_mesh_with(spec, assets, SceneOptions::default())
}

/// [`load_mesh`] with options: a mesh path that is absolute or climbs out with `..` is an
/// error naming the body and the path unless `options` allow it.
pub fn load_mesh_with(
    spec: &BodySpec,
    assets: &Path,
    options: SceneOptions,
) -> Result<TetMesh, WorldError> {
    let err = |message: String| WorldError::Mesh {
        body: spec.name.clone().into(),
        message,
    };
    check_mesh_path(spec, options)?;
    let mesh = match &spec.mesh {
        MeshSource::File(file) => {
            let path = assets.join(file);
            read_tet_mesh(&path)
                .map_err(|e| err(format!("{}: {e}", path.display())))?
                .mesh
        }
        MeshSource::Generated { organ, resolution } => {
            organ.generate(*resolution).map_err(|e| {
                err(format!(
                    "mesh: generating {} at resolution {resolution}: {e}",
                    organ.name()
                ))
            })?
        }
    };
    placed_mesh(&mesh, &spec.placement).map_err(err)
}

/// Refuses a mesh path that is absolute or climbs out of the assets folder with `..` (an
/// error naming the body and the path) unless `options` allow it.
pub fn check_mesh_path(spec: &BodySpec, options: SceneOptions) -> Result<(), WorldError> {
    let MeshSource::File(file) = &spec.mesh else {
        return Ok(());
    };
    if leaves_assets(file) && !options.allow_outside_assets {
        return Err(WorldError::Mesh {
            body: spec.name.clone().into(),
            message: format!(
                "mesh path `{file}` leaves the assets folder (absolute, or `..`); the caller \
                 can allow it (`SceneOptions::allow_outside_assets`, `simulate \
                 --allow-outside-assets`, the scene loader's `allow_outside_assets` setting)"
            ),
        });
    }
    Ok(())
}

/// The level settings of a scene body on its placed mesh.
pub fn body_settings(
    spec: &BodySpec,
    mesh: &TetMesh,
    gravity: Vec3,
) -> Result<BodySettings, WorldError> {
    let bad = |message: &str| WorldError::Mesh {
        body: spec.name.clone().into(),
        message: message.into(),
    };
    let method = spec.precise;
    let dt = if method.is_fem() {
        spec.fem
            .ok_or_else(|| bad("a FEM precise method needs `fem` settings"))?
            .dt
    } else {
        spec.msd
            .ok_or_else(|| bad("an MSD precise method needs `msd` settings"))?
            .dt
    };
    let fem: FemParams = spec.fem.map(|f| f.params).unwrap_or(CYLINDER_FEM.params);
    let msd: MsdParams = spec.msd.map(|m| m.params).unwrap_or(CYLINDER_MSD.params);
    let mut s = BodySettings::new(fem, msd, dt);
    s.precise = method;
    if let Some(f) = spec.fem {
        s.fem_integrator = f.integrator;
    }
    if let Some(m) = spec.msd {
        s.msd_spring_stiffness = m.spring_stiffness;
    }
    s.cage = spec.cage.kind;
    s.cage_msd = spec.cage.msd.params;
    s.cage_dynamics = spec.cage.dynamics;
    s.gravity = gravity;
    s.boundary = spec.anchor.boundary(mesh);
    Ok(s)
}

/// A scene body ready to build: its placed mesh, level settings and heat field, if any.
#[derive(Debug, Clone)]
pub struct SceneBody {
    /// Body name.
    pub name: String,
    /// Mesh in scene coordinates (placement applied).
    pub mesh: TetMesh,
    /// Level settings.
    pub settings: BodySettings,
    /// Heat parameters and boundary (`None`: no temperature field).
    pub heat: Option<(crate::heat::HeatParams, HeatBoundary)>,
    /// Surface friction.
    pub friction: Friction,
    /// Fracture toughness (0: a blade cuts it freely; see [`WorldBody::set_toughness`]).
    pub toughness: f64,
}

/// Reads or generates every body of the scene (mesh files relative to `assets`) and the world
/// settings they share: the world step is the bodies' common precise step (an error names a
/// body that differs, when it is added), contact settings scale with the smallest body
/// dimension. What [`SoftTissueWorld::from_scene`] and the Bevy plugin build from.
pub fn scene_bodies(
    scene: &Scene,
    assets: &Path,
) -> Result<(WorldConfig, Vec<SceneBody>), WorldError> {
    scene_bodies_with(scene, assets, SceneOptions::default())
}

/// [`scene_bodies`] with options (see [`SceneOptions`]).
pub fn scene_bodies_with(
    scene: &Scene,
    assets: &Path,
    options: SceneOptions,
) -> Result<(WorldConfig, Vec<SceneBody>), WorldError> {
    scene.validate()?;
    let gravity = Vec3::from(scene.gravity);
    let mut built = Vec::with_capacity(scene.bodies.len());
    for spec in &scene.bodies {
        let mesh = load_mesh_with(spec, assets, options)?;
        let settings = body_settings(spec, &mesh, gravity)?;
        built.push(SceneBody {
            name: spec.name.clone(),
            heat: spec.heat.map(|p| (p, HeatBoundary::insulated())),
            friction: spec.friction.unwrap_or_default(),
            toughness: spec.toughness.unwrap_or(0.0),
            mesh,
            settings,
        });
    }
    let Some(first) = built.first() else {
        return Err(WorldError::TimeStep("the scene has no bodies".into()));
    };
    let dt = first.settings.dt;
    let scale = built
        .iter()
        .map(|b| b.mesh.bbox().smallest_dimension())
        .fold(f64::INFINITY, f64::min);
    let config = WorldConfig {
        dt,
        contact: ContactConfig::for_scale(scale),
    };
    Ok((config, built))
}

impl SoftTissueWorld {
    /// Builds the scene's bodies (see [`scene_bodies`]).
    pub fn from_scene(scene: &Scene, assets: &Path) -> Result<Self, WorldError> {
        Self::from_scene_with(scene, assets, SceneOptions::default())
    }

    /// [`SoftTissueWorld::from_scene`] with options (see [`SceneOptions`]).
    pub fn from_scene_with(
        scene: &Scene,
        assets: &Path,
        options: SceneOptions,
    ) -> Result<Self, WorldError> {
        let (config, bodies) = scene_bodies_with(scene, assets, options)?;
        let obstacles = scene_obstacles(scene, assets, options)?;
        let mut world = SoftTissueWorld::new(config)?;
        for b in bodies {
            let mut body = WorldBody::new(b.name, Arc::new(b.mesh), b.settings, b.heat)?;
            body.set_friction(b.friction)?;
            body.set_toughness(b.toughness)?;
            world.add_body(body)?;
        }
        for o in obstacles {
            world.add_obstacle(o)?;
        }
        Ok(world)
    }
}

/// The pose of a placement (XYZ Euler angles in degrees, then the translation).
pub fn placement_pose(placement: &Placement) -> crate::contact::Pose {
    let [rx, ry, rz] = placement.rotation_deg.map(f64::to_radians);
    crate::contact::Pose::from_parts(
        nalgebra::Translation3::from(Vec3::from(placement.translation)),
        nalgebra::UnitQuaternion::from_euler_angles(rx, ry, rz),
    )
}

/// The rigid shape of an obstacle spec (a mesh read relative to `assets`, inside it unless
/// `options` allow otherwise).
pub fn obstacle_shape(
    spec: &ObstacleSpec,
    assets: &Path,
    options: SceneOptions,
) -> Result<RigidShape, WorldError> {
    let err = |message: String| WorldError::Mesh {
        body: spec.name.clone().into(),
        message,
    };
    Ok(match &spec.shape {
        ObstacleShape::Plane => RigidShape::Plane,
        ObstacleShape::Box { half_extents } => RigidShape::Box {
            half_extents: Vec3::from(*half_extents),
        },
        ObstacleShape::Sphere { radius } => RigidShape::Sphere { radius: *radius },
        ObstacleShape::Capsule { radius, length } => RigidShape::Capsule {
            radius: *radius,
            length: *length,
        },
        ObstacleShape::Mesh(file) => {
            if leaves_assets(file) && !options.allow_outside_assets {
                return Err(err(format!(
                    "mesh path `{file}` leaves the assets folder (absolute, or `..`)"
                )));
            }
            let path = assets.join(file);
            let surface = crate::mesh::io::read_surface(&path)
                .map_err(|e| err(format!("{}: {e}", path.display())))?;
            let shape = MeshShape::new(surface.positions, surface.triangles)
                .map_err(|e| err(format!("{}: {e}", path.display())))?;
            RigidShape::Mesh(Arc::new(shape))
        }
    })
}

/// Every obstacle of the scene, built (shapes read, placed, friction checked).
pub fn scene_obstacles(
    scene: &Scene,
    assets: &Path,
    options: SceneOptions,
) -> Result<Vec<Obstacle>, WorldError> {
    scene
        .obstacles
        .iter()
        .map(|o| {
            let shape = obstacle_shape(o, assets, options)?;
            Obstacle::new(
                o.name.clone(),
                shape,
                placement_pose(&o.placement),
                o.friction.unwrap_or_default(),
            )
            .map_err(|source| WorldError::Contact {
                name: o.name.clone().into(),
                source,
            })
        })
        .collect()
}

/// Whether a scene's file path leaves the assets folder (absolute, or through `..`).
fn leaves_assets(file: &str) -> bool {
    Path::new(file).components().any(|c| {
        matches!(
            c,
            std::path::Component::ParentDir
                | std::path::Component::RootDir
                | std::path::Component::Prefix(_)
        )
    })
}
