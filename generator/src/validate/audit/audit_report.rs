//! What `audit.json` holds, the bars of `--check`, and the terminal summary.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use stereo_io::MapKind;

use super::tally::{DEPTH_RELATIVE, MapIssue, MapTally, NORMAL_DEGREES, PixelIssue, Tally};

/// The bars `stereogen audit --check` applies (to every sample, every category and the whole
/// audit). The map bars apply where a dataset has that map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bars {
    /// Least share of non-silhouette pixels within 0.01 px of ray casting.
    pub min_share_within_0_01: f64,
    /// Most flying pixels.
    pub max_flying: u64,
    /// Most files whose checksum differs from the manifest.
    pub max_checksum_mismatches: u64,
    /// Least share of checked depth pixels within 1e-4 relative of ray casting.
    #[serde(default = "default_map_share")]
    pub min_depth_share: f64,
    /// Least share of checked normal pixels within 0.5° of ray casting.
    #[serde(default = "default_map_share")]
    pub min_normals_share: f64,
    /// Least share of checked instance pixels with the hit object's id.
    #[serde(default = "default_map_share")]
    pub min_instance_share: f64,
    /// Least share of checked semantic pixels with the hit object's class.
    #[serde(default = "default_map_share")]
    pub min_semantic_share: f64,
}

fn default_map_share() -> f64 {
    0.9999
}

impl Default for Bars {
    fn default() -> Self {
        Self {
            min_share_within_0_01: 0.9999,
            max_flying: 0,
            max_checksum_mismatches: 0,
            min_depth_share: default_map_share(),
            min_normals_share: default_map_share(),
            min_instance_share: default_map_share(),
            min_semantic_share: default_map_share(),
        }
    }
}

impl Bars {
    /// The bar of map `kind`.
    pub fn map_share(&self, kind: MapKind) -> f64 {
        match kind {
            MapKind::Depth => self.min_depth_share,
            MapKind::Normals => self.min_normals_share,
            MapKind::Instance => self.min_instance_share,
            MapKind::Semantic => self.min_semantic_share,
        }
    }
}

/// What "in bounds" means for map `kind`, for people.
pub fn map_bound(kind: MapKind) -> String {
    match kind {
        MapKind::Depth => format!("within {DEPTH_RELATIVE:e} relative"),
        MapKind::Normals => format!("within {NORMAL_DEGREES}°"),
        MapKind::Instance => "the hit object's id".to_string(),
        MapKind::Semantic => "the hit object's class".to_string(),
    }
}

/// Whether `share` (`None`: nothing checked) meets the bar of `kind`.
fn map_passes(bars: &Bars, kind: MapKind, share: Option<f64>) -> bool {
    share.is_none_or(|s| s >= bars.map_share(kind))
}

/// One map over a group of samples.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapGroup {
    #[serde(flatten)]
    pub tally: MapTally,
    /// Share of checked pixels within bounds.
    pub share_in_bounds: Option<f64>,
    pub pass: bool,
}

/// One audited sample.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SampleAudit {
    pub id: String,
    pub category: String,
    pub index: u64,
    pub tally: Tally,
    /// Its worst pixels.
    pub worst: Vec<PixelIssue>,
    /// Files (manifest keys) whose SHA-256 is not the manifest's.
    pub checksum_mismatches: Vec<String>,
    /// What kept (part of) the sample from being audited: unreadable files, a missing scene.json,
    /// a scene Blender could not build.
    pub problems: Vec<String>,
    pub objects: usize,
    pub triangles: usize,
    /// Seconds of ray casting and comparison (Blender's time not included).
    pub seconds: f64,
    /// The maps beside the disparity (by [`MapKind::name`]), where the sample has them.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub maps: BTreeMap<String, MapTally>,
    /// The worst pixels of each map.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub map_worst: Vec<MapIssue>,
    pub pass: bool,
}

