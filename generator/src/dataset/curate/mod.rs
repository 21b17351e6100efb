//! `stereogen curate`: self-curation with a trained model (FoundationStereo's loop for its FSD
//! data). A scores file from `crestereo score` names the samples a network trained on the data
//! still gets wrong; those over a rule ([`FlagRule`], by default Bad-2 > 60%) are listed and,
//! with `replace`, each is replaced by a newly rendered sample, so the dataset keeps its size.
//!
//! A round runs in three durable steps, each of which a re-run finds and continues:
//! 1. **plan**: the flagged samples and their replacements go to `curation.jsonl`, then the round
//!    (not complete) to `dataset.json`;
//! 2. **render**: the replacements are rendered by `generate` into the round's own folder
//!    (`curation/round-NNNN/`, a dataset of its own: resumable, locked, every file verified);
//! 3. **commit**: the top-level manifest is rewritten whole without the flagged samples and with
//!    the replacements ([`apply_rounds`]), then the round is marked complete.
//!
//! A replacement's index is a pure function of (seed, flagged index, round) and the recipe: the
//! first of a fixed sequence of draws above [`REPLACEMENT_BASE`] that falls in the flagged
//! sample's category (the dataset keeps its category mix) and is not yet in the dataset. A
//! curated dataset is therefore re-made from recipe, seed and curation log ([`CurateSource::Log`]).

pub mod apply;
pub mod scores;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use rand::Rng;
use stereo_io::datasets::stereogen::{
    CurationRecord, CurationRound, append_sidecar, curation_round_dir, read_sidecar, retain_sidecar,
};

pub use apply::{apply_rounds, read_records, replaced_indices, round_entries};
pub use scores::{FlagRule, Pixels, Scores, read_scores};

use super::generate::{GenerateOptions, GenerateSummary, Progress, generate};
use super::lock::DatasetLock;
use super::shard::ShardId;
use super::{DatasetInfo, DatasetLayout, ManifestEntry, read_manifest};
use crate::plan::{Recipe, SeedTree, scene_category};
use crate::render::WorkerOptions;

/// Replacement indices lie in `REPLACEMENT_BASE .. REPLACEMENT_BASE + REPLACEMENT_SPAN`: far
/// above any range one dataset renders (2^40, about 1.1 × 10^12), so they never meet a planned
/// sample's index, and their ids (13-16 digits) tell them apart at a glance.
pub const REPLACEMENT_BASE: u64 = 1 << 40;
const REPLACEMENT_SPAN: u64 = 1 << 52;
/// Draws tried for a replacement in the flagged sample's category: a category of weight w is
/// missed by all of them with probability (1 - w)^4096; the recipe checker bounds weights well
/// above what makes that matter.
const REPLACEMENT_DRAWS: u64 = 4096;

/// Where a round's flagged samples come from.
#[derive(Debug, Clone)]
pub enum CurateSource {
    /// A scores file and the rule that flags a sample.
    Scores { path: PathBuf, rule: FlagRule },
    /// Another dataset's `curation.jsonl`: every round it records, replayed in order (the same
    /// samples flagged, the same replacements drawn), to re-make a curated dataset from its
    /// recipe, seed and log.
    Log(PathBuf),
}

#[derive(Debug, Clone)]
pub struct CurateOptions {
    /// The dataset (a plain one, or a farm's merged output).
    pub dataset: PathBuf,
    pub source: CurateSource,
    /// Render replacements; without it the flagged samples are only listed.
    pub replace: bool,
    pub workers: usize,
    pub worker_options: WorkerOptions,
    pub stop: crate::interrupt::StopFlag,
    pub break_lock: bool,
    pub faults: crate::render::FaultPlan,
    /// Render only this shard's part of the round's replacements (`index % N == K`), into the
    /// round's `shards/KKKK-of-NNNN/`, as one task of a farm; a run without it then commits the
    /// round from the shards.
    pub shard: Option<ShardId>,
}

/// One flagged sample.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Flagged {
    pub index: u64,
    pub id: String,
    pub category: String,
    pub score: f64,
}

