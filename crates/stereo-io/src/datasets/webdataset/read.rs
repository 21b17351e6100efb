//! Reading a WebDataset folder: its splits' shards (every split, or those named), checked
//! against their index, with each
//! sample's members located once (tar headers only) so any sample can be read by seeking, and
//! any shard read front to back ([`ShardReader`]: one open file, members in stored order) by a
//! loader that streams shards.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::scan::{ListedMember, scan_tar};
use super::{INDEX_SUFFIX, ShardIndex, member};
use crate::datasets::{
    DatasetFormat, InstanceRecord, SampleMaps, SampleMeta, StereoDataset, StereoSample,
};
use crate::error::{Error, Result};
use crate::exr_io::decode_disparity_exr;
use crate::image_io::{decode_bytes, to_rgb};
use crate::limits::open_inside;

mod maps;
pub use maps::decode_member_maps;

/// A member of a sample: its name after `<key>.` and where its data lies in the shard.
#[derive(Debug, Clone)]
struct Member {
    suffix: String,
    offset: u64,
    size: u64,
}

#[derive(Debug, Clone)]
pub(super) struct SampleEntry {
    pub(super) key: String,
    shard: usize,
    members: Vec<Member>,
}

impl SampleEntry {
    pub(super) fn suffixes(&self) -> impl Iterator<Item = &str> {
        self.members.iter().map(|m| m.suffix.as_str())
    }
}

/// A WebDataset folder opened for reading ([`StereoDataset`]); samples in index order: the
/// splits opened, by name, each split's shards in order, each shard's samples as stored.
pub struct WebDataset {
    root: PathBuf,
    /// The splits opened, sorted by name.
    splits: Vec<String>,
    shards: Vec<PathBuf>,
    pub(super) samples: Vec<SampleEntry>,
}

impl WebDataset {
    /// Whether `root` holds a WebDataset index.
    pub fn is_webdataset(root: &Path) -> bool {
        !index_files(root).is_empty()
    }

    /// The error for a folder an export is still writing or was killed writing (its progress
    /// file is there, its index not yet), if `root` is one.
    pub fn unfinished_error(root: &Path) -> Option<Error> {
        root.join(super::write::PROGRESS_FILE).is_file().then(|| {
            Error::format(
                root,
                "an unfinished WebDataset export (no index yet): re-run the export command to finish it",
            )
        })
    }

    /// The splits of the export at `root` (one per `<split>.index.json`), sorted by name. An
    /// unfinished export, or a folder with no index, is an error.
    pub fn split_names(root: &Path) -> Result<Vec<String>> {
        if let Some(e) = Self::unfinished_error(root) {
            return Err(e);
        }
        let names: Vec<String> = index_files(root)
            .iter()
            .filter_map(|p| p.file_name()?.to_str()?.strip_suffix(INDEX_SUFFIX))
            .map(str::to_string)
            .collect();
        if names.is_empty() {
            return Err(Error::format(
                root,
                format!(
                    "no <split>{INDEX_SUFFIX}: not a WebDataset export, or one that did not finish"
                ),
            ));
        }
        Ok(names)
    }

    /// Opens every split in `root` (what tools that read a whole export want: `stats`,
    /// `report`, a conversion). A trainer or an evaluation should name its splits
    /// ([`Self::open_splits`]): an export's `val` part is not training data.
    pub fn open(root: &Path) -> Result<Self> {
        let all = Self::split_names(root)?;
        Self::open_splits(root, &all)
    }

