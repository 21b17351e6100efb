//! What curation does to a manifest, in one place: every writer of a top-level manifest (`curate`
//! itself, `merge` of a farm) passes its entries through [`apply_rounds`], and `generate` counts
//! a replaced sample as done ([`replaced_indices`]), so no later run brings one back.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use anyhow::{Context, bail};
use stereo_io::datasets::stereogen::{CurationRecord, CurationRound, read_sidecar};

use crate::dataset::layout::entry_under;
use crate::dataset::{DatasetLayout, ManifestEntry, read_manifest};

/// Every record of `curation.jsonl` (none when the dataset was never curated).
pub fn read_records(layout: &DatasetLayout) -> anyhow::Result<Vec<CurationRecord>> {
    Ok(read_sidecar::<CurationRecord>(&layout.curation_log())?.records)
}

/// Indices of samples replaced by a finished round: done for good, never rendered again.
pub fn replaced_indices(
    layout: &DatasetLayout,
    rounds: &[CurationRound],
) -> anyhow::Result<BTreeSet<u64>> {
    let finished: BTreeSet<u32> = rounds
        .iter()
        .filter(|r| r.complete)
        .map(|r| r.round)
        .collect();
    if finished.is_empty() {
        return Ok(BTreeSet::new());
    }
    Ok(read_records(layout)?
        .into_iter()
        .filter(|r| finished.contains(&r.round))
        .map(|r| r.index)
        .collect())
}

/// The note a replacement's manifest entry carries.
fn replacement_note(round: &CurationRound, r: &CurationRecord) -> String {
    format!(
        "curation round {}: replaces {} ({} was {:.1})",
        round.round, r.id, round.rule, r.score
    )
}

/// `entries` (a top-level manifest's, any order) with `rounds` applied in order: each round's
/// flagged samples taken out, its replacements (read from the round's folder, paths made
/// relative to the root) put in. Applying a round twice changes nothing. Sorted by index.
pub fn apply_rounds(
    layout: &DatasetLayout,
    entries: Vec<ManifestEntry>,
    rounds: &[CurationRound],
) -> anyhow::Result<Vec<ManifestEntry>> {
    if rounds.is_empty() {
        return Ok(entries);
    }
    let records = read_records(layout)?;
    let mut by_index: BTreeMap<u64, ManifestEntry> =
        entries.into_iter().map(|e| (e.index, e)).collect();
    for round in rounds {
        let mine: Vec<&CurationRecord> =
            records.iter().filter(|r| r.round == round.round).collect();
        let staged = round_entries(layout, &round.dir)?;
        for r in &mine {
            by_index.remove(&r.index);
            let Some(e) = staged.get(&r.replacement_index) else {
                bail!(
                    "curation round {}: the replacement {} of sample {} has not been rendered into {} (is a farm task of the round unfinished?)",
                    round.round,
                    r.replacement_id,
                    r.id,
                    round.dir.display()
                );
            };
            let mut e = e.clone();
            let note = replacement_note(round, r);
            if !e.notes.contains(&note) {
                e.notes.push(note);
            }
            by_index.insert(e.index, e);
        }
    }
    Ok(by_index.into_values().collect())
}

/// A round folder's finished samples by index, their paths relative to the dataset's root: its
/// own manifest, or, for a round rendered by a farm's tasks (`curate --shard K/N`), the
/// manifests of its shard folders.
pub fn round_entries(
    layout: &DatasetLayout,
    dir: &Path,
) -> anyhow::Result<BTreeMap<u64, ManifestEntry>> {
    check_round_dir(layout, dir)?;
    let round = DatasetLayout::new(layout.abs(dir));
    let mut parts = vec![(dir.to_path_buf(), round.manifest())];
    if round.shards_dir().is_dir() {
        for (id, _) in round.shard_dirs()?.shards {
            let rel = dir
                .join(stereo_io::datasets::stereogen::SHARDS_DIR)
                .join(id.dir_name());
            parts.push((rel, round.shard(id).manifest()));
        }
    }
    let mut out = BTreeMap::new();
    for (prefix, path) in parts.into_iter().filter(|(_, p)| p.is_file()) {
        let contents = read_manifest(&path).context("reading a curation round's samples")?;
        out.extend(
            contents
                .entries
                .into_iter()
                .map(|e| (e.index, entry_under(&prefix, e))),
        );
    }
    Ok(out)
}

