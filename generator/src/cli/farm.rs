//! `stereogen farm slurm|k8s|openjd`: write the job files of a farm run.

use std::path::PathBuf;

use anyhow::Context;
use stereogen::dataset::TaskArgs;
use stereogen::dataset::export::WebDatasetArgs;
use stereogen::dataset::merge::WebDatasetTarget;
use stereogen::farm::{FarmOptions, Scheduler, TimeLimit, write_job_files};
use stereogen::render::Device;

use stereogen::estimate::{self, Estimate, Target};

use super::estimate::{SampleArgs, measure_printing_progress};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SchedulerArg {
    /// An sbatch job array, a dependent merge-and-check job, and submit.sh.
    Slurm,
    /// A batch/v1 Indexed Job, and a merge-and-check Job to apply after it.
    K8s,
    /// An Open Job Description template (jobtemplate-2023-09): Render, Merge, Check steps.
    Openjd,
}

#[derive(Debug, clap::Args)]
pub struct FarmArgs {
    /// The scheduler to write for.
    #[arg(value_enum)]
    scheduler: SchedulerArg,
    // What every task renders, passed on to its `generate` as it is (--count is the whole
    // dataset's; --threads defaults to the task's cores divided by --workers).
    #[command(flatten)]
    task: TaskArgs,
    /// Render tasks (one shard each).
    #[arg(long, value_name = "T")]
    tasks: u64,
    /// The shared output directory, as the tasks see it (absolute; Kubernetes: where the
    /// volume is mounted).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// GPUs each task asks for (Slurm --gpus-per-task, Kubernetes nvidia.com/gpu).
    #[arg(long, value_name = "G")]
    gpus_per_task: Option<u32>,
    /// CPU cores each task asks for (Slurm --cpus-per-task, Kubernetes requests.cpu, OpenJD
    /// amount.worker.vcpu) [default: workers × --threads; without --threads 8 for a CPU render, 4
    /// for a GPU render, at least one per worker]. Every task's command line names its Cycles
    /// threads (--threads, else these cores divided by --workers).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    cpus_per_task: Option<u32>,
    /// Memory each task asks for (Slurm: 16G; Kubernetes: 16Gi).
    #[arg(long, value_name = "SIZE")]
    memory: Option<String>,
    /// Wall-time limit of a task, in Slurm's forms (12:00:00, 1-06:00:00, 90 = minutes): Slurm
    /// --time, Kubernetes activeDeadlineSeconds of a pod, OpenJD action timeout; the merge step
    /// gets it too [default: with --estimate, 1.5 × the largest task's projected wall time plus
    /// --grace, rounded up to 5 minutes (render tasks only); without, none: the scheduler's
    /// default applies].
    #[arg(long, value_name = "TIME", value_parser = clap::value_parser!(TimeLimit))]
    time_limit: Option<TimeLimit>,
    /// Slurm partition.
    #[arg(long, value_name = "P")]
    partition: Option<String>,
    /// Container image with stereogen and its Blender environment (Kubernetes).
    #[arg(long, value_name = "IMG", default_value = "stereogen:latest")]
    image: String,
    /// PersistentVolumeClaim holding the shared output (Kubernetes).
    #[arg(long, value_name = "NAME", default_value = "stereogen-data")]
    volume_claim: String,
    /// Tasks running at once [default: all].
    #[arg(long, value_name = "M")]
    max_parallel: Option<u64>,
    /// The stereogen executable the tasks run [default: this one (Slurm, OpenJD); `stereogen`
    /// (Kubernetes, from the image's PATH)].
    #[arg(long, value_name = "PATH")]
    stereogen: Option<PathBuf>,
    /// Job name (prefix of the scheduler's job names).
    #[arg(long, value_name = "NAME", default_value = "stereogen")]
    name: String,
    /// Seconds a task has between SIGTERM and SIGKILL (Kubernetes grace period, OpenJD notify
    /// period); Slurm sends SIGTERM this long before the time limit (--signal=TERM@SECS).
    #[arg(long, value_name = "SECS", default_value_t = 120)]
    grace: u64,
    /// The merge step recomputes every checksum (merge --verify).
    #[arg(long)]
    verify: bool,
    /// The merge step also writes the merged dataset as WebDataset shards into DIR (merge
    /// --webdataset; absolute, like --out; Kubernetes: under --out), cut by --shard-size,
    /// --shuffle-seed and --splits.
    #[arg(long, value_name = "DIR")]
    webdataset: Option<PathBuf>,
    #[command(flatten)]
    shards: WebDatasetArgs,
    /// Environment of every task, KEY=VALUE (repeatable), e.g. STEREOGEN_HOME=/shared/stereogen.
    #[arg(long = "env", value_name = "KEY=VALUE", value_parser = parse_env)]
    env: Vec<(String, String)>,
    /// Where the job files go [default: OUT/jobs].
    #[arg(long, value_name = "DIR")]
    job_dir: Option<PathBuf>,
    /// First render --sample K of the run's samples here (as `stereogen estimate` does), print
    /// the run's cost for --count and --tasks (per task: samples, wall time, core-hours), write
    /// it as JOB_DIR/estimate.json, and set the time limit from it when --time-limit is not given.
    /// Without it nothing is rendered and the files are written at once.
    #[arg(long)]
    estimate: bool,
    #[command(flatten)]
    sampling: SampleArgs,
}

