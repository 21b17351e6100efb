//! `crestereo` command line: inference on an image pair, and a CPU bench.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use clap::{Parser, Subcommand, ValueEnum};

use crestereo::io::{read_bgr, write_exr, write_pfm, write_visualisation};
use crestereo::weights::load_weights;
use crestereo::{
    CREStereoConfig, CpuAutodiffBackend, CpuBackend, InferenceOptions, infer_disparity,
    sequence_loss,
};

#[derive(Parser, Debug)]
#[command(
    name = "crestereo",
    version,
    about = "CREStereo stereo matching (Burn, CPU)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Estimate the disparity of a rectified pair (left view).
    Infer {
        #[command(flatten)]
        args: InferArgs,
        /// CPU threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Backend.
        #[arg(long, value_enum, default_value_t = DeviceKind::Cpu)]
        device: DeviceKind,
    },
    /// Time one training step and one inference (random weights and inputs).
    Bench {
        #[arg(long, value_enum, default_value_t = BenchWhat::All)]
        what: BenchWhat,
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Training-step size override: batch,height,width,iters (default 2,384,512,10).
        #[arg(long, value_delimiter = ',')]
        train_size: Option<Vec<usize>>,
        /// Inference size override: height,width (default 480,640).
        #[arg(long, value_delimiter = ',')]
        infer_size: Option<Vec<usize>>,
    },
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum DeviceKind {
    /// Flex CPU backend.
    Cpu,
    /// CUDA GPU 0 (needs the `cuda` feature).
    Cuda,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum BenchWhat {
    All,
    Train,
    Infer,
}

fn set_threads(n: usize) {
    if n > 0 {
        // SAFETY: called at start-up before any other thread exists.
        unsafe { std::env::set_var("RAYON_NUM_THREADS", n.to_string()) };
    }
}

fn peak_rss_mib() -> f64 {
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

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Infer { args, threads, device } => {
            set_threads(threads);
            match device {
                DeviceKind::Cpu => infer::<CpuBackend>(&args, &Default::default()),
                #[cfg(feature = "cuda")]
                DeviceKind::Cuda => infer::<burn::backend::Cuda>(&args, &Default::default()),
                #[cfg(not(feature = "cuda"))]
                DeviceKind::Cuda => {
                    bail!("this build has no CUDA backend: rebuild with `--features cuda`")
                }
            }
        }
        Command::Bench {
            what,
            threads,
            train_size,
            infer_size,
        } => {
            set_threads(threads);
            let ts = train_size.unwrap_or_else(|| vec![2, 384, 512, 10]);
            let is = infer_size.unwrap_or_else(|| vec![480, 640]);
            if ts.len() != 4 || is.len() != 2 {
                bail!("--train-size takes batch,height,width,iters and --infer-size height,width");
            }
            match what {
                BenchWhat::Train => bench_train(ts[0], ts[1], ts[2], ts[3]),
                BenchWhat::Infer => bench_infer(is[0], is[1]),
                BenchWhat::All => {
                    let exe = std::env::current_exe()?;
                    let ts: Vec<String> = ts.iter().map(|v| v.to_string()).collect();
                    let is: Vec<String> = is.iter().map(|v| v.to_string()).collect();
                    for w in ["train", "infer"] {
                        let status = std::process::Command::new(&exe)
                            .args(["bench", "--what", w, "--threads", &threads.to_string()])
                            .args(["--train-size", &ts.join(","), "--infer-size", &is.join(",")])
                            .status()?;
                        if !status.success() {
                            bail!("bench {w} failed");
                        }
                    }
                    Ok(())
                }
            }
        }
    }
}

#[derive(Debug, clap::Args)]
struct InferArgs {
    /// Left image (PNG/JPEG).
    left: PathBuf,
    /// Right image (PNG/JPEG).
    right: PathBuf,
    /// Output disparity: float32 EXR (channel "Y"), or PFM if the name ends in .pfm.
    #[arg(short, long)]
    output: PathBuf,
    /// Also write a PFM copy here.
    #[arg(long)]
    pfm: Option<PathBuf>,
    /// Colourised disparity PNG with a colour bar.
    #[arg(long)]
    viz: Option<PathBuf>,
    /// Weights: a reference PyTorch state dict (.pt/.pth) or a Burn record (.mpk).
    #[arg(long, env = "CRESTEREO_WEIGHTS")]
    weights: Option<PathBuf>,
    /// Refinement iterations per pass.
    #[arg(long, default_value_t = 20)]
    iters: usize,
    /// Stacked cascades: 1, 2 (reference test procedure) or 3.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=3))]
    stages: u8,
}

fn infer<B: Backend>(a: &InferArgs, device: &B::Device) -> Result<()> {
    let (left, right): (&Path, &Path) = (&a.left, &a.right);
    let l = read_bgr(left)?;
    let r = read_bgr(right)?;
    if (l.width, l.height) != (r.width, r.height) {
        bail!(
            "left image {} is {}x{} but right image {} is {}x{}",
            left.display(),
            l.width,
            l.height,
            right.display(),
            r.width,
            r.height
        );
    }
    let weights = a
        .weights
        .as_deref()
        .context("no weights given: pass --weights FILE or set CRESTEREO_WEIGHTS")?;
    let model = CREStereoConfig::new().init::<B>(device);
    let model = load_weights(model, weights, device)?;
    let t0 = Instant::now();
    let disp = infer_disparity(
        &model,
        &l,
        &r,
        InferenceOptions {
            iters: a.iters,
            stages: usize::from(a.stages),
        },
        device,
    )?;
    eprintln!(
        "inference {}x{} ({} stages, {} iters): {:.2}s",
        l.width,
        l.height,
        usize::from(a.stages),
        a.iters,
        t0.elapsed().as_secs_f64()
    );
    let output: &Path = &a.output;
    if output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pfm"))
    {
        write_pfm(output, disp.width, disp.height, &disp.data)?;
    } else {
        write_exr(output, disp.width, disp.height, &disp.data)?;
    }
    if let Some(p) = &a.pfm {
        write_pfm(p, disp.width, disp.height, &disp.data)?;
    }
    if let Some(v) = &a.viz {
        write_visualisation(v, disp.width, disp.height, &disp.data)?;
    }
    Ok(())
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

fn bench_train(n: usize, h: usize, w: usize, iters: usize) -> Result<()> {
    type B = CpuAutodiffBackend;
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

fn bench_infer(h: usize, w: usize) -> Result<()> {
    type B = CpuBackend;
    let device = Default::default();
    let model = CREStereoConfig::new().init::<B>(&device);
    let (l, r) = random_images::<B>(1, h, w, &device);
    let t0 = Instant::now();
    let pred = crestereo::infer::cascade(
        &model,
        l,
        r,
        InferenceOptions {
            iters: 20,
            stages: 2,
        },
    );
    let _ = pred.into_data();
    println!(
        "inference (1x{h}x{w}, two-pass, 20 iters, threads {}): {:.2}s, peak RSS {:.0} MiB",
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into()),
        t0.elapsed().as_secs_f64(),
        peak_rss_mib()
    );
    Ok(())
}
