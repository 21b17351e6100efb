//! The stats pass over a dataset (our folder layout or a WebDataset export of it, see
//! [`crate::validate::dataset_files`]), in four steps: [`load`] the recipe and manifest, the
//! [`objects`] pass over every SceneSpec (object-level sample), the [`pixels`] pass that streams
//! every disparity EXR through the accumulators in parallel, and [`compute`]'s assembly into a
//! [`StatsReport`] ([`stats_report`]: what `stats.json` holds and each group's OK/FAIL/SKIP;
//! [`ks_family`]: the KS tests as one family with a stated false-alarm rate). A dataset with maps
//! beside the disparity also gets their summary ([`maps`]).

pub mod difficulty;
pub mod files;
pub mod ks_family;
pub mod load;
pub mod maps;
pub mod objects;
pub mod pixels;
pub mod stats_report;
pub mod summary;

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use self::ks_family::holm_levels;
use self::stats_report::MIN_OBJECTS_TO_JUDGE;
use self::stats_report::{CategoryStats, ObjectStats, PixelStats, StatsReport, Status};
use super::accumulate::PixelAcc;
use super::hist::{MAX_GAP_BINS, equal_mass_edges, gap_bins_for};
use crate::plan::Dist;
pub use summary::summary_lines;

/// Default number of bins of the pixel-level histogram over the law's support (stats.json, plots).
pub const DEFAULT_BINS: usize = 64;

#[derive(Debug, Clone)]
pub struct StatsOptions {
    pub dataset: PathBuf,
    /// The family-wise false-alarm rate of the KS tests, and the significance of each gap
    /// check's bin-count rule.
    pub ks_alpha: f64,
    /// Bins of the pixel-level histogram over the law's support; [`DEFAULT_BINS`] when unset.
    pub bins: Option<usize>,
    /// Gap-check bins for every category; chosen from the object count when unset.
    pub gap_bins: Option<usize>,
    /// Also read every file of every sample, check its SHA-256 against the manifest and decode
    /// the images fully (`--verify`); a mismatch is an error of the report.
    pub verify: bool,
}

impl StatsOptions {
    pub fn new(dataset: impl Into<PathBuf>) -> Self {
        Self {
            dataset: dataset.into(),
            ks_alpha: 0.01,
            bins: None,
            gap_bins: None,
            verify: false,
        }
    }

    fn check(&self) -> anyhow::Result<()> {
        if !(self.ks_alpha > 0.0 && self.ks_alpha < 1.0) {
            bail!("--ks-alpha must lie in (0, 1), got {}", self.ks_alpha);
        }
        if let Some(k) = self.gap_bins
            && !(1..=1024).contains(&k)
        {
            bail!("--gap-bins must lie in 1..=1024, got {k}");
        }
        Ok(())
    }

    /// Gap-check edges for a group of `n` objects: equal-mass bins of the law, as many as the
    /// object count supports (or `--gap-bins`).
    fn gap_edges(&self, law: &Dist, n: usize) -> Option<Vec<f64>> {
        let (lo, hi) = law.support();
        let k = self
            .gap_bins
            .unwrap_or_else(|| gap_bins_for(n, self.ks_alpha));
        (k > 0 && n > 0 && hi > lo).then(|| equal_mass_edges(law, k))
    }

    fn gap_rule(&self) -> String {
        match self.gap_bins {
            Some(k) => format!("{k} equal-mass bins of the law (--gap-bins)"),
            None => format!(
                "largest k <= {MAX_GAP_BINS} with k*(1-1/k)^n <= {} for n objects; equal-mass bins of the law",
                self.ks_alpha
            ),
        }
    }
}

