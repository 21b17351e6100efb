//! A run in progress, one step at a time: micro-batches from the loader, the sequence loss with
//! its non-finite guard, gradient accumulation, (in a data-parallel run) the replicas' all-reduce,
//! Adam on the schedule, logs, validation and checkpoints.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::module::AutodiffModule;
use burn::optim::{GradientsAccumulator, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereo, sequence_loss};

use super::logs::{RunLogs, StepReport, append};
use super::session::{Session, Validation};
use super::{
    Adam, TrainOptions, TrainOutcome, existing_checkpoint, initial_learner, open_training_data,
    prepare_run, resume, start_loader_share,
};
use crate::checkpoint::{Learner, TrainState, save_checkpoint};
use crate::config::TrainConfig;
use crate::data::share::Share;
use crate::data::{Loader, collate};
use crate::eval::evaluate;
use crate::parallel::replica::{Replica, StepFigures, weights_fingerprint};

/// The summed gradients of one step's passes on this replica.
struct Accumulated<B: AutodiffBackend> {
    grads: GradientsAccumulator<CREStereo<B>>,
    loss: f64,
    /// Per pass: the summed absolute error of the last prediction over valid pixels and the
    /// number of valid pixels.
    errors: Vec<(f64, f64)>,
    /// False once a pass's loss was not finite (later passes are then not run).
    finite: bool,
}

/// The step as taken: mean gradients (none when skipped) and the figures to log.
struct TakenStep {
    grads: Option<GradientsParams>,
    loss: f64,
    epe: f64,
    finite: bool,
    stop: bool,
}

/// A run in progress: the network and its optimiser, the data stream, the logs and where the
/// run stands. [`super::train`] drives it one step at a time.
pub(super) struct Trainer<'a, B: AutodiffBackend> {
    cfg: &'a TrainConfig,
    run: &'a Path,
    opts: &'a TrainOptions,
    device: &'a B::Device,
    model: CREStereo<B>,
    optim: Adam<B>,
    state: TrainState,
    loader: Loader,
    /// Replica 0 (or the only one) writes the logs and checkpoints.
    logs: Option<RunLogs>,
    validation: Option<Validation>,
    session: Session,
    outcome: TrainOutcome,
    /// The step of this session's newest checkpoint.
    last_checkpoint: Option<u64>,
    /// The step this session stops after.
    end: u64,
    /// This replica of a data-parallel run.
    replica: Option<Replica<B>>,
}

impl<'a, B: AutodiffBackend> Trainer<'a, B> {
    /// Opens the run: its directory, data, network and optimiser (restored on resume), logs and
    /// data stream. In a data-parallel run every replica starts from replica 0's weights and the
    /// replicas are checked to agree (weights, step, data position) before the first step.
    pub(super) fn open(
        cfg: &'a TrainConfig,
        run: &'a Path,
        opts: &'a TrainOptions,
        device: &'a B::Device,
        replica: Option<Replica<B>>,
    ) -> Result<Self> {
        let leads = replica.as_ref().is_none_or(Replica::leads);
        let latest = if leads {
            prepare_run(cfg, run, opts.resume)?
        } else {
            existing_checkpoint(run, opts.resume)?
        };
        let source = open_training_data(cfg, leads)?;
        let validation = Validation::open(cfg)?;
        let mut learner = initial_learner::<B>(cfg, device)?;
        if let Some(checkpoint) = &latest {
            learner = resume(cfg, checkpoint, learner, device, leads)?;
        }
        let Learner {
            mut model,
            optim,
            state,
        } = learner;
        let share = match &replica {
            Some(r) => {
                if latest.is_none() {
                    model = r.share_weights(model, device)?;
                }
                r.check_same(
                    "the weights, step and data position they start from (is the run directory shared?)",
                    &[weights_fingerprint::<B, _>(&model)?, state.step, state.samples],
                    device,
                )?;
                Share::new(r.index, r.count, cfg.batch_size)
            }
            None => Share::whole(),
        };
        let logs = if leads {
            Some(RunLogs::open(run, state.step, cfg.log.tensorboard)?)
        } else {
            None
        };
        let loader = start_loader_share(cfg, source, state.samples, share);
        let end = opts.stop_at.map_or(cfg.steps, |s| s.min(cfg.steps));
        let session = Session::start(opts, cfg.steps, &state, leads);
        let outcome = TrainOutcome {
            step: state.step,
            first_loss: None,
            last_loss: None,
            skipped_steps: state.skipped_steps,
            checkpoint: None,
            samples_per_s: 0.0,
            resumed_from: latest.map(|c| c.step),
            interrupted: false,
            session_steps: 0,
            session_s: 0.0,
            sync_s: 0.0,
        };
        Ok(Self {
            cfg,
            run,
            opts,
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
            replica,
        })
    }

    pub(super) fn finished(&self) -> bool {
        self.state.step >= self.end
    }

    fn leads(&self) -> bool {
        self.replica.as_ref().is_none_or(Replica::leads)
    }

