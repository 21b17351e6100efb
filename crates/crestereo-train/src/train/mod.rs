//! The training loop: micro-batches from the [`Loader`], the sequence loss with a non-finite
//! guard, gradient accumulation, Adam on the paper's schedule, checkpoints, CSV / TensorBoard
//! logs and periodic validation.
//!
//! A run lives in one directory: `config.toml` (the resolved config), `train_log.csv`,
//! `val_log.csv`, `tensorboard/`, `checkpoints/step-*/`.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::module::AutodiffModule;
use burn::optim::{AdamConfig, GradientsAccumulator, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::ElementConversion;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereo, CREStereoConfig, sequence_loss};
use indicatif::{ProgressBar, ProgressStyle};

use crate::checkpoint::{TrainState, list_checkpoints, load_checkpoint, save_checkpoint};
use crate::config::TrainConfig;
use crate::data::{Loader, MixedSource, Planner, collate, open_data};
use crate::eval::{EvalOptions, evaluate};
use crate::tensorboard::EventWriter;

#[derive(Debug, Clone, Default)]
pub struct TrainOptions {
    /// Continue from the run's newest checkpoint (a fresh start when it has none).
    pub resume: bool,
    pub progress: bool,
    /// Stop (with a checkpoint) after this step without changing the schedule: time-boxed runs
    /// and the resume test.
    pub stop_at: Option<u64>,
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
}

const TRAIN_CSV_HEADER: &str = "step,samples,lr,loss,epe,samples_per_s,elapsed_s,skipped_steps";
const VAL_CSV_HEADER: &str = "step,images,epe,rms,bad_1,bad_2,bad_3,d1,nonocc_epe,nonocc_bad_2";

/// The fields a resumed run must share with the stored config: what defines the loss curve.
/// Steps, loader, checkpoint, log and validation settings may change between sessions.
fn identity(cfg: &TrainConfig) -> serde_json::Value {
    serde_json::json!({
        "seed": cfg.seed, "batch_size": cfg.batch_size, "accumulate": cfg.accumulate, "iters": cfg.iters,
        "gamma": cfg.gamma, "adam": cfg.adam, "schedule": cfg.schedule, "augment": cfg.augment,
        "datasets": cfg.datasets, "init_weights": cfg.init_weights,
    })
}

