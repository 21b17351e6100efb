//! `stereogen estimate` (and `farm ... --estimate`): what a dataset will cost, measured by
//! rendering a few of its own planned samples through the library's `generate` (the same call
//! `stereogen generate` makes, into a temporary dataset that is removed afterwards).
//!
//! The measured samples are samples of the dataset asked for (same recipe, seed and range),
//! drawn at random (`--sample-seed`) and spread over the recipe's categories by weight, at least
//! one each. From each sample's manifest line come its wall time, the worker's own stage times,
//! its files and their sizes:
//! - **Worker start-up** (Blender start and `import bpy`) is a per-task cost: a worker starts
//!   lazily inside its first sample, whose timings say so (`worker_start_s`; from a worker that
//!   does not, the first sample's time not covered by its stages, less the usual uncovered rest
//!   of a sample); it is taken out of the sample.
//! - **Per-task fixed time** is the run's wall time not spent on samples (asset index, opening
//!   the dataset, worker start-up, shutdown).
//! - A sample's time is split into its **parallel part** (the colour and depth renders, which
//!   Cycles spreads over threads) and its **serial part** (scene build, saving, writing and
//!   checking files). Projected to `c` cores per worker the parallel part scales by
//!   `cores here / c` (Cycles' near-linear thread scaling), the serial part does not;
//!   core-hours are wall hours × cores asked for (GPU-hours: × GPUs), so a serial part costs more
//!   core-hours on a wider task.
//!
//! Per category: the projected sample count (the exact count of the range where it is at most
//! [`EXACT_COUNT_LIMIT`], else from the weights), core-hours with the standard error of the mean
//! over the measured samples (categories measured once borrow the pooled relative spread), and
//! the output files and bytes (per-sample files and manifest line; per task `dataset.json` and
//! its manifest; with more than one task, the merged manifest).

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use anyhow::{Context, bail};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use stereogen::dataset::generate::{GenerateOptions, Progress};
use stereogen::dataset::interrupt::{self, Interrupted};
use stereogen::dataset::{DatasetLayout, TaskArgs, generate, read_manifest};
use stereogen::farm::TimeLimit;
use stereogen::plan::{Recipe, scene_category};
use stereogen::render::Device;

/// Ranges up to this many samples get their categories counted exactly (planning a sample's
/// category is a hash and a draw); longer ones are split by the weights.
pub const EXACT_COUNT_LIMIT: u64 = 5_000_000;
/// A time limit set from an estimate is this many times the largest task's projected wall time
/// (plus the grace period), rounded up to [`TIME_LIMIT_STEP_S`]: room for slower cores, a busy
/// shared filesystem and scenes costlier than the few measured.
pub const TIME_LIMIT_SAFETY: f64 = 1.5;
pub const TIME_LIMIT_STEP_S: u64 = 300;
/// The timing a sample's manifest line carries when its worker started for it.
const WORKER_START_TIMING: &str = "worker_start_s";

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

/// One measured sample.
#[derive(Debug, Clone, Serialize)]
pub struct SampleCost {
    pub index: u64,
    pub category: String,
    /// Wall seconds of the sample on one worker, worker start-up excluded.
    pub seconds: f64,
    /// The part of `seconds` in the colour and depth renders.
    pub parallel_seconds: f64,
    /// Its files (images, disparities, scene) and their bytes.
    pub files: u64,
    pub bytes: u64,
    /// Bytes of its manifest line.
    pub manifest_bytes: u64,
}

