//! `stereogen stats`: compute the report, write `stats.json` (and plots), print the summary.

use std::path::PathBuf;

use stereogen::validate::{StatsOptions, compute, plots, summary_lines, write_json};

/// Writes into `out` (default: the dataset root); with `check`, fails when any category misses
/// its target.
pub fn run(
    opts: &StatsOptions,
    out: Option<PathBuf>,
    plot: bool,
    check: bool,
) -> anyhow::Result<()> {
    let report = compute(opts)?;
    let dir = out.unwrap_or_else(|| opts.dataset.clone());
    let json = write_json(&report, &dir)?;
    for line in summary_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", json.display());
    if plot {
        for p in plots::write_plots(&report, &dir)? {
            println!("wrote {}", p.display());
        }
    }
    if opts.verify && report.errors.is_empty() {
        println!(
            "verified: every file of the {} samples matches its manifest checksum and decodes",
            report.samples
        );
    }
    // A broken or unreadable file never looks like success, with or without --check.
    if !report.errors.is_empty() {
        anyhow::bail!(
            "{} file(s) of the dataset are unreadable or fail verification (see the ERROR lines above)",
            report.errors.len()
        );
    }
    if check && !report.pass {
        anyhow::bail!(
            "stats --check: the dataset does not follow its recipe (see the FAIL and ERROR lines above)"
        );
    }
    Ok(())
}
