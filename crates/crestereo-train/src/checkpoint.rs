//! Checkpoints: `<run>/checkpoints/step-NNNNNNNN/` holding the model, the optimiser state and
//! the training state (step, data position, seed). Each file goes through the project's
//! durable-write path (`stereo_io::write_bytes_atomically`: checked writes, fsync, rename), into a
//! hidden temp directory that is renamed into place once all three are whole, so neither a crash
//! nor a full disk mid-save leaves a half checkpoint that `--resume` would pick; older checkpoints
//! are pruned only after the new one is complete.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::optim::Optimizer;
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
        if let Some(step) = name
            .strip_prefix("step-")
            .and_then(|s| s.parse::<u64>().ok())
            && e.path().join(STATE).is_file()
        {
            out.push(Checkpoint {
                step,
                dir: e.path(),
            });
        }
    }
    out.sort();
    Ok(out)
}

/// Saves a checkpoint atomically and keeps the newest `keep`. Returns its directory.
pub fn save_checkpoint<B, O>(
    run: &Path,
    model: &CREStereo<B>,
    optim: &O,
    state: &TrainState,
    keep: usize,
) -> Result<PathBuf>
where
    B: AutodiffBackend,
    O: Optimizer<CREStereo<B>, B>,
{
    let dir = checkpoints_dir(run);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    remove_orphaned_temp_checkpoints(&dir);
    let name = format!("step-{:08}", state.step);
    let tmp = dir.join(format!(".tmp-{name}-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir(&tmp)?;
    let write = || -> Result<()> {
        crestereo::weights::save_record(model, tmp.join(MODEL))?;
        crestereo::weights::save_any_record::<B, _>(optim.to_record(), tmp.join(OPTIMIZER))?;
        let json = serde_json::to_vec_pretty(state)?;
        stereo_io::write_bytes_atomically(&tmp.join(STATE), &json)?;
        Ok(())
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e.context(format!(
            "cannot write checkpoint {} (nothing replaced)",
            dir.join(&name).display()
        )));
    }
    let target = dir.join(&name);
    if target.exists() {
        std::fs::remove_dir_all(&target)?;
    }
    std::fs::rename(&tmp, &target)
        .with_context(|| format!("cannot move checkpoint into {}", target.display()))?;
    std::fs::File::open(&dir)?.sync_all()?;
    let all = list_checkpoints(run)?;
    if all.len() > keep {
        for old in &all[..all.len() - keep] {
            std::fs::remove_dir_all(&old.dir)
                .with_context(|| format!("cannot prune {}", old.dir.display()))?;
        }
    }
    Ok(target)
}

/// Removes the temp directories (`.tmp-step-N-PID`) of saves whose process died mid-save.
fn remove_orphaned_temp_checkpoints(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let owner = name
            .strip_prefix(".tmp-")
            .and_then(|rest| rest.rsplit('-').next())
            .and_then(|pid| pid.parse::<u32>().ok());
        if let Some(pid) = owner
            && !stereo_io::atomic::process_alive(pid)
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Reads a checkpoint's training state.
pub fn read_state(checkpoint: &Path) -> Result<TrainState> {
    let path = checkpoint.join(STATE);
    let text = std::fs::read(&path)
        .with_context(|| format!("{} is not a checkpoint (no {STATE})", checkpoint.display()))?;
    serde_json::from_slice(&text).with_context(|| format!("corrupt {}", path.display()))
}

/// Restores model and optimiser from a checkpoint directory.
pub fn load_checkpoint<B, O>(
    checkpoint: &Path,
    model: CREStereo<B>,
    optim: O,
    device: &B::Device,
) -> Result<Learner<B, O>>
where
    B: AutodiffBackend,
    O: Optimizer<CREStereo<B>, B>,
{
    let state = read_state(checkpoint)?;
    let model =
        crestereo::weights::load_record(model, checkpoint.join(format!("{MODEL}.mpk")), device)?;
    let record = crestereo::weights::load_any_record::<B, _>(checkpoint.join(OPTIMIZER), device)
        .with_context(|| format!("loading optimiser state from {}", checkpoint.display()))?;
    Ok(Learner {
        model,
        optim: optim.load_record(record),
        state,
    })
}

/// The model weights file of a checkpoint directory, or `path` itself when it is a file: what
/// `eval`/`infer --weights` accept.
pub fn weights_file(path: &Path) -> Result<PathBuf> {
    if path.is_dir() {
        let direct = path.join(format!("{MODEL}.mpk"));
        if direct.is_file() {
            return Ok(direct);
        }
        // A run directory: its newest checkpoint.
        if let Some(last) = list_checkpoints(path)?.pop() {
            return Ok(last.dir.join(format!("{MODEL}.mpk")));
        }
        bail!(
            "{} holds no checkpoint (expected model.mpk or checkpoints/step-*/)",
            path.display()
        );
    }
    Ok(path.to_path_buf())
}
