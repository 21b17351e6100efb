//! What the report says about a dataset apart from the pixel statistics: its description, the
//! finished samples per category, failures and skipped assets, render times, and the samples that
//! stand out. Read in one pass over the manifest; every problem is kept as a line for the page.

use std::collections::BTreeMap;
use std::path::Path;

use crate::dataset::manifest::{read_failures, read_skipped_assets};
use crate::dataset::{DatasetInfo, DatasetLayout, ManifestEntry};
use crate::validate::dataset_files::DatasetFiles;

/// Lines of failures.jsonl and skipped_assets.jsonl shown on the page, at most.
pub const MAX_LISTED: usize = 50;

/// A JSONL file's lines: the first [`MAX_LISTED`] as (label, text), and how many there are.
pub struct Listed {
    pub lines: Vec<(String, String)>,
    pub total: usize,
}

pub struct Facts {
    pub info: Option<DatasetInfo>,
    /// Finished samples, by index.
    pub entries: Vec<ManifestEntry>,
    pub failures: Listed,
    pub skipped: Listed,
    /// Problems found while reading (one line each, naming the file).
    pub problems: Vec<String>,
    /// Where the samples' files are read from (our folder layout or a WebDataset export).
    pub files: Option<DatasetFiles>,
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
}

/// Reads a JSONL side file; `label`/`text` pick what to show of each line.
/// The first [`MAX_LISTED`] records of a sidecar log as (label, text); a log that cannot be read
/// is a problem and lists nothing.
fn listed<R>(
    records: stereo_io::Result<Vec<R>>,
    line: impl Fn(&R) -> (String, String),
    problems: &mut Vec<String>,
) -> Listed {
    let records = records.unwrap_or_else(|e| {
        problems.push(e.to_string());
        Vec::new()
    });
    Listed {
        lines: records
            .iter()
            .take(MAX_LISTED)
            .map(|r| {
                let (label, text) = line(r);
                (label, truncate(&text, 400))
            })
            .collect(),
        total: records.len(),
    }
}

/// Everything but the pixels. Fails only when `root` is not a directory.
pub fn read(root: &Path) -> anyhow::Result<Facts> {
    anyhow::ensure!(
        root.is_dir(),
        "{}: no such dataset directory",
        root.display()
    );
    let layout = DatasetLayout::new(root);
    let mut problems = Vec::new();
    // An export's manifest lines are in its shards: the folder names them.
    let manifest_name = if DatasetFiles::is_shards(root) {
        root.to_path_buf()
    } else {
        layout.manifest()
    };
    let mut files = DatasetFiles::open(root)
        .map_err(|e| problems.push(e.to_string()))
        .ok();
    let info = match files.as_ref().map(DatasetFiles::read_info) {
        Some(Ok(i)) => Some(i),
        Some(Err(e)) => {
            problems.push(format!("{e}"));
            None
        }
        None => None,
    };
    let entries = match files.as_mut().map(DatasetFiles::manifest) {
        None => Vec::new(),
        Some(Err(_)) if !manifest_name.exists() => Vec::new(),
        Some(Ok(m)) => {
            if m.has_unfinished_line() {
                problems.push(format!(
                    "{}: the unfinished last line was left out (generation still running?)",
                    layout.manifest().display()
                ));
            }
            let mut e = m.entries;
            e.sort_by_key(|e| e.index);
            e
        }
        Some(Err(e)) => {
            problems.push(format!("{e:#}"));
            Vec::new()
        }
    };
    if entries.is_empty() && problems.is_empty() {
        let none = if manifest_name.exists() {
            "holds no finished samples"
        } else {
            "does not exist: no finished samples"
        };
        problems.push(format!("{} {none}", manifest_name.display()));
    }
    problems.extend(files.as_ref().and_then(DatasetFiles::no_logs_note));
    let failures = listed(
        read_failures(&layout.failures()).map(|c| c.records),
        |r| (r.index.to_string(), r.error.clone()),
        &mut problems,
    );
    let skipped = listed(
        read_skipped_assets(&layout.skipped_assets()).map(|c| c.records),
        |r| (r.path.display().to_string(), r.reason.clone()),
        &mut problems,
    );
    Ok(Facts {
        info,
        entries,
        failures,
        skipped,
        problems,
        files,
    })
}

