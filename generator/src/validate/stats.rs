//! The stats pass over a dataset: read the recipe, the manifest and every SceneSpec (object-level
//! sample), then stream every disparity EXR through the accumulators in parallel.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use rayon::prelude::*;

use super::accumulate::{Binning, PixelAcc};
use super::hist::{MAX_GAP_BINS, equal_mass_edges, gap_bins_for};
use super::report::{CategoryStats, ObjectStats, PixelStats, StatsReport, Status};
use crate::dataset::{DatasetInfo, DatasetLayout, ManifestEntry, read_manifest};
use crate::plan::Dist;

/// Default number of bins of the pixel-level histogram over the law's support (stats.json, plots).
pub const DEFAULT_BINS: usize = 64;

#[derive(Debug, Clone)]
pub struct StatsOptions {
    pub dataset: PathBuf,
    /// Significance of the KS test and of the gap check's bin-count rule.
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
}

/// The SHA-256 of `bytes`, as the manifest writes it.
fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Reads one file of a sample: with `verify`, its checksum is compared with the manifest's and
/// an image is decoded in full. Returns the bytes read.
fn read_sample_file(
    root: &Path,
    e: &ManifestEntry,
    key: &str,
    rel: &Path,
    verify: bool,
) -> Result<Vec<u8>, String> {
    let path = root.join(rel);
    let bytes = std::fs::read(&path).map_err(|err| format!("{}: {err}", path.display()))?;
    if verify {
        let Some(recorded) = e.sha256.get(key) else {
            return Err(format!(
                "{}: the manifest records no checksum for it",
                path.display()
            ));
        };
        let actual = sha256_hex(&bytes);
        if &actual != recorded {
            return Err(format!(
                "{}: SHA-256 {actual} differs from the manifest's {recorded}",
                path.display()
            ));
        }
        if matches!(key, "left" | "right") {
            image::load_from_memory(&bytes)
                .map_err(|err| format!("{}: cannot decode: {err}", path.display()))?;
        }
    }
    Ok(bytes)
}

/// Verifies the files the pixel pass does not read (images and the scene file).
fn verify_other_files(root: &Path, e: &ManifestEntry) -> Vec<String> {
    [
        ("left", &e.files.left),
        ("right", &e.files.right),
        ("scene", &e.files.scene),
    ]
    .into_iter()
    .filter_map(|(key, rel)| read_sample_file(root, e, key, rel, true).err())
    .collect()
}

/// A dataset read for statistics: its description, manifest and category list.
struct Loaded {
    info: DatasetInfo,
    entries: Vec<ManifestEntry>,
    /// Recipe categories in recipe order, then any other category found in the manifest.
    categories: Vec<String>,
}

fn load(root: &Path) -> anyhow::Result<Loaded> {
    let layout = DatasetLayout::new(root);
    let info: DatasetInfo = layout
        .read_info()
        .with_context(|| format!("{} is not a stereogen dataset", root.display()))?;
    // stats may run while `generate` appends: an unfinished last line is left out, with a note.
    let manifest = read_manifest(&layout.manifest())?;
    if manifest.has_unfinished_line() {
        eprintln!(
            "stats: {}: ignoring an unfinished last line (generation still running?)",
            layout.manifest().display()
        );
    }
    let entries = manifest.entries;
    let mut categories: Vec<String> = info
        .recipe
        .categories
        .iter()
        .map(|c| c.name.clone())
        .collect();
    for e in &entries {
        if !categories.contains(&e.category) {
            categories.push(e.category.clone());
        }
    }
    Ok(Loaded {
        info,
        entries,
        categories,
    })
}

/// Upper end of the pixel histograms: the largest disparity the manifest reports, or the law's
/// maximum, with 2% headroom. Manifest summaries come from the maps themselves; a value beyond
/// this range is still counted (as `outside_range`).
fn pixel_hi(entries: &[ManifestEntry], law: &Dist) -> f64 {
    let manifest_max = entries
        .iter()
        .flat_map(|e| [e.disparity_left, e.disparity_right])
        .flatten()
        .map(|s| f64::from(s.max))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let hi = manifest_max.max(law.support().1).max(1.0) * 1.02;
    // Round up to 2 significant digits so bins have readable edges.
    let scale = 10f64.powf(hi.log10().floor() - 1.0);
    (hi / scale).ceil() * scale
}

type Fold = (Vec<Option<PixelAcc>>, Vec<String>);

/// A line on stderr at every 10% of a large pass (from whichever thread crosses the mark).
struct Progress {
    total: usize,
    done: AtomicUsize,
    start: Instant,
}

