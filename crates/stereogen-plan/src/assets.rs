//! What the planner may draw from: the asset files a recipe's `[sources]` name, and the built-in
//! content pack, as plain data. Filling it from folders (walking, probing, verifying, caching) is
//! the job of `stereogen-assets`.

use std::path::{Path, PathBuf};

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

/// A photo the planner may put on a surface.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TextureAsset {
    pub path: PathBuf,
    /// Width and height in pixels, when the index could read them (photo sizing needs them).
    pub size: Option<[u32; 2]>,
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
    /// Photos: the recipe's texture folder, or the built-in pack's photos.
    pub textures: Vec<TextureAsset>,
    /// The built-in pack's real meshes, standing in for the ShapeNet and mesh folders a recipe
    /// does not name (a share of those draws; primitives take the rest).
    pub pack_meshes: Vec<MeshAsset>,
    pub skipped: Vec<SkippedAsset>,
    /// A digest of what the planner draws from (file lists, photo sizes, the pack's file
    /// contents), independent of where the files live; `None` for an empty index. A sample is a
    /// pure function of (recipe, seed, index, this fingerprint).
    pub fingerprint: Option<String>,
}

impl AssetIndex {
    /// The pixel size of a photo of the index, if known.
    pub fn texture_size(&self, path: &Path) -> Option<[u32; 2]> {
        self.textures
            .iter()
            .find(|t| t.path == path)
            .and_then(|t| t.size)
    }
}
