//! `stereogen audit`: arguments, a line per audited sample, the summary and the verdict.

use std::path::PathBuf;

use stereogen::validate::audit::{
    AUDIT_FILE, AuditOptions, PixelSelection, SampleAudit, SampleSelection, audit, summary_lines,
    write_json,
};

use super::RuntimeArgs;

/// Check the ground truth of generated samples against the scene geometry: Blender rebuilds each
/// audited scene and exports its evaluated triangles (no render), rays through the pixel centres
/// of both views are cast in f64, and the disparity EXRs are compared with them, and the depth,
/// normal, instance and semantic maps where the dataset has them; files are checked against the
/// manifest's SHA-256. Writes audit.json into DATASET (or --json).
#[derive(Debug, clap::Args)]
pub struct AuditArgs {
    /// Dataset directory (holds manifest.jsonl).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,
    /// How many samples to audit, spread over the categories [default: 16].
    #[arg(long, value_name = "K", conflicts_with = "all")]
    pub samples: Option<usize>,
    /// Audit every sample.
    #[arg(long)]
    pub all: bool,
    /// Pixels audited per sample (the same positions in both views) [default: 4096].
    #[arg(long, value_name = "P", conflicts_with = "every_pixel")]
    pub pixels: Option<usize>,
    /// Audit every pixel.
    #[arg(long)]
    pub every_pixel: bool,
    /// Seed of the sample and pixel choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Exit non-zero when the dataset misses a bar: fewer than 99.99% of non-silhouette pixels
    /// within 0.01 px, any flying pixel, any file changed since the manifest, any sample that
    /// cannot be audited; where it has maps, fewer than 99.99% of non-silhouette pixels with depth
    /// within 1e-4 relative, the normal within 0.5°, the instance and semantic ids equal.
    #[arg(long)]
    pub check: bool,
    /// Where to write the JSON report [default: DATASET/audit.json].
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

pub fn run(args: AuditArgs) -> anyhow::Result<()> {
    let mut opts = AuditOptions::new(&args.dataset);
    if args.all {
        opts.samples = SampleSelection::All;
    } else if let Some(k) = args.samples {
        anyhow::ensure!(k > 0, "--samples must be at least 1");
        opts.samples = SampleSelection::Count(k);
    }
    if args.every_pixel {
        opts.pixels = PixelSelection::Every;
    } else if let Some(p) = args.pixels {
        anyhow::ensure!(p > 0, "--pixels must be at least 1");
        opts.pixels = PixelSelection::Count(p);
    }
    opts.seed = args.seed;
    opts.worker_options = args.runtime.worker_options();
    let progress = |done: usize, total: usize, s: &SampleAudit| {
        let share = s
            .tally
            .share_within_0_01()
            .map_or("-".to_string(), |v| format!("{:.4}%", 100.0 * v));
        eprintln!(
            "audit: [{done}/{total}] {} {}: {} px, within 0.01 px {share}, {} silhouette, {} flying{}",
            if s.pass { "ok  " } else { "FAIL" },
            s.id,
            s.tally.pixels,
            s.tally.silhouette,
            s.tally.flying,
            if s.problems.is_empty() {
                String::new()
            } else {
                format!(" -- {}", s.problems.join("; "))
            }
        );
    };
    let report = audit(&opts, &progress)?;
    let path = args.json.unwrap_or_else(|| args.dataset.join(AUDIT_FILE));
    write_json(&report, &path)?;
    for line in summary_lines(&report) {
        println!("{line}");
    }
    println!("wrote {}", path.display());
    if args.check && !report.pass {
        anyhow::bail!("audit --check: the ground truth misses a bar (see the FAIL lines above)");
    }
    Ok(())
}
