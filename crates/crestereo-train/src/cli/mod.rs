//! The `crestereo` command line: `infer`, `train`, `eval`, `export`, `plot` and `bench`.
//!
//! Every command here is generic over the backend; the binary (`src/main.rs`) parses the
//! arguments with [`main_with`] and binds each command to the backend `--device` names. That is
//! the one place the network is compiled for every backend: the library and its unit tests
//! compile none of them.

pub mod bench;
pub mod bench_device;
pub mod bench_loader;
pub mod devices;
pub mod eval;
pub mod export;
pub mod farm;
pub mod infer;
#[cfg(feature = "kernel-cache")]
pub mod kernel_cache;
pub mod kernel_census;
pub mod network_args;
pub mod score;
pub mod train;
pub mod warmup;

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser, Debug)]
#[command(
    name = "crestereo",
    version,
    about = "CREStereo stereo matching on Burn: inference, training, evaluation"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
// Parsed once at start-up and matched once: the size of the largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Command {
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
    /// Compile every GPU kernel a training config's shapes need into the kernel cache, and say
    /// how many, how long and which (the kernel census, by family and cause), to prepare a
    /// cluster image or a shared cache once.
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
pub struct BackendArgs {
    /// CPU threads for tensor work (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Backend, chosen at run time.
    #[arg(long, value_enum, default_value_t = DeviceKind::Cpu)]
    pub device: DeviceKind,
    /// Matrix products and convolutions on a GPU: `f32` (default) runs them in full float32
    /// through one fixed kernel per shape (no autotuning of them, so a cold start compiles only
    /// what runs; nothing rounded to a 10-bit mantissa); `tf32` hands them to Burn's autotuned
    /// kernels, which use TensorFloat-32 tensor cores on NVIDIA GPUs. Also CRESTEREO_PRECISION.
    /// The CPU backend always computes in float32.
    #[arg(long, value_enum, default_value_t = PrecisionArg::F32)]
    pub precision: PrecisionArg,
}

/// `--precision`.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum PrecisionArg {
    /// Full float32, one fixed kernel per shape class.
    F32,
    /// TensorFloat-32 on NVIDIA tensor cores (Burn's autotuned kernels).
    Tf32,
}

impl From<PrecisionArg> for crestereo::ops::matmul::Precision {
    fn from(p: PrecisionArg) -> Self {
        match p {
            PrecisionArg::F32 => crestereo::ops::matmul::Precision::F32,
            PrecisionArg::Tf32 => crestereo::ops::matmul::Precision::Tf32,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum DeviceKind {
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
pub enum BenchWhat {
    All,
    Train,
    Infer,
    /// Decoded-and-augmented training samples per second (needs --data).
    Loader,
}

impl Command {
    /// The `--threads`, `--device` and `--precision` of the commands that run the network.
    fn backend(&self) -> Option<&BackendArgs> {
        match self {
            Command::Infer { backend, .. }
            | Command::Train { backend, .. }
            | Command::Warmup { backend, .. }
            | Command::Eval { backend, .. }
            | Command::Score { backend, .. } => Some(backend),
            _ => None,
        }
    }

    /// The `--threads` this command was given (0 or none: one per core).
    fn threads(&self) -> usize {
        match self {
            Command::Bench { threads, .. } => *threads,
            other => other.backend().map_or(0, |b| b.threads),
        }
    }

    /// The `--precision` this command was given, if it takes one.
    fn precision(&self) -> Option<PrecisionArg> {
        self.backend().map(|b| b.precision)
    }

    /// The GPU this command runs on, if any (the kernel cache's folder depends on it).
    #[cfg(feature = "kernel-cache")]
    fn gpu_target(&self) -> Option<kernel_cache::GpuTarget> {
        use kernel_cache::GpuTarget;
        let (kind, ordinal) = match self {
            Command::Train {
                args:
                    train::TrainArgs {
                        devices: Some(spec),
                        ..
                    },
                backend,
            } => {
                let list = devices::parse_devices(spec, backend.device).ok()?;
                let first = match list.devices.first() {
                    Some(devices::DeviceIndex::Index(i)) => *i,
                    _ => 0,
                };
                (list.kind, first)
            }
            Command::Bench { device, .. } => (*device, 0),
            other => (other.backend()?.device, 0),
        };
        match kind {
            DeviceKind::Cpu => None,
            DeviceKind::Cuda => Some(GpuTarget::Cuda { ordinal }),
            DeviceKind::Vulkan => Some(GpuTarget::Vulkan),
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

/// The whole program around `run`, the binary's choice of backend for each command: logging, the
/// arguments, the kernel cache and the thread pool set up; `run` on a pool thread; its error
/// chain printed (exit 1), or the exit code of an interrupted run (75).
pub fn main_with(
    run: impl FnOnce(Cli, Option<std::path::PathBuf>) -> Result<()> + Send,
) -> ExitCode {
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
    let cli = Cli::parse();
    let warmup = matches!(cli.command, Command::Warmup { .. });
    // `warmup` always takes the kernel census; other GPU commands when asked. Its layer listens
    // at trace level, so it is only there when wanted (every `log::trace!` of wgpu would reach it).
    let census_file = kernel_census::requested();
    let census_wanted = warmup || census_file.is_some();
    // Each layer has its own filter: the log's leaves the fusion backend's read spans to the
    // counter (`bench --device cuda` prints them per training step), the counter's leaves
    // every event to the log.
    tracing_subscriber::registry()
        .with(log)
        .with(crate::host_reads::layer())
        .with(census_wanted.then(kernel_census::layer))
        .init();
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
    let cache = match cli.command.gpu_target() {
        Some(target) => {
            if census_wanted {
                kernel_census::start();
            }
            kernel_cache::configure(target, census_wanted)
        }
        None => None,
    };
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
    // --precision, else CRESTEREO_PRECISION where the flag was left at its default (or the
    // command has none), else float32.
    use crestereo::ops::matmul::{Precision, set_precision};
    let from_env = match std::env::var("CRESTEREO_PRECISION")
        .ok()
        .map(|v| v.parse::<Precision>())
    {
        Some(Err(e)) => {
            eprintln!("error: CRESTEREO_PRECISION: {e}");
            return ExitCode::FAILURE;
        }
        Some(Ok(p)) => Some(p),
        None => None,
    };
    match (cli.command.precision(), from_env) {
        (Some(PrecisionArg::F32) | None, Some(env)) => set_precision(env),
        (Some(flag), _) => set_precision(flag.into()),
        (None, None) => {}
    }
    // The whole command on a pool thread: each kernel then starts without a cold hand-over.
    let census_dir = cache.clone();
    let outcome = crestereo::ops::threads::on_pool(|| run(cli, cache));
    // `warmup` writes and prints its own census (by phase); the others' goes where asked.
    if !warmup
        && kernel_census::active()
        && let Some(file) = census_file
    {
        let path = file.or_else(|| {
            census_dir
                .as_deref()
                .map(|d| kernel_census::beside_cache(d, "run"))
        });
        match path {
            Some(path) => match kernel_census::snapshot().write(&path) {
                Ok(()) => eprintln!("kernel census: {}", path.display()),
                Err(e) => eprintln!("warning: kernel census not written: {e:#}"),
            },
            None => eprintln!(
                "warning: CRESTEREO_KERNEL_CENSUS=1 but no kernel cache folder to write it beside; name a file instead"
            ),
        }
    }
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<crate::interrupt::Interrupted>().is_some() => {
            eprintln!("{e}");
            ExitCode::from(crate::interrupt::EXIT_INTERRUPTED)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
