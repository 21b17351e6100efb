//! What `crestereo eval --disturb` reports: one row per kind and level, the means of every metric
//! over the images, as JSON (inside the evaluation report), CSV and a printed table.

use std::fmt::Write as _;

use serde::Serialize;

use super::DisturbKind;
use crate::metrics::{CSV_METRICS, DisparityMetrics, metric_values};

/// The evaluation of a dataset under one disturbance of the right view.
#[derive(Debug, Clone, Serialize)]
pub struct DisturbedResult {
    pub kind: DisturbKind,
    pub level: f64,
    pub unit: &'static str,
    pub seed: u64,
    pub images: usize,
    pub failed: usize,
    pub mean_all: Option<DisparityMetrics>,
    pub mean_nonocc: Option<DisparityMetrics>,
    pub seconds_per_image: f64,
}

impl DisturbedResult {
    pub fn headline(&self) -> Option<(&'static str, DisparityMetrics)> {
        headline(self.mean_nonocc, self.mean_all)
    }
}

/// The metrics a robustness row shows: non-occluded pixels where the dataset tells them, else
/// all valid pixels (with the name of those pixels).
pub fn headline(
    nonocc: Option<DisparityMetrics>,
    all: Option<DisparityMetrics>,
) -> Option<(&'static str, DisparityMetrics)> {
    match (nonocc, all) {
        (Some(m), _) => Some(("non-occ", m)),
        (None, Some(m)) => Some(("all", m)),
        (None, None) => None,
    }
}

/// Which pixels the rows' headline metrics are on.
pub fn headline_pixels(rows: &[DisturbedResult]) -> &'static str {
    rows.iter()
        .find_map(|r| r.headline().map(|h| h.0))
        .unwrap_or("all")
}

/// One line per row: kind, level, unit, seed, images, failed, then every metric on all valid
/// pixels and on non-occluded ones (empty where the dataset has no occlusion information).
pub fn disturbance_csv(rows: &[DisturbedResult]) -> String {
    let mut s = String::from("kind,level,unit,seed,images,failed");
    for prefix in ["", "nonocc_"] {
        for m in CSV_METRICS {
            write!(s, ",{prefix}{m}").unwrap();
        }
    }
    s.push('\n');
    for r in rows {
        write!(
            s,
            "{},{},{},{},{},{}",
            r.kind.name(),
            r.level,
            r.unit,
            r.seed,
            r.images,
            r.failed
        )
        .unwrap();
        for m in [&r.mean_all, &r.mean_nonocc] {
            match m {
                Some(m) => metric_values(m)
                    .iter()
                    .for_each(|v| write!(s, ",{v:.6}").unwrap()),
                None => s.push_str(&",".repeat(CSV_METRICS.len())),
            }
        }
        s.push('\n');
    }
    s
}

/// The printed table: one line per kind and level with the headline metrics.
pub fn disturbance_table(rows: &[DisturbedResult]) -> String {
    let mut s = String::new();
    let pixels = headline_pixels(rows);
    writeln!(
        s,
        "right view disturbed ({pixels} pixels)\n{:<12}{:>8}  {:<18}{:>8}{:>9}{:>9}{:>9}{:>9}{:>8}",
        "kind", "level", "unit", "EPE", "Bad-1 %", "Bad-2 %", "D1 %", "RMS", "A95"
    )
    .unwrap();
    for r in rows {
        write!(s, "{:<12}{:>8}  {:<18}", r.kind.name(), r.level, r.unit).unwrap();
        match r.headline() {
            Some((_, m)) => writeln!(
                s,
                "{:>8.3}{:>9.2}{:>9.2}{:>9.2}{:>9.3}{:>8.3}",
                m.epe, m.bad_1, m.bad_2, m.d1, m.rms, m.a95
            )
            .unwrap(),
            None => writeln!(s, "  (no image evaluated)").unwrap(),
        }
    }
    s
}
