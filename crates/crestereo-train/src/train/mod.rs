//! The training loop: micro-batches from the [`Loader`], the sequence loss with a non-finite
//! guard, gradient accumulation, Adam on the paper's schedule, checkpoints, CSV / TensorBoard
//! logs and periodic validation.
//!
//! A run lives in one directory: `config.toml` (the resolved config), `train_log.csv`,
//! `val_log.csv`, `tensorboard/`, `checkpoints/step-*/`.

mod logs;
mod session;
mod trainer;

pub use session::Validation;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use burn::optim::AdamConfig;
use burn::optim::adaptor::OptimizerAdaptor;
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereo, CREStereoConfig};

use crate::checkpoint::{Checkpoint, Learner, TrainState, list_checkpoints, load_checkpoint};
use crate::config::TrainConfig;
use crate::data::share::Share;
use crate::data::{Loader, LoaderSettings, MixedSource, Planner};
use crate::parallel::replica::Replica;
use trainer::Trainer;
pub use trainer::check_batch_split;

#[derive(Debug, Clone, Default)]
pub struct TrainOptions {
    /// Continue from the run's newest checkpoint (a fresh start when it has none).
    pub resume: bool,
    pub progress: bool,
    /// Stop (with a checkpoint) after this step without changing the schedule: time-boxed runs
    /// and the resume test.
    pub stop_at: Option<u64>,
    /// In a data-parallel run, check that the replicas hold the same weights every this many
    /// steps (0: at checkpoints only, where it is always checked).
    pub check_replicas_every: u64,
}

/// What a run (or this part of it) did.
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub step: u64,
    pub first_loss: Option<f64>,
    pub last_loss: Option<f64>,
    pub skipped_steps: u64,
    pub checkpoint: Option<PathBuf>,
    pub samples_per_s: f64,
    pub resumed_from: Option<u64>,
    /// Stopped early by SIGTERM/SIGINT (after a checkpoint): the CLI exits with
    /// [`crate::interrupt::EXIT_INTERRUPTED`].
    pub interrupted: bool,
    /// Steps taken in this session, and its wall-clock seconds.
    pub session_steps: u64,
    pub session_s: f64,
    /// Seconds of this session spent in the replicas' step all-reduce (waiting for the slowest
    /// replica included); 0 for a run of one device.
    pub sync_s: f64,
}

/// Adam over the network's parameters, as Burn builds it.
pub(crate) type Adam<B> = OptimizerAdaptor<burn::optim::Adam, CREStereo<B>, B>;

/// The fields a resumed run must share with the stored config: what defines the loss curve
/// (the WebDataset streaming settings decide the data order, so they are among them). Steps,
/// loader, checkpoint, log and validation settings may change between sessions.
fn identity(cfg: &TrainConfig) -> serde_json::Value {
    serde_json::json!({
        "seed": cfg.seed, "batch_size": cfg.batch_size, "accumulate": cfg.accumulate, "iters": cfg.iters,
        "gamma": cfg.gamma, "adam": cfg.adam, "schedule": cfg.schedule, "augment": cfg.augment,
        "datasets": cfg.datasets, "init_weights": cfg.init_weights, "webdataset": cfg.webdataset,
    })
}

/// `cfg` with the splits of each WebDataset source written out (those named, else the default
/// [`crate::data::choose_splits`] picks), so the stored config says which part of an export a
/// run trains on and a resume that would read other splits is refused. Splits named for another
/// layout are an error.
pub fn with_chosen_splits(cfg: &TrainConfig) -> Result<TrainConfig> {
    let mut cfg = cfg.clone();
    for (i, d) in cfg.datasets.iter_mut().enumerate() {
        let key = format!("datasets[{i}]");
        if crate::data::is_webdataset(&d.path, d.format) {
            d.splits = Some(crate::data::choose_splits(
                &d.path,
                d.splits.as_deref(),
                crate::data::SplitUse::Train,
                &key,
            )?);
        } else if d.splits.is_some() {
            bail!(
                "{key}: splits are named for {}, which is not a WebDataset export",
                d.path.display()
            );
        }
    }
    Ok(cfg)
}

