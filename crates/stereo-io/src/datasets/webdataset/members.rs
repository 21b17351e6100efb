//! A WebDataset export's samples as their members (bytes as stored, nothing decoded), for tools
//! that read a sample's files rather than its arrays: `stats` and `report` read the manifest line
//! in `<key>.json` and the EXRs and PNGs as they are, byte for byte, with their checksums.
//!
//! Opening reads tar headers only (every split's shards, checked against their index as
//! [`super::WebDataset::open`] does); a member is then read by seeking into its shard, never by
//! extracting it.

use std::fs::{self, File};
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::{INDEX_FORMAT, INDEX_SUFFIX, INDEX_VERSION, ShardIndex, WebDataset};
use crate::error::{Error, Result};

/// Where one member's data lies in its shard.
#[derive(Debug, Clone)]
struct Member {
    suffix: String,
    offset: u64,
    size: u64,
}

#[derive(Debug, Clone)]
struct Sample {
    key: String,
    shard: usize,
    members: Vec<Member>,
}

/// Every sample of a WebDataset folder: splits by name, shards in order, samples as stored.
#[derive(Debug, Clone)]
pub struct ShardMembers {
    root: PathBuf,
    shards: Vec<PathBuf>,
    samples: Vec<Sample>,
}

impl ShardMembers {
    /// Lists every member of every shard of `root`. An unfinished export, a shard missing, of
    /// another size than its index says or with another number of samples is an error naming it.
    pub fn open(root: &Path) -> Result<Self> {
        if let Some(e) = WebDataset::unfinished_error(root) {
            return Err(e);
        }
        let mut indices: Vec<PathBuf> = fs::read_dir(root)
            .map_err(|e| Error::io(root, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.to_string_lossy().ends_with(INDEX_SUFFIX))
            .collect();
        indices.sort();
        if indices.is_empty() {
            return Err(Error::format(
                root,
                format!("no <split>{INDEX_SUFFIX}: not a WebDataset export"),
            ));
        }
        let mut out = Self {
            root: root.to_path_buf(),
            shards: vec![],
            samples: vec![],
        };
        for path in indices {
            let text = fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
            let index: ShardIndex = serde_json::from_str(&text)
                .map_err(|e| Error::format(&path, format!("unreadable index: {e}")))?;
            if index.format != INDEX_FORMAT || index.version != INDEX_VERSION {
                return Err(Error::format(
                    &path,
                    format!(
                        "index of format {:?} version {}; this build reads {INDEX_FORMAT:?} version {INDEX_VERSION}",
                        index.format, index.version
                    ),
                ));
            }
            for shard in &index.shards {
                let path = root.join(&shard.name);
                let size = fs::metadata(&path).map_err(|e| Error::io(&path, e))?.len();
                if size != shard.bytes {
                    return Err(Error::format(
                        &path,
                        format!(
                            "shard is {size} bytes, its index says {}: cut short or replaced",
                            shard.bytes
                        ),
                    ));
                }
                let before = out.samples.len();
                out.scan(&path)?;
                let found = out.samples.len() - before;
                if found != shard.samples {
                    return Err(Error::format(
                        &path,
                        format!(
                            "shard holds {found} samples, its index says {}",
                            shard.samples
                        ),
                    ));
                }
            }
        }
        Ok(out)
    }

    /// Lists the members of the shard at `path` from its tar headers.
    fn scan(&mut self, path: &Path) -> Result<()> {
        let shard = self.shards.len();
        self.shards.push(path.to_path_buf());
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let mut archive = tar::Archive::new(file);
        for entry in archive
            .entries_with_seek()
            .map_err(|e| Error::io(path, e))?
        {
            let entry = entry.map_err(|e| Error::io(path, e))?;
            let name = entry
                .path()
                .map_err(|e| Error::io(path, e))?
                .to_string_lossy()
                .into_owned();
            // WebDataset's rule: the key ends at the first dot after the last `/`.
            let dir_end = name.rfind('/').map_or(0, |i| i + 1);
            let Some(dot) = name[dir_end..].find('.').map(|i| dir_end + i) else {
                return Err(Error::format(
                    path,
                    format!("member {name:?} has no extension"),
                ));
            };
            let member = Member {
                suffix: name[dot + 1..].to_string(),
                offset: entry.raw_file_position(),
                size: entry.size(),
            };
            let key = &name[..dot];
            match self.samples.last_mut() {
                Some(s) if s.shard == shard && s.key == key => s.members.push(member),
                _ => self.samples.push(Sample {
                    key: key.to_string(),
                    shard,
                    members: vec![member],
                }),
            }
        }
        Ok(())
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Samples in all shards.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Sample `i`'s key (the part of its member names before the extension).
    pub fn key(&self, i: usize) -> &str {
        &self.samples[i].key
    }

    /// The member names of sample `i` after `<key>.` (`left.png`, `json`, ...), as stored.
    pub fn suffixes(&self, i: usize) -> impl Iterator<Item = &str> {
        self.samples[i].members.iter().map(|m| m.suffix.as_str())
    }

    /// The bytes of member `<key>.<suffix>` of sample `i`; `None` when the sample has no such
    /// member.
    pub fn read(&self, i: usize, suffix: &str) -> Result<Option<Vec<u8>>> {
        let s = &self.samples[i];
        let Some(m) = s.members.iter().find(|m| m.suffix == suffix) else {
            return Ok(None);
        };
        let path = &self.shards[s.shard];
        let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
        let mut bytes = vec![0; m.size as usize];
        file.seek(SeekFrom::Start(m.offset))
            .and_then(|_| file.read_exact(&mut bytes))
            .map_err(|e| Error::io(path, e))?;
        Ok(Some(bytes))
    }

    /// How a member is named in messages: `<shard>/<key>.<suffix>`.
    pub fn path(&self, i: usize, suffix: &str) -> PathBuf {
        let s = &self.samples[i];
        self.shards[s.shard].join(format!("{}.{suffix}", s.key))
    }
}