    /// One optimiser step: the accumulated passes (averaged over the replicas), then Adam — or
    /// no update at all when a loss was not finite. Consumes the trainer because Burn's
    /// optimiser takes the model by value. A stop request (a signal) makes this the session's
    /// last step.
    pub(super) fn step(mut self) -> Result<(Self, StepReport)> {
        let lr = self.cfg.schedule().lr(self.state.step);
        let passes = self.accumulate()?;
        let taken = self.take(passes)?;
        self.state.samples += (self.cfg.batch_size * self.cfg.accumulate) as u64;
        match taken.grads {
            Some(grads) if taken.finite => {
                self.model = self.optim.step(lr, self.model, grads);
                self.outcome.first_loss.get_or_insert(taken.loss);
                self.outcome.last_loss = Some(taken.loss);
            }
            _ => {
                self.state.skipped_steps += 1;
                tracing::warn!(
                    "step {}: non-finite loss, step skipped (weights and optimiser unchanged; {} skipped so far)",
                    self.state.step,
                    self.state.skipped_steps
                );
            }
        }
        self.state.step += 1;
        self.outcome.session_steps += 1;
        self.state.elapsed_s = self.session.elapsed_s();
        if taken.stop && self.state.step < self.end {
            self.end = self.state.step;
            self.outcome.interrupted = true;
            if self.leads() {
                self.session.bar.println(format!(
                    "stop requested (signal): stopping after step {} with a checkpoint",
                    self.state.step
                ));
            }
        }
        let report = StepReport {
            lr,
            loss: taken.loss,
            epe: taken.epe,
            finite: taken.finite,
            samples_per_s: self.session.samples_per_s(),
        };
        self.session.show(self.state.step, &report);
        Ok((self, report))
    }

    /// The step as all replicas take it: this replica's passes alone, or their all-reduce.
    fn take(&mut self, passes: Accumulated<B>) -> Result<TakenStep> {
        let stop = crate::interrupt::requested();
        let Accumulated {
            mut grads,
            loss,
            errors,
            finite,
        } = passes;
        let accumulate = self.cfg.accumulate as f64;
        let Some(replica) = &self.replica else {
            let epe = errors
                .iter()
                .map(|&(err, count)| if count > 0.0 { err / count } else { f64::NAN })
                .map(|epe| epe / accumulate)
                .sum();
            return Ok(TakenStep {
                grads: finite.then(|| grads.grads()),
                loss,
                epe,
                finite,
                stop,
            });
        };
        let figures = StepFigures {
            loss,
            non_finite: !finite,
            stop,
            errors,
        };
        let own = finite.then(|| grads.grads());
        let t0 = std::time::Instant::now();
        let synced = replica.sync_step(&self.model, own, &figures, self.device)?;
        self.outcome.sync_s += t0.elapsed().as_secs_f64();
        Ok(TakenStep {
            grads: synced.grads,
            loss: synced.loss,
            epe: synced.epe,
            finite: synced.finite,
            stop: synced.stop,
        })
    }

    /// This replica's `accumulate` forward/backward passes with their gradients summed. After a
    /// non-finite loss the remaining micro-batches are still drawn, so the data position never
    /// depends on a skip.
    fn accumulate(&mut self) -> Result<Accumulated<B>> {
        let cfg = self.cfg;
        let replicas = self.replica.as_ref().map_or(1, |r| r.count);
        let micro = cfg.batch_size / replicas;
        let mut acc = Accumulated {
            grads: GradientsAccumulator::new(),
            loss: 0.0,
            errors: Vec::with_capacity(cfg.accumulate),
            finite: true,
        };
        for _ in 0..cfg.accumulate {
            let samples: Vec<_> = self
                .loader
                .next_batch(micro)?
                .into_iter()
                .map(|s| s.sample)
                .collect();
            self.session.samples += (samples.len() * replicas) as u64;
            if !acc.finite {
                acc.errors.push((0.0, 0.0));
                continue;
            }
            let batch = collate::<B>(&samples, self.device)?;
            let preds = self.model.forward(batch.left, batch.right, cfg.iters, None);
            let loss = sequence_loss(&preds, batch.disp.clone(), batch.valid.clone(), cfg.gamma)
                .div_scalar(cfg.accumulate as f64);
            let (value, err, count) = loss_and_error(
                &loss,
                preds.last().expect("predictions"),
                &batch.disp,
                &batch.valid,
            );
            acc.errors.push((err, count));
            if !value.is_finite() {
                acc.finite = false;
                continue;
            }
            acc.loss += value;
            let grads = GradientsParams::from_grads(loss.backward(), &self.model);
            acc.grads.accumulate(&self.model, grads);
        }
        Ok(acc)
    }

    /// A row of the training logs every `log.every` steps, at the end, and after every skip.
    pub(super) fn log(&mut self, report: &StepReport) -> Result<()> {
        let step = self.state.step;
        if let Some(logs) = &mut self.logs
            && (step.is_multiple_of(self.cfg.log.every) || step == self.end || !report.finite)
        {
            logs.training(&self.state, report)?;
        }
        Ok(())
    }

