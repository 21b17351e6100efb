//! The GPU path on a software Vulkan device: Mesa's lavapipe runs Burn's wgpu backend (kernels
//! compiled to SPIR-V) on the CPU, so the CubeCL AGCL kernels, their fusion wrappers and a
//! whole training step go through a real GPU compiler and launcher in every CI run.
//!
//! * the AGCL kernels forward and backward against the composed ops and the historical
//!   implementation, and against central finite differences (the checks `tests/agcl.rs` runs
//!   on Flex, `crestereo/tests/agcl_checks`);
//! * the whole network against the reference fixtures at the Flex bounds (layers ≤ 1e-4,
//!   predictions ≤ 1e-3, gradient cosine ≥ 0.9999: `test-support/src/network_fixtures/network_checks.rs`),
//!   and `crestereo infer --device vulkan`'s two-pass disparity against `--device cpu`'s;
//! * three training steps on a fixed sample with a falling loss, counting the backend's reads to
//!   the host: one per step (the logged loss), none inside forward, backward or Adam;
//! * the kernel census: what a cold two-pass inference and a cold training step compile, by
//!   family and cause, held to a budget (a count, not a time), and a copied binary that finds
//!   its twin's kernel cache.
//!
//! lavapipe comes from Debian's `mesa-vulkan-drivers`, installed with apt-get when missing and
//! running as root. Without it the tests print why and pass, unless `STEREOGEN_REQUIRE_VULKAN=1`
//! (set by `.ci/run`), which makes them fail.
#![cfg(feature = "vulkan")]

use std::path::Path;
use std::process::Command;
use std::sync::OnceLock;

use burn::backend::{Autodiff, Wgpu};
use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use crestereo::ops::dispatch::{Kernels, kernels};
use crestereo_train::cli::kernel_census::Census;
use crestereo_train::host_reads::{HostReadCounter, count as reads};
use test_support::agcl_checks::{self, LAVAPIPE as DEVICE};
use test_support::network_fixtures::{self, network_checks};

type W = Wgpu;
type Wa = Autodiff<Wgpu>;

const LAVAPIPE_ICD: &str = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json";

/// Whether lavapipe is installed (installing it when missing and allowed); panics where it must
/// be there (`STEREOGEN_REQUIRE_VULKAN=1`) and is not.
fn lavapipe() -> bool {
    static FOUND: OnceLock<bool> = OnceLock::new();
    *FOUND.get_or_init(|| {
        let present = || Path::new(LAVAPIPE_ICD).exists();
        // SAFETY: geteuid has no preconditions.
        let root = unsafe { libc::geteuid() } == 0;
        if !present() && root {
            eprintln!("vulkan: installing mesa-vulkan-drivers (lavapipe) with apt-get");
            let apt = |args: &[&str]| {
                Command::new("apt-get")
                    .args(args)
                    .env("DEBIAN_FRONTEND", "noninteractive")
                    .status()
                    .is_ok_and(|s| s.success())
            };
            if !apt(&["install", "-y", "--no-install-recommends", "mesa-vulkan-drivers"]) {
                apt(&["update"]);
                apt(&["install", "-y", "--no-install-recommends", "mesa-vulkan-drivers"]);
            }
        }
        let required = std::env::var("STEREOGEN_REQUIRE_VULKAN").is_ok_and(|v| v == "1");
        if present() && std::env::var_os("CUBECL_AUTOTUNE_LEVEL").is_none() {
            // Autotuning compiles and times every candidate kernel of each new shape: minutes
            // on a software device, for no use in a parity test. Set before the first device
            // (this runs before any test touches one); the CLI child inherits it.
            // SAFETY: no other thread reads the environment here (the OnceLock serialises).
            unsafe { std::env::set_var("CUBECL_AUTOTUNE_LEVEL", "minimal") };
        }
        if present() {
            // CubeCL keeps autotune results in the `target/` folder beside the nearest
            // Cargo.toml of the working directory, i.e. inside this crate's sources when cargo
            // runs the tests: this process's go to cargo's scratch folder for tests instead.
            use cubecl_common::config::RuntimeConfig;
            use cubecl_runtime::config::{CubeClRuntimeConfig, cache::CacheConfig};
            let mut config = CubeClRuntimeConfig::from_current_dir().override_from_env();
            config.autotune.cache =
                CacheConfig::File(Path::new(env!("CARGO_TARGET_TMPDIR")).join("cubecl"));
            CubeClRuntimeConfig::set(config);
        }
        match (present(), required) {
            (true, _) => true,
            (false, true) => panic!(
                "STEREOGEN_REQUIRE_VULKAN=1 but lavapipe ({LAVAPIPE_ICD}) is missing and could not be installed (Debian package mesa-vulkan-drivers; needs root)"
            ),
            (false, false) => {
                eprintln!(
                    "vulkan: SKIPPED — lavapipe ({LAVAPIPE_ICD}) is missing; install Debian's mesa-vulkan-drivers, or run as root"
                );
                false
            }
        }
    })
}

