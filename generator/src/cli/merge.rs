//! `stereogen merge OUT`: one dataset over a farm's shards, or a line per problem.

use std::path::PathBuf;

use stereogen::dataset::merge::{MergeOptions, merge};

#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The farm's shared output directory (holds shards/).
    #[arg(value_name = "OUT")]
    out: PathBuf,
    /// Recompute every file's SHA-256 [default: sizes of every file, checksums of a sample].
    #[arg(long)]
    verify: bool,
}

pub fn run(a: MergeArgs) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    let report = merge(&MergeOptions {
        out: a.out.clone(),
        verify: a.verify,
    })?;
    for note in &report.notes {
        eprintln!("note: {note}");
    }
    for problem in &report.problems {
        println!("problem: {problem}");
    }
    if !report.problems.is_empty() {
        anyhow::bail!(
            "merge: {} problem(s) in {}; nothing written",
            report.problems.len(),
            a.out.display()
        );
    }
    println!(
        "merged {} samples of {} shards into {} ({} files checked, {} checksums recomputed, {:.1} s)",
        report.samples,
        report.shards,
        a.out
            .join(stereo_io::datasets::stereogen::MANIFEST_FILE)
            .display(),
        report.files_checked,
        report.files_hashed,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
