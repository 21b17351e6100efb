//! `stereogen merge OUT`: one dataset over a farm's shard directories. Checks that every shard
//! was made with the same recipe, seed and stereogen version, that the shards cover the range
//! exactly once and are finished, and that the files are there (and intact), then writes the
//! top-level `dataset.json`, `manifest.jsonl` (paths into the shards) and `merge.json`. Nothing
//! is copied. With any problem nothing is written and each problem is one line of the report.
//!
//! With [`MergeOptions::webdataset`] the merged dataset is then written as WebDataset shards by
//! the same call `export --format webdataset` makes, so a farm run ends in shards after one pass
//! over its sample files (the merge's checks read their sizes and a sample of their checksums;
//! the shard writer reads each file once). A merge with problems writes no shard folder.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::bail;
use rayon::prelude::*;
use stereo_io::DatasetInfo;
use stereo_io::datasets::stereogen::{ChecksumCheck, MergeInfo, ShardDirs, ShardId, ShardInfo};
use stereo_io::digest::sha256_file;

use super::curate::apply::{apply_rounds, write_manifest};
use super::export::{ExportFormat, ExportOptions, ExportSummary, WebDatasetArgs, export};
use super::layout::{DatasetLayout, entry_under};
use super::lock::{LockState, inspect, unix_now};
use super::manifest::{ManifestEntry, read_failures, read_manifest};

/// At most this many files are named one by one; the rest are counted.
const MAX_FILE_PROBLEMS: usize = 20;
/// Without `--verify`: hash at least this many samples, or 1% of them if that is more.
const MIN_HASHED_SAMPLES: usize = 32;

#[derive(Debug, Clone)]
pub struct MergeOptions {
    pub out: PathBuf,
    /// Recompute every file's SHA-256 (otherwise: sizes of all, checksums of a sample).
    pub verify: bool,
    /// After a merge without problems, also write the merged dataset as WebDataset shards.
    pub webdataset: Option<WebDatasetTarget>,
}

/// `merge --webdataset DIR`: where the shards go and how they are cut.
#[derive(Debug, Clone, PartialEq)]
pub struct WebDatasetTarget {
    pub dir: PathBuf,
    pub shards: WebDatasetArgs,
    /// Replace an export already in `dir` (an unfinished one of the same options resumes
    /// without it).
    pub force: bool,
}

impl WebDatasetTarget {
    /// `--webdataset DIR` and the shard options, as a command line gives them.
    pub fn to_args(&self) -> Vec<String> {
        let mut a = vec![
            "--webdataset".to_string(),
            self.dir.to_string_lossy().into_owned(),
        ];
        a.extend(self.shards.to_args());
        if self.force {
            a.push("--force".into());
        }
        a
    }
}

/// Refuses a shard folder that would overwrite the farm's output: OUT itself, or a folder under
/// OUT/shards (which merge reads).
pub fn check_webdataset_dir(out: &Path, dir: &Path) -> anyhow::Result<()> {
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let (out, dir) = (abs(out), abs(dir));
    let shards = out.join(stereo_io::datasets::stereogen::SHARDS_DIR);
    if dir == out || dir.starts_with(&shards) {
        bail!(
            "--webdataset {}: the shards cannot go into the farm's output {} or its shards/; name a folder of their own (e.g. {})",
            dir.display(),
            out.display(),
            out.join("webdataset").display()
        );
    }
    Ok(())
}

/// What merge found; `problems` empty means it wrote the merged dataset.
#[derive(Debug, Clone, Default)]
pub struct MergeReport {
    pub problems: Vec<String>,
    /// Things worth knowing that do not stop the merge.
    pub notes: Vec<String>,
    pub shards: u64,
    pub samples: u64,
    pub files_checked: u64,
    pub files_hashed: u64,
    /// What `--webdataset` wrote.
    pub webdataset: Option<stereo_io::WebDatasetSummary>,
}

/// One shard directory as read for the merge.
struct Shard {
    id: ShardId,
    layout: DatasetLayout,
    /// `shards/KKKK-of-NNNN`, how problems name it.
    name: String,
    info: Option<DatasetInfo>,
    range: Option<ShardInfo>,
    entries: Vec<ManifestEntry>,
}

