//! The planner's integration tests, one module per subject, built as one binary.

mod backgrounds;
mod pack_planning;
mod plan_laws;
mod scene_spec_check;
mod spec_bytes;
