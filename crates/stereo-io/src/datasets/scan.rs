//! The folder walking and naming every layout's reader shares.

use std::path::{Path, PathBuf};

use walkdir::WalkDir;

use crate::error::{Error, Result};

/// `path` relative to `root`, as text: the stable id of a sample.
pub(crate) fn rel_id(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .to_string_lossy()
        .into_owned()
}

/// The entries under `root`, sorted by name, following links.
pub(crate) fn walk(root: &Path, max_depth: usize) -> impl Iterator<Item = walkdir::DirEntry> {
    WalkDir::new(root)
        .max_depth(max_depth)
        .follow_links(true)
        .sort_by_file_name()
        .into_iter()
        .filter_map(|e| e.ok())
}

pub(crate) fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// `path` if it is a file; else an error naming it as the `what` of `for_`.
pub(crate) fn require(path: PathBuf, what: &str, for_: &Path) -> Result<PathBuf> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(Error::format(
            &path,
            format!("missing: the {what} of {}", for_.display()),
        ))
    }
}