impl Progress {
    fn new(total: usize) -> Self {
        Self {
            total,
            done: AtomicUsize::new(0),
            start: Instant::now(),
        }
    }

    fn tick(&self) {
        let n = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        if self.total >= 2000 && n * 10 / self.total != (n - 1) * 10 / self.total {
            eprintln!(
                "stats: {n}/{} samples read ({:.0} s)",
                self.total,
                self.start.elapsed().as_secs_f64()
            );
        }
    }
}

/// Computes the statistics of the dataset at `opts.dataset`.
pub fn compute(opts: &StatsOptions) -> anyhow::Result<StatsReport> {
    if !(opts.ks_alpha > 0.0 && opts.ks_alpha < 1.0) {
        bail!("--ks-alpha must lie in (0, 1), got {}", opts.ks_alpha);
    }
    if let Some(k) = opts.gap_bins
        && !(1..=1024).contains(&k)
    {
        bail!("--gap-bins must lie in 1..=1024, got {k}");
    }
    let root = &opts.dataset;
    let Loaded {
        info,
        entries,
        categories,
    } = load(root)?;
    let law = info.recipe.placement.disparity_px.clone();
    let (law_min, law_max) = law.support();
    let cat_of = |name: &str| {
        categories
            .iter()
            .position(|c| c == name)
            .expect("every manifest category is listed")
    };

    // Object level: the target disparities of every SceneSpec.
    let specs: Vec<Result<(usize, Vec<f64>), String>> = entries
        .par_iter()
        .map(|e| {
            let path = root.join(&e.files.scene);
            let spec = crate::dataset::read_scene_spec(&path).map_err(|err| format!("{err:#}"))?;
            Ok((cat_of(&e.category), spec.target_disparities().collect()))
        })
        .collect();
    let mut errors = Vec::new();
    let mut objects: Vec<Vec<f64>> = vec![Vec::new(); categories.len()];
    let mut samples = vec![0u64; categories.len()];
    for r in specs {
        match r {
            Ok((c, t)) => objects[c].extend(t),
            Err(e) => errors.push(e),
        }
    }
    for e in &entries {
        samples[cat_of(&e.category)] += 1;
    }

    // Gap-check bins: equal-mass bins of the law, as many as the object count supports.
    let edges_for = |n: usize| -> Option<Vec<f64>> {
        let k = opts
            .gap_bins
            .unwrap_or_else(|| gap_bins_for(n, opts.ks_alpha));
        (k > 0 && n > 0 && law_max > law_min).then(|| equal_mass_edges(&law, k))
    };
    let gap_edges: Vec<Option<Vec<f64>>> = objects.iter().map(|o| edges_for(o.len())).collect();
    let all_edges = edges_for(objects.iter().map(Vec::len).sum());

    let width = entries.iter().map(|e| e.width as usize).max().unwrap_or(1);
    let height = entries.iter().map(|e| e.height as usize).max().unwrap_or(1);
    let binning = Binning::new(
        pixel_hi(&entries, &law),
        (law_min, law_max),
        opts.bins.unwrap_or(DEFAULT_BINS).clamp(1, 4096),
        width,
        height,
    );

    // Pixel level: every map once, in parallel, never more than one pair per thread in memory.
    let new_acc = |c: usize| PixelAcc::new(&binning, gap_edges[c].as_deref(), all_edges.as_deref());
    let progress = Progress::new(entries.len());
    let (accs, read_errors): Fold = entries
        .par_iter()
        .fold(
            || (vec![None; categories.len()], Vec::new()),
            |(mut accs, mut errs): Fold, e| {
                let c = cat_of(&e.category);
                for (view, (key, rel)) in [
                    ("disp_left", &e.files.disp_left),
                    ("disp_right", &e.files.disp_right),
                ]
                .into_iter()
                .enumerate()
                {
                    let path = root.join(rel);
                    let read = read_sample_file(root, e, key, rel, opts.verify).and_then(|bytes| {
                        stereo_io::decode_disparity_exr(&bytes, &path)
                            .map_err(|err| err.to_string())
                    });
                    match read {
                        Ok((map, _)) => accs[c]
                            .get_or_insert_with(|| new_acc(c))
                            .add_map(view, &map),
                        Err(msg) => {
                            // Every message names its file; add it only if one does not.
                            errs.push(if msg.contains(&*path.to_string_lossy()) {
                                msg
                            } else {
                                format!("{}: {msg}", path.display())
                            });
                        }
                    }
                }
                if opts.verify {
                    errs.extend(verify_other_files(root, e));
                }
                progress.tick();
                (accs, errs)
            },
        )
        .reduce(
            || (vec![None; categories.len()], Vec::new()),
            |(mut a, mut ea), (b, eb)| {
                for (x, y) in a.iter_mut().zip(b) {
                    match (x.as_mut(), y) {
                        (Some(x), Some(y)) => x.merge(&y),
                        (None, y) => *x = y,
                        (Some(_), None) => {}
                    }
                }
                ea.extend(eb);
                (a, ea)
            },
        );
    errors.extend(read_errors);
    errors.sort();

    let mut cats = Vec::new();
    let mut total: Option<PixelAcc> = None;
    for (c, name) in categories.iter().enumerate() {
        let obj = ObjectStats::new(&mut objects[c], &law, opts.ks_alpha);
        let pixels = accs[c].as_ref().map(|a| PixelStats::new(a, a.gap.as_ref()));
        if let Some(a) = &accs[c] {
            match &mut total {
                Some(t) => t.merge(a),
                None => total = Some(a.clone()),
            }
        }
        cats.push(CategoryStats::new(name, samples[c], obj, pixels));
    }
    let mut all_objects: Vec<f64> = objects.concat();
    let overall_pixels = total
        .as_ref()
        .map(|a| PixelStats::new(a, a.gap_all.as_ref()));
    let overall = CategoryStats::new(
        "all",
        entries.len() as u64,
        ObjectStats::new(&mut all_objects, &law, opts.ks_alpha),
        overall_pixels,
    );
    // An empty dataset proves nothing: it does not pass.
    let pass = !entries.is_empty()
        && errors.is_empty()
        && overall.status != Status::Fail
        && cats.iter().all(|c| c.status != Status::Fail);
    let gap_rule = match opts.gap_bins {
        Some(k) => format!("{k} equal-mass bins of the law (--gap-bins)"),
        None => format!(
            "largest k <= {MAX_GAP_BINS} with k*(1-1/k)^n <= {} for n objects; equal-mass bins of the law",
            opts.ks_alpha
        ),
    };
    Ok(StatsReport {
        dataset: root.display().to_string(),
        recipe: info.recipe.name.clone(),
        law_support: [law_min, law_max],
        law,
        samples: entries.len(),
        ks_alpha: opts.ks_alpha,
        pixel_range: [0.0, binning.hi],
        gap_rule,
        categories: cats,
        overall,
        errors,
        pass,
    })
}

