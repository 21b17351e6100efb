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

mod cost;
mod measure;
mod pick;
mod projection;
mod table;

use std::path::PathBuf;

pub use cost::{Measurement, SampleCost};
pub use measure::{MeasureProgress, SampleRun, read_costs, render_samples};
pub use pick::pick_indices;
pub use projection::{
    CategoryEstimate, EXACT_COUNT_LIMIT, Estimate, Spread, TIME_LIMIT_SAFETY, TIME_LIMIT_STEP_S,
    Target, TaskEstimate, project,
};

use crate::dataset::TaskArgs;
use crate::interrupt::StopFlag;

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