/// Finished samples per category: (name, count), recipe categories first.
pub fn counts(facts: &Facts) -> Vec<(String, usize)> {
    let mut by: BTreeMap<&str, usize> = BTreeMap::new();
    for e in &facts.entries {
        *by.entry(&e.category).or_default() += 1;
    }
    let mut out: Vec<(String, usize)> = Vec::new();
    if let Some(info) = &facts.info {
        for c in &info.recipe.categories {
            out.push((c.name.clone(), by.remove(c.name.as_str()).unwrap_or(0)));
        }
    }
    out.extend(by.into_iter().map(|(k, v)| (k.to_string(), v)));
    out
}

fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    v
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    super::super::hist::quantile_sorted(sorted, q).unwrap_or(f64::NAN)
}

/// Render-time figures: (label, value) rows, overall then the mean per worker step.
pub fn render_times(entries: &[ManifestEntry]) -> Vec<(String, String)> {
    let t = sorted(entries.iter().map(|e| e.render_seconds).collect());
    if t.is_empty() {
        return Vec::new();
    }
    let total: f64 = t.iter().sum();
    let mut rows = vec![
        ("samples timed".to_string(), t.len().to_string()),
        (
            "seconds per sample: mean".into(),
            format!("{:.2}", total / t.len() as f64),
        ),
        (
            "median / p95 / max".into(),
            format!(
                "{:.2} / {:.2} / {:.2}",
                quantile(&t, 0.5),
                quantile(&t, 0.95),
                t[t.len() - 1]
            ),
        ),
        (
            "worker time in all".into(),
            format!("{:.2} h", total / 3600.0),
        ),
    ];
    let mut stages: BTreeMap<&str, (f64, usize)> = BTreeMap::new();
    for e in entries {
        for (k, v) in &e.render_timings {
            let s = stages.entry(k).or_default();
            s.0 += v;
            s.1 += 1;
        }
    }
    rows.extend(stages.into_iter().map(|(k, (sum, n))| {
        (
            format!("step {k}: mean"),
            format!("{:.3} s", sum / n as f64),
        )
    }));
    rows
}

/// What a sample is measured by when looking for ones that stand out, with the least spread
/// that counts (so a dataset whose samples all agree flags none for a hair's difference).
const MEASURES: [(&str, f64); 3] = [
    ("valid fraction", 0.02),
    ("largest disparity (px)", 1.0),
    ("render seconds", 0.5),
];

fn measures(e: &ManifestEntry) -> [Option<f64>; 3] {
    let (l, r) = (e.disparity_left.as_ref(), e.disparity_right.as_ref());
    let valid = match (l, r) {
        (Some(a), Some(b)) => Some(a.valid_fraction.min(b.valid_fraction)),
        _ => Some(0.0),
    };
    let max = l
        .into_iter()
        .chain(r)
        .map(|s| f64::from(s.max))
        .filter(|v| v.is_finite())
        .reduce(f64::max);
    [valid, max, Some(e.render_seconds)]
}

/// Robust z-score above which a sample stands out.
pub const OUTLIER_Z: f64 = 4.0;

