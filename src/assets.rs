//! Assets: tetrahedral meshes (`.msh`, `.vtk`, `.vtu`, `.node`) and scene files
//! (`.scene.ron`). A loader error names the file and what is wrong in it; Bevy logs it.

use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::prelude::*;
use soft_tissue_core::contact::ContactConfig;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::{FormatError, MeshFormat, parse_tet_mesh, parse_tetgen};
use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD, MeshSource, Scene, SceneError};
use soft_tissue_core::world::{SceneOptions, WorldError, check_mesh_path, placed_mesh};

use crate::components::{
    MsdMaterial, ObstacleCollider, SoftBody, SoftBodyTuning, SoftObstacle, TissueHeat,
    TissueMaterial,
};
use crate::physics::SoftTissueConfig;

/// A tetrahedral mesh, shared (`Arc`) with every body built from it.
#[derive(Asset, TypePath, Clone, Debug)]
pub struct TetMeshAsset(pub Arc<TetMesh>);

impl From<TetMesh> for TetMeshAsset {
    fn from(m: TetMesh) -> Self {
        TetMeshAsset(Arc::new(m))
    }
}

/// Why a tetrahedral mesh did not load.
#[derive(Debug, thiserror::Error)]
pub enum TetMeshLoadError {
    /// The file (or the `.ele` beside a `.node`) could not be read.
    #[error("{path}: {message}")]
    Read {
        /// The file.
        path: String,
        /// The reader's message.
        message: String,
    },
    /// The file's contents are not a valid mesh (the message names the element or line).
    #[error(transparent)]
    Format(#[from] FormatError),
}

/// Parses the mesh file `path` of contents `bytes` (reading the `.ele` beside a `.node`).
async fn parse_mesh(
    bytes: &[u8],
    path: &std::path::Path,
    load_context: &mut LoadContext<'_>,
) -> Result<TetMesh, TetMeshLoadError> {
    let name = path.display().to_string();
    let format = MeshFormat::from_path(path).ok_or_else(|| TetMeshLoadError::Read {
        path: name.clone(),
        message: "unknown extension: expected .msh, .vtk, .vtu or .node".into(),
    })?;
    let loaded = match format {
        MeshFormat::TetGen => {
            let ele_path = path.with_extension("ele");
            let ele_name = ele_path.display().to_string();
            let ele = load_context.read_asset_bytes(ele_path).await.map_err(|e| {
                TetMeshLoadError::Read {
                    path: ele_name.clone(),
                    message: e.to_string(),
                }
            })?;
            parse_tetgen(bytes, &name, &ele, &ele_name)?
        }
        _ => parse_tet_mesh(bytes, format, &name)?,
    };
    log_notes(&name, &loaded.notes);
    Ok(loaded.mesh)
}

/// Logs what a reader worked around in file `name`, a line each.
fn log_notes(name: &str, notes: &[String]) {
    for note in notes {
        info!("{name}: {note}");
    }
}

/// Loads `.msh` (Gmsh 1, 2.2, 4.1), `.vtk`, `.vtu` and `.node` (with the `.ele` beside it).
#[derive(Default, TypePath)]
pub struct TetMeshLoader;

impl AssetLoader for TetMeshLoader {
    type Asset = TetMeshAsset;
    type Settings = ();
    type Error = TetMeshLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        _settings: &(),
        load_context: &mut LoadContext<'_>,
    ) -> Result<TetMeshAsset, TetMeshLoadError> {
        let path = load_context.path().path().to_path_buf();
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| TetMeshLoadError::Read {
                path: path.display().to_string(),
                message: e.to_string(),
            })?;
        Ok(TetMeshAsset(Arc::new(
            parse_mesh(&bytes, &path, load_context).await?,
        )))
    }

    fn extensions(&self) -> &[&str] {
        &["msh", "vtk", "vtu", "node"]
    }
}

