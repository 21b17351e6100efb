//! `crestereo warmup`: compiles and autotunes, into the kernel cache, every GPU kernel a
//! training config's shapes need (a training step at the per-replica batch and crop, the
//! validation images' sizes, and any inference sizes named), and says how many and how long —
//! so a cluster image or a shared cache folder is prepared once per build instead of by the
//! first minutes of every job.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::TrainConfig;
use anyhow::{Context, Result};
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereoConfig, InferenceOptions, sequence_loss};

use super::bench_device::{infer_padded, random_batch};

#[derive(Debug, clap::Args)]
pub struct WarmupArgs {
    /// The training config whose shapes to prepare: crop, batch per replica, iterations, and
    /// the validation set's image sizes.
    #[arg(long)]
    pub config: PathBuf,
    /// Replicas the global batch will be split over (the number of --devices times processes).
    #[arg(long, default_value_t = 1)]
    pub replicas: usize,
    /// Inference sizes to prepare too, HxW, repeatable (what `crestereo infer` or `eval` will
    /// see), two-pass at 20 iterations as `infer` runs by default.
    #[arg(long = "infer-size", value_name = "HxW")]
    pub infer_sizes: Vec<String>,
    /// CubeCL's autotune effort: minimal, balanced (CubeCL's default), extensive or full. The
    /// same level must be used later for the results to be found: set
    /// CRESTEREO_AUTOTUNE_LEVEL for the training and inference commands too.
    #[arg(long, value_name = "LEVEL")]
    pub autotune_level: Option<String>,
}

/// The kernel cache's entries: compiled kernels and autotune results (one line each in CubeCL's
/// append-only files).
#[derive(Debug, Clone, Copy, Default)]
struct Census {
    kernels: usize,
    tuned: usize,
}

fn census(dir: Option<&Path>) -> Census {
    fn walk(dir: &Path, inside_autotune: bool, c: &mut Census) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let path = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            let autotune = inside_autotune || name.contains("autotune");
            if path.is_dir() {
                walk(&path, autotune, c);
            } else if let Ok(bytes) = std::fs::read(&path) {
                let lines = bytes.iter().filter(|&&b| b == b'\n').count();
                if autotune {
                    c.tuned += lines;
                } else if name == "toc" || name.starts_with("toc") {
                    c.kernels += lines;
                }
            }
        }
    }
    let mut c = Census::default();
    if let Some(d) = dir {
        walk(d, false, &mut c);
    }
    c
}

/// Runs the warm-up on `device` of backend `B`; `cache` is the kernel cache folder in use.
pub fn run<B: AutodiffBackend>(
    a: &WarmupArgs,
    device: &B::Device,
    cache: Option<&Path>,
) -> Result<()> {
    let cfg = TrainConfig::from_file(&a.config)?;
    cfg.validate()?;
    crate::train::check_batch_split(&cfg, a.replicas.max(1))?;
    let level = std::env::var("CRESTEREO_AUTOTUNE_LEVEL").unwrap_or_else(|_| "balanced".into());
    let before = census(cache);
    let started = Instant::now();
    println!(
        "warm-up on {} (autotune level {level}); kernel cache: {}",
        B::name(device),
        cache.map_or("none (CPU backend, or caches off)".into(), |d| d
            .display()
            .to_string())
    );
    let micro = cfg.batch_size / a.replicas.max(1);
    let [h, w] = cfg.augment.crop;
    let t0 = Instant::now();
    crate::oom::on_device(
        || training_step::<B>(micro, h, w, cfg.iters, device),
        &format!(
            "a training step of {micro} × {h}x{w} at {} iterations",
            cfg.iters
        ),
        crate::oom::TRAINING_ADVICE,
    )?;
    println!(
        "  training step, {micro} per replica at {h}x{w}, {} iterations: {:.1} s",
        cfg.iters,
        t0.elapsed().as_secs_f64()
    );
    let mut sizes: Vec<(usize, usize, InferenceOptions)> = Vec::new();
    // The validation images' sizes (decoded: a dataset states no sizes of its own).
    if let Some(v) = crate::train::Validation::open(&cfg)? {
        let eval = v.options();
        let opts = InferenceOptions {
            iters: eval.iters,
            stages: eval.stages,
        };
        for i in 0..eval.count(v.data.len()) {
            let s = v
                .data
                .sample(i)
                .with_context(|| format!("validation sample {i}"))?;
            let (sh, sw) = (s.left.height, s.left.width);
            if !sizes.iter().any(|&(a, b, _)| (a, b) == (sh, sw)) {
                sizes.push((sh, sw, opts));
            }
        }
    }
    for s in &a.infer_sizes {
        let [sh, sw] = super::train::parse_crop(s)?;
        sizes.push((
            sh,
            sw,
            InferenceOptions {
                iters: 20,
                stages: 2,
            },
        ));
    }
    for (sh, sw, opts) in sizes {
        let t0 = Instant::now();
        crate::oom::on_device(
            || inference::<B::InnerBackend>(sh, sw, opts, device),
            &format!("inference at {sh}x{sw}"),
            "infer smaller images (or with fewer --iters/--stages)",
        )?;
        println!(
            "  inference at {sh}x{sw}, {} iterations, {} stage(s): {:.1} s",
            opts.iters,
            opts.stages,
            t0.elapsed().as_secs_f64()
        );
    }
    let after = census(cache);
    println!(
        "warm-up done in {:.1} s: {} compiled kernels ({} new), {} autotune results ({} new) in the cache",
        started.elapsed().as_secs_f64(),
        after.kernels,
        after.kernels.saturating_sub(before.kernels),
        after.tuned,
        after.tuned.saturating_sub(before.tuned)
    );
    Ok(())
}

/// One training step on random data of the run's shapes: forward, sequence loss, backward, Adam.
fn training_step<B: AutodiffBackend>(
    n: usize,
    h: usize,
    w: usize,
    iters: usize,
    device: &B::Device,
) -> Result<()> {
    let model = CREStereoConfig::new().init::<B>(device);
    let mut optim = AdamConfig::new().init();
    let b = random_batch::<B>(n, h, w, device);
    let preds = model.forward(b.left, b.right, iters, None);
    let loss = sequence_loss(&preds, b.disp, b.valid, 0.9);
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    let model = optim.step(1e-4, model, grads);
    // Waits for the device: the step's kernels have run (and been compiled and tuned).
    let _ = crate::parallel::flat::flatten_parameters::<B, _>(&model)
        .slice(0..1)
        .into_data();
    Ok(())
}

fn inference<B: Backend>(
    h: usize,
    w: usize,
    opts: InferenceOptions,
    device: &B::Device,
) -> Result<()> {
    let model = CREStereoConfig::new().init::<B>(device);
    let b = random_batch::<B>(1, h, w, device);
    infer_padded(&model, b.left, b.right, opts);
    Ok(())
}
