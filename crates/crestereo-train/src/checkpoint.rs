//! Checkpoints: `<run>/checkpoints/step-NNNNNNNN/` holding the model, the optimiser state and
//! the training state (step, data position, seed). A checkpoint is written into a hidden temp
//! directory (each file encoded in memory and written durably through `stereo_io::atomic`, so
//! a disk that fills up is an error, never a short file), renamed into place and the rename
//! synced, so a crash mid-save never leaves a half checkpoint that `--resume` would pick; older
//! checkpoints are pruned only after the new one is complete. Temp directories of saves that
//! were killed are removed by the next save.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::optim::Optimizer;
use burn::module::Module;
use burn::record::{FullPrecisionSettings, NamedMpkBytesRecorder, NamedMpkFileRecorder, Record, Recorder};
use burn::tensor::backend::AutodiffBackend;
use crestereo::CREStereo;
use serde::{Deserialize, Serialize};

/// Everything besides tensors that a resumed run needs to continue exactly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Optimiser steps taken (including skipped ones).
    pub step: u64,
    /// The data position: the ordinal of the next sample. With the seed this is the whole RNG
    /// state: every sample's choice and augmentation is a function of (seed, ordinal).
    pub samples: u64,
    pub seed: u64,
    /// Steps skipped by the non-finite-loss guard.
    pub skipped_steps: u64,
    /// Wall-clock seconds spent training so far.
    pub elapsed_s: f64,
}

/// A complete checkpoint of a run.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Checkpoint {
    pub step: u64,
    pub dir: PathBuf,
}

/// The network, its optimiser and the training state: what a checkpoint holds.
pub struct Learner<B: AutodiffBackend, O> {
    pub model: CREStereo<B>,
    pub optim: O,
    pub state: TrainState,
}

const MODEL: &str = "model";
const OPTIMIZER: &str = "optimizer";
const STATE: &str = "state.json";

fn recorder() -> NamedMpkFileRecorder<FullPrecisionSettings> {
    NamedMpkFileRecorder::<FullPrecisionSettings>::new()
}

/// A record as the bytes [`recorder`] writes to a `.mpk` file (Burn's file recorder writes
/// through a `BufWriter` whose last flush can fail unnoticed; these bytes are written durably).
fn mpk_bytes<B: burn::tensor::backend::Backend, R: Record<B>>(record: R) -> Result<Vec<u8>> {
    NamedMpkBytesRecorder::<FullPrecisionSettings>::new().record(record, ()).map_err(|e| anyhow::anyhow!("cannot encode: {e}"))
}

const TEMP_PREFIX: &str = ".tmp-";