    /// Evaluates the held-out data when due. Every replica of a parallel run evaluates it (the
    /// same weights give the same figures), so none waits on another; replica 0 logs.
    pub(super) fn validate(&mut self) -> Result<()> {
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
        if let (Some(m), Some(logs)) = (report.mean_all, &mut self.logs) {
            logs.validation(step, &report, &m)?;
            self.session.bar.println(format!(
                "step {step}: validation EPE {:.3}, Bad-2 {:.2}% on {} images",
                m.epe, m.bad_2, report.images
            ));
        }
        Ok(())
    }

    /// A checkpoint every `checkpoint.every` steps and at the end; in a parallel run the
    /// replicas are checked to hold the same weights then (and every
    /// `check_replicas_every` steps).
    pub(super) fn checkpoint(&mut self) -> Result<()> {
        let step = self.state.step;
        let due = step.is_multiple_of(self.cfg.checkpoint.every) || step == self.end;
        let every = self.opts.check_replicas_every;
        if due || (every > 0 && step.is_multiple_of(every)) {
            self.check_replicas()?;
        }
        if due {
            self.save()?;
        }
        Ok(())
    }

    fn check_replicas(&self) -> Result<()> {
        if let Some(r) = &self.replica {
            let print = weights_fingerprint::<B, _>(&self.model)?;
            r.check_same(
                &format!("their weights after step {}", self.state.step),
                &[print, self.state.step],
                self.device,
            )
            .context("the replicas diverged")?;
        }
        Ok(())
    }

    fn save(&mut self) -> Result<()> {
        if !self.leads() {
            self.last_checkpoint = Some(self.state.step);
            return Ok(());
        }
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
    /// samples, the replica leaving the collective, and the outcome.
    pub(super) fn finish(mut self) -> Result<TrainOutcome> {
        let step = self.state.step;
        if self.last_checkpoint != Some(step) && step > 0 && self.outcome.resumed_from != Some(step)
        {
            self.check_replicas()?;
            self.save()?;
        }
        self.session.bar.finish_and_clear();
        self.list_skipped_samples()?;
        let samples_per_s = self.session.samples_per_s();
        self.outcome.session_s = self.session.session_s();
        if let Some(r) = self.replica.take() {
            r.collective.leave()?;
        }
        Ok(TrainOutcome {
            step,
            skipped_steps: self.state.skipped_steps,
            samples_per_s,
            ..self.outcome
        })
    }

    /// Appends the samples the loader could not read (and replaced) to `skipped_samples.jsonl`
    /// (replica `r > 0` of a parallel run: `skipped_samples.replica-r.jsonl`).
    fn list_skipped_samples(&self) -> Result<()> {
        let skipped = self.loader.skipped.lock().unwrap().clone();
        if skipped.is_empty() {
            return Ok(());
        }
        let path: PathBuf = match self.replica.as_ref().map(|r| r.index) {
            Some(r) if r > 0 => self.run.join(format!("skipped_samples.replica-{r}.jsonl")),
            _ => self.run.join("skipped_samples.jsonl"),
        };
        for s in &skipped {
            append(
                &path,
                &serde_json::json!({"dataset": s.dataset, "id": s.id, "error": s.error})
                    .to_string(),
            )?;
        }
        tracing::warn!(
            "{} unreadable training samples were replaced by neighbours (listed in {})",
            skipped.len(),
            path.display()
        );
        Ok(())
    }
}

/// The step's logged figures, read back to the host together (one read per micro-batch: the
/// backend waits for the device once): the loss, and the summed absolute disparity error of the
/// last prediction over valid pixels with the number of valid pixels.
fn loss_and_error<B: Backend>(
    loss: &Tensor<B, 1>,
    pred: &Tensor<B, 4>,
    disp: &Tensor<B, 3>,
    valid: &Tensor<B, 3>,
) -> (f64, f64, f64) {
    let [n, _, h, w] = pred.dims();
    let d = pred
        .clone()
        .slice([0..n, 0..1, 0..h, 0..w])
        .reshape([n, h, w]);
    let err = ((d - disp.clone()).abs() * valid.clone()).sum();
    let count = valid.clone().sum();
    let figures = crestereo::cat(vec![loss.clone().reshape([1]), err, count], 0)
        .into_data()
        .convert::<f64>()
        .into_vec::<f64>()
        .expect("three float figures");
    (figures[0], figures[1], figures[2])
}

/// Refuses a global batch the replicas cannot share evenly.
pub fn check_batch_split(cfg: &TrainConfig, replicas: usize) -> Result<()> {
    if !cfg.batch_size.is_multiple_of(replicas) {
        bail!(
            "the batch of {} samples cannot be split evenly over {replicas} replicas: --batch-size is the global batch (the paper's is 16 = 8 GPUs × 2); choose a multiple of {replicas}",
            cfg.batch_size
        );
    }
    Ok(())
}
