//! What a dataset will cost, measured by rendering a few of its own planned samples through the
//! library's [`generate`](crate::dataset::generate) (the same call `stereogen generate` makes,
//! into a temporary dataset that is removed afterwards), then projected onto the whole run.
//! `stereogen estimate` and `stereogen farm ... --estimate` are its two callers.
//!
//! Measuring is three steps, each its own function:
//! 1. **pick** ([`pick_indices`]): which samples. They are samples of the dataset asked for
//!    (same recipe, seed and range), drawn at random (a sample seed) and spread over the
//!    recipe's categories by weight, at least one each.
//! 2. **run** ([`render_samples`]): render them with the task's workers into a temporary dataset.
//! 3. **read** ([`read_costs`]): from each sample's manifest line come its wall time, the
//!    worker's own stage times, its files and their sizes:
//!    - **Worker start-up** (Blender start and `import bpy`) is a per-task cost: a worker starts
//!      lazily inside its first sample, whose timings say so
//!      ([`WORKER_START_TIMING`](crate::render::protocol::WORKER_START_TIMING); from a worker
//!      that does not, the first sample's time not covered by its stages, less the usual
//!      uncovered rest of a sample); it is taken out of the sample.
//!    - **Per-task fixed time** is the run's wall time not spent on samples (asset index,
//!      opening the dataset, worker start-up, shutdown).
//!    - A sample's time is split into its **parallel part** (the colour and depth renders, which
//!      Cycles spreads over threads) and its **serial part** (scene build, saving, writing and
//!      checking files).
//!
//! [`project`] then carries a [`Measurement`] to a [`Target`]: projected to `c` cores per worker
//! the parallel part scales by `cores here / c` (Cycles' near-linear thread scaling), the serial
//! part does not; core-hours are wall hours × cores asked for (GPU-hours: × GPUs), so a serial
//! part costs more core-hours on a wider task. Per category: the projected sample count (the
//! exact count of the range where it is at most [`EXACT_COUNT_LIMIT`], else from the weights),
//! core-hours with the standard error of the mean over the measured samples (categories measured
//! once borrow the pooled relative spread), and the output files and bytes (per-sample files and
//! manifest line; per task `dataset.json` and its manifest; with more than one task, the merged
//! manifest).

mod measure;
mod pick;
mod projection;
mod table;

use std::path::PathBuf;

use serde::Serialize;

pub use measure::{MeasureProgress, SampleRun, read_costs, render_samples};
pub use pick::pick_indices;
pub use projection::{CategoryEstimate, Estimate, Spread, Target, TaskEstimate, project};

use crate::dataset::TaskArgs;
use crate::interrupt::StopFlag;
use crate::render::Device;

/// Ranges up to this many samples get their categories counted exactly (planning a sample's
/// category is a hash and a draw); longer ones are split by the weights.
pub const EXACT_COUNT_LIMIT: u64 = 5_000_000;
/// A time limit set from an estimate is this many times the largest task's projected wall time
/// (plus the grace period), rounded up to [`TIME_LIMIT_STEP_S`]: room for slower cores, a busy
/// shared filesystem and scenes costlier than the few measured.
pub const TIME_LIMIT_SAFETY: f64 = 1.5;
pub const TIME_LIMIT_STEP_S: u64 = 300;

/// Which samples are rendered to measure, and where (what `--sample`, `--sample-seed` and
/// `--work` say).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sampling {
    /// How many planned samples to render.
    pub samples: u64,
    /// Seed of the draw of which samples.
    pub seed: u64,
    /// Where the temporary dataset goes; `None`: the system's temporary folder.
    pub work: Option<PathBuf>,
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

/// Picks, renders and reads: the three steps in order (see the module docs). `stop` ends the
/// render early (the call then fails with [`Interrupted`](crate::interrupt::Interrupted));
/// `progress` hears what is rendered.
pub fn measure(
    task: &TaskArgs,
    sampling: &Sampling,
    stop: StopFlag,
    progress: &(dyn Fn(MeasureProgress<'_>) + Sync),
) -> anyhow::Result<Measurement> {
    let recipe = task.recipe.load()?;
    if task.count == 0 {
        anyhow::bail!("--count must be at least 1");
    }
    let indices = pick_indices(
        &recipe,
        task.seed,
        task.start,
        task.count,
        sampling.samples,
        sampling.seed,
    );
    let work = sampling.work.clone().unwrap_or_else(std::env::temp_dir);
    let run = render_samples(task, recipe, &indices, &work, stop, progress)?;
    read_costs(&run)
    // `run` (and its temporary dataset) is removed here.
}

/// Median of `v` (0 for none).
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
