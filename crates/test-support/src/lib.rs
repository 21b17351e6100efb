//! What the workspace's tests share, in one place instead of files included by path: pinned
//! Python environments (OpenCV, PyTorch, onnxruntime, the maturin-built wheel), small file systems
//! for disk-full tests, hostile-archive editing, tiny datasets with known values, running a
//! command and reading what it said; with the `generator` feature the end-to-end helpers (the
//! real renderer and CLIs, analytic scenes, a local Slurm cluster), with `network` the network's
//! reference fixtures and the AGCL checks that run on every backend.

pub mod files;
pub mod io_fixtures;
pub mod pinned_venv;
pub mod python_envs;
pub mod run;
pub mod small_fs;
pub mod turns;
pub mod zip_edit;

#[cfg(feature = "generator")]
mod e2e;
#[cfg(feature = "generator")]
pub use e2e::*;
#[cfg(feature = "generator")]
pub mod scenes;
#[cfg(feature = "generator")]
pub mod slurm_cluster;

#[cfg(feature = "network")]
pub mod agcl_checks;
#[cfg(feature = "network")]
pub mod network_fixtures;

pub use run::{output_text, run_fails, run_ok, run_shown};
