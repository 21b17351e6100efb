//! Where `stats` and `report` read a dataset's files from: our folder layout (`manifest.jsonl`
//! and the files it names), or a WebDataset export of it (`stereogen export --format
//! webdataset`), whose `<key>.json` members carry the manifest lines and whose other members are
//! the sample's files byte for byte, read straight from the tar shards. The layout is detected:
//! a folder with a `<split>.index.json` is an export.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use stereo_io::datasets::webdataset::members::ShardMembers;

use crate::dataset::{DatasetInfo, DatasetLayout, ManifestContents, ManifestEntry, read_manifest};

/// A dataset's files, in either layout.
pub enum DatasetFiles {
    Folder(DatasetLayout),
    Shards {
        members: ShardMembers,
        /// Manifest index → sample of the shards.
        by_index: HashMap<u64, usize>,
    },
}

impl DatasetFiles {
    /// Whether `root` is a WebDataset export (finished or not) rather than our folder layout.
    pub fn is_shards(root: &Path) -> bool {
        stereo_io::WebDataset::is_webdataset(root)
            || stereo_io::WebDataset::unfinished_error(root).is_some()
    }

    /// The layout `root` holds. Opening an export reads its shards' tar headers; the manifest is
    /// read by [`DatasetFiles::manifest`].
    pub fn open(root: &Path) -> stereo_io::Result<Self> {
        if Self::is_shards(root) {
            Ok(Self::Shards {
                members: ShardMembers::open(root)?,
                by_index: HashMap::new(),
            })
        } else {
            Ok(Self::Folder(DatasetLayout::new(root)))
        }
    }

    pub fn root(&self) -> &Path {
        match self {
            Self::Folder(l) => &l.root,
            Self::Shards { members, .. } => members.root(),
        }
    }

    /// `dataset.json` (an export carries the source's).
    pub fn read_info(&self) -> stereo_io::Result<DatasetInfo> {
        DatasetLayout::new(self.root()).read_info()
    }

    /// The finished samples: `manifest.jsonl`, or the manifest lines of the export's samples (by
    /// index). Remembers where each sample of an export lies for [`DatasetFiles::read`].
    pub fn manifest(&mut self) -> stereo_io::Result<ManifestContents> {
        let (members, by_index) = match self {
            Self::Folder(l) => return read_manifest(&l.manifest()),
            Self::Shards { members, by_index } => (members, by_index),
        };
        let mut entries = Vec::with_capacity(members.len());
        for i in 0..members.len() {
            let path = members.path(i, "json");
            let bytes = members
                .read(i, "json")?
                .ok_or_else(|| stereo_io::Error::format(&path, "missing from its sample"))?;
            let facts: serde_json::Value = serde_json::from_slice(&bytes)
                .map_err(|e| stereo_io::Error::format(&path, format!("unreadable: {e}")))?;
            let line = facts.get("manifest").filter(|m| !m.is_null()).ok_or_else(|| {
                stereo_io::Error::format(
                    &path,
                    "holds no manifest line: an export of a dataset that is not a stereogen dataset",
                )
            })?;
            let entry: ManifestEntry = serde_json::from_value(line.clone()).map_err(|e| {
                stereo_io::Error::format(&path, format!("unreadable manifest line: {e}"))
            })?;
            if by_index.insert(entry.index, i).is_some() {
                return Err(stereo_io::Error::format(
                    &path,
                    format!("a second sample of index {}", entry.index),
                ));
            }
            entries.push(entry);
        }
        entries.sort_by_key(|e| e.index);
        Ok(ManifestContents {
            entries,
            unfinished_bytes: 0,
        })
    }

    /// The member of `e`'s sample that holds its file `key` (`left` → `left.png`, `scene` →
    /// `scene.json.gz`, ...): the first whose name after `<key>.` is `key` and an extension.
    fn member(&self, e: &ManifestEntry, key: &str) -> Option<(usize, String)> {
        let Self::Shards { members, by_index } = self else {
            return None;
        };
        let i = *by_index.get(&e.index)?;
        let prefix = format!("{key}.");
        let suffix = members
            .suffixes(i)
            .find(|s| s.starts_with(&prefix))
            .map_or_else(|| default_suffix(key), str::to_string);
        Some((i, suffix))
    }

    /// Where sample `e`'s file `key` lies (for messages): its path, or `<shard>/<key>.<member>`.
    pub fn path(&self, e: &ManifestEntry, key: &str) -> PathBuf {
        match self {
            Self::Folder(l) => l.abs(file_of(e, key)),
            Self::Shards { members, .. } => match self.member(e, key) {
                Some((i, suffix)) => members.path(i, &suffix),
                None => members.root().join(format!("{}.{key}", e.id)),
            },
        }
    }

    /// The bytes of sample `e`'s file `key`, as stored.
    pub fn read(&self, e: &ManifestEntry, key: &str) -> stereo_io::Result<Vec<u8>> {
        let path = self.path(e, key);
        match self {
            Self::Folder(_) => std::fs::read(&path).map_err(|err| stereo_io::Error::io(&path, err)),
            Self::Shards { members, .. } => {
                let (i, suffix) = self
                    .member(e, key)
                    .ok_or_else(|| stereo_io::Error::format(&path, "no such sample"))?;
                members
                    .read(i, &suffix)?
                    .ok_or_else(|| stereo_io::Error::format(&path, "missing from its sample"))
            }
        }
    }

    /// Whether sample `e` has its file `key` (an export may lack the SceneSpec).
    pub fn has(&self, e: &ManifestEntry, key: &str) -> bool {
        match self {
            Self::Folder(_) => true,
            Self::Shards { members, .. } => self
                .member(e, key)
                .is_some_and(|(i, suffix)| members.suffixes(i).any(|s| s == suffix)),
        }
    }

    /// The line `stats` prints when an export's samples carry no SceneSpec: what it cannot
    /// compute from the shards. `None` for our folder layout and for exports that carry them.
    pub fn no_scenes_note(&self, entries: &[ManifestEntry]) -> Option<String> {
        let shards = matches!(self, Self::Shards { .. });
        (shards && !entries.iter().any(|e| self.has(e, "scene"))).then(|| {
            format!(
                "{} is a WebDataset export whose shards carry no SceneSpecs: the object-level statistics (KS tests) and the gap checks (whose bins follow the object count) cannot be computed from it; the pixel statistics are",
                self.root().display()
            )
        })
    }

    /// The line `report` shows for an export: the logs it does not carry.
    pub fn no_logs_note(&self) -> Option<String> {
        matches!(self, Self::Shards { .. }).then(|| {
            format!(
                "{} is a WebDataset export: it carries no failures.jsonl or skipped_assets.jsonl, so none are listed",
                self.root().display()
            )
        })
    }
}

/// The member name a file key has when a sample lacks it (for the message that says so).
fn default_suffix(key: &str) -> String {
    match key {
        "left" | "right" => format!("{key}.png"),
        "disp_left" | "disp_right" => format!("{key}.exr"),
        "scene" => "scene.json.gz".into(),
        _ => key.to_string(),
    }
}

/// The manifest's relative path of file `key` (a map's key too: `depth_left`, ...; the scene
/// file for a key the sample does not have).
fn file_of<'a>(e: &'a ManifestEntry, key: &str) -> &'a Path {
    let f = &e.files;
    match key {
        "left" => &f.left,
        "right" => &f.right,
        "disp_left" => &f.disp_left,
        "disp_right" => &f.disp_right,
        _ => f
            .all()
            .into_iter()
            .find(|(k, _)| *k == key)
            .map_or(&f.scene, |(_, p)| p),
    }
}
