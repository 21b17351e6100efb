//! `stereogen estimate`: the arguments, a call into [`stereogen::estimate`], and what it prints.
//! `farm --estimate` measures the same way ([`SampleArgs`], [`measure_printing_progress`]).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use stereogen::dataset::TaskArgs;
use stereogen::dataset::generate::Progress;
use stereogen::estimate::{self, MeasureProgress, Measurement, Sampling, Target};
use stereogen::interrupt;

/// Which samples are rendered to measure, and where.
#[derive(Debug, Clone, clap::Args)]
pub struct SampleArgs {
    /// Samples rendered to measure the cost: planned samples of this dataset (its recipe, --seed
    /// and range), drawn at random and spread over the recipe's categories by weight, at least
    /// one per category where K allows.
    #[arg(long = "sample", value_name = "K", default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..))]
    pub sample: u64,
    /// Seed of the draw of which samples are measured.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub sample_seed: u64,
    /// Where the measured samples are rendered: a temporary folder inside DIR, removed afterwards
    /// [default: the system's temporary folder].
    #[arg(long, value_name = "DIR")]
    pub work: Option<PathBuf>,
}

impl SampleArgs {
    fn sampling(&self) -> Sampling {
        Sampling {
            samples: self.sample,
            seed: self.sample_seed,
            work: self.work.clone(),
        }
    }
}

/// `stereogen estimate`'s arguments.
#[derive(Debug, clap::Args)]
pub struct EstimateArgs {
    /// The dataset to estimate (--count N of --recipe R with --seed S), and how the samples are
    /// rendered here (--workers, --threads, --device, ...), as `generate` takes them.
    #[command(flatten)]
    pub task: TaskArgs,
    #[command(flatten)]
    pub sampling: SampleArgs,
    /// Tasks the run is split into: each pays the per-task start-up once; the largest task's
    /// samples and wall time are printed.
    #[arg(long, value_name = "T", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub tasks: u64,
    /// Print the estimate as JSON (on stdout; progress stays on stderr).
    #[arg(long)]
    pub json: bool,
}

/// [`estimate::measure`], stoppable by SIGINT/SIGTERM, its progress on stderr.
pub fn measure_printing_progress(
    task: &TaskArgs,
    sampling: &SampleArgs,
) -> anyhow::Result<Measurement> {
    let stop = interrupt::install()?;
    let n = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    estimate::measure(task, &sampling.sampling(), stop, &|event| match event {
        MeasureProgress::Rendering {
            recipe,
            indices,
            workers,
            threads,
            folder,
        } => {
            n.store(indices.len(), Ordering::SeqCst);
            eprintln!(
                "stereogen estimate: rendering {} sample(s) of {recipe} (indices {indices:?}) with {workers} worker(s) × {threads} thread(s) in {}",
                indices.len(),
                folder.display()
            );
        }
        MeasureProgress::Sample(Progress::Rendered { index, seconds }) => {
            let k = done.fetch_add(1, Ordering::SeqCst) + 1;
            let n = n.load(Ordering::SeqCst);
            eprintln!("stereogen estimate: sample {index} rendered in {seconds:.1} s ({k}/{n})");
        }
        MeasureProgress::Sample(Progress::Failed { id, error, .. }) => {
            done.fetch_add(1, Ordering::SeqCst);
            eprintln!("stereogen estimate: sample {id} failed: {error}");
        }
        MeasureProgress::Sample(Progress::Started { .. }) => {}
    })
}

/// `stereogen estimate`.
pub fn run(a: EstimateArgs) -> anyhow::Result<()> {
    let recipe = a.task.recipe.load()?;
    let m = measure_printing_progress(&a.task, &a.sampling)?;
    let target = Target::like(&m, a.tasks);
    let e = estimate::project(&m, &recipe, a.task.seed, a.task.start, a.task.count, target);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print!("{}", e.text());
    }
    Ok(())
}
