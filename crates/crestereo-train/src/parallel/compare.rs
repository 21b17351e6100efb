//! How far apart two runs of the same config are — the check that a data-parallel run follows a
//! one-device run with the whole batch: their logged losses step by step, and the weights of a
//! checkpoint both wrote.

use std::path::Path;

use anyhow::{Context, Result, bail};
use crestereo::weights::{load_record, named_parameters};
use crestereo::{CREStereoConfig, CpuBackend};

/// The relative differences between two runs.
#[derive(Debug, Clone, PartialEq)]
pub struct RunDifference {
    /// Of the logged losses, |a − b| / |a|, largest over the steps both logged.
    pub loss: f64,
    /// Of the weights together, ‖a − b‖₂ / ‖a‖₂, leaving out the biases an instance
    /// normalisation cancels ([`crestereo::network::encoder::bias_cancelled_by_instance_norm`]): no
    /// output depends on them, their gradient is rounding noise, and Adam moves them by about
    /// the learning rate either way, in any two runs whose sums round differently.
    pub weight: f64,
    /// The same over every weight, those biases included.
    pub all_weights: f64,
    /// Tensor by tensor (the cancelled biases left out): the largest ‖a − b‖₂ / ‖a‖₂, and its
    /// name.
    pub worst_tensor: (f64, String),
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
    // (difference², norm²) over the weights that matter, and over all.
    let (mut kept, mut all) = ((0.0f64, 0.0f64), (0.0f64, 0.0f64));
    let mut worst_tensor = (0.0f64, String::new());
    for ((name, x), (_, y)) in checkpoint_weights(a, step)?
        .iter()
        .zip(&checkpoint_weights(b, step)?)
    {
        let (mut d2, mut n2) = (0.0f64, 0.0f64);
        for (p, q) in x.iter().zip(y) {
            let d = f64::from(p - q);
            d2 += d * d;
            n2 += f64::from(*p) * f64::from(*p);
        }
        if !d2.is_finite() {
            bail!("{name} is not finite in one of the runs");
        }
        all = (all.0 + d2, all.1 + n2);
        if crestereo::network::encoder::bias_cancelled_by_instance_norm(name) {
            continue;
        }
        kept = (kept.0 + d2, kept.1 + n2);
        let rel = d2.sqrt() / n2.sqrt().max(1e-30);
        if rel > worst_tensor.0 {
            worst_tensor = (rel, name.clone());
        }
    }
    let ratio = |(d2, n2): (f64, f64)| d2.sqrt() / n2.sqrt().max(1e-30);
    let (weight, all_weights) = (ratio(kept), ratio(all));
    Ok(RunDifference {
        loss,
        weight,
        all_weights,
        worst_tensor,
    })
}