/// Samples far from the rest (robust z-score over median and MAD of each measure beyond
/// [`OUTLIER_Z`]): (position in `entries`, why), the most extreme first, at most `limit`.
pub fn outliers(entries: &[ManifestEntry], limit: usize) -> Vec<(usize, String)> {
    let all: Vec<[Option<f64>; 3]> = entries.iter().map(measures).collect();
    let mut found: Vec<(f64, usize, String)> = Vec::new();
    for (m, (name, floor)) in MEASURES.iter().enumerate() {
        let values = sorted(all.iter().filter_map(|v| v[m]).collect());
        if values.len() < 5 {
            continue;
        }
        let median = quantile(&values, 0.5);
        let mad = quantile(
            &sorted(values.iter().map(|v| (v - median).abs()).collect()),
            0.5,
        );
        let scale = (1.4826 * mad).max(*floor);
        for (i, v) in all.iter().enumerate() {
            if let Some(x) = v[m] {
                let z = (x - median) / scale;
                if z.abs() > OUTLIER_Z {
                    found.push((
                        z.abs(),
                        i,
                        format!(
                            "{name} {} (median {})",
                            super::chart::short(x),
                            super::chart::short(median)
                        ),
                    ));
                }
            }
        }
    }
    found.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut out: Vec<(usize, String)> = Vec::new();
    for (_, i, why) in found {
        match out.iter().position(|(j, _)| *j == i) {
            Some(k) => out[k].1 = format!("{}; {why}", out[k].1),
            None if out.len() < limit => out.push((i, why)),
            None => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A manifest entry with the figures the outlier search reads.
    pub fn entry(index: u64, category: &str, valid: f64, max: f32, seconds: f64) -> ManifestEntry {
        let summary =
            serde_json::json!({"min": 0.5, "max": max, "mean": 3.0, "valid_fraction": valid});
        let id = format!("{index:07}");
        serde_json::from_value(serde_json::json!({
            "id": id, "category": category, "seed": 0, "index": index,
            "files": {"left": "l.png", "right": "r.png", "disp_left": "l.exr", "disp_right": "r.exr", "scene": "s.json"},
            "width": 8, "height": 6, "f_px": 10.0, "baseline_m": 0.1, "cx": 4.0, "cy": 3.0,
            "disparity_left": summary, "disparity_right": summary, "render_seconds": seconds,
            "render_timings": {"build_s": 0.5}, "sha256": {}, "stereogen_version": "0"
        }))
        .unwrap()
    }

    #[test]
    fn samples_far_from_the_rest_stand_out_and_close_ones_do_not() {
        let mut entries: Vec<ManifestEntry> = (0..40)
            .map(|i| {
                entry(
                    i,
                    "tree",
                    0.99 + 0.0002 * i as f64,
                    20.0 + 0.1 * i as f32,
                    2.0 + 0.01 * i as f64,
                )
            })
            .collect();
        assert!(
            outliers(&entries, 5).is_empty(),
            "{:?}",
            outliers(&entries, 5)
        );
        entries[7].disparity_left.as_mut().unwrap().valid_fraction = 0.4;
        entries[12].render_seconds = 60.0;
        entries[12].disparity_right.as_mut().unwrap().max = 400.0;
        let found = outliers(&entries, 5);
        assert_eq!(
            found.iter().map(|f| f.0).collect::<Vec<_>>(),
            [12, 7],
            "{found:?}"
        );
        assert!(
            found[0].1.contains("render seconds") && found[0].1.contains("largest disparity"),
            "{found:?}"
        );
        assert_eq!(outliers(&entries, 1).len(), 1);
        let rows = render_times(&entries);
        assert_eq!(rows[0], ("samples timed".to_string(), "40".to_string()));
        assert!(
            rows.iter()
                .any(|(k, v)| k == "step build_s: mean" && v == "0.500 s")
        );
    }

    #[test]
    fn the_gallery_takes_every_category_in_turn() {
        let cats = [
            "tree", "tree", "tree", "tree", "tree", "tree", "hole", "hole", "shapenet",
        ];
        let entries: Vec<ManifestEntry> = cats
            .iter()
            .enumerate()
            .map(|(i, c)| entry(i as u64, c, 1.0, 10.0, 1.0))
            .collect();
        let chosen = super::super::gallery::choose(&entries, 5);
        // Turns: each category one, then hole and tree another (shapenet has no more); tree's two spread over its range.
        assert_eq!(chosen, [0, 3, 6, 7, 8]);
        assert_eq!(super::super::gallery::choose(&entries, 99).len(), 9);
        assert_eq!(
            chosen,
            super::super::gallery::choose(&entries, 5),
            "deterministic"
        );
    }
}
