//! `crestereo warmup`: compiles (and, where something is still autotuned, autotunes) into the
//! kernel cache every GPU kernel a training config's shapes need (a training step at the
//! per-replica batch and crop, the validation images' sizes, and any inference sizes named),
//! and says how many, how long and which: the kernel census of this process
//! ([`super::kernel_census`]), per phase and by family and cause, printed and written as JSON
//! beside the cache — so a cluster image or a shared cache folder is prepared once per build
//! instead of by the first minutes of every job, and a change that compiles more shows.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::TrainConfig;
use anyhow::{Context, Result};
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereoConfig, InferenceOptions, sequence_loss};

use super::bench_device::{infer_padded, random_batch};
use super::kernel_census;

#[derive(Debug, clap::Args)]
pub struct WarmupArgs {
    /// The training config whose shapes to prepare: crop, batch per replica, iterations, and
    /// the validation set's image sizes. Without it: the paper's training step (batch 2 of
    /// 384x512 at 10 iterations), or what --crop, --batch-size and --iters say.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replicas the global batch will be split over (the number of --devices times processes).
    #[arg(long, default_value_t = 1)]
    pub replicas: usize,
    // --batch-size, --crop, --iters: the training step's shape, over the config's.
    #[command(flatten)]
    pub shape: super::train::StepShapeArgs,
    /// Prepare no training step: only the inference sizes.
    #[arg(long)]
    pub no_training_step: bool,
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
struct CacheEntries {
    kernels: usize,
    tuned: usize,
}

fn cache_entries(dir: Option<&Path>) -> CacheEntries {
    fn walk(dir: &Path, inside_autotune: bool, c: &mut CacheEntries) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let path = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if name == "census" {
                continue;
            }
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
    let mut c = CacheEntries::default();
    if let Some(d) = dir {
        walk(d, false, &mut c);
    }
    c
}

/// The config whose shapes the warm-up prepares: the file's, or the defaults, with the
/// command line's overrides.
fn warmup_config(a: &WarmupArgs) -> Result<TrainConfig> {
    let mut cfg = match &a.config {
        Some(path) => {
            let cfg = TrainConfig::from_file(path)?;
            cfg.validate()?;
            cfg
        }
        None => TrainConfig::default(),
    };
    a.shape.apply(&mut cfg)?;
    Ok(cfg)
}

/// Runs the warm-up on `device` of backend `B`; `cache` is the kernel cache folder in use.
pub fn run<B: AutodiffBackend>(
    a: &WarmupArgs,
    device: &B::Device,
    cache: Option<&Path>,
) -> Result<()> {
    let cfg = warmup_config(a)?;
    crate::train::check_batch_split(&cfg, a.replicas.max(1))?;
    let level = std::env::var("CRESTEREO_AUTOTUNE_LEVEL").unwrap_or_else(|_| "balanced".into());
    let before = cache_entries(cache);
    let started = Instant::now();
    println!(
        "warm-up on {} (autotune level {level}); kernel cache: {}",
        B::name(device),
        cache.map_or("none (CPU backend, or caches off)".into(), |d| d
            .display()
            .to_string())
    );
    let mut phases = Vec::new();
    if !a.no_training_step {
        let micro = cfg.batch_size / a.replicas.max(1);
        let [h, w] = cfg.augment.crop;
        let phase = format!("training step {micro}x{h}x{w}, {} iterations", cfg.iters);
        kernel_census::set_phase(&phase);
        let t0 = Instant::now();
        crate::oom::on_device(
            || training_step::<B>(micro, h, w, cfg.iters, device),
            &format!(
                "a training step of {micro} × {h}x{w} at {} iterations",
                cfg.iters
            ),
            crate::oom::TRAINING_ADVICE,
        )?;
        println!("  {phase}: {:.1} s", t0.elapsed().as_secs_f64());
        phases.push(phase);
    }
    for (sh, sw, opts) in inference_sizes(a, &cfg)? {
        let phase = format!(
            "inference {sh}x{sw}, {} iterations, {} stage(s)",
            opts.iters, opts.stages
        );
        kernel_census::set_phase(&phase);
        let t0 = Instant::now();
        crate::oom::on_device(
            || inference::<B::InnerBackend>(sh, sw, opts, device),
            &format!("inference at {sh}x{sw}"),
            "infer smaller images (or with fewer --iters/--stages)",
        )?;
        println!("  {phase}: {:.1} s", t0.elapsed().as_secs_f64());
        phases.push(phase);
    }
    let after = cache_entries(cache);
    println!(
        "warm-up done in {:.1} s: {} compiled kernels ({} new), {} autotune results ({} new) in the cache",
        started.elapsed().as_secs_f64(),
        after.kernels,
        after.kernels.saturating_sub(before.kernels),
        after.tuned,
        after.tuned.saturating_sub(before.tuned)
    );
    report_census(&phases, cache)
}

/// Prints what this process compiled, per phase and in all, and writes the census JSON (to
/// CRESTEREO_KERNEL_CENSUS=FILE, else beside the kernel cache).
fn report_census(phases: &[String], cache: Option<&Path>) -> Result<()> {
    if !kernel_census::active() {
        return Ok(());
    }
    let census = kernel_census::snapshot();
    println!(
        "kernels compiled by this process (run: launched by the work; tuning: compiled while autotuning):"
    );
    for phase in phases {
        println!("  {phase}: {} kernels", census.count_in(phase));
    }
    print!("{}", census.table());
    let path = match kernel_census::requested() {
        Some(Some(file)) => Some(file),
        _ => cache.map(|d| kernel_census::beside_cache(d, "warmup")),
    };
    if let Some(path) = path {
        census.write(&path)?;
        println!("kernel census: {}", path.display());
    }
    Ok(())
}

/// The inference sizes to prepare: the validation images' (decoded: a dataset states no sizes
/// of its own) and the ones named.
fn inference_sizes(
    a: &WarmupArgs,
    cfg: &TrainConfig,
) -> Result<Vec<(usize, usize, InferenceOptions)>> {
    let mut sizes: Vec<(usize, usize, InferenceOptions)> = Vec::new();
    if a.config.is_some()
        && let Some(v) = crate::train::Validation::open(cfg)?
    {
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
    Ok(sizes)
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