/// The wgpu backend on lavapipe takes the CubeCL AGCL kernels (lavapipe adds floats
/// atomically): the checks below exercise the kernels, not the composed fallback.
fn assert_kernels() {
    assert_eq!(kernels::<W>(&DEVICE), Kernels::Wgpu);
    assert_eq!(kernels::<Wa>(&DEVICE), Kernels::AutodiffWgpu);
}

#[test]
fn agcl_kernels_forward_and_backward() {
    if !lavapipe() {
        return;
    }
    assert_kernels();
    agcl_checks::offset_corr_forward::<W>();
    agcl_checks::warp_forward::<W>();
    agcl_checks::shift_corr_forward_and_gradients::<W, Wa>();
    agcl_checks::offset_corr_and_warp_gradients::<Wa>();
    agcl_checks::offset_corr_finite_differences::<W>();
}

#[test]
fn network_forward_matches_fixtures() {
    if !lavapipe() {
        return;
    }
    assert_kernels();
    network_checks::train_forward_intermediates_predictions_and_loss::<W>(&DEVICE);
}

#[test]
fn gradients_match_fixtures() {
    if !lavapipe() {
        return;
    }
    let w = network_checks::gradients::<Wa>(&DEVICE, false);
    network_checks::assert_float32_gradients(&w);
}

