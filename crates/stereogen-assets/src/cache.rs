//! A small on-disk cache for folder indexes, keyed by the folder and invalidated when any
//! directory under it changes (a new or removed file changes its directory's mtime).

use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use serde::{Serialize, de::DeserializeOwned};
use sha2::{Digest, Sha256};
use walkdir::WalkDir;

/// A fingerprint of every directory's path and mtime under `root`: cheap next to reading files.
pub fn tree_stamp(root: &Path) -> String {
    let mut h = Sha256::new();
    for entry in WalkDir::new(root)
        .follow_links(true)
        .sort_by_file_name()
        .into_iter()
        .flatten()
    {
        if entry.file_type().is_dir() {
            let mtime = entry
                .metadata()
                .ok()
                .and_then(|m| m.modified().ok())
                .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos());
            h.update(entry.path().to_string_lossy().as_bytes());
            h.update(mtime.to_le_bytes());
        }
    }
    h.finalize()
        .iter()
        .take(12)
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn cache_path(home: &Path, kind: &str, key: &str) -> PathBuf {
    let digest: String = Sha256::digest(key.as_bytes())
        .iter()
        .take(8)
        .map(|b| format!("{b:02x}"))
        .collect();
    home.join("index").join(format!("{kind}-{digest}.json"))
}

/// Returns the cached value for (kind, key) if its stamp matches, else builds, stores and returns it.
pub fn cached<T: Serialize + DeserializeOwned>(
    home: &Path,
    kind: &str,
    key: &str,
    stamp: &str,
    build: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let path = cache_path(home, kind, key);
    if let Ok(text) = std::fs::read_to_string(&path)
        && let Ok((s, value)) = serde_json::from_str::<(String, T)>(&text)
        && s == stamp
    {
        return Ok(value);
    }
    let value = build()?;
    if let Some(dir) = path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    // A cache that cannot be written only costs time on the next run.
    if let Ok(json) = serde_json::to_string(&(stamp, &value)) {
        let _ = stereo_io::write_bytes_atomically(&path, json.as_bytes());
    }
    Ok(value)
}
