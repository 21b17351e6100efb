//! stereo-io's integration tests, one module per subject, built as one binary.
//! `cargo test -p stereo-io --test integration fuzz_seeds::` runs one module. `support/` and
//! `fixtures/` are shared with other crates' tests (included by path there).

#[allow(dead_code)]
#[path = "../support/small_fs.rs"]
#[macro_use]
mod small_fs;
#[path = "../fixtures/mod.rs"]
mod fixtures;
#[path = "../support/pinned_venv.rs"]
mod pinned_venv;
#[allow(dead_code)]
#[path = "../support/zip_edit.rs"]
mod zip_edit;

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
