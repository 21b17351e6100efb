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
use stereogen::dataset::generate::{GenerateOptions, Progress, WORKER_START_TIMING};
use stereogen::dataset::{DatasetLayout, TaskArgs, generate, read_manifest};
use stereogen::farm::TimeLimit;
use stereogen::interrupt::{self, Interrupted};
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

mod projection;
pub use projection::*;

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
