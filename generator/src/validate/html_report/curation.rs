//! The report's curation section: the rounds `dataset.json` records, and a gallery of replaced
//! samples, each above the sample that replaced it.

use std::collections::BTreeMap;

use stereo_io::datasets::stereogen::{CurationRecord, CurationRound};

use super::gallery::{Tile, tile};
use crate::dataset::curate::apply::{read_records, replaced_entries};
use crate::dataset::{DatasetLayout, ManifestEntry};
use crate::validate::dataset_files::DatasetFiles;

/// Replaced samples shown, at most (each with its replacement: two tiles).
pub const MAX_REPLACED: usize = 12;

/// One round as a table row.
pub struct CurationRow {
    pub round: u32,
    pub rule: String,
    pub model: String,
    pub scored: u64,
    pub replaced: u64,
    pub state: &'static str,
}

pub fn rows(rounds: &[CurationRound]) -> Vec<CurationRow> {
    rounds
        .iter()
        .map(|r| CurationRow {
            round: r.round,
            rule: r.rule.clone(),
            model: format!("{} ({})", r.model, r.model_fingerprint),
            scored: r.scored,
            replaced: r.replaced,
            state: if r.complete { "complete" } else { "unfinished" },
        })
        .collect()
}

/// Tiles of the first [`MAX_REPLACED`] replaced samples of the finished rounds, each followed by
/// its replacement; what cannot be shown becomes a problem line.
pub fn tiles(
    files: &DatasetFiles,
    rounds: &[CurationRound],
    entries: &[ManifestEntry],
    problems: &mut Vec<String>,
) -> Vec<Tile> {
    let DatasetFiles::Folder(layout) = files else {
        // An export carries the manifest's samples only, not the replaced ones.
        return Vec::new();
    };
    let records = match read_records(layout) {
        Ok(r) => r,
        Err(e) => {
            problems.push(format!("curation: {e:#}"));
            return Vec::new();
        }
    };
    let now: BTreeMap<u64, &ManifestEntry> = entries.iter().map(|e| (e.index, e)).collect();
    let mut pairs = Vec::new();
    for round in rounds.iter().filter(|r| r.complete) {
        let before = before(layout, round, problems);
        for r in records.iter().filter(|r| r.round == round.round) {
            if pairs.len() == MAX_REPLACED {
                break;
            }
            pairs.push((
                round,
                r,
                before.get(&r.index).cloned(),
                now.get(&r.replacement_index),
            ));
        }
    }
    let mut out = Vec::new();
    for (round, r, old, new) in pairs {
        match old {
            Some(e) => out.push(tile(files, &e, flagged_caption(round, r))),
            None => problems.push(format!(
                "curation round {}: no record of replaced sample {}",
                round.round, r.id
            )),
        }
        match new {
            Some(e) => out.push(tile(
                files,
                e,
                format!("round {}: the replacement of {}", round.round, r.id),
            )),
            None => problems.push(format!(
                "curation round {}: the replacement {} of {} is not in the manifest",
                round.round, r.replacement_id, r.id
            )),
        }
    }
    out
}

/// The replaced samples' manifest lines of one round, by index.
fn before(
    layout: &DatasetLayout,
    round: &CurationRound,
    problems: &mut Vec<String>,
) -> BTreeMap<u64, ManifestEntry> {
    match replaced_entries(layout, &round.dir) {
        Ok(v) => v.into_iter().map(|e| (e.index, e)).collect(),
        Err(e) => {
            problems.push(format!("curation round {}: {e:#}", round.round));
            BTreeMap::new()
        }
    }
}

fn flagged_caption(round: &CurationRound, r: &CurationRecord) -> String {
    format!(
        "round {}: replaced ({} was {:.1}) by {}",
        round.round, round.rule, r.score, r.replacement_id
    )
}
