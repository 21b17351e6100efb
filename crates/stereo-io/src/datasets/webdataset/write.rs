//! `export --format webdataset`: any dataset [`open_dataset_with`] reads, as tar shards.

use std::collections::HashMap;
use std::fs::{self, File};
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{
    INDEX_FORMAT, INDEX_SUFFIX, INDEX_VERSION, ShardEntry, ShardIndex, member, sample_key,
};
use crate::atomic::{place, temp_sibling, write_bytes_atomically};
use crate::datasets::export::{SampleSelection, export_name};
use crate::datasets::stereogen::{DatasetLayout, VIEWS, read_manifest};
use crate::datasets::{
    DatasetFormat, ReadOptions, StereoDataset, StereoSample, map_member, open_dataset_with,
};
use crate::error::{Error, Result};
use crate::exr_io::encode_disparity_exr;
use crate::image_io::{Image, Samples, encode_png};
use crate::maps::MapKind;

/// The progress of an unfinished export, rewritten after each shard: what a re-run of the same
/// command resumes from.
pub(crate) const PROGRESS_FILE: &str = ".webdataset-progress.json";

/// The dataset card `stereogen export` writes beside the shards (replaced with them by `--force`).
pub const CARD_FILE: &str = "README.md";

#[derive(Debug, Clone, PartialEq)]
pub struct WebDatasetOptions {
    /// A shard is closed once it holds at least this many bytes.
    pub shard_bytes: u64,
    /// Seeds the order of the samples across shards (a farm's shards are ordered by index).
    pub shuffle_seed: u64,
    /// Split names and fractions, in order; the fractions sum to 1.
    pub splits: Vec<(String, f64)>,
    /// Replace an existing export in the output folder.
    pub force: bool,
}

impl Default for WebDatasetOptions {
    fn default() -> Self {
        Self {
            shard_bytes: 1 << 30,
            shuffle_seed: 0,
            splits: vec![("train".into(), 1.0)],
            force: false,
        }
    }
}

/// `train=0.98,val=0.02` as split names and fractions (which must sum to 1).
pub fn parse_splits(s: &str) -> std::result::Result<Vec<(String, f64)>, String> {
    let mut out = Vec::new();
    for part in s.split(',') {
        let (name, frac) = part
            .split_once('=')
            .ok_or_else(|| format!("split {part:?} is not NAME=FRACTION"))?;
        let ok_name =
            !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !ok_name {
            return Err(format!("split name {name:?}: letters, digits and _ only"));
        }
        let frac: f64 = frac
            .parse()
            .ok()
            .filter(|f: &f64| (0.0..=1.0).contains(f))
            .ok_or_else(|| format!("split {name}: fraction {frac:?} is not a number in 0..=1"))?;
        if out.iter().any(|(n, _)| n == name) {
            return Err(format!("split {name} named twice"));
        }
        out.push((name.to_string(), frac));
    }
    let sum: f64 = out.iter().map(|(_, f)| f).sum();
    if (sum - 1.0).abs() > 1e-9 {
        return Err(format!("split fractions sum to {sum}, not 1"));
    }
    Ok(out)
}

/// What an export wrote.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WebDatasetSummary {
    pub samples: usize,
    pub shards: usize,
    pub bytes: u64,
    /// Shards found complete from an interrupted run and kept.
    pub resumed_shards: usize,
}

/// What the progress file records: the plan (a resumed run must make the same one) and the
/// shards finished so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Progress {
    plan: Plan,
    done: Vec<(String, ShardEntry)>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Plan {
    source: PathBuf,
    samples: usize,
    shard_bytes: u64,
    shuffle_seed: u64,
    splits: Vec<(String, f64)>,
    /// The caller's selection (`--where`), when the export takes part of the dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    selection: Option<String>,
}

