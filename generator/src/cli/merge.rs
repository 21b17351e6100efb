//! `stereogen merge OUT`: one dataset over a farm's shards, or a line per problem; with
//! `--webdataset DIR`, also that dataset as WebDataset shards.

use std::path::PathBuf;

use stereogen::dataset::export::WebDatasetArgs;
use stereogen::dataset::merge::{MergeOptions, WebDatasetTarget, merge};

#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The farm's shared output directory (holds shards/).
    #[arg(value_name = "OUT")]
    out: PathBuf,
    /// Recompute every file's SHA-256 [default: sizes of every file, checksums of a sample].
    #[arg(long)]
    verify: bool,
    /// After a merge without problems, write the merged dataset as WebDataset shards into DIR,
    /// as `export --format webdataset` does (a killed run resumes them when re-run; a merge with
    /// problems writes nothing there).
    #[arg(long, value_name = "DIR")]
    webdataset: Option<PathBuf>,
    #[command(flatten)]
    shards: WebDatasetArgs,
    /// With --webdataset: replace the export already in DIR.
    #[arg(long, requires = "webdataset")]
    force: bool,
}

pub fn run(a: MergeArgs) -> anyhow::Result<()> {
    if a.webdataset.is_none() && !a.shards.is_default() {
        anyhow::bail!("--shard-size, --shuffle-seed, --splits and --where need --webdataset DIR");
    }
    let t0 = std::time::Instant::now();
    let report = merge(&MergeOptions {
        out: a.out.clone(),
        verify: a.verify,
        webdataset: a.webdataset.clone().map(|dir| WebDatasetTarget {
            dir,
            shards: a.shards.clone(),
            force: a.force,
        }),
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
    if let (Some(s), Some(dir)) = (&report.webdataset, &a.webdataset) {
        println!(
            "wrote {} sample(s) as {} WebDataset shard(s), {} bytes ({} kept from an interrupted run) -> {}",
            s.samples,
            s.shards,
            s.bytes,
            s.resumed_shards,
            dir.display()
        );
    }
    Ok(())
}
