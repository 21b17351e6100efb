//! The first step of the stats pass: the dataset's description, manifest and category list, from
//! our folder layout or a WebDataset export of it ([`DatasetFiles`]).

use std::path::Path;

use anyhow::Context;

use crate::dataset::{DatasetInfo, ManifestEntry};
use crate::validate::dataset_files::DatasetFiles;

/// A dataset read for statistics.
pub struct Loaded {
    pub info: DatasetInfo,
    pub entries: Vec<ManifestEntry>,
    /// Recipe categories in recipe order, then any other category found in the manifest.
    pub categories: Vec<String>,
    /// Where the samples' files are read from.
    pub files: DatasetFiles,
}

impl Loaded {
    /// The index of a manifest entry's category in [`Loaded::categories`].
    pub fn category_of(&self, e: &ManifestEntry) -> usize {
        self.categories
            .iter()
            .position(|c| *c == e.category)
            .expect("every manifest category is listed")
    }
}

pub fn load(root: &Path) -> anyhow::Result<Loaded> {
    let mut files = DatasetFiles::open(root)?;
    let info: DatasetInfo = files
        .read_info()
        .with_context(|| format!("{} is not a stereogen dataset", root.display()))?;
    // stats may run while `generate` appends: an unfinished last line is left out, with a note.
    let manifest = files.manifest()?;
    if manifest.has_unfinished_line() {
        eprintln!(
            "stats: {}: ignoring an unfinished last line (generation still running?)",
            root.join("manifest.jsonl").display()
        );
    }
    let entries = manifest.entries;
    let mut categories: Vec<String> = info
        .recipe
        .categories
        .iter()
        .map(|c| c.name.clone())
        .collect();
    for e in &entries {
        if !categories.contains(&e.category) {
            categories.push(e.category.clone());
        }
    }
    Ok(Loaded {
        info,
        entries,
        categories,
        files,
    })
}
