//! Indexing a folder of asset files (meshes, photos): what every such folder index shares, the
//! check that the folder is there, its cache key and the cached walk over its files.

use std::path::Path;

use anyhow::{Context, bail};
use serde::{Serialize, de::DeserializeOwned};
use stereogen_plan::assets::SkippedAsset;
use walkdir::{DirEntry, WalkDir};

use super::cache::{cached, tree_stamp};

/// Refuses a folder that is not there, naming what it was to hold (`what`: "mesh", "texture").
pub fn check_root(root: &Path, what: &str) -> anyhow::Result<()> {
    if !root.is_dir() {
        bail!(
            "{what} folder {} does not exist or is not a directory",
            root.display()
        );
    }
    Ok(())
}

/// The cache key of a folder: its canonical path, so that other paths to the same folder share
/// one cached index.
pub fn folder_key(root: &Path) -> String {
    root.canonicalize()
        .unwrap_or_else(|_| root.to_path_buf())
        .display()
        .to_string()
}

/// Indexes every file under the `what` folder `root`, cached under `home` as `cache_kind`.
/// `classify` says what a file is: `None` not one of the folder's kind, `Some(Err(reason))` one
/// that is left out and listed with the reason, `Some(Ok(asset))` one indexed.
pub fn index_files<T: Serialize + DeserializeOwned>(
    root: &Path,
    home: &Path,
    what: &str,
    cache_kind: &str,
    mut classify: impl FnMut(&DirEntry) -> Option<Result<T, String>>,
) -> anyhow::Result<(Vec<T>, Vec<SkippedAsset>)> {
    check_root(root, what)?;
    cached(
        home,
        cache_kind,
        &folder_key(root),
        &tree_stamp(root),
        || {
            let mut found = Vec::new();
            let mut skipped = Vec::new();
            for entry in WalkDir::new(root).follow_links(true).sort_by_file_name() {
                let entry = entry.with_context(|| format!("cannot walk {}", root.display()))?;
                match classify(&entry) {
                    None => {}
                    Some(Ok(asset)) => found.push(asset),
                    Some(Err(reason)) => skipped.push(SkippedAsset {
                        path: entry.path().to_path_buf(),
                        reason,
                    }),
                }
            }
            Ok((found, skipped))
        },
    )
}