/// Writes a top-level manifest whole (temp file, fsync, rename), one line per entry.
pub fn write_manifest(layout: &DatasetLayout, entries: &[ManifestEntry]) -> anyhow::Result<()> {
    write_entries(&layout.manifest(), entries)
}

/// Manifest lines into `path`, whole (temp file, fsync, rename).
pub fn write_entries(path: &Path, entries: &[ManifestEntry]) -> anyhow::Result<()> {
    let mut text = String::new();
    for e in entries {
        text.push_str(&serde_json::to_string(e)?);
        text.push('\n');
    }
    stereo_io::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

/// The manifest lines of the samples round `dir` replaced, as they were (paths relative to the
/// root): `<dir>/replaced.jsonl`, for the report's gallery of replaced samples.
pub fn replaced_entries(layout: &DatasetLayout, dir: &Path) -> anyhow::Result<Vec<ManifestEntry>> {
    check_round_dir(layout, dir)?;
    let path = layout.abs(dir).join(REPLACED_FILE);
    if !path.is_file() {
        return Ok(Vec::new());
    }
    Ok(read_manifest(&path)?.entries)
}

/// In a round's folder: the manifest lines of the samples it replaced.
pub const REPLACED_FILE: &str = "replaced.jsonl";

/// A round's folder, as `dataset.json` names it, must lie inside the dataset.
pub fn check_round_dir(layout: &DatasetLayout, dir: &Path) -> anyhow::Result<()> {
    if let Some(problem) = stereo_io::limits::relative_path_buf_problem(dir) {
        bail!(
            "{}: the curation round folder {} {problem}",
            layout.info().display(),
            dir.display()
        );
    }
    Ok(())
}

/// What `audit` says of a dataset's curation: a line per round, and a problem for each replaced
/// sample back in the manifest or replacement missing from it.
pub fn check_curation(
    layout: &DatasetLayout,
    rounds: &[CurationRound],
    entries: &[ManifestEntry],
) -> (Vec<String>, Vec<String>) {
    let (mut lines, mut problems) = (Vec::new(), Vec::new());
    if rounds.is_empty() {
        return (lines, problems);
    }
    let records = match read_records(layout) {
        Ok(r) => r,
        Err(e) => return (lines, vec![format!("curation: {e:#}")]),
    };
    let held: BTreeSet<u64> = entries.iter().map(|e| e.index).collect();
    for round in rounds {
        let mine: Vec<&CurationRecord> =
            records.iter().filter(|r| r.round == round.round).collect();
        if !round.complete {
            lines.push(format!(
                "curation round {}: unfinished ({} sample(s) to replace); re-run its curate command",
                round.round,
                mine.len()
            ));
            continue;
        }
        let before = problems.len();
        for r in &mine {
            if held.contains(&r.index) {
                problems.push(format!(
                    "curation round {}: replaced sample {} is in the manifest again",
                    round.round, r.id
                ));
            }
            if !held.contains(&r.replacement_index) {
                problems.push(format!(
                    "curation round {}: replacement {} (of {}) is not in the manifest",
                    round.round, r.replacement_id, r.id
                ));
            }
        }
        lines.push(format!(
            "curation round {}: {} sample(s) replaced ({}; model {} {}): {}",
            round.round,
            mine.len(),
            round.rule,
            round.model,
            round.model_fingerprint,
            if problems.len() == before {
                "none is in the manifest, every replacement is"
            } else {
                "INCONSISTENT"
            }
        ));
    }
    (lines, problems)
}