/// Writes `stats.json` into `dir` atomically and returns its path.
pub fn write_json(report: &StatsReport, dir: &Path) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("stats.json");
    let json = serde_json::to_string_pretty(report)?;
    stereo_io::write_bytes_atomically(&path, json.as_bytes())?;
    Ok(path)
}

/// The terminal summary: one line per category, the overall line, read errors, and the verdict.
pub fn summary_lines(report: &StatsReport) -> Vec<String> {
    let w = report
        .categories
        .iter()
        .map(|c| c.name.len())
        .max()
        .unwrap_or(3)
        .max(3);
    let (lo, hi) = (report.law_support[0], report.law_support[1]);
    let mut lines = vec![format!(
        "stats of {} ({} samples, recipe {}, law on [{lo}, {hi}] px, KS alpha {})",
        report.dataset, report.samples, report.recipe, report.ks_alpha
    )];
    lines.extend(report.categories.iter().map(|c| c.line(w)));
    lines.push(report.overall.line(w));
    for e in report.errors.iter().take(10) {
        lines.push(format!("ERROR {e}"));
    }
    if report.errors.len() > 10 {
        lines.push(format!(
            "ERROR ... and {} more unreadable files",
            report.errors.len() - 10
        ));
    }
    let failing: Vec<&str> = report
        .categories
        .iter()
        .chain([&report.overall])
        .filter(|c| c.status == Status::Fail)
        .map(|c| c.name.as_str())
        .collect();
    lines.push(if report.pass {
        let tested = report
            .categories
            .iter()
            .filter(|c| c.status == Status::Ok)
            .count();
        format!(
            "verdict: PASS ({tested} of {} categories tested, all follow the law)",
            report.categories.len()
        )
    } else if report.samples == 0 {
        "verdict: FAIL (the dataset has no samples)".to_string()
    } else if failing.is_empty() {
        format!("verdict: FAIL ({} unreadable file(s))", report.errors.len())
    } else {
        format!(
            "verdict: FAIL ({} miss the target{})",
            failing.join(", "),
            if report.errors.is_empty() {
                String::new()
            } else {
                format!("; {} unreadable file(s)", report.errors.len())
            }
        )
    });
    lines
}
