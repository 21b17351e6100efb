//! The end-to-end tests: the real `stereogen` and `crestereo` binaries, the real Blender worker,
//! Slurm, Chromium and the Python packages, one module per subject, built as one binary (one
//! link of the generator and the trainer instead of thirty). `cargo test --release --workspace
//! --test integration farm_slurm::` runs one module (`--workspace` builds the binaries the tests
//! run).
//!
//! The modules' tests run side by side, two at a time on two cores, where each file used to be
//! a process of its own: what a machine holds once (the local Slurm cluster, apt-get) is taken
//! in turn through the test-support crate, and every test works in its own temporary folder.

mod asset_sources;
mod audit_generated;
mod audit_maps;
mod backgrounds;
mod cli_faults;
mod content_pack;
mod curate;
mod determinism_and_memory;
mod difficulty;
mod estimate;
mod every_variant;
mod exactness;
mod export_roundtrip;
mod export_webdataset;
mod farm_job_files;
mod farm_merge;
mod farm_slurm;
mod farm_webdataset;
mod fault_sweep;
mod generate_cli;
mod guide;
mod io_python;
mod maps;
mod mesh_folder;
mod python_wheel;
mod render_study;
mod report_browser;
mod rerender_exact;
mod scene_recipes;
mod setup_runtime;
mod stats_generated;
mod train_slurm;
mod worker_protocol;