/// A config stored before runs recorded their splits read every split of a WebDataset export:
/// its entries without splits mean all of them (for the identity check on resume).
fn stored_splits(mut old: TrainConfig) -> TrainConfig {
    for d in &mut old.datasets {
        if d.splits.is_none() && crate::data::is_webdataset(&d.path, d.format) {
            d.splits = stereo_io::WebDataset::split_names(&d.path).ok();
        }
    }
    old
}

/// Prepares the run directory: stores the config on a fresh start, checks it on resume.
/// Returns the checkpoint to continue from.
fn prepare_run(cfg: &TrainConfig, run: &Path, resume: bool) -> Result<Option<Checkpoint>> {
    std::fs::create_dir_all(run)
        .with_context(|| format!("cannot create run directory {}", run.display()))?;
    let stored = run.join("config.toml");
    let latest = existing_checkpoint(run, resume)?;
    if resume
        && let Some(old) = TrainConfig::stored(run)?
        && identity(&stored_splits(old)) != identity(cfg)
    {
        bail!(
            "the config differs from the one this run started with ({}) in seed, batch, iters, loss, optimiser, schedule, augmentation, data (WebDataset splits included) or WebDataset streaming — resume with the same config (steps, loader, checkpoint, log and validation settings may change)",
            stored.display()
        );
    }
    let text = toml::to_string_pretty(cfg).context("cannot serialise the config")?;
    stereo_io::write_bytes_atomically(&stored, text.as_bytes())
        .with_context(|| format!("cannot write {}", stored.display()))?;
    Ok(latest)
}

/// The checkpoint a run continues from (`None` on a fresh start); refuses a fresh start over
/// existing checkpoints. Writes nothing (the replicas of a parallel run other than 0 call it).
fn existing_checkpoint(run: &Path, resume: bool) -> Result<Option<Checkpoint>> {
    let latest = list_checkpoints(run)?.pop();
    if !resume && latest.is_some() {
        bail!(
            "{} already holds checkpoints: pass --resume to continue it, or choose another --out",
            run.display()
        );
    }
    Ok(if resume { latest } else { None })
}

/// A freshly initialised network whose weights depend only on `seed`, whatever else the
/// process does meanwhile (see [`CREStereoConfig::init_seeded`]).
pub fn seeded_model<B: Backend>(seed: u64, device: &B::Device) -> CREStereo<B> {
    CREStereoConfig::new().init_seeded(seed, device)
}

/// The training datasets, opened (and announced with their shares when `announce`).
fn open_training_data(cfg: &TrainConfig, announce: bool) -> Result<Arc<MixedSource>> {
    let source = MixedSource::open(&cfg.datasets)?;
    if announce {
        for (name, w) in source.names.iter().zip(&source.weights) {
            tracing::info!("training data {:.1}%: {name}", 100.0 * w);
        }
    }
    Ok(Arc::new(source))
}

/// The data stream of the run from sample `position` on.
pub fn start_loader(cfg: &TrainConfig, source: Arc<MixedSource>, position: u64) -> Loader {
    start_loader_share(cfg, source, position, Share::whole())
}

/// `share`'s part of the run's data stream from sample `position` (global) on.
pub fn start_loader_share(
    cfg: &TrainConfig,
    source: Arc<MixedSource>,
    position: u64,
    share: Share,
) -> Loader {
    let lens: Vec<usize> = source.datasets.iter().map(|d| d.len()).collect();
    let layouts = source.stream_layouts(&cfg.webdataset);
    for (name, l) in source.names.iter().zip(&layouts) {
        if let Some(l) = l.as_ref().filter(|_| share.replica == 0) {
            tracing::info!(
                "streaming {name}: {} shards dealt to {} streams each epoch, a shuffle buffer of {} samples per stream",
                l.shard_samples.len(),
                l.streams,
                l.buffer
            );
        }
    }
    let planner = Planner::with_layouts(cfg.seed, &source.weights, &lens, layouts);
    let settings = LoaderSettings {
        augment: cfg.augment.clone(),
        workers: cfg.workers(),
        prefetch: cfg.loader.prefetch,
        retries: cfg.loader.max_bad_retries,
    };
    Loader::start_share(source, planner, position, settings, share)
}