/// Keeps the CSV rows up to `step` (a resumed run rewrites what came after its checkpoint).
fn truncate_csv(path: &Path, header: &str, step: u64) -> Result<()> {
    let kept: Vec<String> = match std::fs::read_to_string(path) {
        Ok(text) => text
            .lines()
            .skip(1)
            .filter(|l| l.split(',').next().and_then(|s| s.parse::<u64>().ok()).is_some_and(|s| s <= step))
            .map(str::to_string)
            .collect(),
        Err(_) => Vec::new(),
    };
    let mut text = format!("{header}\n");
    for l in kept {
        text.push_str(&l);
        text.push('\n');
    }
    stereo_io::write_bytes_atomically(path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

fn append(path: &Path, line: &str) -> Result<()> {
    let mut f = OpenOptions::new().append(true).create(true).open(path).with_context(|| format!("cannot open {}", path.display()))?;
    writeln!(f, "{line}").with_context(|| format!("cannot write {}", path.display()))
}

/// Prepares the run directory: stores the config on a fresh start, checks it on resume.
fn prepare_run(cfg: &TrainConfig, run: &Path, resume: bool) -> Result<Option<(u64, PathBuf)>> {
    std::fs::create_dir_all(run).with_context(|| format!("cannot create run directory {}", run.display()))?;
    let stored = run.join("config.toml");
    let latest = list_checkpoints(run)?.pop();
    if !resume && latest.is_some() {
        bail!("{} already holds checkpoints: pass --resume to continue it, or choose another --out", run.display());
    }
    if resume
        && let Some(old) = TrainConfig::stored(run)?
        && identity(&old) != identity(cfg)
    {
        bail!(
            "the config differs from the one this run started with ({}) in seed, batch, iters, loss, optimiser, schedule, augmentation or data — resume with the same config (steps, loader, checkpoint, log and validation settings may change)",
            stored.display()
        );
    }
    let text = toml::to_string_pretty(cfg).context("cannot serialise the config")?;
    stereo_io::write_bytes_atomically(&stored, text.as_bytes()).with_context(|| format!("cannot write {}", stored.display()))?;
    Ok(if resume { latest } else { None })
}

/// Mean absolute disparity error of the last prediction over valid pixels.
fn batch_epe<B: Backend>(pred: &Tensor<B, 4>, disp: &Tensor<B, 3>, valid: &Tensor<B, 3>) -> f64 {
    let [n, _, h, w] = pred.dims();
    let d = pred.clone().slice([0..n, 0..1, 0..h, 0..w]).reshape([n, h, w]);
    let err = ((d - disp.clone()).abs() * valid.clone()).sum().into_scalar().elem::<f64>();
    let count = valid.clone().sum().into_scalar().elem::<f64>();
    if count > 0.0 { err / count } else { f64::NAN }
}

/// A freshly initialised network whose weights depend only on `seed`. Burn's backends draw
/// initial weights from one process-wide RNG, so two threads initialising at once (tests, or a
/// tool running several evaluations) would interleave their draws; the lock keeps seed → weights
/// a function. (Found by the accumulation test: in-process runs started from different weights.)
pub fn seeded_model<B: Backend>(seed: u64, device: &B::Device) -> CREStereo<B> {
    static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
    B::seed(device, seed);
    let model = CREStereoConfig::new().init(device);
    // Burn creates parameters lazily, on first use: read them all now, inside the lock.
    let _ = crestereo::weights::named_parameters(&model);
    model
}

/// Trains (or continues) a run. Generic over the autodiff backend: Flex on CPU, CUDA with the
/// `cuda` feature.
pub fn train<B: AutodiffBackend>(cfg: &TrainConfig, run: &Path, opts: &TrainOptions, device: &B::Device) -> Result<TrainOutcome> {
    cfg.validate()?;
    let latest = prepare_run(cfg, run, opts.resume)?;
    let schedule = cfg.schedule();
    let source = Arc::new(MixedSource::open(&cfg.datasets)?);
    for (name, w) in source.names.iter().zip(&source.weights) {
        tracing::info!("training data {:.1}%: {name}", 100.0 * w);
    }
    let validation = match &cfg.validation {
        Some(v) => Some((v, open_data(&v.path, v.format.as_deref(), "validation")?)),
        None => None,
    };

    let mut model: CREStereo<B> = seeded_model(cfg.seed, device);
    if let Some(w) = &cfg.init_weights {
        model = crestereo::weights::load_weights(model, w, device)?;
    }
    let mut optim = AdamConfig::new()
        .with_beta_1(cfg.adam.beta1 as f32)
        .with_beta_2(cfg.adam.beta2 as f32)
        .with_epsilon(cfg.adam.eps as f32)
        .init::<B, CREStereo<B>>();
    let mut state = TrainState { step: 0, samples: 0, seed: cfg.seed, skipped_steps: 0, elapsed_s: 0.0 };
    let train_csv = run.join("train_log.csv");
    let val_csv = run.join("val_log.csv");
    let resumed_from = if let Some((step, dir)) = &latest {
        (model, optim, state) = load_checkpoint(dir, model, optim, device)?;
        if state.seed != cfg.seed || state.step != *step {
            bail!("checkpoint {} does not belong to this run (seed {} / step {})", dir.display(), state.seed, state.step);
        }
        tracing::info!("resuming from {} (step {}, sample {})", dir.display(), state.step, state.samples);
        Some(state.step)
    } else {
        None
    };
    truncate_csv(&train_csv, TRAIN_CSV_HEADER, state.step)?;
    truncate_csv(&val_csv, VAL_CSV_HEADER, state.step)?;
    let mut tb = if cfg.log.tensorboard { Some(EventWriter::create(&run.join("tensorboard"))?) } else { None };

    let lens: Vec<usize> = source.datasets.iter().map(|d| d.len()).collect();
    let planner = Planner::new(cfg.seed, &source.weights, &lens);
    let mut loader = Loader::start(source.clone(), planner, state.samples, cfg.augment.clone(), cfg.workers(), cfg.loader.prefetch, cfg.loader.max_bad_retries);

    let end = opts.stop_at.map_or(cfg.steps, |s| s.min(cfg.steps));
    let bar = if opts.progress { ProgressBar::new(cfg.steps) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} step {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_position(state.step);
    let t0 = Instant::now();
    let elapsed_before = state.elapsed_s;
    let mut samples_this_session = 0u64;
    let mut outcome = TrainOutcome { step: state.step, first_loss: None, last_loss: None, skipped_steps: state.skipped_steps, checkpoint: None, samples_per_s: 0.0, resumed_from };
    let mut last_checkpoint_step = None;

    while state.step < end {
        let lr = schedule.lr(state.step);
        let mut accumulator = GradientsAccumulator::<CREStereo<B>>::new();
        let (mut loss_sum, mut epe_sum, mut finite) = (0.0, 0.0, true);
        for _ in 0..cfg.accumulate {
            let samples: Vec<_> = loader.next_batch(cfg.batch_size)?.into_iter().map(|s| s.sample).collect();
            samples_this_session += samples.len() as u64;
            if !finite {
                continue; // keep consuming: the data position must not depend on a skip
            }
            let batch = collate::<B>(&samples, device)?;
            let preds = model.forward(batch.left, batch.right, cfg.iters, None);
            let loss = sequence_loss(&preds, batch.disp.clone(), batch.valid.clone(), cfg.gamma).div_scalar(cfg.accumulate as f64);
            let value = loss.clone().into_scalar().elem::<f64>();
            if !value.is_finite() {
                finite = false;
                continue;
            }
            loss_sum += value;
            epe_sum += batch_epe(preds.last().expect("predictions"), &batch.disp, &batch.valid) / cfg.accumulate as f64;
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            accumulator.accumulate(&model, grads);
        }
        state.samples = loader.position();
        if finite {
            model = optim.step(lr, model, accumulator.grads());
            outcome.first_loss.get_or_insert(loss_sum);
            outcome.last_loss = Some(loss_sum);
        } else {
            state.skipped_steps += 1;
            tracing::warn!("step {}: non-finite loss, step skipped (weights and optimiser unchanged; {} skipped so far)", state.step, state.skipped_steps);
        }
        state.step += 1;
        state.elapsed_s = elapsed_before + t0.elapsed().as_secs_f64();
        let rate = samples_this_session as f64 / t0.elapsed().as_secs_f64().max(1e-9);
        let loss_shown = if finite { loss_sum } else { f64::NAN };
        bar.set_position(state.step);
        bar.set_message(format!("loss {loss_shown:.4} epe {epe_sum:.3} lr {lr:.2e} {rate:.2} samples/s"));
        if state.step.is_multiple_of(cfg.log.every) || state.step == end || !finite {
            append(&train_csv, &format!("{},{},{lr:e},{loss_shown},{},{rate:.4},{:.2},{}", state.step, state.samples, if finite { epe_sum } else { f64::NAN }, state.elapsed_s, state.skipped_steps))?;
            if let Some(tb) = tb.as_mut() {
                tb.scalar("train/loss", state.step, loss_shown)?;
                tb.scalar("train/epe", state.step, epe_sum)?;
                tb.scalar("train/lr", state.step, lr)?;
                tb.scalar("train/samples_per_s", state.step, rate)?;
                tb.flush()?;
            }
        }
        if let Some((v, ds)) = &validation
            && (state.step.is_multiple_of(v.every) || state.step == end)
        {
            let opts = EvalOptions { iters: v.iters, stages: v.stages, limit: v.limit, ..EvalOptions::default() };
            let report = evaluate(&model.valid(), ds.as_ref(), "training", &opts, device, |_, _, _| {})?;
            if let Some(m) = report.mean_all {
                let n = report.mean_nonocc;
                append(&val_csv, &format!("{},{},{},{},{},{},{},{},{},{}", state.step, report.images, m.epe, m.rms, m.bad_1, m.bad_2, m.bad_3, m.d1, n.map_or(f64::NAN, |n| n.epe), n.map_or(f64::NAN, |n| n.bad_2)))?;
                if let Some(tb) = tb.as_mut() {
                    for (tag, x) in [("val/epe", m.epe), ("val/bad_2", m.bad_2), ("val/d1", m.d1)] {
                        tb.scalar(tag, state.step, x)?;
                    }
                    tb.flush()?;
                }
                bar.println(format!("step {}: validation EPE {:.3}, Bad-2 {:.2}% on {} images", state.step, m.epe, m.bad_2, report.images));
            }
        }
        if state.step.is_multiple_of(cfg.checkpoint.every) || state.step == end {
            outcome.checkpoint = Some(save_checkpoint(run, &model, &optim, &state, cfg.checkpoint.keep)?);
            last_checkpoint_step = Some(state.step);
        }
    }
    if last_checkpoint_step != Some(state.step) && state.step > 0 && resumed_from != Some(state.step) {
        outcome.checkpoint = Some(save_checkpoint(run, &model, &optim, &state, cfg.checkpoint.keep)?);
    }
    bar.finish_and_clear();
    let skipped = loader.skipped.lock().unwrap().clone();
    if !skipped.is_empty() {
        let lines: Vec<String> = skipped.iter().map(|s| serde_json::json!({"dataset": s.dataset, "id": s.id, "error": s.error}).to_string()).collect();
        for l in &lines {
            append(&run.join("skipped_samples.jsonl"), l)?;
        }
        tracing::warn!("{} unreadable training samples were replaced by neighbours (listed in skipped_samples.jsonl)", lines.len());
    }
    outcome.step = state.step;
    outcome.skipped_steps = state.skipped_steps;
    outcome.samples_per_s = samples_this_session as f64 / t0.elapsed().as_secs_f64().max(1e-9);
    Ok(outcome)
}
