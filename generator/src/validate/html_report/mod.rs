//! `stereogen report DATASET`: one self-contained HTML page about a dataset — recipe and
//! fingerprint, samples per category, failures and skipped assets, render times, the disparity
//! distribution against the recipe's law (as `stats` computes it), row/column coverage, the
//! audit's results when `audit.json` exists, a gallery, the samples that stand out, and the
//! rounds of curation with the samples they replaced. A dataset with maps beside the disparity
//! also gets their summary, its semantic class table and a row of map thumbnails per gallery
//! tile ([`maps`]).
//!
//! It reads our folder layout or a WebDataset export of it (`export --format webdataset`), whose
//! members it reads straight from the shards ([`super::dataset_files`]).
//!
//! Self-contained: the charts are inline SVG, the pictures data: URIs, the style inline; no
//! script, no network. Fast and small on large datasets: the statistics stream over the maps
//! (`stats`), the manifest is read once, and only the gallery and outlier samples' files are
//! opened for pictures — at most [`MAX_THUMBNAILS`] + [`MAX_OUTLIERS`] samples, each three
//! thumbnails at most [`gallery::THUMB_WIDTH`] px wide; lists stop at [`facts::MAX_LISTED`]
//! lines. The page states these caps.

pub mod chart;
pub mod curation;
pub mod facts;
pub mod gallery;
pub mod maps;
pub mod sections;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use askama::Template;

use self::facts::Facts;
use self::gallery::Tile;
use self::sections::{AuditSection, StatsSection};
use super::audit::{AUDIT_FILE, read_json};
use super::stats::{StatsOptions, compute};

/// Gallery samples, at most.
pub const MAX_THUMBNAILS: usize = 200;
/// Samples listed as standing out, at most.
pub const MAX_OUTLIERS: usize = 12;
/// Gallery samples by default.
pub const DEFAULT_THUMBNAILS: usize = 12;

