//! The training loop: micro-batches from the [`Loader`], the sequence loss with a non-finite
//! guard, gradient accumulation, Adam on the paper's schedule, checkpoints, CSV / TensorBoard
//! logs and periodic validation.
//!
//! A run lives in one directory: `config.toml` (the resolved config), `train_log.csv`,
//! `val_log.csv`, `tensorboard/`, `checkpoints/step-*/`.

mod logs;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::module::AutodiffModule;
use burn::optim::adaptor::OptimizerAdaptor;
use burn::optim::{AdamConfig, GradientsAccumulator, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereo, CREStereoConfig, sequence_loss};
use indicatif::{ProgressBar, ProgressStyle};
use stereo_io::StereoDataset;

use crate::checkpoint::{
    Checkpoint, Learner, TrainState, list_checkpoints, load_checkpoint, save_checkpoint,
};
use crate::config::{TrainConfig, ValidationSettings};
use crate::data::{Loader, MixedSource, Planner, collate, open_data};
use crate::eval::{EvalOptions, evaluate};
use logs::{RunLogs, StepReport, append};

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

/// Adam over the network's parameters, as Burn builds it.
type Adam<B> = OptimizerAdaptor<burn::optim::Adam, CREStereo<B>, B>;

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
    let latest = list_checkpoints(run)?.pop();
    if !resume && latest.is_some() {
        bail!(
            "{} already holds checkpoints: pass --resume to continue it, or choose another --out",
            run.display()
        );
    }
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
    Ok(if resume { latest } else { None })
}

