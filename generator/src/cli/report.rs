//! `stereogen report`: one self-contained HTML page about a dataset.

use std::path::PathBuf;

use stereogen::validate::html_report::{DEFAULT_THUMBNAILS, ReportOptions, write_report};

/// One self-contained HTML file about DATASET (no script, no network): recipe and fingerprint,
/// samples per category, failures, render times, the disparity distribution against the
/// recipe's law, row/column coverage, the audit's results (when audit.json exists), a gallery and
/// the samples that stand out. Problems with the dataset are listed on the page.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Dataset directory (holds manifest.jsonl).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,
    /// Where to write the page [default: DATASET/report.html].
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Samples in the gallery (at most 200).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_THUMBNAILS)]
    pub thumbnails: usize,
}

pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let out = args.out.unwrap_or_else(|| args.dataset.join("report.html"));
    let summary = write_report(&ReportOptions {
        dataset: args.dataset,
        out,
        thumbnails: args.thumbnails,
    })?;
    println!(
        "wrote {} ({:.1} KiB in {:.2} s: {} samples, {} in the gallery, {} standing out, {} problem(s) listed)",
        summary.path.display(),
        summary.bytes as f64 / 1024.0,
        summary.seconds,
        summary.samples,
        summary.gallery,
        summary.outliers,
        summary.problems
    );
    Ok(())
}
