//! `stereogen curate`: the library's curation with a progress bar, a table of the flagged
//! samples and a one-line summary.

use std::path::PathBuf;

use anyhow::bail;
use stereogen::dataset::DatasetLayout;
use stereogen::dataset::curate::{
    CurateOptions, CurateReport, CurateSource, FlagRule, Pixels, curate,
};
use stereogen::dataset::shard::{ShardArg, resolve_shard};
use stereogen::interrupt::{self, Interrupted};
use stereogen::render::FaultPlan;

use super::RuntimeArgs;
use super::generate::{draw, progress_bar};

#[derive(Debug, clap::Args)]
pub struct CurateArgs {
    /// The dataset (a plain one, or a farm's merged output).
    #[arg(value_name = "DATASET")]
    dataset: PathBuf,
    /// Per-sample scores of DATASET from `crestereo score`.
    #[arg(
        long,
        value_name = "FILE",
        required_unless_present = "from_log",
        conflicts_with = "from_log"
    )]
    scores: Option<PathBuf>,
    /// Flag a sample whose Bad-2 (percentage of pixels more than 2 px off) is above this
    /// (FoundationStereo's rule for its FSD data: 60).
    #[arg(long, value_name = "PERCENT", default_value_t = FlagRule::DEFAULT_MAX_BAD2)]
    max_bad2: f64,
    /// Which pixels' Bad-2 the rule reads: every valid pixel, or the non-occluded ones.
    #[arg(long, value_enum, default_value_t = Pixels::All)]
    pixels: Pixels,
    /// Replace each flagged sample by a newly rendered one of its category, at an index drawn
    /// from (seed, its index, the round): the dataset keeps its size, `curation.jsonl` and
    /// `dataset.json` record the round. A killed run continues when re-run.
    #[arg(long)]
    replace: bool,
    /// Re-make the curation of another dataset of the same recipe and seed: replay every round
    /// of its curation.jsonl (the same samples replaced by the same new ones).
    #[arg(long, value_name = "CURATION_JSONL")]
    from_log: Option<PathBuf>,
    /// With --replace, as one task of a farm: render only the replacements with index % N == K
    /// into the round's shards/KKKK-of-NNNN/ (`auto`: K and N from the scheduler, as `generate
    /// --shard auto`). The first task to start plans the round; once every task finished, the
    /// same command without --shard commits it.
    #[arg(long, value_name = "K/N|auto", requires = "replace", value_parser = clap::value_parser!(ShardArg))]
    shard: Option<ShardArg>,
    /// Blender worker processes rendering replacements in parallel.
    #[arg(long, value_name = "K", default_value_t = 1)]
    workers: usize,
    #[command(flatten)]
    runtime: RuntimeArgs,
    /// Take the dataset's lock even if another process seems to hold it.
    #[arg(long)]
    break_lock: bool,
    /// Hide the progress bar.
    #[arg(long)]
    no_progress: bool,
    /// Also write what was found and done as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Test hook, as `generate`'s.
    #[arg(long = "test-fault", env = "STEREOGEN_FAULT", hide = true, value_name = "FAULTS", value_parser = clap::value_parser!(FaultPlan))]
    fault: Option<FaultPlan>,
}

/// The most flagged samples printed one per line.
const LISTED: usize = 40;

pub fn run(a: CurateArgs) -> anyhow::Result<()> {
    let source = match (&a.scores, &a.from_log) {
        (Some(path), _) => CurateSource::Scores {
            path: path.clone(),
            rule: FlagRule {
                max_bad2: a.max_bad2,
                pixels: a.pixels,
            },
        },
        (None, Some(log)) => CurateSource::Log(log.clone()),
        (None, None) => unreachable!("clap requires one of the two"),
    };
    let replace = a.replace || a.from_log.is_some();
    let opts = CurateOptions {
        dataset: a.dataset.clone(),
        source,
        replace,
        workers: a.workers,
        worker_options: a.runtime.worker_options(),
        stop: if replace {
            interrupt::install()?
        } else {
            Default::default()
        },
        break_lock: a.break_lock,
        faults: a.fault.clone().unwrap_or_default(),
        shard: match a.shard {
            Some(arg) => {
                let detected = resolve_shard(arg, None)?;
                if arg == ShardArg::Auto {
                    tracing::info!("shard {} ({})", detected.shard, detected.source);
                }
                Some(detected.shard)
            }
            None => None,
        },
    };
    let bar = progress_bar(replace && !a.no_progress);
    let outcome = curate(&opts, &|event| draw(&bar, event));
    bar.finish_and_clear();
    let report = outcome?;
    print_report(&a, &report, replace);
    if let Some(path) = &a.json {
        stereo_io::write_bytes_atomically(path, serde_json::to_string_pretty(&report)?.as_bytes())?;
    }
    if let Some(s) = &report.render {
        if s.interrupted {
            return Err(Interrupted::now().into());
        }
        if !s.failed.is_empty() {
            bail!(
                "{} replacement(s) failed; the round stays open: re-run the same command to retry them",
                s.failed.len()
            );
        }
    }
    Ok(())
}

fn print_report(a: &CurateArgs, r: &CurateReport, replace: bool) {
    if a.scores.is_some() {
        println!(
            "{} of {} scored samples flagged by {} ({} unscored)",
            r.flagged.len(),
            r.scored,
            r.rule,
            r.unscored
        );
    }
    for f in r.flagged.iter().take(LISTED) {
        println!("  {:>16}  {:<14} {:6.1}", f.id, f.category, f.score);
    }
    if r.flagged.len() > LISTED {
        println!("  … and {} more", r.flagged.len() - LISTED);
    }
    if !replace {
        if !r.flagged.is_empty() {
            println!("re-run with --replace to render a replacement for each");
        }
        return;
    }
    let log = DatasetLayout::new(&a.dataset).curation_log();
    match (r.rounds.as_slice(), &r.render) {
        ([], None) => println!("nothing to replace"),
        ([], Some(s)) if a.shard.is_some() => println!(
            "this task's part of the round: {} replacement(s) rendered, {} already there; once every task finished, commit the round with the same command without --shard",
            s.rendered, s.skipped
        ),
        ([], Some(_)) => println!("the round is not finished; re-run the same command"),
        (rounds, render) => println!(
            "curation round(s) {} finished: {} replacement(s) rendered, {} kept from an interrupted run; recorded in {}",
            rounds
                .iter()
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join(", "),
            render.as_ref().map_or(0, |s| s.rendered),
            render.as_ref().map_or(0, |s| s.skipped),
            log.display()
        ),
    }
}
