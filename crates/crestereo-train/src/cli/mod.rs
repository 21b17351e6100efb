//! The `crestereo` command line: `infer`, `train`, `eval`, `export`, `plot` and `bench`.

mod bench;
mod bench_device;
mod bench_loader;
mod devices;
mod eval;
mod export;
mod farm;
mod infer;
#[cfg(feature = "kernel-cache")]
mod kernel_cache;
mod network_args;
mod score;
mod train;
mod warmup;

use std::process::ExitCode;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use crestereo::{CpuAutodiffBackend, CpuBackend};

#[derive(Parser, Debug)]
#[command(
    name = "crestereo",
    version,
    about = "CREStereo stereo matching on Burn: inference, training, evaluation"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
// Parsed once at start-up and matched once: the size of the largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
enum Command {
    /// Estimate the disparity of a rectified pair (left view).
    Infer {
        #[command(flatten)]
        args: infer::InferArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Train (or continue training) a model on stereogen output and public stereo datasets.
    Train {
        #[command(flatten)]
        args: train::TrainArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Evaluate weights on a dataset: EPE, RMS, Bad-τ, D1, A50–A99, mxIoU; JSON + per-image CSV.
    Eval {
        #[command(flatten)]
        args: eval::EvalArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Score every sample of a dataset with a model: the per-image metrics of `eval` (EPE,
    /// Bad-τ, D1, ... on all and non-occluded pixels), one JSON line each, resumable.
    Score {
        #[command(flatten)]
        args: score::ScoreArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Compile and autotune every GPU kernel a training config's shapes need into the kernel
    /// cache, and say how many and how long (prepare a cluster image or a shared cache once).
    Warmup {
        #[command(flatten)]
        args: warmup::WarmupArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Job files for running training on a cluster: `farm slurm` writes an sbatch script for a
    /// multi-node data-parallel run.
    #[command(subcommand)]
    Farm(farm::FarmCommand),
    /// Take a model out of the binary: an ONNX graph or a PyTorch state dict.
    #[command(subcommand)]
    Export(export::ExportCommand),
    /// Draw a run's loss and validation curves as a PNG.
    Plot {
        /// The training run directory (reads train_log.csv and val_log.csv).
        run: std::path::PathBuf,
        /// Output PNG.
        #[arg(short, long)]
        out: std::path::PathBuf,
        /// Moving-average window (steps) of the smoothed loss line.
        #[arg(long, default_value_t = 25)]
        smooth: usize,
    },
    /// Write analytic stereo pairs (two textured planes, exact disparity for both views) in the
    /// CREStereo layout: a smoke test of a training setup without rendering anything.
    Synth {
        #[arg(long)]
        out: std::path::PathBuf,
        #[arg(long, default_value_t = 8)]
        count: usize,
        /// Image size HxW.
        #[arg(long, default_value = "64x128")]
        size: String,
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// Time one training step and one inference (random weights and inputs), or the data
    /// loader (`--what loader`).
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
        /// Backend: `cuda` or `vulkan` times the GPU in this process (a warm-up run, then the
        /// median of --repeats; `cuda` needs a build with `--features cuda`).
        #[arg(long, value_enum, default_value_t = DeviceKind::Cpu)]
        device: DeviceKind,
        /// Timed runs after the warm-up (GPU devices only).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        #[command(flatten)]
        loader: bench_loader::LoaderBenchArgs,
    },
}

#[derive(Debug, clap::Args)]
struct BackendArgs {
    /// CPU threads for tensor work (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Backend, chosen at run time.
    #[arg(long, value_enum, default_value_t = DeviceKind::Cpu)]
    device: DeviceKind,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum DeviceKind {
    /// Flex CPU backend.
    Cpu,
    /// CUDA GPU 0 (needs a build with `--features cuda`).
    Cuda,
    /// wgpu with kernels compiled to SPIR-V for Vulkan (the default build has it). Picks wgpu's
    /// high-performance adapter (a discrete GPU first); choose another with
    /// CUBECL_WGPU_DEFAULT_DEVICE, e.g. `DiscreteGpu(1)`, `IntegratedGpu(0)` or `Cpu`.
    #[value(alias = "wgpu")]
    Vulkan,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum BenchWhat {
    All,
    Train,
    Infer,
    /// Decoded-and-augmented training samples per second (needs --data).
    Loader,
}

impl Command {
    /// The `--threads` this command was given (0 or none: one per core).
    fn threads(&self) -> usize {
        match self {
            Command::Infer { backend, .. }
            | Command::Train { backend, .. }
            | Command::Warmup { backend, .. }
            | Command::Eval { backend, .. }
            | Command::Score { backend, .. } => backend.threads,
            Command::Bench { threads, .. } => *threads,
            _ => 0,
        }
    }
}

fn set_threads(n: usize) {
    if n > 0 {
        // SAFETY: called at start-up before any other thread exists. Set as well as the pool
        // size so that child processes (`bench --what all`) and the bench's report see it.
        unsafe { std::env::set_var("RAYON_NUM_THREADS", n.to_string()) };
    }
}

/// Runs `$body` with `B` bound to the chosen backend (`$ad` for autodiff, `$plain` otherwise).
macro_rules! with_backend {
    ($kind:expr, $ad:tt, |$b:ident| $body:expr) => {
        match $kind {
            DeviceKind::Cpu => {
        type $b = with_backend!(@cpu $ad);
                $body
            }
            #[cfg(feature = "cuda")]
            DeviceKind::Cuda => {
        type $b = with_backend!(@cuda $ad);
                $body
            }
            #[cfg(not(feature = "cuda"))]
            DeviceKind::Cuda => {
                bail!("this build has no CUDA backend: rebuild with `--features cuda`")
            }
            #[cfg(feature = "wgpu")]
            DeviceKind::Vulkan => {
        type $b = with_backend!(@wgpu $ad);
                $body
            }
            #[cfg(not(feature = "wgpu"))]
            DeviceKind::Vulkan => {
                bail!("this build has no wgpu/Vulkan backend: rebuild with `--features vulkan`")
            }
        }
    };
    (@cpu true) => {
        CpuAutodiffBackend
    };
    (@cpu false) => {
        CpuBackend
    };
    (@cuda true) => {
        crestereo::CudaAutodiffBackend
    };
    (@cuda false) => {
        crestereo::CudaBackend
    };
    (@wgpu true) => {
        crestereo::WgpuAutodiffBackend
    };
    (@wgpu false) => {
        crestereo::WgpuBackend
    };
}

fn run(cli: Cli, cache: Option<std::path::PathBuf>) -> Result<()> {
    match cli.command {
        Command::Infer { args, backend } => {
            with_backend!(backend.device, false, |B| infer::infer::<B>(
                &args,
                &Default::default()
            ))
        }
        Command::Train { args, backend } => {
            let devices = args
                .devices
                .as_deref()
                .map(|d| devices::parse_devices(d, backend.device))
                .transpose()?;
            let kind = devices.as_ref().map_or(backend.device, |d| d.kind);
            with_backend!(kind, true, |B| train::run::<B>(
                &args,
                &Default::default(),
                devices.as_ref()
            ))
        }
        Command::Eval { args, backend } => {
            with_backend!(backend.device, false, |B| eval::run::<B>(
                &args,
                &Default::default()
            ))
        }
        Command::Score { args, backend } => {
            with_backend!(backend.device, false, |B| score::run::<B>(
                &args,
                &Default::default()
            ))
        }
        Command::Warmup { args, backend } => {
            // The CPU backend compiles nothing: no cache to speak of.
            let cache = cache
                .as_deref()
                .filter(|_| backend.device != DeviceKind::Cpu);
            with_backend!(backend.device, true, |B| warmup::run::<B>(
                &args,
                &Default::default(),
                cache
            ))
        }
        Command::Farm(command) => farm::run(&command),
        Command::Export(command) => export::run(&command),
        Command::Plot { run, out, smooth } => {
            crestereo_train::plot::plot_run(&run, &out, smooth)?;
            eprintln!("wrote {}", out.display());
            Ok(())
        }
        Command::Synth {
            out,
            count,
            size,
            seed,
        } => {
            let [h, w] = train::parse_crop(&size)?;
            crestereo_train::synthetic::write_crestereo_dataset(&out, count, w, h, seed)?;
            eprintln!("wrote {count} pairs of {w}x{h} to {}", out.display());
            Ok(())
        }
        Command::Bench {
            what,
            threads,
            train_size,
            infer_size,
            device,
            repeats,
            loader,
        } => run_bench(
            what, threads, train_size, infer_size, device, repeats, loader,
        ),
    }
}

/// `crestereo bench`: one part in this process, or both in child processes.
fn run_bench(
    what: BenchWhat,
    threads: usize,
    train_size: Option<Vec<usize>>,
    infer_size: Option<Vec<usize>>,
    device: DeviceKind,
    repeats: usize,
    loader: bench_loader::LoaderBenchArgs,
) -> Result<()> {
    let ts = train_size.unwrap_or_else(|| vec![2, 384, 512, 10]);
    let is = infer_size.unwrap_or_else(|| vec![480, 640]);
    if ts.len() != 4 || is.len() != 2 {
        bail!("--train-size takes batch,height,width,iters and --infer-size height,width");
    }
    if what == BenchWhat::Loader {
        return bench_loader::run(&loader);
    }
    if device != DeviceKind::Cpu {
        let plan = bench_device::DeviceBench {
            train: what != BenchWhat::Infer,
            infer: what != BenchWhat::Train,
            train_size: &ts,
            infer_size: &is,
            repeats,
        };
        return match device {
            DeviceKind::Cuda => bench_device::run_cuda(&plan),
            _ => bench_device::run_wgpu(&plan),
        };
    }
    if what != BenchWhat::All {
        println!("{}", bench::cpu_line());
    }
    match what {
        BenchWhat::Train => bench::bench_train(ts[0], ts[1], ts[2], ts[3]),
        BenchWhat::Infer => bench::bench_infer(is[0], is[1]),
        BenchWhat::Loader => unreachable!("timed above"),
        BenchWhat::All => {
            // Separate processes, so each peak RSS is its own.
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

/// The whole program: parse, run, print the error chain on failure.
pub fn main() -> ExitCode {
    use tracing_subscriber::prelude::*;
    let log = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .without_time()
        .with_filter(
            tracing_subscriber::EnvFilter::try_from_env("CRESTEREO_LOG")
                // CubeCL logs every autotuned kernel shape at info, Burn's collective every
                // connection and transfer: quiet unless asked for.
                .unwrap_or_else(|_| {
                    "info,cubecl_runtime=warn,burn_collective=warn,burn_collective::global::orchestrator=off,burn_communication=warn".into()
                }),
        );
    // Each layer has its own filter: the log's leaves the fusion backend's read spans to the
    // counter (`bench --device cuda` prints them per training step), the counter's leaves
    // every event to the log.
    tracing_subscriber::registry()
        .with(log)
        .with(crestereo_train::host_reads::layer())
        .init();
    let cli = Cli::parse();
    if let Command::Warmup { args, .. } = &cli.command
        && let Some(level) = &args.autotune_level
    {
        #[cfg(feature = "kernel-cache")]
        if let Err(e) = kernel_cache::parse_autotune_level(level) {
            eprintln!("error: --autotune-level: {e}");
            return ExitCode::FAILURE;
        }
        // SAFETY: at start-up, before any other thread exists; read by `kernel_cache`.
        unsafe { std::env::set_var("CRESTEREO_AUTOTUNE_LEVEL", level) };
    }
    #[cfg(feature = "kernel-cache")]
    let cache = kernel_cache::configure();
    #[cfg(not(feature = "kernel-cache"))]
    let cache: Option<std::path::PathBuf> = None;
    if let Some(dir) = &cache {
        tracing::debug!("GPU kernel cache: {}", dir.display());
    }
    // A bad CRESTEREO_ISA is a clear error here rather than a panic inside the first kernel.
    if let Err(e) = crestereo::ops::simd::isa_from_env() {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    set_threads(cli.command.threads());
    // The whole command on a pool thread: each kernel then starts without a cold hand-over.
    match crestereo::ops::threads::on_pool(|| run(cli, cache)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e)
            if e.downcast_ref::<crestereo_train::interrupt::Interrupted>()
                .is_some() =>
        {
            eprintln!("{e}");
            ExitCode::from(crestereo_train::interrupt::EXIT_INTERRUPTED)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
