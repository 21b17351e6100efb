//! What `stats.json` holds, how a category's numbers are derived from its accumulators, and the
//! per-category OK/FAIL decision with its one-line summary.

use serde::Serialize;

use crate::plan::Dist;
use crate::plan::dist::ks_distance;
use crate::validate::accumulate::{Coverage, PixelAcc, ViewAcc};
use crate::validate::hist::{EdgeHist, Percentiles, UniformHist, quantile_sorted, rice_bins};

/// Groups with fewer content objects are not judged ("too few samples to judge"): at the
/// default family rate 0.01 over five tests, the first Holm level is 0.002, where the KS critical
/// value of 13 objects is 0.495 and of 12 is 0.513 — below 13 objects the test could not even
/// see a law with half its mass misplaced, and the gap check has at most 2 bins.
pub const MIN_OBJECTS_TO_JUDGE: usize = 13;

#[derive(Debug, Clone, Serialize)]
pub struct StatsReport {
    pub dataset: String,
    pub recipe: String,
    /// The disparity law of the recipe (`placement.disparity_px`).
    pub law: Dist,
    pub law_support: [f64; 2],
    pub samples: usize,
    /// The family-wise false-alarm rate of the object-level KS tests (Holm over the judged
    /// groups), and the significance of each gap check's bin-count rule.
    pub ks_alpha: f64,
    /// Groups (categories, all) with fewer content objects are not judged: too few to tell.
    pub min_objects_to_judge: usize,
    /// Range of the pixel-level histograms (px).
    pub pixel_range: [f64; 2],
    /// Rule that chose the gap-check bin counts.
    pub gap_rule: String,
    pub categories: Vec<CategoryStats>,
    pub overall: CategoryStats,
    /// Samples whose files could not be read.
    pub errors: Vec<String>,
    /// What could not be computed from this dataset and why (an export without SceneSpecs).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// The rounds of `stereogen curate --replace` the dataset went through.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub curation: Vec<stereo_io::datasets::stereogen::CurationRound>,
    /// The manifest's difficulty facts per category, then `all` (none for a manifest written
    /// before they were measured).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub difficulty: Vec<super::difficulty::DifficultyStats>,
    /// The maps beside the disparity (depth, normals, instance, semantic), where the dataset
    /// has them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub maps: Option<super::maps::MapStats>,
    pub pass: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    Ok,
    Fail,
    /// Nothing to test (no samples or no content objects).
    Skip,
}

#[derive(Debug, Clone, Serialize)]
pub struct CategoryStats {
    pub name: String,
    pub samples: u64,
    pub objects: ObjectStats,
    pub pixels: Option<PixelStats>,
    pub status: Status,
    pub problems: Vec<String>,
}

/// The object-level sample: target disparities of the content objects, from the SceneSpecs.
#[derive(Debug, Clone, Serialize)]
pub struct ObjectStats {
    pub count: usize,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub mean: Option<f64>,
    pub percentiles: Option<Percentiles>,
    pub ks_distance: Option<f64>,
    /// The critical value at [`ObjectStats::ks_level`]; unset when the group is not judged.
    pub ks_critical: Option<f64>,
    /// This group's significance level in the Holm step-down over the judged groups.
    pub ks_level: Option<f64>,
    /// Rice-rule bins over the law's support.
    pub histogram: Option<UniformHist>,
}

#[derive(Debug, Clone, Serialize)]
pub struct ViewStats {
    pub pixels: u64,
    pub valid: u64,
    pub invalid_fraction: f64,
    pub mean: Option<f64>,
    pub percentiles: Option<Percentiles>,
}

/// Empty pixel-level bins inside the law's support (equal-mass bins of the law).
#[derive(Debug, Clone, Serialize)]
pub struct GapCheck {
    pub bins: usize,
    pub edges: Vec<f64>,
    pub counts: Vec<u64>,
    pub empty: Vec<[f64; 2]>,
}