/// One category, or everything.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GroupAudit {
    pub name: String,
    pub samples: usize,
    pub tally: Tally,
    pub share_within_0_01: Option<f64>,
    pub share_within_0_5: Option<f64>,
    pub silhouette_share: Option<f64>,
    pub lr_share_within_0_1: Option<f64>,
    pub checksum_mismatches: u64,
    /// Samples that could not be audited.
    pub problems: u64,
    /// The maps beside the disparity (by [`MapKind::name`]), where the samples have them.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub maps: BTreeMap<String, MapGroup>,
    pub pass: bool,
}

/// `audit.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AuditReport {
    pub dataset: String,
    pub stereogen_version: String,
    pub seed: u64,
    /// "all" or the requested count.
    pub samples_requested: String,
    /// "every" or the count per sample.
    pub pixels_requested: String,
    /// Finished samples in the manifest when the audit started.
    pub manifest_samples: usize,
    /// An unfinished last manifest line was left out (a run still writing).
    pub unfinished_manifest_line: bool,
    pub bars: Bars,
    pub categories: Vec<GroupAudit>,
    pub overall: GroupAudit,
    /// The worst pixels over all samples.
    pub worst: Vec<PixelIssue>,
    /// The worst pixels of each map beside the disparity over all samples.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub map_worst: Vec<MapIssue>,
    pub samples: Vec<SampleAudit>,
    /// Wall seconds of the whole audit, and of ray casting and comparison alone.
    pub seconds: f64,
    pub cast_seconds: f64,
    /// Ray casting and comparison per million audited pixels (both views).
    pub cast_seconds_per_megapixel: Option<f64>,
    /// Problems that are not one sample's.
    pub problems: Vec<String>,
    /// One line per round of curation (`stereogen curate --replace`) and how it checked.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub curation: Vec<String>,
    pub pass: bool,
}

fn pct(x: Option<f64>) -> String {
    x.map_or("-".to_string(), |v| format!("{:.4}%", 100.0 * v))
}

impl GroupAudit {
    pub fn new(name: &str, samples: &[&SampleAudit], bars: &Bars) -> Self {
        let mut tally = Tally::default();
        samples.iter().for_each(|s| tally.merge(&s.tally));
        let checksum_mismatches = samples
            .iter()
            .map(|s| s.checksum_mismatches.len() as u64)
            .sum();
        let problems = samples.iter().filter(|s| !s.problems.is_empty()).count() as u64;
        let share = tally.share_within_0_01();
        let mut maps: BTreeMap<String, MapGroup> = BTreeMap::new();
        for kind in MapKind::ALL {
            let mut t: Option<MapTally> = None;
            for m in samples.iter().filter_map(|s| s.maps.get(kind.name())) {
                t.get_or_insert_with(MapTally::default).merge(m);
            }
            if let Some(tally) = t {
                let share_in_bounds = tally.share_in_bounds();
                maps.insert(
                    kind.name().to_string(),
                    MapGroup {
                        tally,
                        share_in_bounds,
                        pass: map_passes(bars, kind, share_in_bounds),
                    },
                );
            }
        }
        let pass = !samples.is_empty()
            && share.is_none_or(|s| s >= bars.min_share_within_0_01)
            && tally.flying <= bars.max_flying
            && checksum_mismatches <= bars.max_checksum_mismatches
            && problems == 0
            && maps.values().all(|m| m.pass);
        Self {
            name: name.to_string(),
            samples: samples.len(),
            share_within_0_01: share,
            share_within_0_5: tally.share_within_0_5(),
            silhouette_share: tally.silhouette_share(),
            lr_share_within_0_1: tally.lr_share_within_0_1(),
            tally,
            checksum_mismatches,
            problems,
            maps,
            pass,
        }
    }

