//! What a run keeps besides the network: its held-out data and this session's clock and
//! progress bar.

use std::time::Instant;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};
use stereo_io::StereoDataset;

use super::TrainOptions;
use super::logs::StepReport;
use crate::checkpoint::TrainState;
use crate::config::{TrainConfig, ValidationSettings};
use crate::data::open_data;
use crate::eval::EvalOptions;

/// Held-out data evaluated during training.
pub struct Validation {
    settings: ValidationSettings,
    pub data: Box<dyn StereoDataset>,
}

impl Validation {
    /// The config's validation data, opened (none when the config has no `[validation]`).
    pub fn open(cfg: &TrainConfig) -> Result<Option<Self>> {
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
    pub(super) fn due(&self, step: u64, end: u64) -> bool {
        step.is_multiple_of(self.settings.every) || step == end
    }

    /// How the validation evaluates: iterations, stages and how many images.
    pub fn options(&self) -> EvalOptions {
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
pub(super) struct Session {
    pub(super) bar: ProgressBar,
    started: Instant,
    /// Training time of the earlier sessions.
    elapsed_before: f64,
    /// Samples this session trained on (all replicas' together).
    pub(super) samples: u64,
}

impl Session {
    /// The progress bar is shown when asked for and `shows` (replica 0 of a parallel run).
    pub(super) fn start(opts: &TrainOptions, steps: u64, state: &TrainState, shows: bool) -> Self {
        let bar = if opts.progress && shows {
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
    pub(super) fn elapsed_s(&self) -> f64 {
        self.elapsed_before + self.started.elapsed().as_secs_f64()
    }

    /// Wall-clock seconds of this session.
    pub(super) fn session_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    pub(super) fn samples_per_s(&self) -> f64 {
        self.samples as f64 / self.started.elapsed().as_secs_f64().max(1e-9)
    }

    pub(super) fn show(&self, step: u64, r: &StepReport) {
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