/// Settings of the surface loader (in an asset's `.meta` file): how a closed triangle
/// surface becomes tetrahedra (see [`soft_tissue_core::mesh::tetrahedralize`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SurfaceLoaderSettings {
    /// About this many tetrahedra (used when `edge_length` is not set).
    pub target_tets: usize,
    /// Lattice spacing, about the interior edge length, in scene units (after `units`).
    pub edge_length: Option<f64>,
    /// Smallest dihedral angle kept, degrees.
    pub min_dihedral_deg: f64,
    /// The surface's unit in scene units (every coordinate is multiplied by it).
    pub units: f64,
    /// Where meshed results are kept, keyed by the file's bytes, these settings and the
    /// mesher's revision, so a second start does not mesh again (`None`: the system's
    /// temporary folder, `bevy_soft_tissue-meshes`).
    pub cache_dir: Option<std::path::PathBuf>,
}

impl Default for SurfaceLoaderSettings {
    fn default() -> Self {
        SurfaceLoaderSettings {
            target_tets: 1500,
            edge_length: None,
            min_dihedral_deg: 8.0,
            units: 1.0,
            cache_dir: None,
        }
    }
}

/// Why a surface did not become a tetrahedral mesh.
#[derive(Debug, thiserror::Error)]
pub enum SurfaceLoadError {
    /// The file could not be read, or is not a valid surface.
    #[error(transparent)]
    Read(#[from] TetMeshLoadError),
    /// The surface could not be meshed (the error names the defect).
    #[error("{path}: {source}")]
    Mesh {
        /// The file.
        path: String,
        /// Why.
        source: soft_tissue_core::mesh::tetrahedralize::TetrahedralizeError,
    },
}

/// Loads a closed triangle surface (`.obj`, `.stl`, `.ply`, or a glTF scene's triangles, `.gltf`
/// with its buffers or `.glb`) as a soft body's tetrahedral mesh:
/// it is meshed on load (off the main thread, as loaders run) with the asset's
/// [`SurfaceLoaderSettings`], and the result is cached on disk. The surface itself is the
/// labelled sub-asset `Surface` (a Bevy `Mesh`), to draw the body with through
/// [`crate::VisualMesh::mesh`]: `assets.load("organ.stl#Surface")`.
#[derive(Default, TypePath)]
pub struct SurfaceLoader;

/// FNV-1a, 64 bits: a cache key that stays the same across runs and Rust versions.
fn fnv1a(parts: &[&[u8]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in parts {
        for &b in *p {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}

impl AssetLoader for SurfaceLoader {
    type Asset = TetMeshAsset;
    type Settings = SurfaceLoaderSettings;
    type Error = SurfaceLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        settings: &SurfaceLoaderSettings,
        load_context: &mut LoadContext<'_>,
    ) -> Result<TetMeshAsset, SurfaceLoadError> {
        use soft_tissue_core::mesh::io::{
            gltf_external_uris, parse_gltf, parse_obj, parse_ply, parse_stl_with_notes,
        };
        use soft_tissue_core::mesh::tetrahedralize::{
            REVISION, TetrahedralizeOptions, tetrahedralize,
        };
        let path = load_context.path().path().to_path_buf();
        let name = path.display().to_string();
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| TetMeshLoadError::Read {
                path: name.clone(),
                message: e.to_string(),
            })?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        // A `.gltf`'s buffers in other files are read through the asset server, beside it;
        // their bytes join the cache key.
        let mut external: Vec<(String, Vec<u8>)> = Vec::new();
        let parsed = match ext.as_deref() {
            // A binary STL whose header count its data overrules is read, with a note.
            Some("stl") => parse_stl_with_notes(&bytes, &name).map(|loaded| {
                log_notes(&name, &loaded.notes);
                loaded.surface
            }),
            Some("ply") => parse_ply(&bytes, &name),
            Some("gltf" | "glb") => {
                let dir = path.parent().map(|p| p.to_path_buf()).unwrap_or_default();
                for uri in gltf_external_uris(&bytes, &name).map_err(TetMeshLoadError::from)? {
                    let file = dir.join(&uri);
                    let data = load_context
                        .read_asset_bytes(file.clone())
                        .await
                        .map_err(|e| TetMeshLoadError::Read {
                            path: file.display().to_string(),
                            message: e.to_string(),
                        })?;
                    external.push((uri, data));
                }
                parse_gltf(&bytes, &name, &mut |uri| {
                    external
                        .iter()
                        .find(|(u, _)| u == uri)
                        .map(|(_, d)| d.clone())
                        .ok_or_else(|| FormatError::Unsupported {
                            file: name.clone(),
                            message: format!("buffer {uri:?} was not read"),
                        })
                })
            }
            _ => parse_obj(&bytes, &name),
        };
        let mut surface = parsed.map_err(TetMeshLoadError::from)?;
        let bad_units = !(settings.units.is_finite() && settings.units > 0.0);
        if bad_units {
            return Err(TetMeshLoadError::Read {
                path: name,
                message: format!("units must be positive, found {}", settings.units),
            }
            .into());
        }
        for p in &mut surface.positions {
            *p *= settings.units;
        }
        // The surface as a Bevy mesh, for drawing the body with it.
        let mut visual = Mesh::new(
            bevy::mesh::PrimitiveTopology::TriangleList,
            bevy::asset::RenderAssetUsages::default(),
        );
        let positions: Vec<[f32; 3]> = surface
            .positions
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        visual.insert_attribute(Mesh::ATTRIBUTE_POSITION, positions);
        visual.insert_indices(bevy::mesh::Indices::U32(
            surface.triangles.iter().flatten().copied().collect(),
        ));
        visual.compute_smooth_normals();
        load_context.add_labeled_asset("Surface".to_string(), visual);

        let mut parts: Vec<&[u8]> = vec![&bytes];
        parts.extend(external.iter().map(|(_, d)| d.as_slice()));
        // The mesher's revision too: an upgrade that changes its meshes meshes again.
        let settings_text = format!(
            "{}|{:?}|{}|{}|r{REVISION}",
            settings.target_tets, settings.edge_length, settings.min_dihedral_deg, settings.units
        );
        parts.push(settings_text.as_bytes());
        let key = fnv1a(&parts);
        let dir = settings
            .cache_dir
            .clone()
            .unwrap_or_else(|| std::env::temp_dir().join("bevy_soft_tissue-meshes"));
        let cached = dir.join(format!("{key:016x}.vtu"));
        if let Ok(data) = std::fs::read(&cached)
            && let Ok(loaded) =
                parse_tet_mesh(&data, MeshFormat::Vtu, &cached.display().to_string())
        {
            info!(
                "{name}: meshed surface taken from the cache {}",
                cached.display()
            );
            return Ok(TetMeshAsset(Arc::new(loaded.mesh)));
        }
        let options = TetrahedralizeOptions {
            edge_length: settings.edge_length,
            target_tets: Some(settings.target_tets),
            min_dihedral_deg: settings.min_dihedral_deg,
        };
        let (mesh, report) =
            tetrahedralize(&surface, &options).map_err(|source| SurfaceLoadError::Mesh {
                path: name.clone(),
                source,
            })?;
        info!(
            "{name}: meshed to {} tetrahedra, dihedral {:.1}..{:.1} deg, volume {:+.2} % of the \
             enclosed",
            report.tets,
            report.min_dihedral_deg,
            report.max_dihedral_deg,
            100.0 * (report.volume / report.enclosed_volume - 1.0)
        );
        if report.defects.buried_triangles > 0 {
            info!(
                "{name}: parts of the surface overlap; meshed as their union ({} triangles \
                 buried inside it)",
                report.defects.buried_triangles
            );
        }
        if let Some(short) = report.shortfall() {
            warn!("{name}: {short}");
        }
        // The cache is a convenience: failing to write it costs the next start a meshing.
        let written = std::fs::create_dir_all(&dir).and_then(|()| {
            let data = soft_tissue_core::mesh::io::write_tet_mesh_bytes(
                &mesh,
                MeshFormat::Vtu,
                soft_tissue_core::mesh::io::WriteOptions { binary: true },
                &cached.display().to_string(),
            )
            .map_err(std::io::Error::other)?;
            std::fs::write(&cached, data)
        });
        if let Err(e) = written {
            warn!("{name}: the meshed surface was not cached ({e})");
        }
        Ok(TetMeshAsset(Arc::new(mesh)))
    }

    fn extensions(&self) -> &[&str] {
        &["obj", "stl", "ply", "gltf", "glb"]
    }
}

/// A scene file: the bodies of a scene and their settings (see
/// [`soft_tissue_core::scenario::Scene`]), with every body's mesh, read or generated and
/// placed where the scene puts it, loaded with it (labelled sub-assets `Body0`, `Body1`, …).
/// Spawn its bodies with a [`SoftTissueSceneRoot`].
#[derive(Asset, TypePath, Clone, Debug)]
pub struct SceneAsset {
    /// The scene.
    pub scene: Scene,
    /// Every body's placed mesh, in scene order.
    #[dependency]
    pub meshes: Vec<Handle<TetMeshAsset>>,
    /// The scene's obstacles, built (shapes read, placed), in scene order.
    pub obstacles: Vec<soft_tissue_core::contact::Obstacle>,
}

/// Why a scene file did not load.
#[derive(Debug, thiserror::Error)]
pub enum SceneLoadError {
    /// The file could not be read.
    #[error("{path}: {message}")]
    Read {
        /// The file.
        path: String,
        /// The reader's message.
        message: String,
    },
    /// The RON does not parse or a body is inconsistent (the message names it).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A body's mesh path leaves the assets folder (the message names the body and path).
    #[error(transparent)]
    Path(#[from] WorldError),
    /// A body's mesh did not load (the error names the file). No entity exists yet: the
    /// body is named by its place in the scene file's `bodies` and its name there.
    #[error("body `{name}` (bodies[{body}]): {source}")]
    Mesh {
        /// The body's index in the scene file's `bodies` (from 0).
        body: usize,
        /// The body's name in the scene file.
        name: String,
        /// Why.
        source: TetMeshLoadError,
    },
    /// An obstacle's shape did not load or is unusable (the message names the file).
    #[error("obstacle `{obstacle}`: {message}")]
    Obstacle {
        /// The obstacle.
        obstacle: String,
        /// Why.
        message: String,
    },
}

/// Settings of the scene loader (in an asset's `.meta` file).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SceneLoaderSettings {
    /// Let the scene's mesh paths leave the assets folder (absolute paths, `..`). Off by
    /// default: such a scene is refused, naming the body and the path.
    pub allow_outside_assets: bool,
}

/// Loads `.scene.ron` files.
#[derive(Default, TypePath)]
pub struct SceneLoader;

impl AssetLoader for SceneLoader {
    type Asset = SceneAsset;
    type Settings = SceneLoaderSettings;
    type Error = SceneLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        settings: &SceneLoaderSettings,
        load_context: &mut LoadContext<'_>,
    ) -> Result<SceneAsset, SceneLoadError> {
        let name = load_context.path().to_string();
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| SceneLoadError::Read {
                path: name.clone(),
                message: e.to_string(),
            })?;
        let text = String::from_utf8(bytes).map_err(|e| SceneLoadError::Read {
            path: name.clone(),
            message: format!("not UTF-8: {e}"),
        })?;
        let scene = Scene::from_ron(&text, &name)?;
        scene.validate()?;
        let options = SceneOptions {
            allow_outside_assets: settings.allow_outside_assets,
        };
        let mut meshes = Vec::with_capacity(scene.bodies.len());
        for (i, body) in scene.bodies.iter().enumerate() {
            check_mesh_path(body, options)?;
            let mesh_err = |source| SceneLoadError::Mesh {
                body: i,
                name: body.name.clone(),
                source,
            };
            let mesh = match &body.mesh {
                MeshSource::File(file) => {
                    let path = std::path::PathBuf::from(file);
                    let bytes = load_context
                        .read_asset_bytes(path.clone())
                        .await
                        .map_err(|e| {
                            mesh_err(TetMeshLoadError::Read {
                                path: file.clone(),
                                message: e.to_string(),
                            })
                        })?;
                    parse_mesh(&bytes, &path, load_context)
                        .await
                        .map_err(mesh_err)?
                }
                MeshSource::Generated { organ, resolution } => {
                    organ.generate(*resolution).map_err(|e| WorldError::Mesh {
                        body: body.name.clone().into(),
                        message: format!(
                            "generating {} at resolution {resolution}: {e}",
                            organ.name()
                        ),
                    })?
                }
            };
            let placed =
                placed_mesh(&mesh, &body.placement).map_err(|message| WorldError::Mesh {
                    body: body.name.clone().into(),
                    message,
                })?;
            meshes.push(
                load_context.add_labeled_asset(format!("Body{i}"), TetMeshAsset::from(placed)),
            );
        }
        let mut obstacles = Vec::with_capacity(scene.obstacles.len());
        for o in &scene.obstacles {
            let err = |message: String| SceneLoadError::Obstacle {
                obstacle: o.name.clone(),
                message,
            };
            let shape = match &o.shape {
                soft_tissue_core::scenario::ObstacleShape::Mesh(file) => {
                    let bytes = load_context
                        .read_asset_bytes(std::path::PathBuf::from(file))
                        .await
                        .map_err(|e| err(format!("{file}: {e}")))?;
                    let surface = soft_tissue_core::mesh::io::parse_surface(&bytes, file)
                        .map_err(|e| err(e.to_string()))?;
                    let shape = soft_tissue_core::contact::MeshShape::new(
                        surface.positions,
                        surface.triangles,
                    )
                    .map_err(|e| err(format!("{file}: {e}")))?;
                    soft_tissue_core::contact::RigidShape::Mesh(std::sync::Arc::new(shape))
                }
                _ => soft_tissue_core::world::obstacle_shape(o, std::path::Path::new(""), options)
                    .map_err(|e| err(e.to_string()))?,
            };
            obstacles.push(
                soft_tissue_core::contact::Obstacle::new(
                    o.name.clone(),
                    shape,
                    soft_tissue_core::world::placement_pose(&o.placement),
                    o.friction.unwrap_or_default(),
                )
                .map_err(|e| err(e.to_string()))?,
            );
        }
        Ok(SceneAsset {
            scene,
            meshes,
            obstacles,
        })
    }