    /// One line per map, for the terminal (none without maps).
    pub fn map_lines(&self, name_width: usize) -> Vec<String> {
        MapKind::ALL
            .into_iter()
            .filter_map(|kind| Some((kind, self.maps.get(kind.name())?)))
            .map(|(kind, m)| {
                let t = &m.tally;
                let max = match kind {
                    MapKind::Depth => format!("  max {:.2e} relative", t.max_error),
                    MapKind::Normals => format!("  max {:.3}°", t.max_error),
                    _ => String::new(),
                };
                let crease = if kind == MapKind::Normals {
                    format!(", {} checked on creases", t.crease)
                } else {
                    String::new()
                };
                format!(
                    "{} {:<name_width$} {:<8} {:>10} px  {} {:>9} of {} checked ({} validity mismatches){max}  silhouette {} ({} disagree){crease}",
                    if m.pass { "OK  " } else { "FAIL" },
                    self.name,
                    kind.name(),
                    t.pixels,
                    map_bound(kind),
                    pct(m.share_in_bounds),
                    t.checked,
                    t.validity_mismatch,
                    t.silhouette,
                    t.edge_disagree
                )
            })
            .collect()
    }

    /// One line for the terminal.
    pub fn line(&self, name_width: usize) -> String {
        let t = &self.tally;
        format!(
            "{} {:<name_width$} {:>5} samples {:>10} px  within 0.01 px {:>9}  within 0.5 px {:>9}  max {:.2e} px  silhouette {:>8} ({} disagree)  flying {}  L-R within 0.1 px {}  checksum mismatches {}{}",
            if self.pass { "OK  " } else { "FAIL" },
            self.name,
            self.samples,
            t.pixels,
            pct(self.share_within_0_01),
            pct(self.share_within_0_5),
            t.max_error,
            pct(self.silhouette_share),
            t.silhouette_disagree,
            t.flying,
            pct(self.lr_share_within_0_1),
            self.checksum_mismatches,
            if self.problems > 0 {
                format!("  {} sample(s) not audited", self.problems)
            } else {
                String::new()
            }
        )
    }
}

impl SampleAudit {
    /// Why the sample fails the bars (empty when it passes).
    pub fn reasons(&self, bars: &Bars) -> Vec<String> {
        let t = &self.tally;
        let mut r = Vec::new();
        if let Some(s) = t.share_within_0_01()
            && s < bars.min_share_within_0_01
        {
            let off = t.interior - t.interior_within_0_01;
            let at = self
                .worst
                .iter()
                .find(|w| w.kind != super::tally::IssueKind::Flying);
            let at = at.map_or(String::new(), |w| {
                format!(", worst {:.4} px at {} ({}, {})", w.error, w.view, w.x, w.y)
            });
            r.push(format!(
                "{off} of {} non-silhouette pixels off by more than 0.01 px{at}",
                t.interior
            ));
        }
        if t.flying > bars.max_flying {
            let at = self
                .worst
                .iter()
                .find(|w| w.kind == super::tally::IssueKind::Flying);
            let at = at.map_or(String::new(), |w| {
                format!(
                    ", e.g. {} ({}, {}) = {:.3} px",
                    w.view,
                    w.x,
                    w.y,
                    w.rendered.unwrap_or(0.0)
                )
            });
            r.push(format!("{} flying pixel(s){at}", t.flying));
        }
        for kind in MapKind::ALL {
            let Some(t) = self.maps.get(kind.name()) else {
                continue;
            };
            if map_passes(bars, kind, t.share_in_bounds()) {
                continue;
            }
            let at = self
                .map_worst
                .iter()
                .find(|w| w.map == kind.name() && w.out_of_bounds)
                .map_or(String::new(), |w| {
                    format!(
                        ", worst {:.3e} at {} ({}, {}): {:?} where ray casting gives {:?}",
                        w.error, w.view, w.x, w.y, w.rendered, w.expected
                    )
                });
            r.push(format!(
                "{}: {} of {} checked pixels out of bounds (not {}; {} validity mismatches){at}",
                kind.name(),
                t.checked - t.in_bounds,
                t.checked,
                map_bound(kind),
                t.validity_mismatch
            ));
        }
        for f in &self.checksum_mismatches {
            r.push(format!(
                "{f} changed since the manifest was written (SHA-256 differs)"
            ));
        }
        r.extend(self.problems.iter().cloned());
        r
    }
}

