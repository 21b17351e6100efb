//! A dataset made by many tasks: each task writes its own shard directory, a complete dataset of
//! its own, and `stereogen merge` writes the top-level manifest over all of them.
//!
//! ```text
//! <out>/shards/0003-of-0064/            one task's dataset (dataset.json, manifest.jsonl, ...)
//! <out>/shards/0003-of-0064/shard.json  which shard it is and the whole dataset's index range
//! <out>/dataset.json                    written by merge: recipe, seed, version (as every shard's)
//! <out>/manifest.jsonl                  written by merge: every shard's entries, paths into the shards
//! <out>/merge.json                      written by merge: how many shards, range, how it checked
//! ```
//!
//! A merged manifest's `files` are relative to `<out>` (`shards/0003-of-0064/tree/..._left.png`),
//! so every reader of our layout reads a merged dataset like any other; nothing is copied.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::DatasetLayout;
use crate::error::{Error, Result};

/// The folder of `<out>` that holds the shard directories.
pub const SHARDS_DIR: &str = "shards";
/// `shard.json`: a shard directory's place in the whole dataset.
pub const SHARD_INFO_FILE: &str = "shard.json";
/// `merge.json`: what `stereogen merge` checked when it wrote the top-level manifest.
pub const MERGE_INFO_FILE: &str = "merge.json";

/// Shard `index` of `count`: the samples `i` with `i % count == index`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct ShardId {
    pub index: u64,
    pub count: u64,
}

impl ShardId {
    /// `None` unless `index < count`.
    pub fn new(index: u64, count: u64) -> Option<Self> {
        (index < count).then_some(Self { index, count })
    }

    /// Whether sample `i` belongs to this shard.
    pub fn owns(&self, i: u64) -> bool {
        i % self.count == self.index
    }

    /// `0003-of-0064`: zero-padded to at least 4 digits, both numbers to the same width, so the
    /// directories of one farm sort in shard order.
    pub fn dir_name(&self) -> String {
        let width = self.count.to_string().len().max(4);
        format!("{:0width$}-of-{:0width$}", self.index, self.count)
    }

    /// The inverse of [`ShardId::dir_name`]; `None` for any other name.
    pub fn parse_dir_name(name: &str) -> Option<Self> {
        let (k, n) = name.split_once("-of-")?;
        let digits = |s: &str| s.len() >= 4 && s.bytes().all(|b| b.is_ascii_digit());
        if !digits(k) || !digits(n) {
            return None;
        }
        Self::new(k.parse().ok()?, n.parse().ok()?)
    }
}

impl fmt::Display for ShardId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// `shard.json`: which shard a directory holds, and the range of the whole dataset
/// (`start .. start + count`) the farm run asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardInfo {
    pub shard: ShardId,
    pub start: u64,
    pub count: u64,
}

/// How `merge` checked the files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChecksumCheck {
    /// Every file's SHA-256 recomputed (`--verify`).
    All,
    /// Every file present and non-empty; the SHA-256 of a sample of them recomputed.
    Sampled,
}

/// `merge.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MergeInfo {
    pub shards: u64,
    pub start: u64,
    pub count: u64,
    pub checksums: ChecksumCheck,
    /// Files whose checksum was recomputed.
    pub files_hashed: u64,
    /// Seconds since the Unix epoch when the merge was written.
    pub merged_unix_s: u64,
}

/// What [`DatasetLayout::shard_dirs`] finds under `<root>/shards`.
#[derive(Debug, Clone, Default)]
pub struct ShardDirs {
    /// Shard directories (`KKKK-of-NNNN`), in shard order.
    pub shards: Vec<(ShardId, DatasetLayout)>,
    /// Folders with other names.
    pub others: Vec<PathBuf>,
}

impl DatasetLayout {
    /// `<root>/shards`.
    pub fn shards_dir(&self) -> PathBuf {
        self.root.join(SHARDS_DIR)
    }

    /// The dataset directory of one shard: `<root>/shards/KKKK-of-NNNN`.
    pub fn shard(&self, id: ShardId) -> DatasetLayout {
        DatasetLayout::new(self.shards_dir().join(id.dir_name()))
    }

    /// `shard.json` of this (shard) directory.
    pub fn shard_info(&self) -> PathBuf {
        self.root.join(SHARD_INFO_FILE)
    }