/// Reads every shard, checks everything, and writes the merge if nothing is wrong.
pub fn merge(opts: &MergeOptions) -> anyhow::Result<MergeReport> {
    if let Some(t) = &opts.webdataset {
        check_webdataset_dir(&opts.out, &t.dir)?;
    }
    let out = DatasetLayout::new(&opts.out);
    let ShardDirs {
        shards: found,
        others,
    } = out.shard_dirs()?;
    if found.is_empty() {
        bail!(
            "{}: no shard directories (KKKK-of-NNNN) under {}",
            opts.out.display(),
            out.shards_dir().display()
        );
    }
    let mut report = MergeReport::default();
    for o in others {
        report.notes.push(format!(
            "{} is not a shard directory (KKKK-of-NNNN); ignored",
            o.display()
        ));
    }
    let count = farm_size(&found, &mut report);
    let shards: Vec<Shard> = found
        .into_iter()
        .filter(|(id, _)| id.count == count)
        .map(|(id, layout)| load_shard(id, layout, &mut report))
        .collect();
    report.shards = count;
    report_missing_shards(&shards, count, &mut report);
    let reference = check_provenance(&shards, &mut report);
    let range = check_ranges(&shards, &mut report);
    if let Some((start, n)) = range {
        check_coverage(&shards, start, n, &mut report);
    }
    check_files(&shards, opts.verify, &mut report);
    report.samples = shards.iter().map(|s| s.entries.len() as u64).sum();
    if !report.problems.is_empty() {
        return Ok(report);
    }
    let (Some(mut info), Some((start, n))) = (reference, range) else {
        unreachable!("no problem means a reference shard and a range")
    };
    // A merge after `curate` keeps its rounds: the shards hold what the farm rendered, the
    // rounds what curation replaced since.
    if out.info().is_file() {
        info.curation = out.read_info::<serde_json::Value>()?.curation;
    }
    write_merge(
        &out,
        &shards,
        &info,
        start,
        n,
        opts.verify,
        report.files_hashed,
    )?;
    if let Some(t) = &opts.webdataset {
        report.webdataset = Some(write_shards(&opts.out, t)?);
    }
    Ok(report)
}

/// The merged dataset in `out` as WebDataset shards: `export --format webdataset`'s own call.
fn write_shards(
    out: &Path,
    target: &WebDatasetTarget,
) -> anyhow::Result<stereo_io::WebDatasetSummary> {
    let opts = ExportOptions {
        dataset: out.to_path_buf(),
        from: Some(stereo_io::DatasetFormat::Stereogen),
        format: ExportFormat::WebDataset,
        out: target.dir.clone(),
        jpeg_quality: None,
        jpeg_chroma: stereo_io::ChromaSampling::Full,
        middlebury_variant: stereo_io::ReadOptions::default().middlebury_variant,
        shards: target.shards.options(target.force),
        selection: target.shards.selection.clone(),
    };
    match export(&opts) {
        Ok(ExportSummary::Shards(s)) => Ok(s),
        Ok(ExportSummary::Layout { .. }) => unreachable!("a WebDataset export writes shards"),
        Err(e) => Err(e.context(format!(
            "merged {}, but did not write its WebDataset shards into {}",
            out.display(),
            target.dir.display()
        ))),
    }
}

/// The number of shards: what most directories say (the largest on a tie); the others are problems.
/// The shards of a farm of `count` that have no directory: the first few by name, then how many
/// more. The count comes from directory names (`0000-of-99999999999` is one), so the report is
/// bounded, never one line per shard.
fn report_missing_shards(shards: &[Shard], count: u64, report: &mut MergeReport) {
    const LISTED: usize = 20;
    let present: BTreeSet<u64> = shards.iter().map(|s| s.id.index).collect();
    let missing = count - present.len() as u64;
    let first: Vec<u64> = (0..count)
        .filter(|k| !present.contains(k))
        .take(LISTED)
        .collect();
    for &k in &first {
        report.problems.push(format!(
            "shards/{} is missing: none of its samples were rendered",
            ShardId { index: k, count }.dir_name()
        ));
    }
    if missing > first.len() as u64 {
        report.problems.push(format!(
            "{} more of the {count} shards are missing",
            missing - first.len() as u64
        ));
    }
}