    fn extensions(&self) -> &[&str] {
        &["scene.ron"]
    }
}

/// Spawns the bodies of a scene asset as children of this entity once it has loaded, sets
/// the simulation's step (the app's fixed timestep, `Time<Fixed>`) to the scene's and
/// [`SoftTissueConfig`]'s contact scale and gravity to the scene's. The bodies keep the
/// scene's placements; the entity's own transform moves them all.
#[derive(Component, Reflect, Clone, Debug, Default)]
#[reflect(Component)]
#[require(Transform)]
pub struct SoftTissueSceneRoot(pub Handle<SceneAsset>);

/// The bodies a [`SoftTissueSceneRoot`] spawned, in scene order.
#[derive(Component, Clone, Debug, Default)]
pub struct SceneBodies(pub Vec<Entity>);

/// The components of scene body `i` (its mesh already placed by the loader).
fn scene_body(asset: &SceneAsset, i: usize) -> (Name, SoftBody, TissueMaterial, SoftBodyTuning) {
    let spec = &asset.scene.bodies[i];
    let fem = spec.fem.map_or(CYLINDER_FEM.params, |f| f.params);
    let msd = spec.msd.map_or(CYLINDER_MSD.params, |m| m.params);
    let springs = spec.msd.map(|m| m.spring_stiffness).unwrap_or_default();
    let body = SoftBody::new(asset.meshes[i].clone())
        .with_method(spec.precise)
        .with_cage(spec.cage.kind)
        .with_anchor(spec.anchor);
    let mut tuning = SoftBodyTuning {
        cage_dynamics: spec.cage.dynamics,
        cage_msd: spec.cage.msd.params,
        ..SoftBodyTuning::default()
    };
    if let Some(f) = spec.fem {
        tuning.fem_integrator = f.integrator;
    }
    (
        Name::new(spec.name.clone()),
        body,
        TissueMaterial {
            fem,
            msd: MsdMaterial::Own {
                params: msd,
                springs,
            },
            friction: spec.friction.unwrap_or_default(),
            toughness: spec.toughness.unwrap_or(0.0),
        },
        tuning,
    )
}

