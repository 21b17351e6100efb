//! Indexes of what a recipe draws from: the user's asset folders (ShapeNet, any mesh folder, photo
//! textures) and the built-in content pack. Built with `walkdir`, cached under
//! `$STEREOGEN_HOME/index/`, sorted so that planning is deterministic. Files that are plainly
//! broken are left out and listed in `skipped`. Also: fetching Objaverse objects into a mesh folder.
//!
//! The index itself ([`AssetIndex`]) is pure data and lives with the planner in `stereogen-plan`;
//! this crate only fills it, so the planner needs no file system.

pub mod blender_env;
pub mod cache;
pub mod folder;
pub mod meshes;
pub mod objaverse;
pub mod pack;
pub mod textures;

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};
pub use stereogen_plan::assets::{AssetIndex, MeshAsset, SkippedAsset, TextureAsset};
use stereogen_plan::recipe::SourcesRecipe;

/// `$STEREOGEN_HOME`, or `$HOME/.cache/stereogen`: the Blender environment, scripts and indexes.
pub fn stereogen_home() -> PathBuf {
    if let Some(h) = std::env::var_os("STEREOGEN_HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h);
    }
    let home = std::env::var_os("HOME")
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    home.join(".cache").join("stereogen")
}

/// Feeds a folder's file list into the fingerprint, relative to the folder so that a moved folder
/// keeps it.
fn hash_files<'a>(
    h: &mut Sha256,
    what: &str,
    root: &Path,
    files: impl Iterator<Item = (&'a Path, String)>,
) {
    h.update(format!("[{what}]\n"));
    for (path, extra) in files {
        h.update(format!(
            "{} {extra}\n",
            path.strip_prefix(root).unwrap_or(path).display()
        ));
    }
}

/// [`hash_files`] of a mesh folder's index (a mesh file has nothing to add to its path).
fn hash_meshes(h: &mut Sha256, what: &str, root: &Path, meshes: &[MeshAsset]) {
    hash_files(
        h,
        what,
        root,
        meshes.iter().map(|m| (m.path.as_path(), String::new())),
    );
}

/// Indexes the folders a recipe names and, when `sources.builtin_pack` is set, the built-in pack
/// (its photos stand in for an unset `textures`, its meshes for unset `shapenet` and `meshes`).
/// An empty index means the planner's procedural shapes and textures. Folder indexes are cached
/// under `home`; the pack is installed there on first use if `stereogen setup` has not done it.
pub fn index_sources(sources: &SourcesRecipe, home: &Path) -> anyhow::Result<AssetIndex> {
    let mut index = AssetIndex::default();
    let mut h = Sha256::new();
    if let Some(root) = &sources.shapenet {
        let (found, skipped) = meshes::index_shapenet(root, &sources.shapenet_synsets, home)?;
        hash_meshes(&mut h, "shapenet", root, &found);
        index.shapenet = found;
        index.skipped.extend(skipped);
    }
    if let Some(root) = &sources.meshes {
        let (found, skipped) = meshes::index_mesh_folder(root, home)?;
        hash_meshes(&mut h, "meshes", root, &found);
        index.meshes = found;
        index.skipped.extend(skipped);
    }
    if let Some(root) = &sources.textures {
        let (found, skipped) = textures::index_textures(root, home)?;
        hash_files(
            &mut h,
            "textures",
            root,
            found
                .iter()
                .map(|t| (t.path.as_path(), format!("{:?}", t.size))),
        );
        index.textures = found;
        index.skipped.extend(skipped);
    }
    let wants_pack_photos = sources.textures.is_none();
    let wants_pack_meshes = sources.shapenet.is_none() && sources.meshes.is_none();
    if sources.builtin_pack && (wants_pack_photos || wants_pack_meshes) {
        let dir = pack::ensure_installed(home)?;
        let pack = pack::index_pack(&dir, &sources.exclude_licences);
        h.update(format!("[pack {}]\n", pack.fingerprint));
        if wants_pack_photos {
            index.textures = pack.photos();
        }
        if wants_pack_meshes {
            index.pack_meshes = pack.meshes();
        }
        index.skipped.extend(pack.skipped);
    }
    let empty = index.shapenet.is_empty()
        && index.meshes.is_empty()
        && index.textures.is_empty()
        && index.pack_meshes.is_empty();
    if !empty {
        index.fingerprint = Some(
            h.finalize()
                .iter()
                .take(8)
                .map(|b| format!("{b:02x}"))
                .collect(),
        );
    }
    // Skipped files are reported by the caller (`generate` once per dataset and file, in
    // `skipped_assets.jsonl` too), not here: a warning here would print each of them twice.
    Ok(index)
}