    /// Opens the named splits of `root`, in index order (by name) whatever the order asked,
    /// each once. A split the export does not have is an error listing those it has; a shard
    /// missing, of another size than its index says, or holding other than its index's number
    /// of samples is an error naming it.
    pub fn open_splits<S: AsRef<str>>(root: &Path, splits: &[S]) -> Result<Self> {
        let available = Self::split_names(root)?;
        if splits.is_empty() {
            return Err(Error::format(
                root,
                format!("no split asked for; its splits: {}", available.join(", ")),
            ));
        }
        for want in splits {
            let want = want.as_ref();
            if !available.iter().any(|a| a == want) {
                return Err(Error::format(
                    root,
                    format!(
                        "no split {want:?} in this WebDataset export; its splits: {}",
                        available.join(", ")
                    ),
                ));
            }
        }
        let chosen: Vec<String> = available
            .into_iter()
            .filter(|a| splits.iter().any(|w| w.as_ref() == a))
            .collect();
        let mut out = Self {
            root: root.to_path_buf(),
            splits: chosen,
            shards: vec![],
            samples: vec![],
        };
        for split in out.splits.clone() {
            let index = ShardIndex::read(root, &split)?;
            for shard in &index.shards {
                let path = root.join(&shard.name);
                let (file, size) = open_inside(root, &shard.name)?;
                if size != shard.bytes {
                    return Err(Error::format(
                        &path,
                        format!(
                            "shard is {size} bytes, its index says {}: cut short or replaced (an interrupted copy or export?)",
                            shard.bytes
                        ),
                    ));
                }
                let before = out.samples.len();
                let members = scan_tar(BufReader::new(file), size, &path)?;
                out.add_shard(path.clone(), members)?;
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

    /// The splits this dataset holds (those opened), sorted by name.
    pub fn splits(&self) -> &[String] {
        &self.splits
    }

    /// Adds the samples of a shard listed by [`scan_tar`]: a sample is a run of members with
    /// the same key, each suffix once (a second `left.png` would be read by some loaders and
    /// passed over by others).
    fn add_shard(&mut self, path: PathBuf, members: Vec<ListedMember>) -> Result<()> {
        let shard = self.shards.len();
        for listed in members {
            let m = Member {
                suffix: listed.suffix,
                offset: listed.offset,
                size: listed.size,
            };
            match self.samples.last_mut() {
                Some(s) if s.shard == shard && s.key == listed.key => {
                    if s.members.iter().any(|old| old.suffix == m.suffix) {
                        return Err(Error::format(
                            &path,
                            format!(
                                "member {:?} (data at byte offset {}) repeats a member of its sample",
                                format!("{}.{}", listed.key, m.suffix),
                                m.offset
                            ),
                        ));
                    }
                    s.members.push(m)
                }
                _ => self.samples.push(SampleEntry {
                    key: listed.key,
                    shard,
                    members: vec![m],
                }),
            }
        }
        self.shards.push(path);
        Ok(())
    }

    /// The shard files opened, in index order: each a plain file name inside [`Self::root`].
    pub fn shard_paths(&self) -> &[PathBuf] {
        &self.shards
    }

    pub(super) fn read_member(&self, s: &SampleEntry, suffix: &str) -> Result<Option<Vec<u8>>> {
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

    /// Where a member is named in errors: `<shard>/<key>.<suffix>`.
    pub(super) fn member_path(&self, s: &SampleEntry, suffix: &str) -> PathBuf {
        self.shards[s.shard].join(format!("{}.{suffix}", s.key))
    }
}

/// `<root>/*.index.json`, sorted by split name.
fn index_files(root: &Path) -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = fs::read_dir(root)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.to_string_lossy().ends_with(INDEX_SUFFIX))
        .collect();
    found.sort();
    found
}

impl StereoDataset for WebDataset {
    fn format(&self) -> DatasetFormat {
        DatasetFormat::WebDataset
    }

    fn root(&self) -> &Path {
        &self.root
    }

    fn len(&self) -> usize {
        self.samples.len()
    }

    fn id(&self, index: usize) -> Option<&str> {
        self.samples.get(index).map(|s| s.key.as_str())
    }

    fn sample(&self, index: usize) -> Result<StereoSample> {
        let s = self
            .samples
            .get(index)
            .ok_or_else(|| crate::datasets::out_of_range(self, index))?;
        self.decode_with(s, &|suffix| {
            Ok(self.read_member(s, suffix)?.map(Cow::Owned))
        })
    }

    fn maps(&self, index: usize) -> Result<SampleMaps> {
        let s = self
            .samples
            .get(index)
            .ok_or_else(|| crate::datasets::out_of_range(self, index))?;
        self.maps_with(s, &|suffix| {
            Ok(self.read_member(s, suffix)?.map(Cow::Owned))
        })
    }
}

impl WebDataset {
    /// A sample from its members' bytes, however they were read (seeking or streaming): `get`
    /// returns a member's bytes by suffix, `None` where the sample has no such member.
    fn decode_with<'a>(&self, s: &SampleEntry, get: &MemberBytes<'a>) -> Result<StereoSample> {
        let need = |suffix: &str| -> Result<(Cow<'a, [u8]>, PathBuf)> {
            let path = self.member_path(s, suffix);
            let bytes =
                get(suffix)?.ok_or_else(|| Error::format(&path, "missing from its sample"))?;
            Ok((bytes, path))
        };
        let image = |view: &str| -> Result<crate::image_io::RgbImage> {
            let suffix = ["png", "jpg"]
                .iter()
                .map(|ext| format!("{view}.{ext}"))
                .find(|sfx| s.members.iter().any(|m| &m.suffix == sfx))
                .unwrap_or_else(|| format!("{view}.png"));
            let (bytes, path) = need(&suffix)?;
            Ok(to_rgb(decode_bytes(&bytes, &path)?))
        };
        let (left, right) = (image(member::LEFT)?, image(member::RIGHT)?);
        let (bytes, path) = need(member::DISP_LEFT)?;
        let disp_left = decode_disparity_exr(&bytes, &path)?.0;
        let disp_right = match get(member::DISP_RIGHT)? {
            Some(b) => Some(decode_disparity_exr(&b, &self.member_path(s, member::DISP_RIGHT))?.0),
            None => None,
        };
        let valid_left = match get(member::VALID_LEFT)? {
            Some(b) => {
                let path = self.member_path(s, member::VALID_LEFT);
                Some(
                    decode_bytes(&b, &path)?
                        .to_luma8()
                        .into_raw()
                        .iter()
                        .map(|&v| v != 0)
                        .collect(),
                )
            }
            None => None,
        };
        let (bytes, path) = need(member::JSON)?;
        let facts = sample_facts(&bytes, &path)?;
        let mut meta = SampleMeta {
            format: facts["source_format"].as_str().and_then(|f| f.parse().ok()),
            id: facts["id"].as_str().unwrap_or(&s.key).to_string(),
            f_px: facts["f_px"].as_f64(),
            baseline_m: facts["baseline_m"].as_f64(),
            cx: facts["cx"].as_f64(),
            cy: facts["cy"].as_f64(),
            ndisp: facts["ndisp"].as_u64().and_then(|n| u32::try_from(n).ok()),
            ..Default::default()
        };
        meta.extra = facts_extra(&facts);
        if let Some(table) = facts["manifest"].get("instances") {
            meta.instances = serde_json::from_value::<Vec<InstanceRecord>>(table.clone())
                .map_err(|e| Error::format(&path, format!("unreadable instance table: {e}")))?;
        }
        Ok(StereoSample {
            left,
            right,
            disp_left,
            disp_right,
            valid_left,
            meta,
        })
    }
}

/// A sample's facts (its `<key>.json` member, read from `path`).
pub(super) fn sample_facts(bytes: &[u8], path: &Path) -> Result<serde_json::Value> {
    serde_json::from_slice(bytes)
        .map_err(|e| Error::format(path, format!("unreadable sample facts: {e}")))
}

/// The facts' `extra` (key → text; a value that is not text as its JSON).
pub(super) fn facts_extra(facts: &serde_json::Value) -> BTreeMap<String, String> {
    facts["extra"]
        .as_object()
        .map(|extra| {
            extra
                .iter()
                .map(|(k, v)| {
                    (
                        k.clone(),
                        v.as_str().map_or_else(|| v.to_string(), str::to_string),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Decodes one sample from its members as a loader that streams a shard has them (`(suffix,
/// bytes)` after `<key>.`, e.g. `left.png`, `disp_left.exr`, `json`): the arrays
/// [`WebDataset`]'s `sample` returns for it, bit for bit. `shard` only names the members in errors.
pub fn decode_members(
    shard: &Path,
    key: &str,
    members: &[(String, Vec<u8>)],
) -> Result<StereoSample> {
    let (dataset, entry) = streamed(shard, key, members);
    dataset.decode_with(&entry, &|suffix| {
        Ok(members
            .iter()
            .find(|(s, _)| s == suffix)
            .map(|(_, b)| Cow::Borrowed(b.as_slice())))
    })
}

/// A one-shard dataset holding the sample `key` of `members` (as streamed, not located).
fn streamed(shard: &Path, key: &str, members: &[(String, Vec<u8>)]) -> (WebDataset, SampleEntry) {
    let dataset = WebDataset {
        root: shard.parent().unwrap_or(Path::new("")).to_path_buf(),
        splits: vec![],
        shards: vec![shard.to_path_buf()],
        samples: vec![],
    };
    let entry = SampleEntry {
        key: key.to_string(),
        shard: 0,
        members: members
            .iter()
            .map(|(suffix, bytes)| Member {
                suffix: suffix.clone(),
                offset: 0,
                size: bytes.len() as u64,
            })
            .collect(),
    };
    (dataset, entry)
}

/// A member's bytes by suffix (`None`: the sample has no such member), borrowed or read.
type MemberBytes<'a> = dyn Fn(&str) -> Result<Option<Cow<'a, [u8]>>> + 'a;

/// A sample's members as stored (nothing decoded): what a streaming loader buffers. Its cost in
/// memory is the sum of its member sizes (a 960×540 sample of ours: about 2.3 MB).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawSample {
    /// The sample's index in the [`WebDataset`].
    pub index: usize,
    /// `(suffix, bytes)` in stored order: `left.png`, `right.png`, `disp_left.exr`, ...
    pub members: Vec<(String, Vec<u8>)>,
}

impl RawSample {
    /// The bytes of member `<key>.<suffix>`, if the sample has one.
    pub fn member(&self, suffix: &str) -> Option<&[u8]> {
        self.members
            .iter()
            .find(|(s, _)| s == suffix)
            .map(|(_, b)| b.as_slice())
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.members.iter().map(|(_, b)| b.len()).sum()
    }
}

impl WebDataset {
    /// The number of samples of each shard, shards in index order: shard `n` holds the samples
    /// numbered from the sum of the counts before it, consecutively.
    pub fn shard_samples(&self) -> Vec<usize> {
        let mut counts = vec![0; self.shards.len()];
        for s in &self.samples {
            counts[s.shard] += 1;
        }
        counts
    }

    /// Sample `index`'s members by seeking into its shard (random access).
    pub fn read_raw(&self, index: usize) -> Result<RawSample> {
        let s = self
            .samples
            .get(index)
            .ok_or_else(|| crate::datasets::out_of_range(self, index))?;
        let members = s
            .members
            .iter()
            .map(|m| {
                let bytes = self.read_member(s, &m.suffix)?.unwrap_or_default();
                Ok((m.suffix.clone(), bytes))
            })
            .collect::<Result<_>>()?;
        Ok(RawSample { index, members })
    }

    /// Decodes a sample read raw (by [`Self::read_raw`] or a [`ShardReader`]): the same arrays
    /// [`StereoDataset::sample`] returns for its index, bit for bit.
    pub fn decode(&self, raw: &RawSample) -> Result<StereoSample> {
        let s = self
            .samples
            .get(raw.index)
            .ok_or_else(|| crate::datasets::out_of_range(self, raw.index))?;
        self.decode_with(s, &|suffix| Ok(raw.member(suffix).map(Cow::Borrowed)))
    }

    /// The maps of a sample read raw: the same maps [`StereoDataset::maps`] returns for its
    /// index, bit for bit.
    pub fn decode_maps(&self, raw: &RawSample) -> Result<SampleMaps> {
        let s = self
            .samples
            .get(raw.index)
            .ok_or_else(|| crate::datasets::out_of_range(self, raw.index))?;
        self.maps_with(s, &|suffix| Ok(raw.member(suffix).map(Cow::Borrowed)))
    }

    /// Opens shard `shard` (numbered in index order) for reading front to back.
    pub fn shard_reader(&self, shard: usize) -> Result<ShardReader> {
        let path = self.shards.get(shard).ok_or_else(|| {
            Error::format(
                &self.root,
                format!("shard {shard} of {} asked for", self.shards.len()),
            )
        })?;
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        Ok(ShardReader {
            shard,
            path: path.clone(),
            file: BufReader::with_capacity(1 << 20, file),
            pos: 0,
            next: self.samples.partition_point(|s| s.shard < shard),
        })
    }
}

/// One shard read sequentially: one open file, samples and their members in stored order,
/// moving forward only (samples passed over are skipped without reading their bytes).
pub struct ShardReader {
    shard: usize,
    path: PathBuf,
    file: BufReader<File>,
    /// The file position of `file`.
    pos: u64,
    /// The lowest sample index that may still be read.
    next: usize,
}

impl ShardReader {
    /// The shard's number in the dataset's index order.
    pub fn shard(&self) -> usize {
        self.shard
    }

    /// Reads sample `index` of `dataset` (the dataset this reader was opened from), which must
    /// lie in this shard at or after the samples already read.
    pub fn read(&mut self, dataset: &WebDataset, index: usize) -> Result<RawSample> {
        let s = dataset
            .samples
            .get(index)
            .ok_or_else(|| crate::datasets::out_of_range(dataset, index))?;
        if s.shard != self.shard || index < self.next {
            return Err(Error::format(
                &self.path,
                format!(
                    "sample {index} asked of a reader of shard {} at sample {} (reads go forward within one shard)",
                    self.shard, self.next
                ),
            ));
        }
        self.next = index + 1;
        let mut members = Vec::with_capacity(s.members.len());
        for m in &s.members {
            let bytes = self.read_at(m.offset, m.size).inspect_err(|_| {
                // Where the file stands after a failed read is unknown: seek from the start.
                self.pos = u64::MAX;
            })?;
            members.push((m.suffix.clone(), bytes));
        }
        Ok(RawSample { index, members })
    }

    /// `size` bytes at `offset`, skipping forward from where the file stands (within the
    /// buffer where the gap is small: tar headers and padding).
    fn read_at(&mut self, offset: u64, size: u64) -> Result<Vec<u8>> {
        let io = |e| Error::io(&self.path, e);
        if offset != self.pos {
            match offset.checked_sub(self.pos) {
                Some(gap) => self.file.seek_relative(gap as i64),
                None => self.file.seek(SeekFrom::Start(offset)).map(drop),
            }
            .map_err(io)?;
            self.pos = offset;
        }
        let mut bytes = vec![0; size as usize];
        self.file.read_exact(&mut bytes).map_err(io)?;
        self.pos += size;
        Ok(bytes)
    }
}