/// Writes every sample of the dataset at `source` as WebDataset shards in `out` (see the module
/// notes for the layout). Each shard is written under a temporary name, synced and renamed into
/// place; a killed export resumes from its last whole shard when re-run with the same options;
/// an existing export in `out` is refused unless `opts.force`.
pub fn export_webdataset(
    source: &Path,
    out: &Path,
    from: Option<DatasetFormat>,
    read: &ReadOptions,
    opts: &WebDatasetOptions,
) -> Result<WebDatasetSummary> {
    export_webdataset_selected(source, out, from, read, opts, None)
}

/// [`export_webdataset`] of the samples in `selection` only.
pub fn export_webdataset_selected(
    source: &Path,
    out: &Path,
    from: Option<DatasetFormat>,
    read: &ReadOptions,
    opts: &WebDatasetOptions,
    selection: Option<&SampleSelection>,
) -> Result<WebDatasetSummary> {
    if opts.shard_bytes == 0 {
        return Err(Error::format(out, "the shard size must be at least 1 byte"));
    }
    let dataset = open_dataset_with(source, from, read)?;
    let mut order = SampleSelection::positions(selection, dataset.as_ref());
    let plan = Plan {
        source: source.canonicalize().map_err(|e| Error::io(source, e))?,
        samples: order.len(),
        shard_bytes: opts.shard_bytes,
        shuffle_seed: opts.shuffle_seed,
        splits: opts.splits.clone(),
        selection: selection.map(|s| s.description.clone()),
    };
    let done = prepare_output(out, &plan, opts.force)?;
    let manifest = manifest_lines(source, dataset.format())?;

    order.shuffle(&mut ChaCha8Rng::seed_from_u64(opts.shuffle_seed));
    let mut summary = WebDatasetSummary {
        resumed_shards: done.len(),
        ..Default::default()
    };
    let mut progress = Progress { plan, done };
    let mut start = 0;
    for (split, count) in split_counts(&opts.splits, order.len()) {
        let members = &order[start..start + count];
        start += count;
        let mut entries: Vec<ShardEntry> = progress
            .done
            .iter()
            .filter(|(s, _)| *s == split)
            .map(|(_, e)| e.clone())
            .collect();
        let kept: usize = entries.iter().map(|e| e.samples).sum();
        let mut shard: Option<ShardWriter> = None;
        for &k in &members[kept..] {
            let writer = match &mut shard {
                Some(w) => w,
                None => shard.insert(ShardWriter::create(out, &split, entries.len())?),
            };
            let sample = dataset.sample(k)?;
            let name = export_name(dataset.format(), &sample.meta);
            let maps = map_members(dataset.as_ref(), k, &sample)?;
            writer.append(
                &sample_key(&name),
                &sample_members(&sample, maps, &manifest)?,
            )?;
            if writer.bytes >= opts.shard_bytes {
                let entry = shard.take().expect("open").finish()?;
                progress.done.push((split.clone(), entry.clone()));
                write_json(&out.join(PROGRESS_FILE), &progress)?;
                entries.push(entry);
            }
        }
        if let Some(w) = shard {
            entries.push(w.finish()?);
        }
        summary.samples += count;
        summary.shards += entries.len();
        summary.bytes += entries.iter().map(|e| e.bytes).sum::<u64>();
        let index = ShardIndex {
            format: INDEX_FORMAT.into(),
            version: INDEX_VERSION,
            split: split.clone(),
            samples: count,
            shards: entries,
        };
        write_json(&out.join(format!("{split}{INDEX_SUFFIX}")), &index)?;
    }
    let info = DatasetLayout::new(source).info();
    if info.is_file() {
        let bytes = fs::read(&info).map_err(|e| Error::io(&info, e))?;
        write_bytes_atomically(&out.join("dataset.json"), &bytes)?;
    }
    crate::atomic::remove_file_durably(&out.join(PROGRESS_FILE))?;
    Ok(summary)
}

/// How many samples each split gets: its fraction of `n`, rounded, the last taking the rest.
fn split_counts(splits: &[(String, f64)], n: usize) -> Vec<(String, usize)> {
    let mut left = n;
    let mut out = Vec::new();
    for (i, (name, frac)) in splits.iter().enumerate() {
        let count = if i + 1 == splits.len() {
            left
        } else {
            ((frac * n as f64).round() as usize).min(left)
        };
        left -= count;
        out.push((name.clone(), count));
    }
    out
}