#[derive(Debug, Clone)]
pub struct ReportOptions {
    pub dataset: PathBuf,
    pub out: PathBuf,
    pub thumbnails: usize,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct ReportSummary {
    pub path: PathBuf,
    pub bytes: u64,
    pub seconds: f64,
    pub samples: usize,
    pub gallery: usize,
    pub outliers: usize,
    pub problems: usize,
}

#[derive(Template)]
#[template(path = "report.html")]
struct Page {
    title: String,
    dataset: String,
    version: String,
    recipe_name: String,
    fingerprint: String,
    seed: String,
    recipe_toml: String,
    problems: Vec<String>,
    counts: Vec<(String, usize, String)>,
    total: usize,
    failures: Vec<(String, String)>,
    failures_total: usize,
    skipped: Vec<(String, String)>,
    skipped_total: usize,
    timing: Vec<(String, String)>,
    stats: Option<StatsSection>,
    maps: Option<maps::MapsSection>,
    audit: Option<AuditSection>,
    gallery: Vec<Tile>,
    outliers: Vec<Tile>,
    curation: Vec<curation::CurationRow>,
    replaced: Vec<Tile>,
    caps: String,
}

fn describe(facts: &Facts, page: &mut Page) {
    if let Some(info) = &facts.info {
        page.recipe_name = info.recipe.name.clone();
        page.fingerprint = info.recipe_fingerprint.clone();
        page.seed = info.seed.to_string();
        page.version = info.stereogen_version.clone();
        page.recipe_toml = toml::to_string(&info.recipe)
            .unwrap_or_else(|e| format!("(the recipe cannot be shown as TOML: {e})"));
    }
    let counts = facts::counts(facts);
    page.total = facts.entries.len();
    page.counts = counts
        .into_iter()
        .map(|(n, c)| {
            (
                n,
                c,
                format!("{:.1}%", 100.0 * c as f64 / page.total.max(1) as f64),
            )
        })
        .collect();
    page.failures = facts.failures.lines.clone();
    page.failures_total = facts.failures.total;
    page.skipped = facts.skipped.lines.clone();
    page.skipped_total = facts.skipped.total;
    page.timing = facts::render_times(&facts.entries);
}

/// The statistics of `stats`, or why there are none; and the maps' section, where the dataset
/// has maps or a semantic class table.
fn stats(
    dataset: &Path,
    facts: &Facts,
    problems: &mut Vec<String>,
) -> (Option<StatsSection>, Option<maps::MapsSection>) {
    let classes = facts
        .info
        .as_ref()
        .map_or(&[][..], |i| &i.semantic_classes[..]);
    if facts.info.is_none() || facts.entries.is_empty() {
        return (None, maps::section(classes, None));
    }
    match compute(&StatsOptions::new(dataset)) {
        Ok(s) => {
            problems.extend(s.notes.iter().map(|n| format!("statistics: {n}")));
            problems.extend(
                s.errors
                    .iter()
                    .take(facts::MAX_LISTED)
                    .map(|e| format!("statistics: {e}")),
            );
            if s.errors.len() > facts::MAX_LISTED {
                problems.push(format!(
                    "statistics: ... and {} more samples that could not be read",
                    s.errors.len() - facts::MAX_LISTED
                ));
            }
            (
                Some(sections::stats_section(&s)),
                maps::section(classes, s.maps.as_ref()),
            )
        }
        Err(e) => {
            problems.push(format!("statistics: {e:#}"));
            (None, maps::section(classes, None))
        }
    }
}

fn audit(dataset: &Path, problems: &mut Vec<String>) -> Option<AuditSection> {
    let path = dataset.join(AUDIT_FILE);
    if !path.exists() {
        return None;
    }
    match read_json(&path) {
        Ok(a) => Some(sections::audit_section(&a)),
        Err(e) => {
            problems.push(format!("{e:#}"));
            None
        }
    }
}

/// Writes the page; fails only when the dataset directory does not exist or the page cannot be
/// written. Everything else that is wrong is listed on the page.
pub fn write_report(opts: &ReportOptions) -> anyhow::Result<ReportSummary> {
    let started = Instant::now();
    let facts = facts::read(&opts.dataset)?;
    let mut page = Page {
        title: format!("stereogen dataset {}", opts.dataset.display()),
        dataset: opts.dataset.display().to_string(),
        version: "-".into(),
        recipe_name: "-".into(),
        fingerprint: "-".into(),
        seed: "-".into(),
        recipe_toml: String::new(),
        problems: facts.problems.clone(),
        counts: Vec::new(),
        total: 0,
        failures: Vec::new(),
        failures_total: 0,
        skipped: Vec::new(),
        skipped_total: 0,
        timing: Vec::new(),
        stats: None,
        maps: None,
        audit: None,
        gallery: Vec::new(),
        outliers: Vec::new(),
        curation: Vec::new(),
        replaced: Vec::new(),
        caps: String::new(),
    };
    describe(&facts, &mut page);
    let mut problems = Vec::new();
    (page.stats, page.maps) = stats(&opts.dataset, &facts, &mut problems);
    page.audit = audit(&opts.dataset, &mut problems);
    let n = opts.thumbnails.min(MAX_THUMBNAILS);
    if opts.thumbnails > MAX_THUMBNAILS {
        problems.push(format!(
            "--thumbnails {} capped at {MAX_THUMBNAILS}",
            opts.thumbnails
        ));
    }
    let entries = &facts.entries;
    if let Some(files) = &facts.files {
        let chosen = gallery::choose(entries, n);
        page.gallery = rayon_map(&chosen, |&i| {
            gallery::tile(files, &entries[i], format!("index {}", entries[i].index))
        });
        let odd = facts::outliers(entries, MAX_OUTLIERS);
        page.outliers = rayon_map(&odd, |(i, why)| {
            gallery::tile(files, &entries[*i], why.clone())
        });
        if let Some(info) = &facts.info {
            page.curation = curation::rows(&info.curation);
            page.replaced = curation::tiles(files, &info.curation, entries, &mut problems);
        }
    }
    for t in page
        .gallery
        .iter()
        .chain(&page.outliers)
        .chain(&page.replaced)
    {
        problems.extend(t.problems.iter().map(|p| format!("sample {}: {p}", t.id)));
    }
    page.problems.extend(problems);
    page.caps = format!(
        "Size limits: at most {MAX_THUMBNAILS} gallery samples (chosen deterministically: categories in turn, evenly spaced by index), {MAX_OUTLIERS} outliers and {} replaced samples with their replacements, each as three thumbnails at most {} px wide (JPEG quality {}, disparity PNG); lists stop at {} lines; statistics stream over every map.",
        curation::MAX_REPLACED,
        gallery::THUMB_WIDTH,
        gallery::JPEG_QUALITY,
        facts::MAX_LISTED
    );
    let html = page.render().context("cannot render the report template")?;
    if let Some(dir) = opts.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    stereo_io::write_bytes_atomically(&opts.out, html.as_bytes())
        .with_context(|| format!("cannot write {}", opts.out.display()))?;
    Ok(ReportSummary {
        path: opts.out.clone(),
        bytes: html.len() as u64,
        seconds: started.elapsed().as_secs_f64(),
        samples: entries.len(),
        gallery: page.gallery.len(),
        outliers: page.outliers.len(),
        problems: page.problems.len(),
    })
}

fn rayon_map<T: Sync, U: Send>(items: &[T], f: impl Fn(&T) -> U + Sync + Send) -> Vec<U> {
    use rayon::prelude::*;
    items.par_iter().map(f).collect()
}
