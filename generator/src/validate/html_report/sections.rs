//! The page's sections built from the statistics and the audit: table rows as display strings
//! and the charts as SVG.

use super::chart::{BarChart, short};
use crate::plan::Dist;
use crate::validate::audit::AuditReport;
use crate::validate::hist::{UniformHist, law_density};
use crate::validate::stats::stats_report::{Band, CategoryStats, StatsReport, Status};

/// One category of `stats` as a table row.
pub struct StatsRow {
    pub name: String,
    pub status: &'static str,
    pub samples: u64,
    pub objects: usize,
    pub ks: String,
    pub gap: String,
    pub pixels: String,
    pub invalid: String,
    pub problems: String,
}

pub struct StatsSection {
    pub law: String,
    pub verdict: &'static str,
    pub rows: Vec<StatsRow>,
    /// Per category (then overall): the object-level and the pixel-level chart.
    pub charts: Vec<(String, String, String)>,
    pub coverage: Vec<String>,
}

fn status(s: Status) -> &'static str {
    match s {
        Status::Ok => "OK",
        Status::Fail => "FAIL",
        Status::Skip => "SKIP",
    }
}

fn row(c: &CategoryStats) -> StatsRow {
    let ks = match (c.objects.ks_distance, c.objects.ks_critical) {
        (Some(d), Some(k)) => format!("{d:.4} {} {k:.4}", if d > k { ">" } else { "≤" }),
        _ => "-".into(),
    };
    let p = c.pixels.as_ref();
    StatsRow {
        name: c.name.clone(),
        status: status(c.status),
        samples: c.samples,
        objects: c.objects.count,
        ks,
        gap: p
            .and_then(|p| p.gap_check.as_ref())
            .map_or("-".into(), |g| {
                format!("{} of {} empty", g.empty.len(), g.bins)
            }),
        pixels: p
            .and_then(|p| p.percentiles.as_ref())
            .map_or("-".into(), |q| {
                format!("{:.2} / {:.2} / {:.2}", q.p1, q.p50, q.p99)
            }),
        invalid: p.map_or("-".into(), |p| {
            format!("{:.1}%", 100.0 * p.invalid_fraction)
        }),
        problems: c.problems.join("; "),
    }
}