/// What rendering the samples here measured.
#[derive(Debug, Clone, Serialize)]
pub struct Measurement {
    pub samples: Vec<SampleCost>,
    /// Blender start-up of each worker (seconds), out of its first sample.
    pub worker_start_s: Vec<f64>,
    /// Wall seconds of the run not spent on samples (asset index, dataset, start-up, shutdown).
    pub task_fixed_s: f64,
    pub workers: usize,
    pub threads: u32,
    /// Cores (CPU) or GPUs one worker had here.
    pub units_per_worker: f64,
    pub device: Device,
    /// The machine: CPU model and cores (or "GPU").
    pub machine: String,
    pub worker_restarts: u32,
    pub failed: usize,
    /// Files of a dataset besides its samples' (dataset.json, manifest.jsonl) and their bytes
    /// (the manifest counted in its lines, per sample).
    pub dataset_files: u64,
    pub dataset_bytes: u64,
}

/// A wall-time stage among a sample's timings (not the CPU seconds some workers add as
/// `<stage>_cpu_s`).
fn wall_timing(key: &str) -> bool {
    !key.ends_with("_cpu_s")
}

/// Draws which samples to measure: `k` indices of `start..start+count`, spread over the
/// categories by weight (largest remainder), at least one per category of positive weight when
/// `k` allows; random, from `sample_seed`.
pub fn pick_indices(
    recipe: &Recipe,
    seed: u64,
    start: u64,
    count: u64,
    k: u64,
    sample_seed: u64,
) -> Vec<u64> {
    let k = k.min(count);
    let quotas = quotas(recipe, k);
    let mut want: BTreeMap<&str, u64> = recipe
        .categories
        .iter()
        .zip(&quotas)
        .map(|(c, &q)| (c.name.as_str(), q))
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(sample_seed);
    const DRAWS: u64 = 200_000;
    let candidates: Vec<u64> = if count <= DRAWS {
        let mut all: Vec<u64> = (start..start + count).collect();
        all.shuffle(&mut rng);
        all
    } else {
        (0..DRAWS)
            .map(|_| start + rng.random_range(0..count))
            .collect()
    };
    let mut picked = BTreeSet::new();
    let mut spare = Vec::new();
    for i in candidates {
        if picked.len() as u64 == k {
            break;
        }
        if picked.contains(&i) {
            continue;
        }
        let name = scene_category(recipe, seed, i).name.as_str();
        match want.get_mut(name) {
            Some(q) if *q > 0 => {
                *q -= 1;
                picked.insert(i);
            }
            _ if spare.len() < k as usize => spare.push(i),
            _ => {}
        }
    }
    // A category too rare to be met in the draws leaves its share to the others.
    for i in spare {
        if picked.len() as u64 >= k {
            break;
        }
        picked.insert(i);
    }
    picked.into_iter().collect()
}

/// Samples per category: one each (of positive weight) first, the rest by largest remainder.
fn quotas(recipe: &Recipe, k: u64) -> Vec<u64> {
    let weights: Vec<f64> = recipe
        .categories
        .iter()
        .map(|c| c.weight.max(0.0))
        .collect();
    let positive = weights.iter().filter(|w| **w > 0.0).count() as u64;
    let mut q = vec![0u64; weights.len()];
    let mut left = k;
    if k >= positive {
        for (q, w) in q.iter_mut().zip(&weights) {
            if *w > 0.0 {
                *q = 1;
            }
        }
        left -= positive;
    }
    let total: f64 = weights.iter().sum();
    let shares: Vec<f64> = weights.iter().map(|w| w / total * left as f64).collect();
    let mut given = 0;
    for (q, s) in q.iter_mut().zip(&shares) {
        *q += s.floor() as u64;
        given += s.floor() as u64;
    }
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| {
        let (ra, rb) = (shares[a] - shares[a].floor(), shares[b] - shares[b].floor());
        rb.total_cmp(&ra).then(a.cmp(&b))
    });
    for &i in order.iter().take((left - given) as usize) {
        q[i] += 1;
    }
    q
}

/// The CPU model and core count here, e.g. `AMD EPYC 9B14 (2 cores)`.
fn machine(device: Device) -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    match device {
        Device::Cpu => format!("{model} ({cores} cores)"),
        Device::Gpu => format!("the GPU Cycles picked, host {model} ({cores} cores)"),
    }
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