/// Three Adam steps on the first sample of the fixture pair (reference weights, 2 iterations;
/// one sample and two iterations keep lavapipe's share of CI small): the loss falls at every
/// step, and the only host read of a step is its loss value.
#[test]
fn training_steps_lower_the_loss_without_host_reads() {
    if !lavapipe() {
        return;
    }
    use tracing_subscriber::layer::SubscriberExt;
    let _ = tracing::subscriber::set_global_default(
        tracing_subscriber::registry().with(HostReadCounter),
    );
    // The counter sees reads only through the tracing callsites; check it does before relying
    // on a zero.
    let probe = Tensor::<W, 1>::from_floats([1.0, 2.0], &DEVICE);
    let before = reads();
    let _ = probe.into_data();
    assert_eq!(
        reads() - before,
        1,
        "the read counter does not see host reads"
    );

    let device = DEVICE;
    let mut model = network_fixtures::model::<Wa>(&device);
    let t = "train_b2_64x128";
    let first = |name: &str| {
        let a = network_fixtures::npy(&format!("{t}/{name}.npy"));
        let per_sample = a.data.len() / a.shape[0];
        (a.data[..per_sample].to_vec(), a.shape[1..].to_vec())
    };
    let image = |name: &str| {
        let (data, shape) = first(name);
        Tensor::<Wa, 4>::from_data(
            TensorData::new(data, [1, shape[0], shape[1], shape[2]]),
            &device,
        )
    };
    let map = |name: &str| {
        let (data, _) = first(name);
        Tensor::<Wa, 3>::from_data(TensorData::new(data, [1, 64, 128]), &device)
    };
    let (left, right) = (image("left"), image("right"));
    let (disp, valid) = (map("gt_disp"), map("valid"));
    let mut optim = AdamConfig::new()
        .with_beta_1(0.9)
        .with_beta_2(0.999)
        .with_epsilon(1e-8)
        .init();
    let mut losses = Vec::new();
    for step in 0..3 {
        let t0 = std::time::Instant::now();
        let start = reads();
        let preds = model.forward(left.clone(), right.clone(), 2, None);
        let loss = crestereo::sequence_loss(&preds, disp.clone(), valid.clone(), 0.9);
        let in_forward = reads() - start;
        let value: f64 = loss.clone().into_scalar().elem();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(1e-4, model, grads);
        let total = reads() - start;
        println!(
            "step {step}: loss {value:.6}, host reads: forward {in_forward}, whole step {total}, {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        assert_eq!(in_forward, 0, "host reads inside the forward pass");
        assert_eq!(
            total, 1,
            "host reads in a training step besides the logged loss"
        );
        assert!(value.is_finite());
        losses.push(value);
    }
    assert!(
        losses[1] < losses[0] && losses[2] < losses[1],
        "the loss did not fall: {losses:?}"
    );
}

/// The default precision is in force on the wgpu backend: matrix products take the fixed float32
/// kernel (`crestereo::ops::matmul`), plain and under autodiff, and agree with Flex's to float32
/// rounding, forward and gradients (shapes that are no multiple of any tile, batch broadcast).
#[test]
fn fixed_f32_matmul_matches_the_cpu() {
    if !lavapipe() {
        return;
    }
    use burn::backend::Flex;
    use burn::tensor::Distribution;
    use crestereo::ops::matmul::{Precision, matmul, precision, runs_fixed_f32};
    assert_eq!(precision(), Precision::F32, "float32 is the default");
    let cpu = Default::default();
    let l = Tensor::<Flex, 3>::random([2, 37, 53], Distribution::Normal(0.0, 1.0), &cpu);
    let r = Tensor::<Flex, 3>::random([1, 53, 29], Distribution::Normal(0.0, 1.0), &cpu);
    let up = Tensor::<Flex, 3>::random([2, 37, 29], Distribution::Normal(0.0, 1.0), &cpu);
    let on = |t: &Tensor<Flex, 3>| Tensor::<Wa, 3>::from_data(t.to_data(), &DEVICE);
    let (gl, gr) = (on(&l).require_grad(), on(&r).require_grad());
    assert!(
        runs_fixed_f32(&[&gl, &gr]),
        "autodiff wgpu: not the fixed kernel"
    );
    let plain = (on(&l).inner(), on(&r).inner());
    assert!(
        runs_fixed_f32(&[&plain.0, &plain.1]),
        "wgpu: not the fixed kernel"
    );
    let y = matmul(gl.clone(), gr.clone());
    let grads = (y.clone() * on(&up)).sum().backward();
    let (al, ar) = (
        Tensor::<Autodiff<Flex>, 3>::from_data(l.to_data(), &cpu).require_grad(),
        Tensor::<Autodiff<Flex>, 3>::from_data(r.to_data(), &cpu).require_grad(),
    );
    let y_cpu = al.clone().matmul(ar.clone());
    let g_cpu = (y_cpu.clone() * Tensor::from_data(up.to_data(), &cpu))
        .sum()
        .backward();
    let max_rel = |a: TensorData, b: TensorData| {
        let (a, b) = (a.to_vec::<f32>().unwrap(), b.to_vec::<f32>().unwrap());
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        a.iter()
            .zip(&b)
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()))
            / scale
    };
    let checks = [
        ("product", max_rel(y.into_data(), y_cpu.into_data())),
        (
            "d lhs",
            max_rel(
                gl.grad(&grads).unwrap().into_data(),
                al.grad(&g_cpu).unwrap().into_data(),
            ),
        ),
        (
            "d rhs",
            max_rel(
                gr.grad(&grads).unwrap().into_data(),
                ar.grad(&g_cpu).unwrap().into_data(),
            ),
        ),
    ];
    for (what, err) in checks {
        println!(
            "fixed float32 matmul on lavapipe vs Flex, {what}: max |diff| / max |value| = {err:.2e}"
        );
        // TF32 (10-bit mantissa) would be ~1e-3 here; float32 sums of 53 or 74 terms stay ~1e-6.
        assert!(err <= 1e-5, "{what}: {err}");
    }
}

/// Kernels a cold `crestereo infer --device vulkan` (two-pass, 20 iterations, the fixture pair's
/// 128×192) may compile on lavapipe: every kernel of the work and of its autotunings, at
/// CubeCL's minimal autotune level. Measured: 173 with Burn's autotuned matrix products and
/// convolutions (`--precision tf32`, the path before the fixed float32 kernel), 151 or 152 at
/// the default `f32` (what autotuning and fusion compile varies by a kernel or two from run to
/// run, hence the few kernels of margin). A change that compiles more fails here; lower the
/// figure when one compiles fewer.
const INFER_KERNEL_BUDGET: usize = 156;
/// The same for one training step (batch 1 of 64×128, 2 iterations, Adam) from an empty cache:
/// 391 at `tf32`, 318 to 321 at `f32` (four runs).
const TRAIN_KERNEL_BUDGET: usize = 330;

/// Compiled-kernel count of CubeCL's own compilation log (`CUBECL_DEBUG_LOG`).
fn compiled_in_log(log: &Path) -> usize {
    std::fs::read_to_string(log)
        .map(|l| l.matches("[START_KERNEL_COMPILATION]").count())
        .unwrap_or(0)
}