/// Computes the statistics of the dataset at `opts.dataset`.
pub fn compute(opts: &StatsOptions) -> anyhow::Result<StatsReport> {
    opts.check()?;
    let root = &opts.dataset;
    let loaded = load::load(root)?;
    let law = loaded.info.recipe.placement.disparity_px.clone();
    // An export without SceneSpecs: the object pass is not run, and the report says so.
    let notes: Vec<String> = loaded
        .files
        .no_scenes_note(&loaded.entries)
        .into_iter()
        .collect();
    let mut objects = if notes.is_empty() {
        objects::object_pass(&loaded)
    } else {
        objects::ObjectPass::empty(loaded.categories.len())
    };

    let gap_edges: Vec<Option<Vec<f64>>> = objects
        .targets
        .iter()
        .map(|t| opts.gap_edges(&law, t.len()))
        .collect();
    let all_edges = opts.gap_edges(&law, objects.targets.iter().map(Vec::len).sum());
    let binning = pixels::binning(&loaded, &law, opts.bins.unwrap_or(DEFAULT_BINS));
    let pixels = pixels::pixel_pass(&loaded, opts, |c| {
        PixelAcc::new(&binning, gap_edges[c].as_deref(), all_edges.as_deref())
    });

    let (maps, map_errors) = match maps::map_pass(&loaded, opts) {
        Some((stats, errors)) => (Some(stats), errors),
        None => (None, Vec::new()),
    };
    let mut errors: Vec<String> = objects
        .errors
        .iter()
        .chain(&pixels.errors)
        .chain(&map_errors)
        .map(ToString::to_string)
        .collect();
    errors.sort();
    let all_targets = objects.targets.concat();
    let mut samples = vec![0u64; loaded.categories.len()];
    for e in &loaded.entries {
        samples[loaded.category_of(e)] += 1;
    }
    let groups = assemble(
        &loaded.categories,
        &samples,
        &mut objects.targets,
        all_targets,
        &pixels.accs,
        &law,
        opts.ks_alpha,
    );
    let (categories, overall) = groups;
    // An empty dataset proves nothing: it does not pass.
    let pass = !loaded.entries.is_empty()
        && errors.is_empty()
        && categories
            .iter()
            .chain([&overall])
            .all(|c| c.status != Status::Fail);
    Ok(StatsReport {
        dataset: root.display().to_string(),
        recipe: loaded.info.recipe.name.clone(),
        law_support: [law.support().0, law.support().1],
        samples: loaded.entries.len(),
        ks_alpha: opts.ks_alpha,
        min_objects_to_judge: MIN_OBJECTS_TO_JUDGE,
        pixel_range: [0.0, binning.hi],
        gap_rule: opts.gap_rule(),
        categories,
        overall,
        errors,
        notes,
        curation: loaded.info.curation.clone(),
        difficulty: difficulty::difficulty_stats(&loaded.entries),
        maps,
        pass,
        law,
    })
}

/// Each category's stats and the overall group's: object statistics, the KS family's levels,
/// pixel statistics, and each group's decision.
fn assemble(
    names: &[String],
    samples: &[u64],
    targets: &mut [Vec<f64>],
    mut all_targets: Vec<f64>,
    accs: &[Option<PixelAcc>],
    law: &Dist,
    alpha: f64,
) -> (Vec<CategoryStats>, CategoryStats) {
    let mut objects: Vec<ObjectStats> = targets
        .iter_mut()
        .map(|t| ObjectStats::new(t, law))
        .collect();
    let mut overall_objects = ObjectStats::new(&mut all_targets, law);
    let mut family: Vec<&mut ObjectStats> = objects.iter_mut().collect();
    family.push(&mut overall_objects);
    holm_levels(&mut family, alpha);

    let mut total: Option<PixelAcc> = None;
    for a in accs.iter().flatten() {
        match &mut total {
            Some(t) => t.merge(a),
            None => total = Some(a.clone()),
        }
    }
    let categories = objects
        .into_iter()
        .enumerate()
        .map(|(c, obj)| {
            let pixels = accs[c].as_ref().map(|a| PixelStats::new(a, a.gap.as_ref()));
            CategoryStats::new(&names[c], samples[c], obj, pixels)
        })
        .collect();
    let overall_pixels = total
        .as_ref()
        .map(|a| PixelStats::new(a, a.gap_all.as_ref()));
    let overall = CategoryStats::new("all", samples.iter().sum(), overall_objects, overall_pixels);
    (categories, overall)
}

/// Writes `stats.json` into `dir` atomically and returns its path.
pub fn write_json(report: &StatsReport, dir: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("stats.json");
    let json = serde_json::to_string_pretty(report)?;
    stereo_io::write_bytes_atomically(&path, json.as_bytes())?;
    Ok(path)
}