fn parse_env(s: &str) -> Result<(String, String), String> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?} is not KEY=VALUE"))?;
    Ok((k.to_string(), v.to_string()))
}

pub fn run(a: FarmArgs) -> anyhow::Result<()> {
    if a.webdataset.is_none() && !a.shards.is_default() {
        anyhow::bail!("--shard-size, --shuffle-seed and --splits need --webdataset DIR");
    }
    let scheduler = match a.scheduler {
        SchedulerArg::Slurm => Scheduler::Slurm,
        SchedulerArg::K8s => Scheduler::Kubernetes,
        SchedulerArg::Openjd => Scheduler::OpenJd,
    };
    let stereogen = match (a.stereogen, scheduler) {
        (Some(p), _) => p,
        (None, Scheduler::Kubernetes) => PathBuf::from("stereogen"),
        (None, _) => std::env::current_exe()
            .context("cannot find this stereogen executable; pass --stereogen PATH")?,
    };
    let measure_task = a.task.clone();
    let mut opts = FarmOptions {
        recipe: a.task.recipe.load()?,
        task: a.task,
        tasks: a.tasks,
        job_dir: a.job_dir.unwrap_or_else(|| a.out.join("jobs")),
        out: a.out,
        gpus_per_task: a.gpus_per_task,
        cpus_per_task: a.cpus_per_task,
        memory: a.memory,
        time_limit: a.time_limit,
        merge_time_limit: a.time_limit,
        partition: a.partition,
        image: a.image,
        volume_claim: a.volume_claim,
        max_parallel: a.max_parallel,
        stereogen,
        name: a.name,
        grace_s: a.grace,
        verify: a.verify,
        webdataset: a.webdataset.map(|dir| WebDatasetTarget {
            dir,
            shards: a.shards,
            force: false,
        }),
        env: a.env,
    };
    let estimate = if a.estimate {
        opts.check()?;
        Some(farm_estimate(&mut opts, measure_task, &a.sampling)?)
    } else {
        None
    };
    let files = write_job_files(&opts, scheduler)?;
    for f in &files {
        println!("wrote {}", f.display());
    }
    if let Some(e) = estimate {
        let path = opts.job_dir.join("estimate.json");
        std::fs::write(&path, serde_json::to_string_pretty(&e)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    println!("a render task asks for {}", opts.resources());
    let first = files[0].display();
    match scheduler {
        Scheduler::Slurm => println!("submit: bash {first}"),
        Scheduler::Kubernetes => println!(
            "submit: kubectl apply -f {first}; when it is complete: kubectl apply -f {}",
            files[1].display()
        ),
        Scheduler::OpenJd => println!(
            "check: openjd check {first}; run locally: openjd run {first} --step Check --run-dependencies"
        ),
    }
    println!("watch: stereogen status {}", opts.out.display());
    Ok(())
}

/// `--estimate`: measures here with the task's workers (at most one per core here) and this
/// machine's cores, projects onto the farm's tasks and their cores (or GPUs), prints it, and sets
/// the render tasks' time limit when none was given.
fn farm_estimate(
    opts: &mut FarmOptions,
    mut task: stereogen::dataset::TaskArgs,
    sampling: &SampleArgs,
) -> anyhow::Result<Estimate> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    task.workers = task.workers.clamp(1, cores);
    task.runtime.threads = None;
    let m = measure_printing_progress(&task, sampling)?;
    let units = match opts.task.runtime.device {
        Device::Cpu => f64::from(opts.cpus()),
        Device::Gpu => f64::from(opts.gpus().unwrap_or(1)),
    };
    let target = Target {
        tasks: opts.tasks,
        workers: opts.task.workers,
        units,
    };
    let mut e = estimate::project(
        &m,
        &opts.recipe,
        opts.task.seed,
        opts.task.start,
        opts.task.count,
        target,
    );
    if opts.time_limit.is_none() {
        opts.time_limit = Some(e.set_time_limit(opts.grace_s));
    }
    print!("{}", e.text());
    Ok(e)
}
