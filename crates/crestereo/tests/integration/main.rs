//! The network's integration tests, one module per subject, built as one binary (each binary
//! links Burn and compiles the network again). `cargo test -p crestereo --test integration
//! parity::` runs one module. `composed_ops.rs` stays a binary of its own: it switches every
//! hand-written kernel off for its whole process.
//!
//! `common` and `agcl_checks` are shared with the trainer's tests (included by path there).

#[path = "../agcl_checks/mod.rs"]
mod agcl_checks;
#[path = "../common/mod.rs"]
mod common;
#[allow(dead_code)]
#[path = "../../../stereo-io/tests/support/zip_edit.rs"]
mod zip_edit;

mod agcl;
mod gradients;
mod hostile_input;
mod parity;
mod weights;
