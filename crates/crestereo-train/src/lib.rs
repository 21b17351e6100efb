//! Training and evaluation of CREStereo, and the `crestereo` command line.
//!
//! - [`cli`]: the command line's arguments and commands, generic over the backend; the binary
//!   (`src/main.rs`) only picks the backend. Every backend's copy of the network is compiled
//!   there once, not a second time for the unit tests of a binary.
//! - [`config`]: the training config (TOML), defaulting to the paper's recipe.
//! - [`data`]: datasets mixed by weight, decoded and augmented ahead of the step, deterministic.
//! - [`augment`]: the reference augmentation, one unit per transform.
//! - [`train`]: the loop — sequence loss with a non-finite guard, gradient accumulation, Adam on
//!   the [`schedule`], [`checkpoint`]s with exact resume, CSV and [`tensorboard`] logs.
//! - [`eval`] and [`metrics`]: EPE, RMS, Bad-τ, D1, A50–A99, mxIoU over any dataset.
//! - [`parallel`]: data-parallel training over devices, processes and nodes (Burn's collective).
//! - [`interrupt`]: SIGTERM/SIGINT stop a run after its step, with a checkpoint (exit 75).
//! - [`host_reads`]: counts the GPU backends' host reads (a step should wait only for its loss).
//! - [`synthetic`]: analytic stereo pairs for tests and quick checks.

pub mod augment;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod data;
pub mod disturb;
pub mod eval;
pub mod host_reads;
pub mod interrupt;
pub mod metrics;
pub mod oom;
pub mod parallel;
pub mod plot;
pub mod schedule;
pub mod score;
pub mod synthetic;
pub mod tensorboard;
pub mod tiny_run;
pub mod train;
