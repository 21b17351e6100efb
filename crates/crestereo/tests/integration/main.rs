//! The network's integration tests, one module per subject, built as one binary (each binary
//! links Burn and compiles the network again). `cargo test -p crestereo --test integration
//! parity::` runs one module. `composed_ops` switches every hand-written kernel off for a whole
//! process: its tests run their checks in child processes of this binary.
//!
//! The reference fixtures and the AGCL checks come from the test-support crate (the trainer's
//! Vulkan tests run the same checks on lavapipe).

use test_support::{agcl_checks, network_fixtures, zip_edit};

mod agcl;
mod composed_ops;
mod gradients;
mod hostile_input;
mod parity;
mod weights;
