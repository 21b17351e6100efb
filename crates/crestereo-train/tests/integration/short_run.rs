//! A model after a few training steps, made through the real `crestereo synth` and
//! `crestereo train` (for the export tests and `cli_train`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The flags of a training run small enough for a test: 32×64 crops, 2 iterations, batch 1,
/// no accumulation, no progress bar, 2 threads.
pub const TINY_TRAINING: [&str; 11] = [
    "--crop",
    "32x64",
    "--iters",
    "2",
    "--batch-size",
    "1",
    "--accumulate",
    "1",
    "--no-progress",
    "--threads",
    "2",
];

/// Steps of [`fine_tune`]; its checkpoint is `RUN/checkpoints/step-00000003`.
pub const STEPS: &str = "3";

/// Fine-tunes `reference` for three steps at a small learning rate on two synthetic pairs
/// (32×64 crops, 2 iterations) in `dir/run`, which it returns. The prediction on the fixture
/// pair still moves by several pixels; a random init, or the default rate, gives disparities of
/// hundreds of pixels there, where float32 spaces values 3e-5 px apart and a 1e-4 px bound
/// would measure rounding, not an export.
pub fn fine_tune(dir: &Path, reference: &Path) -> PathBuf {
    let (data, run) = (dir.join("data"), dir.join("run"));
    let crestereo = |args: &[&std::ffi::OsStr]| {
        test_support::run_ok(
            Command::new(env!("CARGO_BIN_EXE_crestereo"))
                .args(args)
                .env("RAYON_NUM_THREADS", "2"),
        );
    };
    let os = |s: &'static str| std::ffi::OsStr::new(s);
    crestereo(&[
        os("synth"),
        os("--out"),
        data.as_os_str(),
        os("--count"),
        os("2"),
        os("--size"),
        os("64x128"),
        os("--seed"),
        os("3"),
    ]);
    let mut train = vec![
        os("train"),
        os("--data"),
        data.as_os_str(),
        os("--out"),
        run.as_os_str(),
        os("--steps"),
        os(STEPS),
        os("--init-weights"),
        reference.as_os_str(),
        os("--lr"),
        os("1e-5"),
    ];
    train.extend(TINY_TRAINING.map(os));
    crestereo(&train);
    run
}