/// Renders the samples [`pick_indices`] draws through `generate` into a temporary dataset under
/// `--work`, and reads their costs back from its manifest and files.
pub fn measure(task: &TaskArgs, sampling: &SampleArgs) -> anyhow::Result<Measurement> {
    let recipe = task.recipe.load()?;
    if task.count == 0 {
        bail!("--count must be at least 1");
    }
    let indices = pick_indices(
        &recipe,
        task.seed,
        task.start,
        task.count,
        sampling.sample,
        sampling.sample_seed,
    );
    let work = sampling.work.clone().unwrap_or_else(std::env::temp_dir);
    std::fs::create_dir_all(&work).with_context(|| format!("cannot create {}", work.display()))?;
    let tmp = tempfile::Builder::new()
        .prefix("stereogen-estimate-")
        .tempdir_in(&work)
        .with_context(|| format!("cannot make a temporary folder in {}", work.display()))?;
    let out = tmp.path().join("dataset");
    let mut opts = GenerateOptions::new(&out, recipe, task.seed, task.count);
    opts.start = task.start;
    opts.workers = task.workers;
    opts.worker_options = task.runtime.worker_options();
    opts.only = Some(indices.clone());
    opts.stop = interrupt::install()?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u32;
    let workers = task.workers.max(1);
    let threads = task
        .runtime
        .threads
        .unwrap_or_else(|| (cores / workers as u32).max(1));
    eprintln!(
        "stereogen estimate: rendering {} sample(s) of {} (indices {:?}) with {workers} worker(s) × {threads} thread(s) in {}",
        indices.len(),
        opts.recipe.name,
        indices,
        tmp.path().display()
    );
    let n = indices.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let summary = generate(&opts, &|event| match event {
        Progress::Rendered { index, seconds } => {
            let k = done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
            eprintln!("stereogen estimate: sample {index} rendered in {seconds:.1} s ({k}/{n})");
        }
        Progress::Failed { id, error, .. } => {
            done.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            eprintln!("stereogen estimate: sample {id} failed: {error}");
        }
        Progress::Started { .. } => {}
    })?;
    if summary.interrupted {
        return Err(Interrupted::now().into());
    }
    let layout = DatasetLayout::new(&out);
    let manifest_path = layout.manifest();
    let entries = read_manifest(&manifest_path)?.entries;
    if entries.is_empty() {
        bail!(
            "no sample rendered ({} failed: {}); nothing to estimate from",
            summary.failed.len(),
            summary.failed.first().map_or("", |f| f.error.as_str())
        );
    }
    // Manifest lines are in the entries' order, one each.
    let raw = std::fs::read_to_string(&manifest_path)?;
    let line_bytes: Vec<u64> = raw.lines().map(|l| l.len() as u64 + 1).collect();

    // A sample that started its worker says so (`worker_start_s` among its timings); where a
    // worker does not, each worker's first sample (the queue hands out `indices` in order)
    // carries its start-up in the time its stages do not cover.
    let firsts: BTreeSet<u64> = indices.iter().copied().take(workers).collect();
    let uncovered = |e: &stereogen::dataset::ManifestEntry| {
        e.render_seconds
            - e.render_timings
                .iter()
                .filter(|(k, _)| wall_timing(k))
                .map(|(_, v)| v)
                .sum::<f64>()
    };
    let usual = median(
        &entries
            .iter()
            .filter(|e| !firsts.contains(&e.index))
            .map(uncovered)
            .collect::<Vec<_>>(),
    );
    let mut worker_start_s = Vec::new();
    let mut samples = Vec::new();
    for (e, manifest_bytes) in entries.iter().zip(line_bytes) {
        let mut seconds = e.render_seconds;
        let start = match e.render_timings.get(WORKER_START_TIMING) {
            Some(&s) => Some(s),
            None if firsts.contains(&e.index) => Some((uncovered(e) - usual).max(0.0)),
            None => None,
        };
        if let Some(start) = start {
            worker_start_s.push(start);
            seconds -= start;
        }
        let parallel_seconds: f64 = e
            .render_timings
            .iter()
            .filter(|(k, _)| wall_timing(k) && (k.starts_with("colour") || k.starts_with("depth")))
            .map(|(_, v)| v)
            .sum();
        let (mut files, mut bytes) = (0, 0);
        for (_, rel) in e.files.all() {
            let p = layout.abs(rel);
            bytes += std::fs::metadata(&p)
                .with_context(|| format!("{}", p.display()))?
                .len();
            files += 1;
        }
        samples.push(SampleCost {
            index: e.index,
            category: e.category.clone(),
            seconds,
            parallel_seconds: parallel_seconds.min(seconds),
            files,
            bytes,
            manifest_bytes,
        });
    }
    let (mut dataset_files, mut dataset_bytes) = (0, 0);
    for f in std::fs::read_dir(&out)? {
        let f = f?;
        if f.file_type()?.is_file() && !f.file_name().to_string_lossy().starts_with('.') {
            dataset_files += 1;
            if f.path() != manifest_path {
                dataset_bytes += f.metadata()?.len();
            }
        }
    }
    let busy: f64 = samples.iter().map(|s| s.seconds).sum();
    let task_fixed_s = (summary.seconds - busy / workers.min(samples.len()) as f64).max(0.0);
    let units_per_worker = match task.runtime.device {
        Device::Cpu => f64::from(threads).min(f64::from(cores) / workers as f64),
        Device::Gpu => 1.0 / workers as f64,
    };
    Ok(Measurement {
        samples,
        worker_start_s,
        task_fixed_s,
        workers,
        threads,
        units_per_worker,
        device: task.runtime.device,
        machine: machine(task.runtime.device),
        worker_restarts: summary.worker_restarts,
        failed: summary.failed.len(),
        dataset_files,
        dataset_bytes,
    })
    // `tmp` is removed here.
}