/// Spawns the bodies of every scene root whose scene has loaded.
fn spawn_scenes(
    mut commands: Commands,
    roots: Query<(Entity, &SoftTissueSceneRoot), Without<SceneBodies>>,
    scenes: Res<Assets<SceneAsset>>,
    meshes: Res<Assets<TetMeshAsset>>,
    mut config: ResMut<SoftTissueConfig>,
    mut fixed: Option<ResMut<Time<Fixed>>>,
) {
    for (root, handle) in &roots {
        let Some(asset) = scenes.get(&handle.0) else {
            continue;
        };
        let Some(placed) = asset
            .meshes
            .iter()
            .map(|h| meshes.get(h))
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let scene = &asset.scene;
        if let Some(first) = scene.bodies.first() {
            let dt = if first.precise.is_fem() {
                first.fem.map(|f| f.dt)
            } else {
                first.msd.map(|m| m.dt)
            };
            // The simulation steps at the fixed timestep.
            if let (Some(dt), Some(fixed)) = (dt, fixed.as_mut())
                && dt.is_finite()
                && dt > 0.0
            {
                let step = std::time::Duration::from_secs_f64(dt);
                if fixed.timestep() != step {
                    fixed.set_timestep(step);
                }
            }
        }
        let scale = placed
            .iter()
            .map(|m| m.0.bbox().smallest_dimension())
            .fold(f64::INFINITY, f64::min);
        if scale.is_finite() {
            config.contact = ContactConfig::for_scale(scale);
        }
        config.gravity = bevy::math::DVec3::from_array(scene.gravity);
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        for (i, spec) in scene.bodies.iter().enumerate() {
            let mut e = commands.spawn((scene_body(asset, i), ChildOf(root)));
            if let Some(h) = spec.heat {
                e.insert(TissueHeat(h));
            }
            bodies.push(e.id());
        }
        for o in &asset.obstacles {
            let pose = o.pose();
            let t = &pose.translation.vector;
            let q = pose.rotation;
            commands.spawn((
                Name::new(o.name().to_string()),
                SoftObstacle {
                    collider: ObstacleCollider::from_shape(o.shape()),
                    friction: *o.friction(),
                },
                Transform::from_xyz(t.x as f32, t.y as f32, t.z as f32).with_rotation(
                    Quat::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32),
                ),
                ChildOf(root),
            ));
        }
        let mut r = commands.entity(root);
        r.insert(SceneBodies(bodies));
        #[cfg(feature = "render")]
        r.insert_if_new(Visibility::default());
    }
}