    /// `merge.json` of this (farm output) directory.
    pub fn merge_info(&self) -> PathBuf {
        self.root.join(MERGE_INFO_FILE)
    }

    /// The shard directories under `<root>/shards`, in shard order; folders with other names
    /// are returned apart (merge reports them). Empty when there is no `shards` folder.
    pub fn shard_dirs(&self) -> Result<ShardDirs> {
        let dir = self.shards_dir();
        let mut shards = Vec::new();
        let mut others = Vec::new();
        let entries = match std::fs::read_dir(&dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(ShardDirs { shards, others });
            }
            Err(e) => return Err(Error::io(&dir, e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&dir, e))?;
            let path = entry.path();
            if !path.is_dir() {
                continue;
            }
            match ShardId::parse_dir_name(&entry.file_name().to_string_lossy()) {
                Some(id) => shards.push((id, DatasetLayout::new(path))),
                None => others.push(path),
            }
        }
        shards.sort_by_key(|(id, _)| (id.count, id.index));
        others.sort();
        Ok(ShardDirs { shards, others })
    }

    /// Whether this is a farm's output whose shards have not been merged yet: a `shards` folder
    /// with shard directories and no top-level manifest. Returns how many shard directories.
    pub fn unmerged_shards(&self) -> Option<usize> {
        if self.manifest().exists() {
            return None;
        }
        let n = self.shard_dirs().ok()?.shards.len();
        (n > 0).then_some(n)
    }

    /// The error every reader gives for an unmerged farm output, or `None` when it is not one.
    pub fn unmerged_error(&self, path: &Path) -> Option<Error> {
        let n = self.unmerged_shards()?;
        Some(Error::format(
            path,
            format!(
                "missing: {} holds {n} shard director{} not merged yet; run `stereogen merge {}` (or read one shard directory under {})",
                self.root.display(),
                if n == 1 { "y" } else { "ies" },
                self.root.display(),
                self.shards_dir().display()
            ),
        ))
    }

    pub fn read_shard_info(&self) -> Result<ShardInfo> {
        read_json(&self.shard_info(), "shard description")
    }

    pub fn write_shard_info(&self, info: &ShardInfo) -> Result<()> {
        write_json(&self.shard_info(), info)
    }

    pub fn read_merge_info(&self) -> Result<MergeInfo> {
        read_json(&self.merge_info(), "merge description")
    }

    pub fn write_merge_info(&self, info: &MergeInfo) -> Result<()> {
        write_json(&self.merge_info(), info)
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path, what: &str) -> Result<T> {
    let text = crate::limits::read_document(path, what)?;
    serde_json::from_str(&text)
        .map_err(|e| Error::format(path, format!("not a stereogen {what}: {e}")))
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let json = serde_json::to_string_pretty(value)
        .map_err(|e| Error::format(path, format!("cannot encode: {e}")))?;
    crate::atomic::write_bytes_atomically(path, json.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_dir_names_round_trip_and_sort() {
        let a = ShardId::new(7, 64).unwrap();
        assert_eq!(a.dir_name(), "0007-of-0064");
        assert_eq!(ShardId::parse_dir_name("0007-of-0064"), Some(a));
        assert_eq!(ShardId::new(3, 12000).unwrap().dir_name(), "00003-of-12000");
        for bad in [
            "7-of-64",
            "0064-of-0064",
            "0001-of-0000",
            "0001_of_0004",
            "x001-of-0004",
            "shard",
        ] {
            assert_eq!(ShardId::parse_dir_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn an_unmerged_farm_output_is_recognised() {
        let dir = tempfile::tempdir().unwrap();
        let layout = DatasetLayout::new(dir.path());
        assert_eq!(layout.unmerged_shards(), None);
        std::fs::create_dir_all(layout.shard(ShardId::new(1, 2).unwrap()).root).unwrap();
        std::fs::create_dir_all(layout.shards_dir().join("notes")).unwrap();
        assert_eq!(layout.unmerged_shards(), Some(1));
        let ShardDirs { shards, others } = layout.shard_dirs().unwrap();
        assert_eq!((shards.len(), others.len()), (1, 1));
        let e = layout
            .unmerged_error(&layout.manifest())
            .unwrap()
            .to_string();
        assert!(
            e.contains("stereogen merge") && e.contains("1 shard directory"),
            "{e}"
        );
        std::fs::write(layout.manifest(), "").unwrap();
        assert_eq!(layout.unmerged_shards(), None);
    }
}
