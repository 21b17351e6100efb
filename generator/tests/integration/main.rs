//! The generator crate's own integration tests (its CLI's help, hostile inputs, `stats --check`
//! and a torn manifest), one module per subject, built as one binary. The end-to-end tests,
//! which render with Blender, live in the workspace's `tests/integration/`.

mod cli_help;
mod hostile_input;
mod stats_check;
mod stats_false_alarms;
mod torn_manifest;