fn farm_size(found: &[(ShardId, DatasetLayout)], report: &mut MergeReport) -> u64 {
    let mut votes: BTreeMap<u64, usize> = BTreeMap::new();
    for (id, _) in found {
        *votes.entry(id.count).or_default() += 1;
    }
    let count = votes
        .iter()
        .max_by_key(|(n, v)| (**v, **n))
        .map(|(n, _)| *n)
        .expect("at least one shard");
    for (id, _) in found.iter().filter(|(id, _)| id.count != count) {
        report.problems.push(format!(
            "shards/{} belongs to a farm of {} shards, the others to {count}",
            id.dir_name(),
            id.count
        ));
    }
    count
}

fn load_shard(id: ShardId, layout: DatasetLayout, report: &mut MergeReport) -> Shard {
    let name = format!("shards/{}", id.dir_name());
    let mut problem = |p: String| report.problems.push(p);
    let info = layout
        .read_info()
        .map_err(|e| problem(format!("{name}: {e}")))
        .ok();
    let range = match layout.read_shard_info() {
        Ok(r) if r.shard != id => {
            problem(format!(
                "{name}/shard.json says shard {}, its directory {id}",
                r.shard
            ));
            None
        }
        Ok(r) => Some(r),
        Err(e) => {
            problem(format!("{name}: {e}"));
            None
        }
    };
    match inspect(&layout.lock()) {
        LockState::Free => {}
        LockState::Held {
            holder,
            heartbeat_age,
        } => problem(format!(
            "{name} is still locked: being written by {} (heartbeat {} s ago); wait for it to finish",
            holder.describe(),
            heartbeat_age.as_secs()
        )),
        LockState::Stale { holder, why } => problem(format!(
            "{name} is still locked by a run that was killed ({}{why}); re-run its task to finish it",
            holder
                .map(|h| format!("{}: ", h.describe()))
                .unwrap_or_default()
        )),
        LockState::LegacyHeld => problem(format!(
            "{name} is still locked by an older stereogen process"
        )),
    }
    let entries = match read_manifest(&layout.manifest()) {
        Ok(c) => {
            if c.has_unfinished_line() {
                problem(format!(
                    "{name}/manifest.jsonl ends in an unfinished line ({} bytes): its run is writing or was killed",
                    c.unfinished_bytes
                ));
            }
            c.entries
        }
        Err(e) => {
            problem(format!("{name}: {e}"));
            Vec::new()
        }
    };
    Shard {
        id,
        layout,
        name,
        info,
        range,
        entries,
    }
}

/// Same recipe fingerprint, seed and stereogen version everywhere; returns the reference
/// (the lowest shard's) description.
fn check_provenance(shards: &[Shard], report: &mut MergeReport) -> Option<DatasetInfo> {
    let (first, info) = shards
        .iter()
        .find_map(|s| s.info.as_ref().map(|i| (s, i)))?;
    let recipe_name = |i: &DatasetInfo| {
        i.recipe
            .get("name")
            .and_then(|n| n.as_str())
            .unwrap_or("?")
            .to_string()
    };
    for s in shards.iter().filter(|s| s.id != first.id) {
        let Some(other) = &s.info else { continue };
        if other.recipe_fingerprint != info.recipe_fingerprint {
            report.problems.push(format!(
                "{} was made with another recipe: fingerprint {} (recipe {:?}), {} with {} (recipe {:?})",
                s.name,
                other.recipe_fingerprint,
                recipe_name(other),
                first.name,
                info.recipe_fingerprint,
                recipe_name(info)
            ));
        }
        if other.seed != info.seed {
            report.problems.push(format!(
                "{} was made with seed {}, {} with seed {}",
                s.name, other.seed, first.name, info.seed
            ));
        }
        if other.stereogen_version != info.stereogen_version {
            report.problems.push(format!(
                "{} was made by stereogen {}, {} by {}",
                s.name, other.stereogen_version, first.name, info.stereogen_version
            ));
        }
    }
    Some(info.clone())
}