/// The network and optimiser a run starts from: a seeded init (or `init_weights`) and a fresh
/// Adam with the config's settings.
pub(crate) fn initial_learner<B: AutodiffBackend>(
    cfg: &TrainConfig,
    device: &B::Device,
) -> Result<Learner<B, Adam<B>>> {
    let mut model: CREStereo<B> = seeded_model(cfg.seed, device);
    if let Some(w) = &cfg.init_weights {
        model = crestereo::weights::load_weights(model, w, device)?;
    }
    let optim = AdamConfig::new()
        .with_beta_1(cfg.adam.beta1 as f32)
        .with_beta_2(cfg.adam.beta2 as f32)
        .with_epsilon(cfg.adam.eps as f32)
        .init::<B, CREStereo<B>>();
    let state = TrainState {
        step: 0,
        samples: 0,
        seed: cfg.seed,
        skipped_steps: 0,
        elapsed_s: 0.0,
    };
    Ok(Learner {
        model,
        optim,
        state,
    })
}

/// Continues from `checkpoint`: model, optimiser and state, refusing a checkpoint of another run.
fn resume<B: AutodiffBackend>(
    cfg: &TrainConfig,
    checkpoint: &Checkpoint,
    fresh: Learner<B, Adam<B>>,
    device: &B::Device,
    announce: bool,
) -> Result<Learner<B, Adam<B>>> {
    let dir = &checkpoint.dir;
    let restored = load_checkpoint(dir, fresh.model, fresh.optim, device)?;
    let state = &restored.state;
    if state.seed != cfg.seed || state.step != checkpoint.step {
        bail!(
            "checkpoint {} does not belong to this run (seed {} / step {})",
            dir.display(),
            state.seed,
            state.step
        );
    }
    if announce {
        tracing::info!(
            "resuming from {} (step {}, sample {})",
            dir.display(),
            state.step,
            state.samples
        );
    }
    Ok(restored)
}

/// Trains (or continues) a run on one device. Generic over the autodiff backend: Flex on CPU,
/// CUDA or wgpu with their features.
pub fn train<B: AutodiffBackend>(
    cfg: &TrainConfig,
    run: &Path,
    opts: &TrainOptions,
    device: &B::Device,
) -> Result<TrainOutcome> {
    cfg.validate()?;
    let cfg = &with_chosen_splits(cfg)?;
    drive(Trainer::<B>::open(cfg, run, opts, device, None)?)
}

/// Trains one replica of a data-parallel run (see [`crate::parallel`], which starts them): the
/// same loop, its passes' gradients averaged with the other replicas' before each Adam step.
pub fn train_replica<B: AutodiffBackend>(
    cfg: &TrainConfig,
    run: &Path,
    opts: &TrainOptions,
    device: &B::Device,
    replica: Replica<B>,
) -> Result<TrainOutcome> {
    cfg.validate()?;
    check_batch_split(cfg, replica.count)?;
    let cfg = &with_chosen_splits(cfg)?;
    drive(Trainer::<B>::open(cfg, run, opts, device, Some(replica))?)
}

fn drive<B: AutodiffBackend>(mut trainer: Trainer<'_, B>) -> Result<TrainOutcome> {
    while !trainer.finished() {
        let report;
        (trainer, report) = trainer.step()?;
        trainer.log(&report)?;
        trainer.validate()?;
        trainer.checkpoint()?;
    }
    trainer.finish()
}