/// min / median / max / mean and the standard error of the mean.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Spread {
    pub min: f64,
    pub median: f64,
    pub max: f64,
    pub mean: f64,
    /// Standard error of the mean (`None` from one value).
    pub sem: Option<f64>,
}

impl Spread {
    fn of(v: &[f64]) -> Self {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sem = (v.len() > 1).then(|| {
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
            (var / n).sqrt()
        });
        Self {
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            median: median(v),
            max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            mean,
            sem,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CategoryEstimate {
    pub name: String,
    pub weight: f64,
    /// Samples of this category in the range.
    pub samples: u64,
    /// Samples measured.
    pub measured: usize,
    /// Measured wall seconds per sample here (worker start-up excluded).
    pub seconds: Option<Spread>,
    /// Device seconds (core- or GPU-seconds) per sample at the target's cores per worker.
    pub device_seconds: Option<Spread>,
    pub hours: f64,
    /// Standard error of `hours`.
    pub hours_sem: f64,
    pub files: u64,
    pub bytes: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TaskEstimate {
    pub tasks: u64,
    /// Samples of the largest task.
    pub samples: u64,
    pub workers: usize,
    /// Cores (CPU) or GPUs a task has.
    pub units: f64,
    /// Projected wall seconds of the largest task, and their standard error.
    pub wall_s: f64,
    pub wall_s_sem: f64,
    /// Device hours of the largest task.
    pub hours: f64,
    /// Fixed wall seconds each task pays once (included in `wall_s`).
    pub fixed_s: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Estimate {
    pub recipe: String,
    pub width: u32,
    pub height: u32,
    pub samples_per_pixel: u32,
    pub seed: u64,
    pub start: u64,
    pub count: u64,
    pub device: String,
    /// `core-hours` or `GPU-hours`.
    pub unit: String,
    pub measured: Measurement,
    /// Measured wall seconds per sample here, over every category.
    pub seconds: Spread,
    pub categories: Vec<CategoryEstimate>,
    /// Device hours of the samples, of the tasks' fixed time, and their sum.
    pub sample_hours: f64,
    pub fixed_hours: f64,
    pub hours: f64,
    pub hours_sem: f64,
    pub files: u64,
    pub bytes: u64,
    pub task: TaskEstimate,
    /// Set by `farm --estimate` when no --time-limit was given: seconds, and how.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_limit_s: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_limit_rule: Option<String>,
}

/// Where the projection goes: how many tasks, and the workers and cores (or GPUs) of each.
#[derive(Debug, Clone, Copy)]
pub struct Target {
    pub tasks: u64,
    pub workers: usize,
    /// Cores (CPU) or GPUs of a task.
    pub units: f64,
}

impl Target {
    /// A run like the measured one: its workers, with the cores they had here.
    pub fn like(m: &Measurement, tasks: u64) -> Self {
        Self {
            tasks,
            workers: m.workers,
            units: m.units_per_worker * m.workers as f64,
        }
    }
}

/// Samples per category in `start..start+count` (exactly, up to [`EXACT_COUNT_LIMIT`]).
fn category_counts(recipe: &Recipe, seed: u64, start: u64, count: u64) -> Vec<u64> {
    if count <= EXACT_COUNT_LIMIT {
        let mut n: BTreeMap<&str, u64> = BTreeMap::new();
        for i in start..start + count {
            *n.entry(scene_category(recipe, seed, i).name.as_str())
                .or_default() += 1;
        }
        recipe
            .categories
            .iter()
            .map(|c| n.get(c.name.as_str()).copied().unwrap_or(0))
            .collect()
    } else {
        let total: f64 = recipe.categories.iter().map(|c| c.weight).sum();
        recipe
            .categories
            .iter()
            .map(|c| (c.weight / total * count as f64).round() as u64)
            .collect()
    }
}

/// Projects a measurement onto `count` samples from `start` run as `target`.
pub fn project(
    m: &Measurement,
    recipe: &Recipe,
    seed: u64,
    start: u64,
    count: u64,
    target: Target,
) -> Estimate {
    let per_worker = target.units / target.workers.max(1) as f64;
    // Wall seconds of a sample on a worker of the target, and its device seconds.
    let wall = |s: &SampleCost| {
        let scale = match m.device {
            Device::Cpu => m.units_per_worker / per_worker,
            Device::Gpu => 1.0,
        };
        (s.seconds - s.parallel_seconds) + s.parallel_seconds * scale
    };
    let counts = category_counts(recipe, seed, start, count);
    // The relative spread pooled over categories measured twice or more, for those measured once.
    let mut pooled = (0.0, 0.0);
    let by_cat = |name: &str| -> Vec<&SampleCost> {
        m.samples.iter().filter(|s| s.category == name).collect()
    };
    for c in &recipe.categories {
        let v: Vec<f64> = by_cat(&c.name)
            .into_iter()
            .map(|s| wall(s) * per_worker)
            .collect();
        if v.len() > 1 {
            let sp = Spread::of(&v);
            let var = v.iter().map(|x| (x - sp.mean).powi(2)).sum::<f64>();
            pooled.0 += var / (sp.mean * sp.mean);
            pooled.1 += (v.len() - 1) as f64;
        }
    }
    // With no category measured twice, the spread over all samples (categories mixed: larger).
    let pooled_cv = if pooled.1 > 0.0 {
        Some((pooled.0 / pooled.1).sqrt())
    } else {
        let all: Vec<f64> = m.samples.iter().map(|s| wall(s) * per_worker).collect();
        let sp = Spread::of(&all);
        sp.sem.map(|sem| sem * (all.len() as f64).sqrt() / sp.mean)
    };
    let mean = |v: &[u64]| v.iter().sum::<u64>() as f64 / v.len().max(1) as f64;
    let mut categories = Vec::new();
    let (mut sample_ds, mut var_ds, mut files, mut bytes) = (0.0, 0.0, 0u64, 0u64);
    let mut manifest_bytes = 0.0;
    for (c, &n) in recipe.categories.iter().zip(&counts) {
        let measured = by_cat(&c.name);
        let pick: Vec<&SampleCost> = if measured.is_empty() {
            m.samples.iter().collect()
        } else {
            measured.clone()
        };
        let ds: Vec<f64> = pick.iter().map(|s| wall(s) * per_worker).collect();
        let sp = Spread::of(&ds);
        let sem = sp
            .sem
            .or_else(|| pooled_cv.map(|cv| cv * sp.mean / (ds.len() as f64).sqrt()))
            .unwrap_or(0.0);
        let f = mean(&pick.iter().map(|s| s.files).collect::<Vec<_>>());
        let b = mean(&pick.iter().map(|s| s.bytes).collect::<Vec<_>>());
        let mb = mean(&pick.iter().map(|s| s.manifest_bytes).collect::<Vec<_>>());
        let nf = n as f64;
        sample_ds += nf * sp.mean;
        var_ds += (nf * sem).powi(2);
        manifest_bytes += nf * mb;
        let cat_files = (nf * f).round() as u64;
        let cat_bytes = (nf * (b + mb)).round() as u64;
        files += cat_files;
        bytes += cat_bytes;
        categories.push(CategoryEstimate {
            name: c.name.clone(),
            weight: c.weight,
            samples: n,
            measured: measured.len(),
            seconds: (!measured.is_empty())
                .then(|| Spread::of(&measured.iter().map(|s| s.seconds).collect::<Vec<_>>())),
            device_seconds: (!measured.is_empty()).then_some(sp),
            hours: nf * sp.mean / 3600.0,
            hours_sem: nf * sem / 3600.0,
            files: cat_files,
            bytes: cat_bytes,
        });
    }
    // Per task: dataset.json and its manifest; more than one task: the merged manifest too.
    files += target.tasks * m.dataset_files;
    bytes += target.tasks * m.dataset_bytes;
    if target.tasks > 1 {
        files += 1;
        bytes += manifest_bytes.round() as u64;
    }
    let fixed_hours = target.tasks as f64 * m.task_fixed_s * target.units / 3600.0;
    let task_samples = count.div_ceil(target.tasks);
    let per_sample_wall = sample_ds / count as f64 / per_worker;
    let per_sample_wall_sem = var_ds.sqrt() / count as f64 / per_worker;
    let workers = target.workers.max(1) as f64;
    let task_wall = m.task_fixed_s + task_samples as f64 * per_sample_wall / workers;
    let task = TaskEstimate {
        tasks: target.tasks,
        samples: task_samples,
        workers: target.workers,
        units: target.units,
        wall_s: task_wall,
        wall_s_sem: task_samples as f64 * per_sample_wall_sem / workers,
        hours: task_wall * target.units / 3600.0,
        fixed_s: m.task_fixed_s,
    };
    Estimate {
        recipe: recipe.name.clone(),
        width: recipe.camera.width,
        height: recipe.camera.height,
        samples_per_pixel: recipe.render.samples,
        seed,
        start,
        count,
        device: m.device.to_string(),
        unit: match m.device {
            Device::Cpu => "core-hours",
            Device::Gpu => "GPU-hours",
        }
        .into(),
        seconds: Spread::of(&m.samples.iter().map(|s| s.seconds).collect::<Vec<_>>()),
        measured: m.clone(),
        categories,
        sample_hours: sample_ds / 3600.0,
        fixed_hours,
        hours: sample_ds / 3600.0 + fixed_hours,
        hours_sem: var_ds.sqrt() / 3600.0,
        files,
        bytes,
        task,
        time_limit_s: None,
        time_limit_rule: None,
    }
}

impl Estimate {
    /// The time limit of a task from this estimate: [`TIME_LIMIT_SAFETY`] × the largest task's
    /// projected wall time, plus `grace_s`, rounded up to [`TIME_LIMIT_STEP_S`].
    pub fn time_limit(&self, grace_s: u64) -> TimeLimit {
        TimeLimit::round_up(
            TIME_LIMIT_SAFETY * self.task.wall_s + grace_s as f64,
            TIME_LIMIT_STEP_S,
        )
    }

    pub fn set_time_limit(&mut self, grace_s: u64) -> TimeLimit {
        let t = self.time_limit(grace_s);
        self.time_limit_s = Some(t.seconds());
        self.time_limit_rule = Some(format!(
            "{TIME_LIMIT_SAFETY} × the largest task's projected {:.0} s + {grace_s} s grace, rounded up to {} min",
            self.task.wall_s,
            TIME_LIMIT_STEP_S / 60
        ));
        t
    }

    /// The estimate as a table.
    pub fn text(&self) -> String {
        let m = &self.measured;
        let unit = &self.unit;
        let mut out = Vec::new();
        let starts: Vec<String> = m.worker_start_s.iter().map(|s| format!("{s:.1}")).collect();
        out.push(format!(
            "estimate of {} samples of {} ({}×{} px, {} samples per pixel), seed {}, on the {}",
            self.count,
            self.recipe,
            self.width,
            self.height,
            self.samples_per_pixel,
            self.seed,
            self.device
        ));
        out.push(format!(
            "measured here: {} sample(s) with {} worker(s) × {} thread(s) on {}{}{}",
            m.samples.len(),
            m.workers,
            m.threads,
            m.machine,
            if m.failed > 0 {
                format!(", {} failed", m.failed)
            } else {
                String::new()
            },
            if m.worker_restarts > 0 {
                format!(", {} worker restart(s)", m.worker_restarts)
            } else {
                String::new()
            }
        ));
        out.push(format!(
            "per task, once: {:.1} s wall (asset index, dataset, shutdown, and worker start-up, Blender import: {} s per worker)",
            m.task_fixed_s,
            starts.join(", ")
        ));
        let t = &self.task;
        let unit_word = match m.device {
            Device::Cpu => "core(s)",
            Device::Gpu => "GPU(s)",
        };
        out.push(format!(
            "projected to {} task(s) of {} worker(s) and {} {unit_word}",
            t.tasks,
            t.workers,
            fmt_units(t.units)
        ));
        out.push(String::new());
        out.push(format!(
            "{:<12} {:>7} {:>9} {:>3}  {:<22} {:>18} {:>10} {:>11}",
            "category", "weight", "samples", "n", "s/sample min/med/max", unit, "output", "files"
        ));
        for c in &self.categories {
            let spread = c.seconds.map_or("(not measured)".to_string(), |s| {
                format!("{:.1} / {:.1} / {:.1}", s.min, s.median, s.max)
            });
            out.push(format!(
                "{:<12} {:>7.3} {:>9} {:>3}  {:<22} {:>18} {:>10} {:>11}",
                c.name,
                c.weight,
                c.samples,
                c.measured,
                spread,
                format!("{} ± {}", fmt_hours(c.hours), fmt_hours(c.hours_sem)),
                fmt_bytes(c.bytes),
                c.files
            ));
        }
        let s = &self.seconds;
        out.push(format!(
            "{:<12} {:>7} {:>9} {:>3}  {:<22} {:>18} {:>10} {:>11}",
            "total",
            "",
            self.count,
            m.samples.len(),
            format!("{:.1} / {:.1} / {:.1}", s.min, s.median, s.max),
            format!("{} ± {}", fmt_hours(self.hours), fmt_hours(self.hours_sem)),
            fmt_bytes(self.bytes),
            self.files
        ));
        out.push(String::new());
        out.push(format!(
            "{unit}: samples {} + per-task fixed time {}; ± is one standard error of the mean over the measured samples",
            fmt_hours(self.sample_hours),
            fmt_hours(self.fixed_hours)
        ));
        out.push(format!(
            "largest task: {} samples, {} ± {} wall ({} {unit})",
            t.samples,
            fmt_duration(t.wall_s),
            fmt_duration(t.wall_s_sem),
            fmt_hours(t.hours)
        ));
        if let (Some(l), Some(rule)) = (self.time_limit_s, &self.time_limit_rule) {
            out.push(format!(
                "time limit per task: {} ({rule})",
                TimeLimit(l).slurm()
            ));
        }
        if m.device == Device::Cpu
            && (t.units / t.workers.max(1) as f64 - m.units_per_worker).abs() > 1e-9
        {
            out.push(format!(
                "cores per worker {} here, {} in the projection: the colour and depth renders scaled linearly, the rest of a sample not",
                fmt_units(m.units_per_worker),
                fmt_units(t.units / t.workers.max(1) as f64)
            ));
        }
        out.join("\n") + "\n"
    }
}

fn fmt_units(u: f64) -> String {
    if (u - u.round()).abs() < 1e-9 {
        format!("{}", u.round() as u64)
    } else {
        format!("{u:.2}")
    }
}

fn fmt_hours(h: f64) -> String {
    if h >= 100.0 {
        format!("{h:.0}")
    } else if h >= 1.0 {
        format!("{h:.1}")
    } else {
        format!("{h:.3}")
    }
}

fn fmt_duration(s: f64) -> String {
    if s >= 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else if s >= 60.0 {
        format!("{:.1} min", s / 60.0)
    } else {
        format!("{s:.1} s")
    }
}

fn fmt_bytes(b: u64) -> String {
    let b = b as f64;
    for (unit, size) in [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)] {
        if b >= size {
            return format!("{:.1} {unit}", b / size);
        }
    }
    format!("{b:.0} B")
}

/// `stereogen estimate`.
pub fn run(a: EstimateArgs) -> anyhow::Result<()> {
    let recipe = a.task.recipe.load()?;
    let m = measure(&a.task, &a.sampling)?;
    let target = Target::like(&m, a.tasks);
    let e = project(&m, &recipe, a.task.seed, a.task.start, a.task.count, target);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print!("{}", e.text());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quotas_give_each_category_one_then_shares_by_weight() {
        let mut r = Recipe::preset("crestereo").unwrap();
        assert_eq!(quotas(&r, 8), vec![2, 2, 2, 2]);
        assert_eq!(quotas(&r, 2).iter().sum::<u64>(), 2);
        r.categories[0].weight = 0.7;
        for c in &mut r.categories[1..] {
            c.weight = 0.1;
        }
        assert_eq!(quotas(&r, 8), vec![4, 2, 1, 1]);
        r.categories[3].weight = 0.0;
        assert_eq!(quotas(&r, 8)[3], 0);
    }

    #[test]
    fn picked_indices_are_the_datasets_own_spread_over_categories_and_seeded() {
        let r = Recipe::preset("crestereo").unwrap();
        let a = pick_indices(&r, 3, 100, 200_000, 8, 0);
        assert_eq!(a, pick_indices(&r, 3, 100, 200_000, 8, 0));
        assert_ne!(a, pick_indices(&r, 3, 100, 200_000, 8, 1));
        assert_eq!(a.len(), 8);
        assert!(a.iter().all(|i| (100..200_100).contains(i)));
        let mut per: BTreeMap<String, usize> = BTreeMap::new();
        for &i in &a {
            *per.entry(scene_category(&r, 3, i).name.clone())
                .or_default() += 1;
        }
        assert!(per.values().all(|&n| n == 2), "{per:?}");
        // A short range: every index at most once.
        assert_eq!(pick_indices(&r, 3, 0, 5, 8, 0).len(), 5);
    }
}