/// Checks a census against CubeCL's own log of the same process and against `budget`, and
/// prints it.
fn check_census(census: &Census, log: &Path, what: &str, budget: usize) {
    println!("{what}: kernel census\n{}", census.table());
    let compiled = census.total.total();
    assert_eq!(
        compiled,
        compiled_in_log(log),
        "{what}: the census and CubeCL's log disagree"
    );
    for k in &census.kernels {
        assert!(
            !k.family.is_empty() && k.key.starts_with("KernelId {"),
            "{what}: a kernel without family or shape key: {k:?}"
        );
    }
    assert!(
        compiled <= budget,
        "{what}: {compiled} kernels compiled from an empty cache, over the budget of {budget}"
    );
}

/// `crestereo infer --device vulkan`, as a user runs it (the default wgpu device, pointed at
/// lavapipe with CUBECL_WGPU_DEFAULT_DEVICE=Cpu), against `crestereo infer --device cpu` on the
/// fixture pair, both two-pass with 20 iterations (the Flex CLI is checked against the
/// reference's prediction in `tests/integration/cli.rs`, and the network on lavapipe against
/// the fixtures above). The Vulkan run is made twice with one kernel cache
/// (`CRESTEREO_KERNEL_CACHE`): the first, from an empty cache, takes the kernel census
/// (`CRESTEREO_KERNEL_CENSUS`), which must count what CubeCL's own compilation log counts and
/// stay within [`INFER_KERNEL_BUDGET`]; the second runs a *copy* of the binary from another
/// folder (the cache is keyed by the binary's content, not its path or time), compiles nothing
/// and gives the same bits.
#[test]
fn cli_infer_on_vulkan_matches_the_cpu() {
    if !lavapipe() {
        return;
    }
    let fixtures = network_fixtures::fixtures();
    let e = fixtures.join("eval_cascade_1x128x192");
    let out = tempfile::tempdir().unwrap();
    let cache = out.path().join("kernels");
    let copy = out.path().join("elsewhere").join("crestereo");
    std::fs::create_dir_all(copy.parent().unwrap()).unwrap();
    std::fs::copy(env!("CARGO_BIN_EXE_crestereo"), &copy).unwrap();
    let census_file = out.path().join("census.json");
    let infer = |bin: &Path, device: &str, run: usize| {
        let pfm = out.path().join(format!("disp_{device}_{run}.pfm"));
        let log = out.path().join(format!("cubecl_{device}_{run}.log"));
        let t0 = std::time::Instant::now();
        let mut cmd = Command::new(bin);
        cmd.arg("infer")
            .args([e.join("left.png"), e.join("right.png")])
            .arg("-o")
            .arg(&pfm)
            .arg("--weights")
            .arg(fixtures.join("weights_seed0.pt"))
            .args(["--iters", "20", "--stages", "2", "--device", device])
            .env("CUBECL_WGPU_DEFAULT_DEVICE", "Cpu")
            .env("CRESTEREO_KERNEL_CACHE", &cache)
            .env("CUBECL_DEBUG_LOG", &log);
        if run == 1 && device == "vulkan" {
            cmd.env("CRESTEREO_KERNEL_CENSUS", &census_file);
        }
        let status = cmd.status().unwrap();
        assert!(status.success(), "crestereo infer --device {device} failed");
        let compiled = compiled_in_log(&log);
        println!(
            "infer --device {device} (run {run}, {}): {compiled} kernels compiled, {:.1} s",
            bin.display(),
            t0.elapsed().as_secs_f64()
        );
        (
            stereo_io::read_disparity(&pfm, None).unwrap().0.data,
            compiled,
            log,
        )
    };
    let bin = Path::new(env!("CARGO_BIN_EXE_crestereo"));
    let (vulkan, compiled_cold, cold_log) = infer(bin, "vulkan", 1);
    let (vulkan_again, compiled_warm, _) = infer(&copy, "vulkan", 2);
    let (cpu, _, _) = infer(bin, "cpu", 1);
    assert!(
        compiled_cold > 0,
        "the compilation log saw no kernel compiled on a cold cache"
    );
    let census = Census::read(&census_file).unwrap();
    check_census(
        &census,
        &cold_log,
        "infer two-pass 20 iterations 128x192",
        INFER_KERNEL_BUDGET,
    );
    assert_eq!(
        compiled_warm, 0,
        "a copy of the binary compiled kernels again although the kernel cache held them"
    );
    assert!(
        vulkan
            .iter()
            .zip(&vulkan_again)
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "cached kernels gave a different disparity"
    );
    let (err, range) = network_fixtures::max_err(&vulkan, &cpu);
    println!(
        "crestereo infer --device vulkan vs --device cpu: max |diff| = {err:.3e} (max |disparity| {range:.2})"
    );
    assert!(err <= 1e-3, "{err}");
}

