//! `crestereo bench --device cuda`: the training step and the two-pass inference on any backend,
//! with a device sync before every clock reading, a warm-up run first (kernel compilation and
//! autotuning) and the median of `repeats` timed runs. Printed in the same format as the CPU
//! bench so `bench/compare.py` and `bench/gpu_run.sh` parse both. Peak device memory is not
//! visible through Burn's backend API: `gpu_run.sh` polls `nvidia-smi` around the process.

use std::time::Instant;

use crate::host_reads;
use anyhow::Result;
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use burn::tensor::ops::PadMode;
use crestereo::{CREStereo, CREStereoConfig, InferenceOptions, sequence_loss};

fn sync<B: Backend>(device: &B::Device) {
    B::sync(device).expect("device sync");
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Random inputs of a training step: images in 0–255, disparities in 0–64, every pixel valid.
pub(super) struct RandomBatch<B: Backend> {
    pub left: Tensor<B, 4>,
    pub right: Tensor<B, 4>,
    pub disp: Tensor<B, 3>,
    pub valid: Tensor<B, 3>,
}

pub(super) fn random_batch<B: Backend>(
    n: usize,
    h: usize,
    w: usize,
    device: &B::Device,
) -> RandomBatch<B> {
    use burn::tensor::Distribution::Uniform;
    let [left, right] = [0, 1].map(|_| Tensor::random([n, 3, h, w], Uniform(0.0, 255.0), device));
    RandomBatch {
        left,
        right,
        disp: Tensor::random([n, h, w], Uniform(0.0, 64.0), device),
        valid: Tensor::ones([n, h, w], device),
    }
}

/// The reference inference of `model` on an `h`×`w` pair: padded (edge) to multiples of 32, then
/// cropped back; read to the host, so the device has finished.
pub(super) fn infer_padded<B: Backend>(
    model: &CREStereo<B>,
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    opts: InferenceOptions,
) {
    let [_, _, h, w] = left.dims();
    let (ph, pw) = (h.div_ceil(32) * 32, w.div_ceil(32) * 32);
    let pad = |t: Tensor<B, 4>| t.pad((0, pw - w, 0, ph - h), PadMode::Edge);
    let pred = crestereo::infer::cascade(model, pad(left), pad(right), opts);
    let _ = pred.slice([0..1, 0..1, 0..h, 0..w]).into_data();
}

pub fn bench_train<B: AutodiffBackend>(
    n: usize,
    h: usize,
    w: usize,
    iters: usize,
    repeats: usize,
    device: &B::Device,
) -> Result<()> {
    let mut model = CREStereoConfig::new().init::<B>(device);
    let mut optim = AdamConfig::new().init();
    let RandomBatch {
        left: l,
        right: r,
        disp,
        valid,
    } = random_batch::<B>(n, h, w, device);
    let (mut fwd, mut bwd, mut total) = (Vec::new(), Vec::new(), Vec::new());
    // Host reads inside forward and inside backward + Adam, summed over the timed steps. The
    // syncs around the clock readings wait for the device but read nothing back.
    let counted = host_reads::visible::<B>(device);
    let (mut reads_fwd, mut reads_rest) = (0, 0);
    for rep in 0..=repeats {
        sync::<B>(device);
        let t0 = Instant::now();
        let r0 = host_reads::count();
        let preds = model.forward(l.clone(), r.clone(), iters, None);
        let loss = sequence_loss(&preds, disp.clone(), valid.clone(), 0.9);
        let r1 = host_reads::count();
        sync::<B>(device);
        let t_fwd = t0.elapsed().as_secs_f64();
        let r2 = host_reads::count();
        let grads = loss.backward();
        sync::<B>(device);
        let t_bwd = t0.elapsed().as_secs_f64() - t_fwd;
        let grads = GradientsParams::from_grads(grads, &model);
        model = optim.step(4e-4, model, grads);
        let r3 = host_reads::count();
        sync::<B>(device);
        if rep > 0 {
            fwd.push(t_fwd);
            bwd.push(t_bwd);
            total.push(t0.elapsed().as_secs_f64());
            reads_fwd += r1 - r0;
            reads_rest += r3 - r2;
        }
    }
    let reads = if counted {
        format!(
            "host reads per step: forward {}, backward+Adam {}",
            reads_fwd as f64 / repeats as f64,
            reads_rest as f64 / repeats as f64
        )
    } else {
        "host reads not counted (no fusion backend, or built without `host-read-count`)".into()
    };
    println!(
        "train step (batch {n}, {h}x{w}, iters {iters}, device {}, median of {repeats} after a warm-up): forward {:.3}s, backward {:.3}s, total incl. Adam {:.3}s, peak RSS {:.0} MiB; {reads}",
        B::name(device),
        median(fwd),
        median(bwd),
        median(total),
        super::bench::peak_rss_mib()
    );
    Ok(())
}

pub fn bench_infer<B: Backend>(
    h: usize,
    w: usize,
    repeats: usize,
    device: &B::Device,
) -> Result<()> {
    let model = CREStereoConfig::new().init::<B>(device);
    let batch = random_batch::<B>(1, h, w, device);
    let opts = InferenceOptions {
        iters: 20,
        stages: 2,
    };
    let mut times = Vec::new();
    for rep in 0..=repeats {
        sync::<B>(device);
        let t0 = Instant::now();
        infer_padded(&model, batch.left.clone(), batch.right.clone(), opts);
        if rep > 0 {
            times.push(t0.elapsed().as_secs_f64());
        }
    }
    println!(
        "inference (1x{h}x{w}, two-pass, 20 iters, device {}, median of {repeats} after a warm-up): {:.3}s, peak RSS {:.0} MiB",
        B::name(device),
        median(times),
        super::bench::peak_rss_mib()
    );
    Ok(())
}

/// What `bench --device` times: the parts asked for, their sizes and the number of timed runs.
pub struct DeviceBench<'a> {
    pub train: bool,
    pub infer: bool,
    /// batch, height, width, iterations
    pub train_size: &'a [usize],
    /// height, width
    pub infer_size: &'a [usize],
    pub repeats: usize,
}

/// The chosen parts on backend `B`'s default device (CUDA GPU 0, or wgpu's default adapter),
/// each in this process.
pub fn run_on<B: AutodiffBackend>(plan: &DeviceBench) -> Result<()> {
    let device = Default::default();
    let (ts, is, repeats) = (plan.train_size, plan.infer_size, plan.repeats);
    if plan.train {
        bench_train::<B>(ts[0], ts[1], ts[2], ts[3], repeats, &device)?;
    }
    if plan.infer {
        bench_infer::<B::InnerBackend>(is[0], is[1], repeats, &device)?;
    }
    Ok(())
}
