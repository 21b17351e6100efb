//! `crestereo bench`: one training step and one inference at fixed sizes, timed, with peak RSS.

use std::time::Instant;

use anyhow::Result;
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::{CREStereoConfig, InferenceOptions, sequence_loss};

pub fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map(|kib| kib / 1024.0)
        .unwrap_or(f64::NAN)
}

/// The processor and the instruction sets the kernels run on (`bench/compare.py` prints it beside
/// PyTorch's own choice).
pub fn cpu_line() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!(
        "cpu: {model}; kernels {} (best here {}), gemm {}",
        crestereo::ops::simd::isa().name(),
        crestereo::ops::simd::Isa::best().name(),
        crestereo::ops::simd::gemm_isa()
    )
}

fn random_images<B: Backend>(
    n: usize,
    h: usize,
    w: usize,
    device: &B::Device,
) -> (Tensor<B, 4>, Tensor<B, 4>) {
    use burn::tensor::Distribution;
    let l = Tensor::<B, 4>::random([n, 3, h, w], Distribution::Uniform(0.0, 255.0), device);
    let r = Tensor::<B, 4>::random([n, 3, h, w], Distribution::Uniform(0.0, 255.0), device);
    (l, r)
}

/// One training step on `B`'s default device (the binary runs it on the CPU backend).
pub fn bench_train<B: AutodiffBackend>(n: usize, h: usize, w: usize, iters: usize) -> Result<()> {
    let device = Default::default();
    let model = CREStereoConfig::new().init::<B>(&device);
    let mut optim = AdamConfig::new()
        .with_beta_1(0.9)
        .with_beta_2(0.999)
        .with_epsilon(1e-8)
        .init();
    let (l, r) = random_images::<B>(n, h, w, &device);
    let disp = Tensor::<B, 3>::random(
        [n, h, w],
        burn::tensor::Distribution::Uniform(0.0, 64.0),
        &device,
    );
    let valid = Tensor::<B, 3>::ones([n, h, w], &device);
    let t0 = Instant::now();
    let preds = model.forward(l, r, iters, None);
    let loss = sequence_loss(&preds, disp, valid, 0.9);
    let t_fwd = t0.elapsed().as_secs_f64();
    let grads = loss.backward();
    let t_bwd = t0.elapsed().as_secs_f64() - t_fwd;
    let grads = GradientsParams::from_grads(grads, &model);
    let _model = optim.step(4e-4, model, grads);
    let total = t0.elapsed().as_secs_f64();
    println!(
        "train step (batch {n}, {h}x{w}, iters {iters}, threads {}): forward {t_fwd:.2}s, backward {t_bwd:.2}s, total incl. Adam {total:.2}s, peak RSS {:.0} MiB",
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into()),
        peak_rss_mib()
    );
    Ok(())
}

/// One two-pass inference on `B`'s default device (the binary runs it on the CPU backend).
pub fn bench_infer<B: Backend>(h: usize, w: usize) -> Result<()> {
    let device = Default::default();
    let model = CREStereoConfig::new().init::<B>(&device);
    let (l, r) = random_images::<B>(1, h, w, &device);
    let t0 = Instant::now();
    // pad (edge, bottom/right) to a multiple of 32 for the two-pass cascade, as `infer` does
    let (ph, pw) = (h.div_ceil(32) * 32, w.div_ceil(32) * 32);
    let pad = |t: Tensor<B, 4>| t.pad((0, pw - w, 0, ph - h), burn::tensor::ops::PadMode::Edge);
    let (l, r) = (pad(l), pad(r));
    let pred = crestereo::infer::cascade(
        &model,
        l,
        r,
        InferenceOptions {
            iters: 20,
            stages: 2,
        },
    );
    let _ = pred.slice([0..1, 0..2, 0..h, 0..w]).into_data();
    println!(
        "inference (1x{h}x{w}, two-pass, 20 iters, threads {}): {:.2}s, peak RSS {:.0} MiB",
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into()),
        t0.elapsed().as_secs_f64(),
        peak_rss_mib()
    );
    Ok(())
}
