//! `crestereo`: see `crestereo --help`. The commands are the `crestereo_train` library's
//! (`src/cli/`), generic over the backend; this binary binds each to the backend `--device` names,
//! so the network is compiled for every backend here and nowhere else. It has no unit tests of its
//! own (`test = false`): the command line's are the library's.

use std::process::ExitCode;

use anyhow::{Result, bail};
use crestereo::{CpuAutodiffBackend, CpuBackend};
use crestereo_train::cli::{
    BenchWhat, Cli, Command, DeviceKind, bench, bench_device, bench_loader, devices, eval, export,
    farm, infer, score, train, warmup,
};

/// What a command asking for a backend this build left out says (the dispatch and `bench`).
#[cfg(not(feature = "cuda"))]
const NO_CUDA: &str = "this build has no CUDA backend: rebuild with `--features cuda`";
#[cfg(not(feature = "wgpu"))]
const NO_WGPU: &str = "this build has no wgpu/Vulkan backend: rebuild with `--features vulkan`";

fn main() -> ExitCode {
    crestereo_train::cli::main_with(run)
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
                bail!(NO_CUDA)
            }
            #[cfg(feature = "wgpu")]
            DeviceKind::Vulkan => {
        type $b = with_backend!(@wgpu $ad);
                $body
            }
            #[cfg(not(feature = "wgpu"))]
            DeviceKind::Vulkan => {
                bail!(NO_WGPU)
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

/// Each command on the backend its `--device` names (autodiff for the ones that train).
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
        Command::Export(command) => export::run::<CpuBackend>(&command, &Default::default()),
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
            #[cfg(feature = "cuda")]
            DeviceKind::Cuda => bench_device::run_on::<crestereo::CudaAutodiffBackend>(&plan),
            #[cfg(not(feature = "cuda"))]
            DeviceKind::Cuda => {
                bail!(NO_CUDA)
            }
            #[cfg(feature = "wgpu")]
            _ => bench_device::run_on::<crestereo::WgpuAutodiffBackend>(&plan),
            #[cfg(not(feature = "wgpu"))]
            _ => bail!(NO_WGPU),
        };
    }
    if what != BenchWhat::All {
        println!("{}", bench::cpu_line());
    }
    match what {
        BenchWhat::Train => bench::bench_train::<CpuAutodiffBackend>(ts[0], ts[1], ts[2], ts[3]),
        BenchWhat::Infer => bench::bench_infer::<CpuBackend>(is[0], is[1]),
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