/// Checks `out` and returns the shards of an interrupted export of the same plan to keep.
fn prepare_output(out: &Path, plan: &Plan, force: bool) -> Result<Vec<(String, ShardEntry)>> {
    fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    crate::atomic::remove_orphaned_temp_files(out);
    let ours = |name: &str| {
        name.ends_with(".tar")
            || name.ends_with(INDEX_SUFFIX)
            || name == "dataset.json"
            || name == CARD_FILE
            || name == PROGRESS_FILE
    };
    let existing: Vec<PathBuf> = fs::read_dir(out)
        .map_err(|e| Error::io(out, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    if force {
        for p in existing
            .iter()
            .filter(|p| ours(&p.file_name().unwrap_or_default().to_string_lossy()))
        {
            crate::atomic::remove_file_durably(p)?;
        }
        return Ok(vec![]);
    }
    let progress_path = out.join(PROGRESS_FILE);
    if progress_path.is_file() {
        let text = fs::read_to_string(&progress_path).map_err(|e| Error::io(&progress_path, e))?;
        let progress: Progress = serde_json::from_str(&text)
            .map_err(|e| Error::format(&progress_path, format!("unreadable progress file: {e}")))?;
        if progress.plan != *plan {
            return Err(Error::format(
                out,
                "holds an unfinished WebDataset export of another dataset or other options: re-run it with the same ones, or pass --force to start over",
            ));
        }
        for (_, shard) in &progress.done {
            let path = out.join(&shard.name);
            let size = fs::metadata(&path).map(|m| m.len()).ok();
            if size != Some(shard.bytes) {
                return Err(Error::format(
                    &path,
                    format!(
                        "a finished shard of the unfinished export is missing or not {} bytes: pass --force to start over",
                        shard.bytes
                    ),
                ));
            }
        }
        return Ok(progress.done);
    }
    if existing.iter().any(|p| {
        !p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .starts_with('.')
    }) {
        return Err(Error::format(
            out,
            "is not empty: pass --force to replace the WebDataset export in it",
        ));
    }
    Ok(vec![])
}

/// What a sample of our datasets carries besides its images: its manifest line (inside the
/// `.json` member) and its SceneSpec file (member `scene.json` / `scene.json.gz`, bytes as
/// stored), so `stats` and `report` can compute the object-level figures from the shards.
struct OurSample {
    manifest_line: serde_json::Value,
    scene: PathBuf,
}

/// For our datasets, each sample's manifest line and SceneSpec path, by sample id.
fn manifest_lines(source: &Path, format: DatasetFormat) -> Result<HashMap<String, OurSample>> {
    if format != DatasetFormat::Stereogen {
        return Ok(HashMap::new());
    }
    let layout = DatasetLayout::new(source);
    let contents = read_manifest(&layout.manifest())?;
    contents
        .entries
        .iter()
        .map(|e| {
            let manifest_line =
                serde_json::to_value(e).map_err(|err| Error::format(source, err.to_string()))?;
            let scene = layout.abs(&e.files.scene);
            Ok((
                e.id.clone(),
                OurSample {
                    manifest_line,
                    scene,
                },
            ))
        })
        .collect()
}

/// The member name of a SceneSpec file: `scene.` and what follows `.scene.` in its file name
/// (`json` or `json.gz`).
fn scene_member(path: &Path) -> String {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    match name.rsplit_once(".scene.") {
        Some((_, ext)) => format!("scene.{ext}"),
        None if name.ends_with(".gz") => "scene.json.gz".into(),
        None => "scene.json".into(),
    }
}

/// The map members of sample `k` (`depth_left.exr`, ...: [`map_member`]): the source's files
/// byte for byte where it keeps them as files (ours), else encoded from what its reader decodes
/// (a WebDataset export's); none for a sample without maps.
fn map_members(
    dataset: &dyn StereoDataset,
    k: usize,
    s: &StereoSample,
) -> Result<Vec<(String, Vec<u8>)>> {
    if !s.meta.maps.is_empty() {
        let read =
            |p: &Path| crate::limits::read_file_capped(p, crate::limits::MAX_ALLOC, "a map file");
        return s
            .meta
            .maps
            .iter()
            .map(|f| Ok((map_member(f.kind, f.view), read(&f.path)?)))
            .collect();
    }
    let maps = dataset.maps(k)?;
    let mut members = Vec::new();
    for kind in MapKind::ALL {
        for view in VIEWS {
            if let Some(bytes) = maps.view(view).encode(kind, view) {
                let bytes = bytes.map_err(|e| Error::format(&s.meta.left_path, e))?;
                members.push((map_member(kind, view), bytes));
            }
        }
    }
    Ok(members)
}

/// The members of a sample: the source's own files where they already are PNG/JPEG images and
/// EXR disparities (byte for byte), encoded otherwise; its `maps` members; then the sample's
/// facts as JSON.
fn sample_members(
    s: &StereoSample,
    maps: Vec<(String, Vec<u8>)>,
    ours: &HashMap<String, OurSample>,
) -> Result<Vec<(String, Vec<u8>)>> {
    let image =
        |path: &Path, rgb: &crate::image_io::RgbImage, view: &str| -> Result<(String, Vec<u8>)> {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            if path.is_file() && matches!(ext.as_str(), "png" | "jpg" | "jpeg") {
                let bytes = crate::image_io::read_image_file(path)?;
                return Ok((
                    format!("{view}.{}", if ext == "jpeg" { "jpg" } else { &ext }),
                    bytes,
                ));
            }
            let png = encode_png(&Image {
                width: rgb.width,
                height: rgb.height,
                channels: 3,
                samples: Samples::U8(rgb.data.clone()),
            })
            .map_err(|e| Error::format(path, e))?;
            Ok((format!("{view}.png"), png))
        };
    let disparity = |path: Option<&Path>,
                     map: &crate::disparity::DisparityMap|
     -> Result<Vec<u8>> {
        match path {
            Some(p)
                if p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) =>
            {
                fs::read(p).map_err(|e| Error::io(p, e))
            }
            _ => encode_disparity_exr(map, &Default::default())
                .map_err(|e| Error::format(path.unwrap_or(Path::new("")), e.to_string())),
        }
    };
    let m = &s.meta;
    let mut out = vec![
        image(&m.left_path, &s.left, member::LEFT)?,
        image(&m.right_path, &s.right, member::RIGHT)?,
        (
            member::DISP_LEFT.into(),
            disparity(Some(&m.disp_left_path), &s.disp_left)?,
        ),
    ];
    if let Some(right) = &s.disp_right {
        out.push((
            member::DISP_RIGHT.into(),
            disparity(m.disp_right_path.as_deref(), right)?,
        ));
    }
    if let Some(keep) = &s.valid_left {
        let mask = Image {
            width: s.disp_left.width,
            height: s.disp_left.height,
            channels: 1,
            samples: Samples::U8(keep.iter().map(|&k| if k { 255 } else { 0 }).collect()),
        };
        let png = encode_png(&mask).map_err(|e| Error::format(&m.left_path, e))?;
        out.push((member::VALID_LEFT.into(), png));
    }
    out.extend(maps);
    let facts = serde_json::json!({
        "id": m.id,
        "source_format": m.format.map(|f| f.name()),
        "f_px": m.f_px,
        "baseline_m": m.baseline_m,
        "cx": m.cx,
        "cy": m.cy,
        "ndisp": m.ndisp,
        "extra": m.extra,
        "manifest": ours.get(&m.id).map(|o| &o.manifest_line),
    });
    if let Some(o) = ours.get(&m.id) {
        let bytes = crate::limits::read_file_capped(
            &o.scene,
            crate::limits::MAX_DOCUMENT_BYTES,
            "a scene spec",
        )?;
        out.push((scene_member(&o.scene), bytes));
    }
    out.push((
        member::JSON.into(),
        serde_json::to_vec(&facts).expect("JSON of plain values"),
    ));
    Ok(out)
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut text = serde_json::to_vec_pretty(value).expect("JSON of plain values");
    text.push(b'\n');
    write_bytes_atomically(path, &text)
}

/// A shard being written under its temporary name.
struct ShardWriter {
    path: PathBuf,
    tmp: PathBuf,
    /// `None` once finished; dropped unfinished (an error), the temporary file goes too.
    tar: Option<tar::Builder<BufWriter<File>>>,
    samples: usize,
    /// Bytes of the members written so far (headers and padding included).
    bytes: u64,
}

impl ShardWriter {
    fn create(out: &Path, split: &str, n: usize) -> Result<Self> {
        let path = out.join(super::shard_name(split, n));
        let tmp = temp_sibling(&path);
        let file = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        let mut tar = tar::Builder::new(BufWriter::new(file));
        tar.mode(tar::HeaderMode::Deterministic);
        Ok(Self {
            path,
            tmp,
            tar: Some(tar),
            samples: 0,
            bytes: 0,
        })
    }

    fn append(&mut self, key: &str, members: &[(String, Vec<u8>)]) -> Result<()> {
        for (suffix, bytes) in members {
            let mut header = tar::Header::new_gnu();
            header.set_size(bytes.len() as u64);
            header.set_mode(0o644);
            header.set_mtime(0);
            header.set_entry_type(tar::EntryType::Regular);
            let name = format!("{key}.{suffix}");
            self.tar
                .as_mut()
                .expect("open until finished")
                .append_data(&mut header, &name, bytes.as_slice())
                .map_err(|e| Error::io(&self.tmp, e))?;
            // A header block, the data padded to 512-byte blocks (long names add blocks too;
            // the size the index records is the file's, measured when it is finished).
            self.bytes += 512 + (bytes.len() as u64).div_ceil(512) * 512;
        }
        self.samples += 1;
        Ok(())
    }

    /// Ends the archive, syncs it and renames it into place.
    fn finish(mut self) -> Result<ShardEntry> {
        let (path, tmp, samples) = (self.path.clone(), self.tmp.clone(), self.samples);
        let tar = self.tar.take().expect("finished once");
        let written = tar
            .into_inner()
            .and_then(|w| w.into_inner().map_err(|e| e.into_error()));
        let done = written.and_then(|file| {
            file.sync_all()?;
            Ok(file.metadata()?.len())
        });
        let bytes = match done {
            Ok(bytes) => bytes,
            Err(e) => {
                let _ = fs::remove_file(&tmp);
                return Err(Error::io(&path, e));
            }
        };
        place(&tmp, &path)?;
        Ok(ShardEntry {
            name: path
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned(),
            samples,
            bytes,
        })
    }
}

impl Drop for ShardWriter {
    fn drop(&mut self) {
        if self.tar.take().is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_parse_and_are_checked() {
        assert_eq!(
            parse_splits("train=0.98,val=0.02").unwrap(),
            vec![("train".into(), 0.98), ("val".into(), 0.02)]
        );
        for (bad, says) in [
            ("train", "NAME=FRACTION"),
            ("train=0.5", "sum to 0.5"),
            ("a.b=1", "letters, digits"),
            ("train=x", "not a number"),
            ("a=0.5,a=0.5", "named twice"),
        ] {
            let e = parse_splits(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn split_counts_cover_every_sample() {
        let splits = parse_splits("train=0.98,val=0.02").unwrap();
        assert_eq!(
            split_counts(&splits, 1000),
            vec![("train".into(), 980), ("val".into(), 20)]
        );
        assert_eq!(
            split_counts(&splits, 3),
            vec![("train".into(), 3), ("val".into(), 0)]
        );
    }
}
