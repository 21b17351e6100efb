//! What the planner may draw from: the asset files a recipe's `[sources]` name, as plain data.
//! Filling it from folders (walking, probing, caching) is the job of `stereogen-assets`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// A mesh file the planner may pick.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeshAsset {
    pub path: PathBuf,
    /// ShapeNet synset id (e.g. "03001627"), when known.
    pub synset: Option<String>,
    /// Human name of the synset from `taxonomy.json` (e.g. "chair"), when known.
    pub label: Option<String>,
}

/// A file the index or a worker refused, with the reason.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkippedAsset {
    pub path: PathBuf,
    pub reason: String,
}

/// Everything the planner may draw from; empty means the built-in procedural shapes and textures.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AssetIndex {
    pub shapenet: Vec<MeshAsset>,
    pub meshes: Vec<MeshAsset>,
    pub textures: Vec<PathBuf>,
    pub skipped: Vec<SkippedAsset>,
}
