//! The difficulty facts of the manifest's lines ([`Difficulty`]: occlusion, low texture, glass
//! and mirror pixels, the disparity range) as distributions per category and overall, for `stats`.

use std::collections::BTreeMap;

use serde::Serialize;
use stereo_io::datasets::stereogen::Difficulty;

use crate::dataset::ManifestEntry;

/// Quantiles of one fact over a group's samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    pub p10: f64,
    pub p50: f64,
    pub p90: f64,
    pub max: f64,
}

impl Spread {
    fn of(mut v: Vec<f64>) -> Self {
        v.sort_unstable_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
        Self {
            p10: q(0.1),
            p50: q(0.5),
            p90: q(0.9),
            max: q(1.0),
        }
    }
}

/// One group's difficulty: how many samples carry the facts, and each fact's spread.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DifficultyStats {
    pub name: String,
    pub samples: usize,
    /// Share of the left view's valid pixels occluded in the right view.
    pub occluded: Spread,
    /// Share of the left image in low texture.
    pub low_texture: Spread,
    /// The 99th percentile of each sample's disparity (px).
    pub disparity_p99: Spread,
    /// Each sample's 99th minus 1st percentile of disparity (px).
    pub disparity_span: Spread,
    /// Share of the left image showing glass or a mirror-like metal, over the samples whose
    /// render had the material-index pass (`None`: none had).
    pub transparent_mirror: Option<Spread>,
}

impl DifficultyStats {
    fn of(name: &str, facts: &[Difficulty]) -> Self {
        let spread = |f: &dyn Fn(&Difficulty) -> f64| Spread::of(facts.iter().map(f).collect());
        Self {
            name: name.to_string(),
            samples: facts.len(),
            occluded: spread(&|d| d.occluded),
            low_texture: spread(&|d| d.low_texture),
            disparity_p99: spread(&|d| f64::from(d.disparity_p99)),
            disparity_span: spread(&|d| f64::from(d.disparity_p99 - d.disparity_p1)),
            transparent_mirror: Some(
                facts
                    .iter()
                    .filter_map(|d| d.transparent_mirror)
                    .collect::<Vec<_>>(),
            )
            .filter(|v| !v.is_empty())
            .map(Spread::of),
        }
    }

    /// `tree   occluded 4.1% (p10 1.2%, p90 9.8%) · low texture ... · disparity p99 ... px`
    pub fn line(&self, w: usize) -> String {
        let pct = |s: &Spread| {
            format!(
                "{:.1}% (p10 {:.1}%, p90 {:.1}%)",
                100.0 * s.p50,
                100.0 * s.p10,
                100.0 * s.p90
            )
        };
        format!(
            "difficulty {:<w$}  occluded {} · low texture {} · glass/mirror {} · disparity p99 {:.1} px (p10 {:.1}, p90 {:.1}) · span {:.1} px  [{} samples]",
            self.name,
            pct(&self.occluded),
            pct(&self.low_texture),
            self.transparent_mirror
                .as_ref()
                .map_or("-".to_string(), pct),
            self.disparity_p99.p50,
            self.disparity_p99.p10,
            self.disparity_p99.p90,
            self.disparity_span.p50,
            self.samples
        )
    }
}

/// Per category (sorted by name) then `all`; empty when no line carries the facts (a manifest
/// written before they were measured).
pub fn difficulty_stats(entries: &[ManifestEntry]) -> Vec<DifficultyStats> {
    let mut by: BTreeMap<&str, Vec<Difficulty>> = BTreeMap::new();
    for e in entries {
        if let Some(d) = e.difficulty {
            by.entry(&e.category).or_default().push(d);
        }
    }
    if by.is_empty() {
        return Vec::new();
    }
    let all: Vec<Difficulty> = by.values().flatten().copied().collect();
    by.iter()
        .map(|(name, facts)| DifficultyStats::of(name, facts))
        .chain([DifficultyStats::of("all", &all)])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_are_nearest_rank_quantiles_per_group() {
        let s = Spread::of((0..=10).rev().map(f64::from).collect());
        assert_eq!((s.p10, s.p50, s.p90, s.max), (1.0, 5.0, 9.0, 10.0));
        let entry = |category: &str, occluded: f64| {
            let mut e: ManifestEntry = serde_json::from_value(serde_json::json!({
                "id": "x", "category": category, "index": 0,
                "files": {"left": "l", "right": "r", "disp_left": "a", "disp_right": "b", "scene": "s"},
                "width": 1, "height": 1, "f_px": 1.0, "baseline_m": 1.0, "cx": 0.5, "cy": 0.5
            }))
            .unwrap();
            e.difficulty = Some(Difficulty {
                occluded,
                low_texture: 0.5,
                disparity_p1: 1.0,
                disparity_p99: 9.0,
                transparent_mirror: Some(occluded / 2.0),
            });
            e
        };
        let mut entries = vec![entry("tree", 0.1), entry("tree", 0.3), entry("hole", 0.2)];
        let mut old = entry("hole", 0.9);
        old.difficulty = None;
        entries.push(old);
        let stats = difficulty_stats(&entries);
        let names: Vec<&str> = stats.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["hole", "tree", "all"]);
        assert_eq!(stats[0].samples, 1);
        assert_eq!(stats[1].occluded.max, 0.3);
        assert_eq!(stats[2].samples, 3);
        assert_eq!(stats[2].occluded.p50, 0.2);
        assert_eq!(stats[2].disparity_span.p50, 8.0);
        assert_eq!(stats[1].transparent_mirror.unwrap().max, 0.15);
        assert!(difficulty_stats(&entries[3..]).is_empty());
    }
}
