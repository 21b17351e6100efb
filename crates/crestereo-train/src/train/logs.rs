//! A run's logs: `train_log.csv`, `val_log.csv` and the TensorBoard event file, continued
//! across sessions of the run.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use crate::checkpoint::TrainState;
use crate::eval::EvalReport;
use crate::metrics::DisparityMetrics;
use crate::tensorboard::EventWriter;

const TRAIN_CSV_HEADER: &str = "step,samples,lr,loss,epe,samples_per_s,elapsed_s,skipped_steps";
const VAL_CSV_HEADER: &str = "step,images,epe,rms,bad_1,bad_2,bad_3,d1,nonocc_epe,nonocc_bad_2";

/// What one optimiser step did.
#[derive(Debug, Clone, Copy)]
pub struct StepReport {
    pub lr: f64,
    /// The mean loss over the step's passes (each pass's loss divided by `accumulate`).
    pub loss: f64,
    /// The mean EPE of the passes' last predictions.
    pub epe: f64,
    /// False when a pass's loss was not finite: the step was skipped.
    pub finite: bool,
    /// Samples per second in this session so far.
    pub samples_per_s: f64,
}

impl StepReport {
    /// The loss as logged and shown: NaN for a skipped step.
    pub fn logged_loss(&self) -> f64 {
        if self.finite { self.loss } else { f64::NAN }
    }
}

/// The CSV logs and the optional TensorBoard writer of a run.
pub struct RunLogs {
    train_csv: PathBuf,
    val_csv: PathBuf,
    tensorboard: Option<EventWriter>,
}

impl RunLogs {
    /// Opens the logs of `run` to continue after `step`: rows past it (written after the
    /// checkpoint a resumed run starts from) are dropped. TensorBoard gets a new event file.
    pub fn open(run: &Path, step: u64, tensorboard: bool) -> Result<Self> {
        let train_csv = run.join("train_log.csv");
        let val_csv = run.join("val_log.csv");
        truncate_csv(&train_csv, TRAIN_CSV_HEADER, step)?;
        truncate_csv(&val_csv, VAL_CSV_HEADER, step)?;
        let tensorboard = if tensorboard {
            Some(EventWriter::create(&run.join("tensorboard"))?)
        } else {
            None
        };
        Ok(Self {
            train_csv,
            val_csv,
            tensorboard,
        })
    }

    /// One row of the training log, after the step `state` ends at.
    pub fn training(&mut self, state: &TrainState, r: &StepReport) -> Result<()> {
        let loss = r.logged_loss();
        let epe = if r.finite { r.epe } else { f64::NAN };
        let row = format!(
            "{},{},{:e},{loss},{epe},{:.4},{:.2},{}",
            state.step, state.samples, r.lr, r.samples_per_s, state.elapsed_s, state.skipped_steps
        );
        append(&self.train_csv, &row)?;
        if let Some(tb) = self.tensorboard.as_mut() {
            tb.scalar("train/loss", state.step, loss)?;
            tb.scalar("train/epe", state.step, r.epe)?;
            tb.scalar("train/lr", state.step, r.lr)?;
            tb.scalar("train/samples_per_s", state.step, r.samples_per_s)?;
            tb.flush()?;
        }
        Ok(())
    }

    /// One row of the validation log: `all` is the report's mean over all valid pixels.
    pub fn validation(
        &mut self,
        step: u64,
        report: &EvalReport,
        all: &DisparityMetrics,
    ) -> Result<()> {
        let m = all;
        let nonocc = report.mean_nonocc;
        let row = format!(
            "{},{},{},{},{},{},{},{},{},{}",
            step,
            report.images,
            m.epe,
            m.rms,
            m.bad_1,
            m.bad_2,
            m.bad_3,
            m.d1,
            nonocc.map_or(f64::NAN, |n| n.epe),
            nonocc.map_or(f64::NAN, |n| n.bad_2)
        );
        append(&self.val_csv, &row)?;
        if let Some(tb) = self.tensorboard.as_mut() {
            for (tag, x) in [("val/epe", m.epe), ("val/bad_2", m.bad_2), ("val/d1", m.d1)] {
                tb.scalar(tag, step, x)?;
            }
            tb.flush()?;
        }
        Ok(())
    }
}

/// Keeps the CSV rows up to `step` (a resumed run rewrites what came after its checkpoint).
fn truncate_csv(path: &Path, header: &str, step: u64) -> Result<()> {
    let kept: Vec<String> = match std::fs::read_to_string(path) {
        Ok(text) => text
            .lines()
            .skip(1)
            .filter(|l| {
                l.split(',')
                    .next()
                    .and_then(|s| s.parse::<u64>().ok())
                    .is_some_and(|s| s <= step)
            })
            .map(str::to_string)
            .collect(),
        Err(_) => Vec::new(),
    };
    let mut text = format!("{header}\n");
    for l in kept {
        text.push_str(&l);
        text.push('\n');
    }
    stereo_io::write_bytes_atomically(path, text.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Appends one line to a text file, creating it.
pub fn append(path: &Path, line: &str) -> Result<()> {
    let mut f = OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    writeln!(f, "{line}").with_context(|| format!("cannot write {}", path.display()))
}