/// The range all shards were asked for; shards that disagree are problems.
fn check_ranges(shards: &[Shard], report: &mut MergeReport) -> Option<(u64, u64)> {
    let (first, r) = shards.iter().find_map(|s| s.range.map(|r| (s, r)))?;
    for s in shards.iter() {
        if let Some(o) = s.range
            && (o.start, o.count) != (r.start, r.count)
        {
            report.problems.push(format!(
                "{} was last run for samples {}..{}, {} for {}..{}; re-run every task with the same --start/--count",
                s.name,
                o.start,
                o.start + o.count,
                first.name,
                r.start,
                r.start + r.count
            ));
        }
    }
    Some((r.start, r.count))
}

/// Every index of `start..start + count` exactly once, each in its own shard.
fn check_coverage(shards: &[Shard], start: u64, count: u64, report: &mut MergeReport) {
    let mut seen: BTreeMap<u64, Vec<&str>> = BTreeMap::new();
    for s in shards {
        for e in &s.entries {
            if !(start..start + count).contains(&e.index) {
                report.problems.push(format!(
                    "{} holds index {} outside the range {start}..{}",
                    s.name,
                    e.index,
                    start + count
                ));
            } else if !s.id.owns(e.index) {
                report.problems.push(format!(
                    "{} holds index {}, which belongs to shard {}",
                    s.name,
                    e.index,
                    ShardId {
                        index: e.index % s.id.count,
                        count: s.id.count
                    }
                    .dir_name()
                ));
            }
            seen.entry(e.index).or_default().push(&s.name);
        }
    }
    for (index, holders) in seen.iter().filter(|(_, h)| h.len() > 1) {
        report.problems.push(format!(
            "index {index} is duplicated: {} entries ({})",
            holders.len(),
            holders.join(", ")
        ));
    }
    let missing: Vec<u64> = (start..start + count)
        .filter(|i| !seen.contains_key(i))
        .collect();
    if !missing.is_empty() {
        report.problems.push(format!(
            "{} of {count} indices are missing: {}",
            missing.len(),
            compact_ranges(&missing)
        ));
    }
    for s in shards {
        let failed = match failed_indices(&s.layout) {
            Ok(failed) => failed,
            Err(e) => {
                report.problems.push(format!("{}: {e}", s.name));
                continue;
            }
        };
        let still: Vec<u64> = failed
            .into_iter()
            .filter(|i| !seen.contains_key(i))
            .collect();
        if !still.is_empty() {
            report.problems.push(format!(
                "{}: {} sample(s) failed ({}), listed in {}/failures.jsonl",
                s.name,
                still.len(),
                compact_ranges(&still),
                s.name
            ));
        }
    }
}

