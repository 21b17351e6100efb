//! Indexes of the user's asset folders: ShapeNet, any mesh folder, photo textures. Built with
//! `walkdir`, cached under `$STEREOGEN_HOME/index/`, sorted so that planning is deterministic.
//! Files that are plainly broken are left out and listed in `skipped`.
//!
//! The index itself ([`AssetIndex`]) is pure data and lives with the planner in `stereogen-plan`;
//! this crate only fills it from folders, so the planner needs no file system.

pub mod cache;
pub mod meshes;
pub mod textures;

use std::path::{Path, PathBuf};

pub use stereogen_plan::assets::{AssetIndex, MeshAsset, SkippedAsset};
use stereogen_plan::recipe::SourcesRecipe;

/// `$STEREOGEN_HOME`, or `$HOME/.cache/stereogen`: the Blender environment, scripts and indexes.
pub fn stereogen_home() -> PathBuf {
    if let Some(h) = std::env::var_os("STEREOGEN_HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h);
    }
    let home = std::env::var_os("HOME").map(PathBuf::from).unwrap_or_else(std::env::temp_dir);
    home.join(".cache").join("stereogen")
}

/// Indexes the folders a recipe names (none: an empty index; the planner then uses its built-in
/// procedural shapes and textures). Indexes are cached under `home`.
pub fn index_sources(sources: &SourcesRecipe, home: &Path) -> anyhow::Result<AssetIndex> {
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