impl AuditReport {
    /// What each sample was audited at: "every pixel" or "N pixels".
    pub fn pixels_per_sample(&self) -> String {
        if self.pixels_requested == "every" {
            "every pixel".to_string()
        } else {
            format!("{} pixels", self.pixels_requested)
        }
    }
}

/// The terminal summary: the categories, the overall line, failing samples by name, the verdict.
pub fn summary_lines(report: &AuditReport) -> Vec<String> {
    let w = crate::validate::name_column_width(report.categories.iter().map(|c| c.name.as_str()));
    let mut lines = vec![format!(
        "audit of {} ({} of {} samples, {} per sample, seed {})",
        report.dataset,
        report.samples.len(),
        report.manifest_samples,
        report.pixels_per_sample(),
        report.seed
    )];
    if report.unfinished_manifest_line {
        lines.push(
            "note: the manifest's unfinished last line was left out (generation still running?)"
                .to_string(),
        );
    }
    lines.extend(report.categories.iter().map(|c| c.line(w)));
    lines.push(report.overall.line(w));
    for g in report.categories.iter().chain([&report.overall]) {
        lines.extend(g.map_lines(w));
    }
    lines.extend(report.curation.iter().cloned());
    for p in &report.problems {
        lines.push(format!("ERROR {p}"));
    }
    for w in report.map_worst.iter().filter(|w| w.out_of_bounds).take(4) {
        lines.push(format!(
            "worst {}: {:.3e} in sample {} ({}), {} view, pixel ({}, {}): {:?} where ray casting gives {:?}",
            w.map, w.error, w.sample, w.category, w.view, w.x, w.y, w.rendered, w.expected
        ));
    }
    for w in report.worst.iter().take(3) {
        lines.push(format!(
            "worst: {:.3e} px ({:?}) in sample {} ({}), {} view, pixel ({}, {})",
            w.error, w.kind, w.sample, w.category, w.view, w.x, w.y
        ));
    }
    let failing: Vec<&SampleAudit> = report.samples.iter().filter(|s| !s.pass).collect();
    for s in failing.iter().take(20) {
        lines.push(format!(
            "FAIL sample {} ({}, index {}): {}",
            s.id,
            s.category,
            s.index,
            s.reasons(&report.bars).join("; ")
        ));
    }
    if failing.len() > 20 {
        lines.push(format!(
            "FAIL ... and {} more samples (see audit.json)",
            failing.len() - 20
        ));
    }
    if let Some(s) = report.cast_seconds_per_megapixel {
        lines.push(format!(
            "ray casting: {:.1} s for {:.2} Mpx ({s:.2} s per Mpx); whole audit {:.1} s",
            report.cast_seconds,
            report.overall.tally.pixels as f64 / 1e6,
            report.seconds
        ));
    }
    let b = &report.bars;
    let maps: Vec<String> = MapKind::ALL
        .into_iter()
        .filter(|k| report.overall.maps.contains_key(k.name()))
        .map(|k| {
            format!(
                ", >= {}% of checked {} pixels {}",
                100.0 * b.map_share(k),
                k.name(),
                map_bound(k)
            )
        })
        .collect();
    lines.push(format!(
        "verdict: {} (bars: >= {}% of non-silhouette pixels within 0.01 px, <= {} flying pixels, <= {} checksum mismatches{}, every sample audited)",
        if report.pass { "PASS" } else { "FAIL" },
        100.0 * b.min_share_within_0_01,
        b.max_flying,
        b.max_checksum_mismatches,
        maps.concat()
    ));
    lines
}