/// Indices listed in a shard's `failures.jsonl`, sorted, each once.
fn failed_indices(layout: &DatasetLayout) -> stereo_io::Result<Vec<u64>> {
    let mut v: Vec<u64> = read_failures(&layout.failures())?
        .records
        .iter()
        .map(|r| r.index)
        .collect();
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

/// `0-3, 7, 9-12` (the first 40 runs, then how many more).
pub fn compact_ranges(sorted: &[u64]) -> String {
    let mut runs: Vec<(u64, u64)> = Vec::new();
    for &i in sorted {
        match runs.last_mut() {
            Some((_, hi)) if *hi + 1 == i => *hi = i,
            _ => runs.push((i, i)),
        }
    }
    let mut s = String::new();
    for (n, (lo, hi)) in runs.iter().enumerate() {
        if n == 40 {
            let _ = write!(s, ", … ({} more runs)", runs.len() - 40);
            break;
        }
        let sep = if n > 0 { ", " } else { "" };
        let _ = if lo == hi {
            write!(s, "{sep}{lo}")
        } else {
            write!(s, "{sep}{lo}-{hi}")
        };
    }
    s
}

/// Every file present and non-empty; checksums of all (`verify`) or of a spread sample.
fn check_files(shards: &[Shard], verify: bool, report: &mut MergeReport) {
    let total: usize = shards.iter().map(|s| s.entries.len()).sum();
    let every = if verify {
        1
    } else {
        (total / MIN_HASHED_SAMPLES.max(total / 100)).max(1)
    };
    let jobs: Vec<(&Shard, &ManifestEntry, bool)> = shards
        .iter()
        .flat_map(|s| s.entries.iter().map(move |e| (s, e)))
        .enumerate()
        .map(|(n, (s, e))| (s, e, n % every == 0))
        .collect();
    let results: Vec<(Vec<String>, u64, u64)> = jobs
        .par_iter()
        .map(|(s, e, hash)| check_sample(s, e, *hash))
        .collect();
    let mut problems = Vec::new();
    for (p, checked, hashed) in results {
        problems.extend(p);
        report.files_checked += checked;
        report.files_hashed += hashed;
    }
    let extra = problems.len().saturating_sub(MAX_FILE_PROBLEMS);
    report
        .problems
        .extend(problems.into_iter().take(MAX_FILE_PROBLEMS));
    if extra > 0 {
        report
            .problems
            .push(format!("… and {extra} more file problems"));
    }
}

fn check_sample(s: &Shard, e: &ManifestEntry, hash: bool) -> (Vec<String>, u64, u64) {
    let mut problems = Vec::new();
    let (mut checked, mut hashed) = (0, 0);
    for (key, rel) in e.files.all() {
        let path = s.layout.abs(rel);
        let shown = format!("{}/{}", s.name, rel.display());
        checked += 1;
        match std::fs::metadata(&path) {
            Err(_) => problems.push(format!(
                "{shown} is missing (sample {} of {})",
                e.index, s.name
            )),
            Ok(m) if m.len() == 0 => {
                problems.push(format!("{shown} is empty (sample {})", e.index))
            }
            Ok(_) if hash => {
                let Some(expected) = e.sha256.get(key) else {
                    continue;
                };
                hashed += 1;
                match sha256_file(&path) {
                    Ok(h) if &h == expected => {}
                    Ok(_) => problems.push(format!("{shown}: SHA-256 differs from the manifest's (changed or damaged since it was written)")),
                    Err(err) => problems.push(format!("{shown}: cannot read: {err}")),
                }
            }
            Ok(_) => {}
        }
    }
    (problems, checked, hashed)
}

/// The top-level files: `dataset.json` (the shards' own), `merge.json`, then `manifest.jsonl`
/// (by index, paths prefixed with the shard directory).
fn write_merge(
    out: &DatasetLayout,
    shards: &[Shard],
    info: &DatasetInfo,
    start: u64,
    count: u64,
    verify: bool,
    files_hashed: u64,
) -> anyhow::Result<()> {
    out.write_info(info)?;
    // merge.json before the manifest: it marks OUT as a farm's output (see generate's checks).
    let checksums = if verify {
        ChecksumCheck::All
    } else {
        ChecksumCheck::Sampled
    };
    out.write_merge_info(&MergeInfo {
        shards: shards.len() as u64,
        start,
        count,
        checksums,
        files_hashed,
        merged_unix_s: unix_now(),
    })?;
    let mut entries: Vec<ManifestEntry> =
        Vec::with_capacity(shards.iter().map(|s| s.entries.len()).sum());
    for s in shards {
        let prefix = Path::new(stereo_io::datasets::stereogen::SHARDS_DIR).join(s.id.dir_name());
        entries.extend(s.entries.iter().cloned().map(|e| entry_under(&prefix, e)));
    }
    entries.sort_by_key(|e| e.index);
    let finished: Vec<_> = info
        .curation
        .iter()
        .filter(|r| r.complete)
        .cloned()
        .collect();
    let entries = apply_rounds(out, entries, &finished)?;
    write_manifest(out, &entries)
}

#[cfg(test)]
mod tests {
    use super::compact_ranges;

    #[test]
    fn ranges_are_compact() {
        assert_eq!(compact_ranges(&[0, 1, 2, 3, 7, 9, 10]), "0-3, 7, 9-10");
        assert_eq!(compact_ranges(&[]), "");
    }
}