/// `crestereo warmup --device vulkan` for one training step from an empty cache: it prints the
/// kernel census by family and cause, writes it beside the kernel cache (in the build's `spirv/`
/// folder), counts what CubeCL's own compilation log counts, and stays within
/// [`TRAIN_KERNEL_BUDGET`].
#[test]
fn warmup_accounts_for_every_kernel_of_a_training_step() {
    if !lavapipe() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("kernels");
    let log = dir.path().join("cubecl.log");
    let t0 = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_crestereo"))
        .args(["warmup", "--device", "vulkan", "--crop", "64x128"])
        .args(["--batch-size", "1", "--iters", "2"])
        .env("CUBECL_WGPU_DEFAULT_DEVICE", "Cpu")
        .env("CRESTEREO_KERNEL_CACHE", &cache)
        .env("CUBECL_DEBUG_LOG", &log)
        .env_remove("CRESTEREO_KERNEL_CENSUS")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!(
        "warmup, one training step on lavapipe: {:.1} s\n{stdout}",
        t0.elapsed().as_secs_f64()
    );
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("training step 1x64x128, 2 iterations"),
        "{stdout}"
    );
    assert!(
        stdout.contains("family") && stdout.contains("tuning"),
        "{stdout}"
    );
    // <cache>/<version>-<hash>/spirv/census/warmup-*.json
    let builds: Vec<_> = std::fs::read_dir(&cache)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name() != "binaries")
        .collect();
    assert_eq!(builds.len(), 1, "one build folder");
    assert!(
        cache.join("binaries").read_dir().unwrap().count() == 1,
        "the binary's hash is kept for its next start"
    );
    let census_dir = builds[0].path().join("spirv").join("census");
    let files: Vec<_> = std::fs::read_dir(&census_dir)
        .unwrap_or_else(|e| panic!("{}: {e}", census_dir.display()))
        .flatten()
        .collect();
    assert_eq!(files.len(), 1);
    let census = Census::read(&files[0].path()).unwrap();
    check_census(
        &census,
        &log,
        "training step 1x64x128, 2 iterations",
        TRAIN_KERNEL_BUDGET,
    );
}

/// Running out of device memory is one line naming what to lower and exit status 71, not a
/// backend panic. Shown on lavapipe, whose device memory is the process's own: the training runs
/// with its address space limited to 6 GB (`ulimit -v`) at a batch of 32 paper crops, so the
/// first large buffer fails (wgpu: "can't allocate buffer of size …", on CubeCL's device thread).
/// Before, that gave thousands of follow-on panics and an abort (SIGABRT).
#[test]
fn training_out_of_device_memory_is_one_line() {
    if !lavapipe() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    crestereo_train::synthetic::write_crestereo_dataset(&data, 4, 512, 384, 0).unwrap();
    let t0 = std::time::Instant::now();
    let out = Command::new("sh")
        .args(["-c", "ulimit -v 6000000 && exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_crestereo"))
        .args(["train", "--device", "vulkan", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(dir.path().join("run"))
        .args(["--steps", "1", "--batch-size", "32", "--accumulate", "1"])
        .args(["--crop", "384x512", "--iters", "4", "--no-progress"])
        .env("CUBECL_WGPU_DEFAULT_DEVICE", "Cpu")
        .env("CRESTEREO_KERNEL_CACHE", dir.path().join("kernels"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!(
        "out of memory on lavapipe: exit {:?} after {:.1} s",
        out.status.code(),
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(
        out.status.code(),
        Some(i32::from(crestereo_train::oom::EXIT_OUT_OF_MEMORY)),
        "{stderr}"
    );
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error: the device ran out of memory during training"))
        .unwrap_or_else(|| panic!("no out-of-memory line in:\n{stderr}"));
    assert!(line.contains("lower --batch-size"), "{line}");
    assert!(
        line.contains("--crop") && line.contains("--iters"),
        "{line}"
    );
    assert!(
        !stderr.contains("panicked"),
        "a panic reached the terminal:\n{stderr}"
    );
}