/// Removes the temp directories of saves whose process is gone.
fn remove_orphaned_temp_dirs(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let owner = name.strip_prefix(TEMP_PREFIX).and_then(|rest| rest.rsplit('-').next()).and_then(|pid| pid.parse::<u32>().ok());
        if owner.is_some_and(|pid| !stereo_io::atomic::process_alive(pid)) {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

pub fn checkpoints_dir(run: &Path) -> PathBuf {
    run.join("checkpoints")
}

/// Complete checkpoints of a run, oldest first.
pub fn list_checkpoints(run: &Path) -> Result<Vec<Checkpoint>> {
    let dir = checkpoints_dir(run);
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(&dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let e = e?;
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(step) = name.strip_prefix("step-").and_then(|s| s.parse::<u64>().ok())
            && e.path().join(STATE).is_file()
        {
            out.push(Checkpoint { step, dir: e.path() });
        }
    }
    out.sort();
    Ok(out)
}

/// Saves a checkpoint atomically and keeps the newest `keep`. Returns its directory.
pub fn save_checkpoint<B, O>(run: &Path, model: &CREStereo<B>, optim: &O, state: &TrainState, keep: usize) -> Result<PathBuf>
where
    B: AutodiffBackend,
    O: Optimizer<CREStereo<B>, B>,
{
    let dir = checkpoints_dir(run);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    remove_orphaned_temp_dirs(&dir);
    let name = format!("step-{:08}", state.step);
    let tmp = dir.join(format!("{TEMP_PREFIX}{name}-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("cannot remove {}", tmp.display()))?;
    }
    std::fs::create_dir(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let write = || -> Result<()> {
        let model_bytes = mpk_bytes::<B, _>(model.clone().into_record()).context("the model")?;
        stereo_io::write_bytes_atomically(&tmp.join(format!("{MODEL}.mpk")), &model_bytes)?;
        let optim_bytes = mpk_bytes::<B, _>(optim.to_record()).context("the optimiser state")?;
        stereo_io::write_bytes_atomically(&tmp.join(format!("{OPTIMIZER}.mpk")), &optim_bytes)?;
        stereo_io::write_bytes_atomically(&tmp.join(STATE), &serde_json::to_vec_pretty(state)?)?;
        Ok(())
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e.context(format!("cannot write checkpoint {} (nothing replaced)", dir.join(&name).display())));
    }
    let target = dir.join(&name);
    if target.exists() {
        std::fs::remove_dir_all(&target).with_context(|| format!("cannot replace {}", target.display()))?;
    }
    std::fs::rename(&tmp, &target).with_context(|| format!("cannot move checkpoint into {}", target.display()))?;
    stereo_io::atomic::sync_dir(&dir)?;
    let all = list_checkpoints(run)?;
    if all.len() > keep {
        for old in &all[..all.len() - keep] {
            std::fs::remove_dir_all(&old.dir).with_context(|| format!("cannot prune {}", old.dir.display()))?;
        }
    }
    Ok(target)
}

/// Reads a checkpoint's training state.
pub fn read_state(checkpoint: &Path) -> Result<TrainState> {
    let path = checkpoint.join(STATE);
    let text = std::fs::read(&path).with_context(|| format!("{} is not a checkpoint (no {STATE})", checkpoint.display()))?;
    serde_json::from_slice(&text).with_context(|| format!("corrupt {}", path.display()))
}

/// Restores model and optimiser from a checkpoint directory.
pub fn load_checkpoint<B, O>(checkpoint: &Path, model: CREStereo<B>, optim: O, device: &B::Device) -> Result<Learner<B, O>>
where
    B: AutodiffBackend,
    O: Optimizer<CREStereo<B>, B>,
{
    let state = read_state(checkpoint)?;
    let model = crestereo::weights::load_record(model, checkpoint.join(format!("{MODEL}.mpk")), device)?;
    let record = Recorder::<B>::load(&recorder(), checkpoint.join(OPTIMIZER), device)
        .map_err(|e| anyhow::anyhow!("loading optimiser state from {}: {e}", checkpoint.display()))?;
    Ok(Learner { model, optim: optim.load_record(record), state })
}

/// Extensions of the weight files `eval`/`infer --weights` load: PyTorch state dicts, Burn records.
const WEIGHT_EXTENSIONS: [&str; 4] = ["pt", "pth", "bin", "mpk"];

/// The model weights file of a checkpoint directory, or `path` itself when it is a weights file:
/// what `eval`/`infer --weights` accept.
pub fn weights_file(path: &Path) -> Result<PathBuf> {
    if !path.exists() {
        bail!("--weights {} does not exist", path.display());
    }
    if path.is_dir() {
        let direct = path.join(format!("{MODEL}.mpk"));
        if direct.is_file() {
            return Ok(direct);
        }
        // A run directory: its newest checkpoint.
        if let Some(last) = list_checkpoints(path)?.pop() {
            return Ok(last.dir.join(format!("{MODEL}.mpk")));
        }
        bail!("{} holds no checkpoint (expected model.mpk or checkpoints/step-*/)", path.display());
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or_default();
    if !WEIGHT_EXTENSIONS.contains(&ext) {
        bail!(
            "--weights {}: not a weights file (expected a PyTorch state dict .pt/.pth/.bin, a Burn record .mpk, a checkpoint directory or a training run)",
            path.display()
        );
    }
    Ok(path.to_path_buf())
}

