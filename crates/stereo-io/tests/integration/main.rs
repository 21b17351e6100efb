//! stereo-io's integration tests, one module per subject, built as one binary.
//! `cargo test -p stereo-io --test integration fuzz_seeds::` runs one module. The helpers (tiny
//! datasets, pinned venvs, small file systems) come from the test-support crate.

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
