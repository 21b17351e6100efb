//! Indexes of the user's asset folders: ShapeNet, any mesh folder, photo textures. Built with
//! `walkdir`, cached under `$STEREOGEN_HOME/index/`, sorted so that planning is deterministic.
//! Files that are plainly broken are left out and listed in `skipped`.

pub mod cache;
pub mod meshes;
pub mod textures;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::plan::recipe::SourcesRecipe;

/// A file the index or a worker refused, with the reason.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkippedAsset {
    pub path: PathBuf,
    pub reason: String,
}

/// Everything the planner may draw from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AssetIndex {
    pub shapenet: Vec<meshes::MeshAsset>,
    pub meshes: Vec<meshes::MeshAsset>,
    pub textures: Vec<PathBuf>,
    pub skipped: Vec<SkippedAsset>,
}

impl AssetIndex {
    /// Indexes the folders a recipe names (none: an empty index; the planner then uses its
    /// built-in procedural shapes and textures).
    pub fn build(sources: &SourcesRecipe, home: &std::path::Path) -> anyhow::Result<Self> {
        let mut index = AssetIndex::default();
        if let Some(root) = &sources.shapenet {
            let (found, skipped) = meshes::index_shapenet(root, &sources.shapenet_synsets, home)?;
            index.shapenet = found;
            index.skipped.extend(skipped);
        }
        if let Some(root) = &sources.meshes {
            let (found, skipped) = meshes::index_mesh_folder(root, home)?;
            index.meshes = found;
            index.skipped.extend(skipped);
        }
        if let Some(root) = &sources.textures {
            let (found, skipped) = textures::index_textures(root, home)?;
            index.textures = found;
            index.skipped.extend(skipped);
        }
        for s in &index.skipped {
            tracing::warn!("skipping asset {}: {}", s.path.display(), s.reason);
        }
        Ok(index)
    }
}
