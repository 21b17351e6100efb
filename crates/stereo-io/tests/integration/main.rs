//! stereo-io's integration tests, one module per subject, built as one binary.
//! `cargo test -p stereo-io --test integration fuzz_seeds::` runs one module. The helpers (tiny
//! datasets, pinned venvs, small file systems) come from the test-support crate.

use std::path::Path;
use std::process::Command;

use test_support::{io_fixtures, pinned_venv, small_fs, zip_edit};

mod conformance;
mod datasets;
mod disk_full;
mod formats;
mod fuzz;
mod fuzz_seeds;
mod hostile_readers;
mod hostile_webdataset;
mod hostile_weights;
mod torchvision_loaders;
mod webdataset;
mod writers;

/// Runs `tests/python/SCRIPT INPUT OUT` with `venv`'s Python (a reader nobody here wrote, saving
/// what it decoded under OUT) and parses the JSON it prints.
fn python_script_json(venv: &Path, script: &str, input: &Path, out: &Path) -> serde_json::Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(script);
    let printed = pinned_venv::run(
        Command::new(venv.join("bin/python"))
            .arg(&path)
            .arg(input)
            .arg(out),
        script,
    );
    serde_json::from_str(printed.trim()).unwrap_or_else(|e| panic!("{e}: {printed}"))
}