/// One band of image rows or columns (relative position 0..1): how many of its pixels are valid,
/// how many are content (disparity at or above the law's minimum, i.e. not the background wall),
/// and the disparity of the content pixels.
#[derive(Debug, Clone, Serialize)]
pub struct Band {
    pub from: f64,
    pub to: f64,
    pub valid_fraction: f64,
    pub content_fraction: f64,
    pub mean: Option<f64>,
    pub p5: Option<f64>,
    pub p50: Option<f64>,
    pub p95: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct PixelStats {
    /// Both views together.
    pub pixels: u64,
    pub valid: u64,
    pub invalid_fraction: f64,
    /// Pixels flagged valid that hold NaN or infinity.
    pub nonfinite_valid: u64,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub mean: Option<f64>,
    pub percentiles: Option<Percentiles>,
    /// Valid pixels beyond `pixel_range` (counted at its ends for percentiles).
    pub outside_range: u64,
    /// Fraction of valid pixels inside the law's support.
    pub in_support_fraction: Option<f64>,
    pub left: ViewStats,
    pub right: ViewStats,
    /// Both views, `--bins` bins over the law's support (`below`/`above`: the rest).
    pub histogram: UniformHist,
    /// Both views, 64 bins over `pixel_range`.
    pub histogram_full: UniformHist,
    pub gap_check: Option<GapCheck>,
    pub rows: Vec<Band>,
    pub cols: Vec<Band>,
}

fn fraction(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

impl ObjectStats {
    /// Non-finite targets (a broken SceneSpec) are left out. The KS level and critical value
    /// are set later, for the whole family ([`super::ks_family::holm_levels`]).
    pub fn new(sample: &mut Vec<f64>, law: &Dist) -> Self {
        sample.retain(|v| v.is_finite());
        sample.sort_by(f64::total_cmp);
        let n = sample.len();
        let (lo, hi) = law.support();
        let histogram = (n > 0 && hi > lo).then(|| {
            let mut h = UniformHist::new(lo, hi, rice_bins(n));
            sample.iter().for_each(|&x| h.add(x));
            h
        });
        Self {
            count: n,
            min: sample.first().copied(),
            max: sample.last().copied(),
            mean: (n > 0).then(|| sample.iter().sum::<f64>() / n as f64),
            percentiles: Percentiles::from_fn(|q| quantile_sorted(sample, q)),
            ks_distance: (n > 0).then(|| ks_distance(sample, law)),
            ks_critical: None,
            ks_level: None,
            histogram,
        }
    }
}

fn view_stats(v: &ViewAcc) -> ViewStats {
    let valid = v.valid();
    ViewStats {
        pixels: v.pixels,
        valid,
        invalid_fraction: fraction(v.pixels - valid, v.pixels),
        mean: (valid > 0).then(|| v.sum / valid as f64),
        percentiles: Percentiles::from_fn(|q| v.fine.quantile(q)),
    }
}

fn bands(c: &Coverage) -> Vec<Band> {
    let n = c.sums.len();
    (0..n)
        .map(|i| {
            let h = &c.hists[i];
            Band {
                from: i as f64 / n as f64,
                to: (i + 1) as f64 / n as f64,
                valid_fraction: fraction(c.valid[i], c.pixels[i]),
                content_fraction: fraction(c.content[i], c.pixels[i]),
                mean: (c.content[i] > 0).then(|| c.sums[i] / c.content[i] as f64),
                p5: h.quantile(0.05),
                p50: h.quantile(0.5),
                p95: h.quantile(0.95),
            }
        })
        .collect()
}

fn gap_check(g: &EdgeHist) -> GapCheck {
    GapCheck {
        bins: g.counts.len(),
        edges: g.edges.clone(),
        counts: g.counts.clone(),
        empty: g.empty_bins(),
    }
}

impl PixelStats {
    /// `gap`: the gap-check histogram that applies to this group (the category's own bins, or
    /// the dataset-wide ones for the overall group).
    pub fn new(acc: &PixelAcc, gap: Option<&EdgeHist>) -> Self {
        let [l, r] = &acc.views;
        let pixels = l.pixels + r.pixels;
        let valid = l.valid() + r.valid();
        let fine = acc.fine_both();
        let in_support = gap.map(|g| fraction(g.counts.iter().sum(), valid));
        PixelStats {
            pixels,
            valid,
            invalid_fraction: fraction(pixels - valid, pixels),
            nonfinite_valid: l.nonfinite + r.nonfinite,
            min: (valid > 0).then(|| l.min.min(r.min)),
            max: (valid > 0).then(|| l.max.max(r.max)),
            mean: (valid > 0).then(|| (l.sum + r.sum) / valid as f64),
            percentiles: Percentiles::from_fn(|q| fine.quantile(q)),
            outside_range: fine.below + fine.above,
            in_support_fraction: in_support,
            left: view_stats(l),
            right: view_stats(r),
            histogram: acc.display.clone(),
            histogram_full: fine.coarsen(fine.bins() / 64),
            gap_check: gap.map(gap_check),
            rows: bands(&acc.rows),
            cols: bands(&acc.cols),
        }
    }
}

impl CategoryStats {
    /// Derives the numbers and decides OK/FAIL/SKIP. Broken maps fail whatever the size; the
    /// statistical tests (KS, gap) judge only groups of at least [`MIN_OBJECTS_TO_JUDGE`] objects.
    pub fn new(name: &str, samples: u64, objects: ObjectStats, pixels: Option<PixelStats>) -> Self {
        let (status, problems) = if samples == 0 {
            (Status::Skip, vec!["no samples".to_string()])
        } else if objects.count == 0 {
            (
                Status::Skip,
                vec!["no content objects with a target disparity".to_string()],
            )
        } else {
            let broken = broken_maps(pixels.as_ref());
            if !broken.is_empty() {
                (Status::Fail, broken)
            } else if objects.count < MIN_OBJECTS_TO_JUDGE {
                (
                    Status::Skip,
                    vec![format!(
                        "too few samples to judge ({} objects, at least {MIN_OBJECTS_TO_JUDGE} needed)",
                        objects.count
                    )],
                )
            } else {
                let missed = missed_law(&objects, pixels.as_ref());
                let status = if missed.is_empty() {
                    Status::Ok
                } else {
                    Status::Fail
                };
                (status, missed)
            }
        };
        Self {
            name: name.to_string(),
            samples,
            objects,
            pixels,
            status,
            problems,
        }
    }

    /// One line for the terminal: status, the numbers the decision used, and the problems.
    pub fn line(&self, name_width: usize) -> String {
        let tag = match self.status {
            Status::Ok => "OK  ",
            Status::Fail => "FAIL",
            Status::Skip => "SKIP",
        };
        let mut s = format!(
            "{tag} {:<name_width$} {:>6} scenes {:>7} objects",
            self.name, self.samples, self.objects.count
        );
        match (self.objects.ks_distance, self.objects.ks_critical) {
            (Some(d), Some(c)) => {
                s += &format!("  KS {d:.4} {} {c:.4}", if d > c { ">" } else { "<=" })
            }
            (Some(d), None) => s += &format!("  KS {d:.4}"),
            _ => {}
        }
        if let Some(p) = &self.pixels {
            if let Some(g) = &p.gap_check {
                s += &format!("  empty bins {}/{}", g.empty.len(), g.bins);
            }
            if let Some(q) = &p.percentiles {
                s += &format!("  px p1/p50/p99 {:.2}/{:.2}/{:.2}", q.p1, q.p50, q.p99);
            }
            s += &format!("  invalid {:.1}%", 100.0 * p.invalid_fraction);
        }
        if !self.problems.is_empty() {
            s += &format!("  -- {}", self.problems.join("; "));
        }
        s
    }
}

/// Maps that are broken whatever the sample size: none read, no valid pixel, non-finite values.
fn broken_maps(pixels: Option<&PixelStats>) -> Vec<String> {
    let Some(p) = pixels else {
        return vec!["no disparity maps could be read".to_string()];
    };
    let mut problems = Vec::new();
    if p.valid == 0 {
        problems.push("no valid pixels".to_string());
    }
    if p.nonfinite_valid > 0 {
        problems.push(format!(
            "{} valid pixels are NaN or infinite",
            p.nonfinite_valid
        ));
    }
    problems
}

/// The statistical tests: the object-level KS test at the group's Holm level, and the gap check.
fn missed_law(objects: &ObjectStats, pixels: Option<&PixelStats>) -> Vec<String> {
    let mut problems = Vec::new();
    if let (Some(d), Some(c)) = (objects.ks_distance, objects.ks_critical)
        && d > c
    {
        problems.push(format!("object-level KS {d:.4} > critical {c:.4}"));
    }
    if let Some(g) = pixels.and_then(|p| p.gap_check.as_ref())
        && !g.empty.is_empty()
    {
        let list: Vec<String> = g
            .empty
            .iter()
            .take(6)
            .map(|[a, b]| format!("[{a:.2}, {b:.2})"))
            .collect();
        let more = if g.empty.len() > 6 {
            format!(" and {} more", g.empty.len() - 6)
        } else {
            String::new()
        };
        problems.push(format!(
            "gap: {}/{} pixel bins empty inside the law's support: {}{more}",
            g.empty.len(),
            g.bins,
            list.join(" ")
        ));
    }
    problems
}