/// Spawns the scene file `path` (relative to the assets folder) through the asset server
/// and updates `app` until its bodies are spawned, with the simulation paused meanwhile
/// (no step runs, none is counted); returns the bodies in scene order, the simulation
/// unpaused. For tests, benchmarks and headless tools: an app spawns a
/// [`SoftTissueSceneRoot`] and carries on.
pub fn spawn_scene_and_wait(app: &mut App, path: &str) -> Result<Vec<Entity>, String> {
    use crate::physics::{SoftPhysics, SoftPhysicsTime};
    let handle: Handle<SceneAsset> = app.world().resource::<AssetServer>().load(path.to_owned());
    let root = app
        .world_mut()
        .spawn(SoftTissueSceneRoot(handle.clone()))
        .id();
    let mut clock = app.world_mut().resource_mut::<Time<SoftPhysics>>();
    let was_paused = clock.is_paused();
    clock.pause();
    let start = std::time::Instant::now();
    let result = loop {
        app.update();
        if let Some(bodies) = app.world().get::<SceneBodies>(root) {
            break Ok(bodies.0.clone());
        }
        if let Some(bevy::asset::LoadState::Failed(e)) = app
            .world()
            .resource::<AssetServer>()
            .get_load_state(&handle)
        {
            break Err(format!("{path}: {e}"));
        }
        if start.elapsed() > std::time::Duration::from_secs(120) {
            break Err(format!("{path}: not loaded after 120 s"));
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    if !was_paused {
        app.world_mut()
            .resource_mut::<Time<SoftPhysics>>()
            .unpause();
    }
    result
}

/// The file name of the mesh behind `mesh` (`liver.vtk`, with its label where it has one:
/// `organ.stl#Surface`), where it was loaded from a path; `None` for a mesh made in code.
pub fn mesh_file_name(server: &AssetServer, mesh: &Handle<TetMeshAsset>) -> Option<String> {
    let path = server.get_path(mesh.id())?;
    let file = path.path().file_name()?.to_string_lossy().into_owned();
    Some(match path.label() {
        Some(label) => format!("{file}#{label}"),
        None => file,
    })
}

/// What to call a body where a person reads it (the inspector, a log line, an error): its
/// [`Name`], else its mesh's file name ([`mesh_file_name`]), else the entity.
pub fn body_label(
    entity: Entity,
    name: Option<&Name>,
    body: Option<&SoftBody>,
    server: &AssetServer,
) -> String {
    if let Some(name) = name {
        return name.as_str().to_owned();
    }
    body.and_then(|b| mesh_file_name(server, &b.mesh))
        .unwrap_or_else(|| format!("{entity}"))
}

/// Gives a body spawned without a [`Name`] its mesh's file name ([`mesh_file_name`]), so
/// that the simulation built from it, its errors and log lines, and the inspector say which
/// organ it is (`liver.vtk`) rather than an entity id (`396v0`). Runs in `PreUpdate`, before
/// the fixed steps that build bodies; a body with a name, or whose mesh was made in code,
/// is left as it is.
#[allow(clippy::type_complexity)]
fn name_bodies(
    mut commands: Commands,
    server: Res<AssetServer>,
    bodies: Query<(Entity, &SoftBody), (Added<SoftBody>, Without<Name>)>,
) {
    for (entity, body) in &bodies {
        if let Some(file) = mesh_file_name(&server, &body.mesh) {
            commands.entity(entity).insert(Name::new(file));
        }
    }
}

/// Registers the mesh and scene assets and their loaders, spawns scene roots, and names
/// unnamed bodies after their mesh files.
#[derive(Default)]
pub struct SoftTissueAssetPlugin;

impl Plugin for SoftTissueAssetPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<SoftTissueConfig>()
            .init_asset::<TetMeshAsset>()
            .init_asset::<SceneAsset>()
            .register_asset_loader(TetMeshLoader)
            .register_asset_loader(SceneLoader)
            .register_asset_loader(SurfaceLoader)
            .register_type::<SoftTissueSceneRoot>()
            .add_systems(PreUpdate, (spawn_scenes, name_bodies));
    }
}
