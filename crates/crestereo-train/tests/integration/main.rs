//! The trainer's integration tests, one module per subject, built as one binary (each binary
//! links Burn and compiles the network again: one instead of eight saves most of the build).
//! `cargo test -p crestereo-train --test integration training::` runs one module.
//! `vulkan.rs` stays a binary of its own: it sets the process's autotune level for CubeCL
//! before the first device opens.
//!
//! Helpers shared with other crates' tests come from the test-support crate.

use test_support::{network_fixtures, pinned_venv};

mod short_run;

mod checkpoint_disk_full;
mod cli;
mod cli_train;
mod export_onnx;
mod export_pytorch;
mod parallel;
mod training;
mod webdataset_stream;

/// A run's `train_log.csv`, each row cut to its first five columns (step, samples, lr, loss,
/// EPE): two runs that trained the same way have equal rows, however long each step took.
fn loss_columns(run: &std::path::Path) -> Vec<String> {
    std::fs::read_to_string(run.join("train_log.csv"))
        .unwrap()
        .lines()
        .map(|l| l.split(',').take(5).collect::<Vec<_>>().join(","))
        .collect()
}
