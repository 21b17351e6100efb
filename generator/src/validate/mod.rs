//! Proof that a dataset follows its recipe: `stereogen stats DATASET`.
//!
//! - [`stats`]: reads the recipe, manifest and SceneSpecs (object-level sample of the disparity
//!   law) and streams every disparity EXR in parallel (pixel level); [`compute`] gives a
//!   [`StatsReport`] (`stats/stats_report.rs`), written as `stats.json`. A category fails when
//!   the Kolmogorov–Smirnov distance between its object targets and the law exceeds the critical
//!   value at its level (the KS tests are one family at `--ks-alpha`, `stats/ks_family.rs`), or
//!   when an equal-mass bin of the law inside its support gets no valid pixel (a gap); see
//!   [`hist::gap_bins_for`] for how many bins the sample size allows.
//! - [`dataset_files`]: our folder layout or a WebDataset export of it, detected; `stats` and
//!   `report` read either.
//! - [`hist`], [`accumulate`]: histograms, percentiles and the streaming accumulators.
//! - [`plots`], [`map_plots`]: PNG plots (`--plot`).
//! - [`audit`]: `stereogen audit`: the ground truth re-derived from the scene geometry by ray casting.
//! - [`html_report`]: `stereogen report`: one self-contained HTML page about a dataset.

pub mod accumulate;
pub mod audit;
pub mod contact_sheet;
pub mod dataset_files;
pub mod hist;
pub mod html_report;
pub mod map_plots;
pub mod plots;
pub mod stats;

pub use stats::stats_report::{CategoryStats, StatsReport, Status};
pub use stats::{StatsOptions, compute, summary_lines, write_json};

/// The width of a terminal summary's name column: the longest category name, at least 3 (`all`).
pub(crate) fn name_column_width<'a>(names: impl Iterator<Item = &'a str>) -> usize {
    names.map(str::len).max().unwrap_or(3).max(3)
}