/// A histogram as densities against the law's density over its support.
fn density_chart(title: &str, h: &UniformHist, law: &Dist, fill: &'static str) -> String {
    let n = h.total().max(1) as f64;
    let w = h.bin_width();
    let curve = law_density(law, h.lo, h.hi, 200);
    let top = h
        .counts
        .iter()
        .map(|&c| c as f64 / (n * w))
        .chain(curve.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    let mut chart = BarChart::new(title, "disparity (px)", (h.lo, h.hi), top);
    for (k, &c) in h.counts.iter().enumerate() {
        let a = h.lo + k as f64 * w;
        chart.bar(
            a,
            a + w,
            c as f64 / (n * w),
            fill,
            format!("[{}, {}): {c}", short(a), short(a + w)),
        );
    }
    chart.curve(&curve, "recipe's law");
    chart.svg()
}

fn coverage_chart(title: &str, bands: &[Band]) -> String {
    let mut chart = BarChart::new(
        title,
        "position in the image (0 = left / top)",
        (0.0, 1.0),
        1.0,
    );
    for b in bands {
        chart.bar(
            b.from,
            b.to,
            b.content_fraction,
            "#2e86c1",
            format!(
                "[{:.2}, {:.2}): content {:.1}%, valid {:.1}%",
                b.from,
                b.to,
                100.0 * b.content_fraction,
                100.0 * b.valid_fraction
            ),
        );
    }
    let points: Vec<(f64, f64)> = bands
        .iter()
        .map(|b| (0.5 * (b.from + b.to), b.valid_fraction))
        .collect();
    chart.curve(&points, "valid fraction (bars: content)");
    chart.svg()
}

pub fn stats_section(s: &StatsReport) -> StatsSection {
    let groups: Vec<&CategoryStats> = s
        .categories
        .iter()
        .chain(std::iter::once(&s.overall))
        .collect();
    let charts = groups
        .iter()
        .filter(|c| c.samples > 0)
        .map(|c| {
            let objects = c.objects.histogram.as_ref().map_or(String::new(), |h| {
                density_chart(
                    &format!("{}: objects ({})", c.name, c.objects.count),
                    h,
                    &s.law,
                    "#7fb3d5",
                )
            });
            let pixels = c.pixels.as_ref().map_or(String::new(), |p| {
                density_chart(
                    &format!("{}: valid pixels in the law's range", c.name),
                    &p.histogram,
                    &s.law,
                    "#82e0aa",
                )
            });
            (c.name.clone(), objects, pixels)
        })
        .collect();
    let coverage = s.overall.pixels.as_ref().map_or(Vec::new(), |p| {
        vec![
            coverage_chart("rows (top to bottom)", &p.rows),
            coverage_chart("columns (left to right)", &p.cols),
        ]
    });
    StatsSection {
        law: format!(
            "{} on [{}, {}] px",
            serde_json::to_string(&s.law).unwrap_or_default(),
            short(s.law_support[0]),
            short(s.law_support[1])
        ),
        verdict: if s.pass { "PASS" } else { "FAIL" },
        rows: groups.iter().map(|c| row(c)).collect(),
        charts,
        coverage,
    }
}

pub struct AuditRow {
    pub name: String,
    pub status: &'static str,
    pub samples: usize,
    pub pixels: u64,
    pub within_0_01: String,
    pub within_0_5: String,
    pub max_error: String,
    pub silhouette: String,
    pub flying: u64,
    pub lr: String,
    pub checksums: u64,
    pub not_audited: u64,
}

pub struct AuditSection {
    pub verdict: &'static str,
    pub summary: String,
    pub rows: Vec<AuditRow>,
    pub worst: Vec<String>,
    pub failing: Vec<String>,
}

fn pct(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{:.4}%", 100.0 * v))
}

pub fn audit_section(a: &AuditReport) -> AuditSection {
    let rows = a
        .categories
        .iter()
        .chain(std::iter::once(&a.overall))
        .map(|g| AuditRow {
            name: g.name.clone(),
            status: if g.pass { "OK" } else { "FAIL" },
            samples: g.samples,
            pixels: g.tally.pixels,
            within_0_01: pct(g.share_within_0_01),
            within_0_5: pct(g.share_within_0_5),
            max_error: format!("{:.2e}", g.tally.max_error),
            silhouette: format!(
                "{} ({}, {} disagree)",
                g.tally.silhouette,
                pct(g.silhouette_share),
                g.tally.silhouette_disagree
            ),
            flying: g.tally.flying,
            lr: pct(g.lr_share_within_0_1),
            checksums: g.checksum_mismatches,
            not_audited: g.problems,
        })
        .collect();
    let worst = a
        .worst
        .iter()
        .take(10)
        .map(|w| {
            format!(
                "{:.3e} px ({:?}): sample {} ({}), {} view, pixel ({}, {})",
                w.error, w.kind, w.sample, w.category, w.view, w.x, w.y
            )
        })
        .collect();
    let failing = a
        .samples
        .iter()
        .filter(|s| !s.pass)
        .take(50)
        .map(|s| {
            format!(
                "{} ({}): {}",
                s.id,
                s.category,
                s.reasons(&a.bars).join("; ")
            )
        })
        .collect();
    let per_mpx = a.cast_seconds_per_megapixel.map_or(String::new(), |s| {
        format!(", {s:.1} s of ray casting per megapixel")
    });
    AuditSection {
        verdict: if a.pass { "PASS" } else { "FAIL" },
        summary: format!(
            "{} of {} samples, {} per sample, seed {}; bars: ≥ {}% of non-silhouette pixels within 0.01 px, ≤ {} flying pixels, ≤ {} checksum mismatches{per_mpx}",
            a.samples.len(),
            a.manifest_samples,
            a.pixels_per_sample(),
            a.seed,
            100.0 * a.bars.min_share_within_0_01,
            a.bars.max_flying,
            a.bars.max_checksum_mismatches
        ),
        rows,
        worst,
        failing,
    }
}