/// The step's logged figures, read back to the host together (one read per micro-batch: the
/// backend waits for the device once): the loss, and the mean absolute disparity error of the
/// last prediction over valid pixels (NaN where no pixel is valid).
fn loss_and_epe<B: Backend>(
    loss: &Tensor<B, 1>,
    pred: &Tensor<B, 4>,
    disp: &Tensor<B, 3>,
    valid: &Tensor<B, 3>,
) -> (f64, f64) {
    let [n, _, h, w] = pred.dims();
    let d = pred
        .clone()
        .slice([0..n, 0..1, 0..h, 0..w])
        .reshape([n, h, w]);
    let err = ((d - disp.clone()).abs() * valid.clone()).sum();
    let count = valid.clone().sum();
    let figures = Tensor::cat(vec![loss.clone().reshape([1]), err, count], 0)
        .into_data()
        .convert::<f64>()
        .into_vec::<f64>()
        .expect("three float figures");
    let epe = if figures[2] > 0.0 {
        figures[1] / figures[2]
    } else {
        f64::NAN
    };
    (figures[0], epe)
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

/// The training datasets, opened and announced with their shares.
fn open_training_data(cfg: &TrainConfig) -> Result<Arc<MixedSource>> {
    let source = MixedSource::open(&cfg.datasets)?;
    for (name, w) in source.names.iter().zip(&source.weights) {
        tracing::info!("training data {:.1}%: {name}", 100.0 * w);
    }
    Ok(Arc::new(source))
}

/// The data stream of the run from sample `position` on.
pub fn start_loader(cfg: &TrainConfig, source: Arc<MixedSource>, position: u64) -> Loader {
    let lens: Vec<usize> = source.datasets.iter().map(|d| d.len()).collect();
    let layouts = source.stream_layouts(&cfg.webdataset);
    for (name, l) in source.names.iter().zip(&layouts) {
        if let Some(l) = l {
            tracing::info!(
                "streaming {name}: {} shards dealt to {} streams each epoch, a shuffle buffer of {} samples per stream",
                l.shard_samples.len(),
                l.streams,
                l.buffer
            );
        }
    }
    let planner = Planner::with_layouts(cfg.seed, &source.weights, &lens, layouts);
    let l = &cfg.loader;
    Loader::start(
        source,
        planner,
        position,
        cfg.augment.clone(),
        cfg.workers(),
        l.prefetch,
        l.max_bad_retries,
    )
}

/// The network and optimiser a run starts from: a seeded init (or `init_weights`) and a fresh
/// Adam with the config's settings.
fn initial_learner<B: AutodiffBackend>(
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
    tracing::info!(
        "resuming from {} (step {}, sample {})",
        dir.display(),
        state.step,
        state.samples
    );
    Ok(restored)
}

/// Held-out data evaluated during training.
struct Validation {
    settings: ValidationSettings,
    data: Box<dyn StereoDataset>,
}

impl Validation {
    fn open(cfg: &TrainConfig) -> Result<Option<Self>> {
        let Some(settings) = &cfg.validation else {
            return Ok(None);
        };
        let data = open_data(
            &settings.path,
            settings.format,
            settings.splits.as_deref(),
            crate::data::SplitUse::Eval,
            "validation",
        )?;
        Ok(Some(Self {
            settings: settings.clone(),
            data,
        }))
    }

    /// Due every `every` steps and at the end.
    fn due(&self, step: u64, end: u64) -> bool {
        step.is_multiple_of(self.settings.every) || step == end
    }

    fn options(&self) -> EvalOptions {
        let s = &self.settings;
        EvalOptions {
            iters: s.iters,
            stages: s.stages,
            limit: s.limit,
            ..EvalOptions::default()
        }
    }
}

/// This session of a run (a resumed run starts a new one): its clock, its sample count and the
/// progress bar.
struct Session {
    bar: ProgressBar,
    started: Instant,
    /// Training time of the earlier sessions.
    elapsed_before: f64,
    samples: u64,
}

impl Session {
    fn start(opts: &TrainOptions, steps: u64, state: &TrainState) -> Self {
        let bar = if opts.progress {
            ProgressBar::new(steps)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} step {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(state.step);
        Self {
            bar,
            started: Instant::now(),
            elapsed_before: state.elapsed_s,
            samples: 0,
        }
    }

    /// Training time of the whole run so far.
    fn elapsed_s(&self) -> f64 {
        self.elapsed_before + self.started.elapsed().as_secs_f64()
    }

    fn samples_per_s(&self) -> f64 {
        self.samples as f64 / self.started.elapsed().as_secs_f64().max(1e-9)
    }

    fn show(&self, step: u64, r: &StepReport) {
        self.bar.set_position(step);
        self.bar.set_message(format!(
            "loss {:.4} epe {:.3} lr {:.2e} {:.2} samples/s",
            r.logged_loss(),
            r.epe,
            r.lr,
            r.samples_per_s
        ));
    }
}

/// The summed gradients of one step's passes.
struct Accumulated<B: AutodiffBackend> {
    grads: GradientsAccumulator<CREStereo<B>>,
    loss: f64,
    epe: f64,
    /// False once a pass's loss was not finite (later passes are then not run).
    finite: bool,
}

/// A run in progress: the network and its optimiser, the data stream, the logs and where the
/// run stands. [`train`] drives it one step at a time.
struct Trainer<'a, B: AutodiffBackend> {
    cfg: &'a TrainConfig,
    run: &'a Path,
    device: &'a B::Device,
    model: CREStereo<B>,
    optim: Adam<B>,
    state: TrainState,
    loader: Loader,
    logs: RunLogs,
    validation: Option<Validation>,
    session: Session,
    outcome: TrainOutcome,
    /// The step of this session's newest checkpoint.
    last_checkpoint: Option<u64>,
    /// The step this session stops after.
    end: u64,
}

impl<'a, B: AutodiffBackend> Trainer<'a, B> {
    /// Opens the run: its directory, data, network and optimiser (restored on resume), logs and
    /// data stream.
    fn open(
        cfg: &'a TrainConfig,
        run: &'a Path,
        opts: &TrainOptions,
        device: &'a B::Device,
    ) -> Result<Self> {
        let latest = prepare_run(cfg, run, opts.resume)?;
        let source = open_training_data(cfg)?;
        let validation = Validation::open(cfg)?;
        let mut learner = initial_learner::<B>(cfg, device)?;
        if let Some(checkpoint) = &latest {
            learner = resume(cfg, checkpoint, learner, device)?;
        }
        let Learner {
            model,
            optim,
            state,
        } = learner;
        let logs = RunLogs::open(run, state.step, cfg.log.tensorboard)?;
        let loader = start_loader(cfg, source, state.samples);
        let end = opts.stop_at.map_or(cfg.steps, |s| s.min(cfg.steps));
        let session = Session::start(opts, cfg.steps, &state);
        let outcome = TrainOutcome {
            step: state.step,
            first_loss: None,
            last_loss: None,
            skipped_steps: state.skipped_steps,
            checkpoint: None,
            samples_per_s: 0.0,
            resumed_from: latest.map(|c| c.step),
        };
        Ok(Self {
            cfg,
            run,
            device,
            model,
            optim,
            state,
            loader,
            logs,
            validation,
            session,
            outcome,
            last_checkpoint: None,
            end,
        })
    }

    fn finished(&self) -> bool {
        self.state.step >= self.end
    }

    /// One optimiser step: the accumulated passes, then Adam — or no update at all when a loss
    /// was not finite. Consumes the trainer because Burn's optimiser takes the model by value.
    fn step(mut self) -> Result<(Self, StepReport)> {
        let lr = self.cfg.schedule().lr(self.state.step);
        let mut passes = self.accumulate()?;
        self.state.samples = self.loader.position();
        if passes.finite {
            self.model = self.optim.step(lr, self.model, passes.grads.grads());
            self.outcome.first_loss.get_or_insert(passes.loss);
            self.outcome.last_loss = Some(passes.loss);
        } else {
            self.state.skipped_steps += 1;
            tracing::warn!(
                "step {}: non-finite loss, step skipped (weights and optimiser unchanged; {} skipped so far)",
                self.state.step,
                self.state.skipped_steps
            );
        }
        self.state.step += 1;
        self.state.elapsed_s = self.session.elapsed_s();
        let report = StepReport {
            lr,
            loss: passes.loss,
            epe: passes.epe,
            finite: passes.finite,
            samples_per_s: self.session.samples_per_s(),
        };
        self.session.show(self.state.step, &report);
        Ok((self, report))
    }

    /// The step's `accumulate` forward/backward passes with their gradients summed. After a
    /// non-finite loss the remaining micro-batches are still drawn, so the data position never
    /// depends on a skip.
    fn accumulate(&mut self) -> Result<Accumulated<B>> {
        let cfg = self.cfg;
        let mut acc = Accumulated {
            grads: GradientsAccumulator::new(),
            loss: 0.0,
            epe: 0.0,
            finite: true,
        };
        for _ in 0..cfg.accumulate {
            let samples: Vec<_> = self
                .loader
                .next_batch(cfg.batch_size)?
                .into_iter()
                .map(|s| s.sample)
                .collect();
            self.session.samples += samples.len() as u64;
            if !acc.finite {
                continue;
            }
            let batch = collate::<B>(&samples, self.device)?;
            let preds = self.model.forward(batch.left, batch.right, cfg.iters, None);
            let loss = sequence_loss(&preds, batch.disp.clone(), batch.valid.clone(), cfg.gamma)
                .div_scalar(cfg.accumulate as f64);
            let (value, epe) = loss_and_epe(
                &loss,
                preds.last().expect("predictions"),
                &batch.disp,
                &batch.valid,
            );
            if !value.is_finite() {
                acc.finite = false;
                continue;
            }
            acc.loss += value;
            acc.epe += epe / cfg.accumulate as f64;
            let grads = GradientsParams::from_grads(loss.backward(), &self.model);
            acc.grads.accumulate(&self.model, grads);
        }
        Ok(acc)
    }

    /// A row of the training logs every `log.every` steps, at the end, and after every skip.
    fn log(&mut self, report: &StepReport) -> Result<()> {
        let step = self.state.step;
        if step.is_multiple_of(self.cfg.log.every) || step == self.end || !report.finite {
            self.logs.training(&self.state, report)?;
        }
        Ok(())
    }

    /// Evaluates the held-out data when due.
    fn validate(&mut self) -> Result<()> {
        let step = self.state.step;
        let Some(validation) = self.validation.as_ref().filter(|v| v.due(step, self.end)) else {
            return Ok(());
        };
        let report = evaluate(
            &self.model.valid(),
            validation.data.as_ref(),
            "training",
            &validation.options(),
            self.device,
            |_, _, _| {},
        )?;
        if let Some(m) = report.mean_all {
            self.logs.validation(step, &report, &m)?;
            self.session.bar.println(format!(
                "step {step}: validation EPE {:.3}, Bad-2 {:.2}% on {} images",
                m.epe, m.bad_2, report.images
            ));
        }
        Ok(())
    }

    /// A checkpoint every `checkpoint.every` steps and at the end.
    fn checkpoint(&mut self) -> Result<()> {
        let step = self.state.step;
        if step.is_multiple_of(self.cfg.checkpoint.every) || step == self.end {
            self.save()?;
        }
        Ok(())
    }

    fn save(&mut self) -> Result<()> {
        let dir = save_checkpoint(
            self.run,
            &self.model,
            &self.optim,
            &self.state,
            self.cfg.checkpoint.keep,
        )?;
        self.outcome.checkpoint = Some(dir);
        self.last_checkpoint = Some(self.state.step);
        Ok(())
    }

    /// Ends the session: a last checkpoint if the newest state has none, the list of replaced
    /// samples, and the outcome.
    fn finish(mut self) -> Result<TrainOutcome> {
        let step = self.state.step;
        if self.last_checkpoint != Some(step) && step > 0 && self.outcome.resumed_from != Some(step)
        {
            self.save()?;
        }
        self.session.bar.finish_and_clear();
        self.list_skipped_samples()?;
        Ok(TrainOutcome {
            step,
            skipped_steps: self.state.skipped_steps,
            samples_per_s: self.session.samples_per_s(),
            ..self.outcome
        })
    }

    /// Appends the samples the loader could not read (and replaced) to `skipped_samples.jsonl`.
    fn list_skipped_samples(&self) -> Result<()> {
        let skipped = self.loader.skipped.lock().unwrap().clone();
        if skipped.is_empty() {
            return Ok(());
        }
        let path = self.run.join("skipped_samples.jsonl");
        for s in &skipped {
            append(
                &path,
                &serde_json::json!({"dataset": s.dataset, "id": s.id, "error": s.error})
                    .to_string(),
            )?;
        }
        tracing::warn!(
            "{} unreadable training samples were replaced by neighbours (listed in skipped_samples.jsonl)",
            skipped.len()
        );
        Ok(())
    }
}

/// Trains (or continues) a run. Generic over the autodiff backend: Flex on CPU, CUDA with the
/// `cuda` feature.
pub fn train<B: AutodiffBackend>(
    cfg: &TrainConfig,
    run: &Path,
    opts: &TrainOptions,
    device: &B::Device,
) -> Result<TrainOutcome> {
    cfg.validate()?;
    let cfg = &with_chosen_splits(cfg)?;
    let mut trainer = Trainer::<B>::open(cfg, run, opts, device)?;
    while !trainer.finished() {
        let report;
        (trainer, report) = trainer.step()?;
        trainer.log(&report)?;
        trainer.validate()?;
        trainer.checkpoint()?;
    }
    trainer.finish()
}
