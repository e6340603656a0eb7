//! Assets: tetrahedral meshes (`.msh`, `.vtk`, `.vtu`, `.node`) and scene files
//! (`.scene.ron`). A loader error names the file and what is wrong in it; Bevy logs it.

use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::prelude::*;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::{FormatError, MeshFormat, parse_tet_mesh, parse_tetgen};
use soft_tissue_core::scenario::{Scene, SceneError};
use soft_tissue_core::world::{SceneOptions, WorldError, check_mesh_path};

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
        let path = load_context.path().clone();
        let name = path.to_string();
        let mut bytes = Vec::new();
        reader
            .read_to_end(&mut bytes)
            .await
            .map_err(|e| TetMeshLoadError::Read {
                path: name.clone(),
                message: e.to_string(),
            })?;
        let format = MeshFormat::from_path(path.path()).ok_or_else(|| TetMeshLoadError::Read {
            path: name.clone(),
            message: "unknown extension: expected .msh, .vtk, .vtu or .node".into(),
        })?;
        let loaded = match format {
            MeshFormat::TetGen => {
                let ele_path = path.path().with_extension("ele");
                let ele_name = ele_path.display().to_string();
                let ele = load_context.read_asset_bytes(ele_path).await.map_err(|e| {
                    TetMeshLoadError::Read {
                        path: ele_name.clone(),
                        message: e.to_string(),
                    }
                })?;
                parse_tetgen(&bytes, &name, &ele, &ele_name)?
            }
            _ => parse_tet_mesh(&bytes, format, &name)?,
        };
        for note in &loaded.notes {
            info!("{name}: {note}");
        }
        Ok(TetMeshAsset(Arc::new(loaded.mesh)))
    }

    fn extensions(&self) -> &[&str] {
        &["msh", "vtk", "vtu", "node"]
    }
}

/// A scene file: the bodies of a scene, their meshes and settings (see
/// [`soft_tissue_core::scenario::Scene`]).
#[derive(Asset, TypePath, Clone, Debug)]
pub struct SceneAsset(pub Scene);

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
        for body in &scene.bodies {
            check_mesh_path(body, options)?;
        }
        Ok(SceneAsset(scene))
    }

    fn extensions(&self) -> &[&str] {
        &["scene.ron"]
    }
}

/// Registers the mesh and scene assets and their loaders.
#[derive(Default)]
pub struct SoftTissueAssetPlugin;

impl Plugin for SoftTissueAssetPlugin {
    fn build(&self, app: &mut App) {
        app.init_asset::<TetMeshAsset>()
            .init_asset::<SceneAsset>()
            .register_asset_loader(TetMeshLoader)
            .register_asset_loader(SceneLoader);
    }
}
