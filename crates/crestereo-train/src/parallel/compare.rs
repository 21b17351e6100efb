//! How far apart two runs of the same config are — the check that a data-parallel run follows a
//! one-device run with the whole batch: their logged losses step by step, and the weights of a
//! checkpoint both wrote.

use std::path::Path;

use anyhow::{Context, Result, bail};
use crestereo::weights::{load_record, named_parameters};
use crestereo::{CREStereoConfig, CpuBackend};

/// The largest relative differences between two runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunDifference {
    /// Of the logged losses, |a − b| / |a|, over the steps both logged.
    pub loss: f64,
    /// Of the weights: per tensor, its largest element difference over its largest magnitude.
    pub weight: f64,
}

/// (step, loss) of every row of a run's `train_log.csv`.
pub fn logged_losses(run: &Path) -> Result<Vec<(u64, f64)>> {
    let path = run.join("train_log.csv");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let step = f.first().and_then(|s| s.parse().ok());
            let loss = f.get(3).and_then(|s| s.parse().ok());
            step.zip(loss)
                .with_context(|| format!("{}: cannot read the row `{l}`", path.display()))
        })
        .collect()
}

/// The named weights of `run`'s checkpoint of step `step`.
pub fn checkpoint_weights(run: &Path, step: u64) -> Result<Vec<(String, Vec<f32>)>> {
    let device = Default::default();
    let file = run.join(format!("checkpoints/step-{step:08}/model.mpk"));
    let model = load_record(
        CREStereoConfig::new().init::<CpuBackend>(&device),
        &file,
        &device,
    )
    .with_context(|| format!("cannot load {}", file.display()))?;
    Ok(named_parameters(&model)
        .into_iter()
        .map(|p| (p.name, p.data))
        .collect())
}

/// Compares runs `a` and `b`: the same logged steps, and the checkpoint of step `step`.
pub fn compare_runs(a: &Path, b: &Path, step: u64) -> Result<RunDifference> {
    let (la, lb) = (logged_losses(a)?, logged_losses(b)?);
    let steps = |l: &[(u64, f64)]| l.iter().map(|r| r.0).collect::<Vec<_>>();
    if steps(&la) != steps(&lb) {
        bail!(
            "the runs logged other steps: {:?} and {:?}",
            steps(&la),
            steps(&lb)
        );
    }
    let loss = la
        .iter()
        .zip(&lb)
        .map(|((_, x), (_, y))| (x - y).abs() / x.abs().max(1e-12))
        .fold(0.0, f64::max);
    let mut weight = 0.0f64;
    for ((name, x), (_, y)) in checkpoint_weights(a, step)?
        .iter()
        .zip(&checkpoint_weights(b, step)?)
    {
        let scale = x.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
        let diff = x
            .iter()
            .zip(y)
            .map(|(p, q)| (p - q).abs())
            .fold(0f32, f32::max);
        if !diff.is_finite() {
            bail!("{name} is not finite in one of the runs");
        }
        weight = weight.max(f64::from(diff / scale));
    }
    Ok(RunDifference { loss, weight })
}