/// What `curate` found and did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct CurateReport {
    pub rule: String,
    /// Samples of the dataset that the scores cover, and those they do not.
    pub scored: u64,
    pub unscored: u64,
    pub flagged: Vec<Flagged>,
    /// Rounds this run finished (with `replace`): their numbers.
    pub rounds: Vec<u32>,
    /// The last round's rendering, when one ran.
    pub render: Option<GenerateSummary>,
}

/// Lists (and with `replace` replaces) the flagged samples of `opts.dataset`.
pub fn curate(
    opts: &CurateOptions,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<CurateReport> {
    let layout = DatasetLayout::new(&opts.dataset);
    let info: DatasetInfo = layout.read_info()?;
    match &opts.source {
        CurateSource::Scores { path, rule } => {
            let scores = read_scores(path, rule)?;
            let entries = read_manifest(&layout.manifest())?.entries;
            let (flagged, scored) = flag(&entries, &scores, rule, path)?;
            let mut report = CurateReport {
                rule: rule.to_string(),
                scored,
                unscored: entries.len() as u64 - scored,
                flagged: flagged.clone(),
                ..Default::default()
            };
            if !opts.replace {
                return Ok(report);
            }
            let lock = lock_root(&layout, opts)?;
            let plan = RoundPlan {
                rule: rule.to_string(),
                scores: path.display().to_string(),
                scores_sha256: scores.sha256.clone(),
                model: scores.model.clone(),
                model_fingerprint: scores.model_fingerprint.clone(),
                scored,
                flagged,
            };
            let (round, render) = run_round(opts, &layout, info, plan, lock, progress)?;
            report.rounds.extend(round);
            report.render = render;
            Ok(report)
        }
        CurateSource::Log(log) => replay(opts, &layout, info, log, progress),
    }
}

/// The flagged samples of `entries` (manifest order) and how many the scores cover. Every scored
/// id must be a sample of the dataset: scores of another dataset are refused, not half-applied.
fn flag(
    entries: &[ManifestEntry],
    scores: &Scores,
    rule: &FlagRule,
    path: &Path,
) -> anyhow::Result<(Vec<Flagged>, u64)> {
    let ids: BTreeSet<&str> = entries.iter().map(|e| e.id.as_str()).collect();
    if let Some(stranger) = scores.by_id.keys().find(|id| !ids.contains(id.as_str())) {
        bail!(
            "{} scores sample {stranger}, which this dataset does not hold: scores of another dataset (or of one curated since)? Score this dataset again",
            path.display()
        );
    }
    let mut scored = 0;
    let mut flagged = Vec::new();
    for e in entries {
        if let Some(score) = scores.by_id.get(&e.id) {
            scored += 1;
            if let Some(s) = score.filter(|s| rule.flags(*s)) {
                flagged.push(Flagged {
                    index: e.index,
                    id: e.id.clone(),
                    category: e.category.clone(),
                    score: s,
                });
            }
        }
    }
    Ok((flagged, scored))
}

/// What a new round is made of, before anything is written.
struct RoundPlan {
    rule: String,
    scores: String,
    scores_sha256: String,
    model: String,
    model_fingerprint: String,
    scored: u64,
    flagged: Vec<Flagged>,
}

/// The replacement of sample `index` in `round`: see the module's doc. `taken`: indices the
/// dataset holds or has held.
pub fn replacement_index(
    recipe: &Recipe,
    seed: u64,
    index: u64,
    round: u32,
    category: &str,
    taken: &BTreeSet<u64>,
) -> anyhow::Result<u64> {
    let draws = SeedTree::for_sample(seed, index)
        .child("curation")
        .nth(u64::from(round));
    for k in 0..REPLACEMENT_DRAWS {
        let candidate = REPLACEMENT_BASE + draws.nth(k).rng().random_range(0..REPLACEMENT_SPAN);
        if scene_category(recipe, seed, candidate).name == category && !taken.contains(&candidate) {
            return Ok(candidate);
        }
    }
    bail!(
        "no replacement for sample {index} in category {category:?} after {REPLACEMENT_DRAWS} draws: is the category still in the recipe?"
    )
}

/// The dataset's lock. A farm's tasks (`shard`) start together and each plans the round under
/// it for a moment, so they wait their turn (up to [`LOCK_PATIENCE`]) rather than fail.
fn lock_root(layout: &DatasetLayout, opts: &CurateOptions) -> anyhow::Result<DatasetLock> {
    let deadline = Instant::now() + LOCK_PATIENCE;
    loop {
        match DatasetLock::acquire(&layout.lock(), opts.break_lock) {
            Err(e)
                if opts.shard.is_some()
                    && Instant::now() < deadline
                    && e.to_string().contains("is being written by") =>
            {
                std::thread::sleep(Duration::from_millis(250));
            }
            done => return done,
        }
    }
}

/// How long a farm task waits for another task's planning of the round.
const LOCK_PATIENCE: Duration = Duration::from_secs(300);

/// Runs (or resumes) one round. Returns the round's number when it completed, and the render's
/// summary when replacements were rendered.
fn run_round(
    opts: &CurateOptions,
    layout: &DatasetLayout,
    mut info: DatasetInfo,
    plan: RoundPlan,
    lock: DatasetLock,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<(Option<u32>, Option<GenerateSummary>)> {
    let round = match info.curation.last() {
        Some(open) if !open.complete => {
            if open.scores_sha256 != plan.scores_sha256 {
                bail!(
                    "curation round {} of {} is unfinished and was planned from other scores ({}, SHA-256 {}); finish it first: re-run with --scores {}",
                    open.round,
                    layout.root.display(),
                    open.scores,
                    &open.scores_sha256[..12],
                    open.scores
                );
            }
            tracing::info!("resuming curation round {}", open.round);
            open.clone()
        }
        _ => {
            if plan.flagged.is_empty() {
                return Ok((None, None));
            }
            let records = plan_records(layout, &info, &plan.flagged)?;
            start_round(layout, &mut info, records, plan)?
        }
    };
    if let Some(shard) = opts.shard {
        // One farm task: its part of the replacements, in its own folder; no commit.
        drop(lock);
        let summary = render(opts, layout, &info, &round, Some(shard), progress)?;
        return Ok((None, Some(summary)));
    }
    finish_round(opts, layout, info, &round, progress)
}

/// Renders the round's replacements (a shard's part of them) with `generate` into its folder.
fn render(
    opts: &CurateOptions,
    layout: &DatasetLayout,
    info: &DatasetInfo,
    round: &CurationRound,
    shard: Option<ShardId>,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<GenerateSummary> {
    apply::check_round_dir(layout, &round.dir)?;
    let records: Vec<CurationRecord> = read_records(layout)?
        .into_iter()
        .filter(|r| r.round == round.round)
        .collect();
    let staging = DatasetLayout::new(layout.abs(&round.dir));
    // The round's folder is a dataset of the same recipe, seed and assets as the root.
    if !staging.info().exists() {
        std::fs::create_dir_all(&staging.root)
            .with_context(|| format!("cannot create {}", staging.root.display()))?;
        let mut own = info.clone();
        own.curation.clear();
        staging.write_info(&own)?;
    }
    let mut g = GenerateOptions::new(&staging.root, info.recipe.clone(), info.seed, u64::MAX);
    g.only = Some(records.iter().map(|r| r.replacement_index).collect());
    g.shard = shard;
    g.workers = opts.workers;
    g.worker_options = opts.worker_options.clone();
    g.stop = opts.stop.clone();
    g.break_lock = opts.break_lock;
    g.faults = opts.faults.clone();
    generate(&g, progress)
}

/// The records of a new round: each flagged sample with its replacement.
fn plan_records(
    layout: &DatasetLayout,
    info: &DatasetInfo,
    flagged: &[Flagged],
) -> anyhow::Result<Vec<CurationRecord>> {
    let round = info.curation.len() as u32 + 1;
    let mut taken: BTreeSet<u64> = read_manifest(&layout.manifest())?
        .entries
        .iter()
        .map(|e| e.index)
        .collect();
    for r in read_records(layout)?.iter().filter(|r| r.round < round) {
        taken.extend([r.index, r.replacement_index]);
    }
    let mut records = Vec::with_capacity(flagged.len());
    for f in flagged {
        let replacement =
            replacement_index(&info.recipe, info.seed, f.index, round, &f.category, &taken)?;
        taken.insert(replacement);
        records.push(CurationRecord::new(
            round,
            f.index,
            &f.id,
            &f.category,
            f.score,
            replacement,
            crate::plan::sampler::sample_id(replacement),
        ));
    }
    Ok(records)
}

/// Step 1: the round's records, then the round in `dataset.json`. Records of the same round
/// number left by a run killed between the two writes are replaced.
fn start_round(
    layout: &DatasetLayout,
    info: &mut DatasetInfo,
    records: Vec<CurationRecord>,
    plan: RoundPlan,
) -> anyhow::Result<CurationRound> {
    let number = info.curation.len() as u32 + 1;
    // The flagged samples' lines as they are, kept for the record (their files stay too).
    let flagged: BTreeSet<u64> = records.iter().map(|r| r.index).collect();
    let replaced: Vec<ManifestEntry> = read_manifest(&layout.manifest())?
        .entries
        .into_iter()
        .filter(|e| flagged.contains(&e.index))
        .collect();
    let dir = layout.abs(&curation_round_dir(number));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    apply::write_entries(&dir.join(apply::REPLACED_FILE), &replaced)?;
    retain_sidecar(&layout.curation_log(), |r: &CurationRecord| {
        r.round < number
    })?;
    append_sidecar(&layout.curation_log(), &records)?;
    let round = CurationRound {
        round: number,
        rule: plan.rule,
        scores: plan.scores,
        scores_sha256: plan.scores_sha256,
        model: plan.model,
        model_fingerprint: plan.model_fingerprint,
        replaced: records.len() as u64,
        scored: plan.scored,
        dir: curation_round_dir(number),
        complete: false,
    };
    info.curation.push(round.clone());
    layout.write_info(info)?;
    tracing::info!(
        "curation round {number}: {} sample(s) to replace",
        records.len()
    );
    Ok(round)
}

/// Steps 2 and 3 of `round` (see the module's doc).
fn finish_round(
    opts: &CurateOptions,
    layout: &DatasetLayout,
    mut info: DatasetInfo,
    round: &CurationRound,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<(Option<u32>, Option<GenerateSummary>)> {
    // A round its farm tasks rendered (shards in its folder) is committed from their folders.
    let staging = DatasetLayout::new(layout.abs(&round.dir));
    let summary = if staging.shards_dir().is_dir() {
        None
    } else {
        let summary = render(opts, layout, &info, round, None, progress)?;
        if summary.interrupted || !summary.failed.is_empty() {
            return Ok((None, Some(summary)));
        }
        Some(summary)
    };
    // Step 3: the whole manifest again, then the round marked complete.
    // The manifest holds the finished rounds already: this one is applied on top.
    let entries = read_manifest(&layout.manifest())?.entries;
    let entries = apply_rounds(layout, entries, std::slice::from_ref(round))?;
    apply::write_manifest(layout, &entries)?;
    for r in info.curation.iter_mut().filter(|r| r.round == round.round) {
        r.complete = true;
    }
    layout.write_info(&info)?;
    Ok((Some(round.round), summary))
}

/// Replays every round of another dataset's log (see [`CurateSource::Log`]): rounds this dataset
/// finished already are checked against the log, the others run.
fn replay(
    opts: &CurateOptions,
    layout: &DatasetLayout,
    mut info: DatasetInfo,
    log: &Path,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<CurateReport> {
    let theirs = read_sidecar::<CurationRecord>(log)?.records;
    if theirs.is_empty() {
        bail!("{} records no curation round", log.display());
    }
    let _lock = lock_root(layout, opts)?;
    let last = theirs.iter().map(|r| r.round).max().unwrap_or(0);
    let mut report = CurateReport {
        rule: format!("replayed from {}", log.display()),
        ..Default::default()
    };
    for number in 1..=last {
        let wanted: Vec<&CurationRecord> = theirs.iter().filter(|r| r.round == number).collect();
        let done = info.curation.iter().find(|r| r.round == number).cloned();
        let round = match done {
            Some(r) if r.complete => {
                check_replayed(layout, number, &wanted)?;
                continue;
            }
            Some(r) => r,
            None => {
                let flagged: Vec<Flagged> = wanted
                    .iter()
                    .map(|r| Flagged {
                        index: r.index,
                        id: r.id.clone(),
                        category: r.category.clone(),
                        score: r.score,
                    })
                    .collect();
                let records = plan_records(layout, &info, &flagged)?;
                for (mine, theirs) in records.iter().zip(&wanted) {
                    if mine.replacement_index != theirs.replacement_index {
                        bail!(
                            "round {number}: sample {} is replaced here by {} but in {} by {}: this dataset was made with another recipe or seed",
                            mine.id,
                            mine.replacement_id,
                            log.display(),
                            theirs.replacement_id
                        );
                    }
                }
                report.flagged.extend(flagged.iter().cloned());
                let plan = RoundPlan {
                    rule: format!("replay of {} round {number}", log.display()),
                    scores: log.display().to_string(),
                    scores_sha256: String::new(),
                    model: "(replayed)".into(),
                    model_fingerprint: String::new(),
                    scored: 0,
                    flagged,
                };
                start_round(layout, &mut info, records, plan)?
            }
        };
        let (finished, render) = finish_round(opts, layout, info.clone(), &round, progress)?;
        report.render = render;
        match finished {
            Some(n) => report.rounds.push(n),
            None => return Ok(report),
        }
        info = layout.read_info()?;
    }
    Ok(report)
}

/// A round this dataset finished must be the log's round: the same samples, the same replacements.
fn check_replayed(
    layout: &DatasetLayout,
    number: u32,
    wanted: &[&CurationRecord],
) -> anyhow::Result<()> {
    let pairs = |rs: &mut dyn Iterator<Item = &CurationRecord>| -> BTreeSet<(u64, u64)> {
        rs.map(|r| (r.index, r.replacement_index)).collect()
    };
    let mine = read_records(layout)?;
    if pairs(&mut mine.iter().filter(|r| r.round == number)) != pairs(&mut wanted.iter().copied()) {
        bail!(
            "{} finished curation round {number} with other samples than the log's",
            layout.root.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replacement_is_fresh_of_the_flagged_category_and_a_function_of_seed_index_round() {
        let recipe = Recipe::preset("crestereo").unwrap();
        let taken: BTreeSet<u64> = (0..100).collect();
        for index in [0u64, 7, 99] {
            let category = scene_category(&recipe, 5, index).name.clone();
            let a = replacement_index(&recipe, 5, index, 1, &category, &taken).unwrap();
            assert!((REPLACEMENT_BASE..REPLACEMENT_BASE + REPLACEMENT_SPAN).contains(&a));
            assert_eq!(scene_category(&recipe, 5, a).name, category);
            // The same inputs, the same replacement; another round, seed or sample, another.
            assert_eq!(
                replacement_index(&recipe, 5, index, 1, &category, &taken).unwrap(),
                a
            );
            assert_ne!(
                replacement_index(&recipe, 5, index, 2, &category, &taken).unwrap(),
                a
            );
            assert_ne!(
                replacement_index(&recipe, 6, index, 1, &category, &taken).unwrap(),
                a
            );
            // A taken candidate is passed over for the next draw of the same sequence.
            let mut more = taken.clone();
            more.insert(a);
            let b = replacement_index(&recipe, 5, index, 1, &category, &more).unwrap();
            assert_ne!(a, b);
            assert_eq!(scene_category(&recipe, 5, b).name, category);
        }
        let e = replacement_index(&recipe, 5, 3, 1, "no-such-category", &taken).unwrap_err();
        assert!(e.to_string().contains("no replacement"), "{e}");
    }
}
