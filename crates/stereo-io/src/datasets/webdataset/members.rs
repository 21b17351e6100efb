//! A WebDataset export's samples as their members (bytes as stored, nothing decoded), for tools
//! that read a sample's files rather than its arrays: `stats` and `report` read the manifest line
//! in `<key>.json` and the EXRs and PNGs as they are, byte for byte, with their checksums.
//!
//! Opening is [`WebDataset::open`] (tar headers only, every shard checked against its index); a
//! member is then read by seeking into its shard, never by extracting it.

use std::path::{Path, PathBuf};

use super::WebDataset;
use crate::datasets::StereoDataset;
use crate::error::Result;

/// Every sample of a WebDataset folder: splits by name, shards in order, samples as stored.
pub struct ShardMembers(WebDataset);

impl ShardMembers {
    /// Lists every member of every shard of `root`. An unfinished export, a shard missing, of
    /// another size than its index says or with another number of samples is an error naming it.
    pub fn open(root: &Path) -> Result<Self> {
        WebDataset::open(root).map(Self)
    }

    /// Like [`Self::open`], the named splits only.
    pub fn open_splits<S: AsRef<str>>(root: &Path, splits: &[S]) -> Result<Self> {
        WebDataset::open_splits(root, splits).map(Self)
    }

    pub fn root(&self) -> &Path {
        self.0.root()
    }

    /// Samples in all shards.
    pub fn len(&self) -> usize {
        self.0.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.samples.is_empty()
    }

    /// Sample `i`'s key (the part of its member names before the extension).
    pub fn key(&self, i: usize) -> &str {
        &self.0.samples[i].key
    }

    /// The member names of sample `i` after `<key>.` (`left.png`, `json`, ...), as stored.
    pub fn suffixes(&self, i: usize) -> impl Iterator<Item = &str> {
        self.0.samples[i].suffixes()
    }

    /// The bytes of member `<key>.<suffix>` of sample `i`; `None` when the sample has no such
    /// member.
    pub fn read(&self, i: usize, suffix: &str) -> Result<Option<Vec<u8>>> {
        self.0.read_member(&self.0.samples[i], suffix)
    }

    /// How a member is named in messages: `<shard>/<key>.<suffix>`.
    pub fn path(&self, i: usize, suffix: &str) -> PathBuf {
        self.0.member_path(&self.0.samples[i], suffix)
    }
}
