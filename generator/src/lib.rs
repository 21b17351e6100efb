//! stereogen: plans synthetic stereo scenes in Rust and renders them with Blender/Cycles into
//! left/right images with exact float32 disparity for both views.
//!
//! - [`plan`]: recipes and the pure-data `SceneSpec` (no Blender): the `stereogen-plan` crate.
//! - [`assets`]: indexes of the asset folders a recipe names: the `stereogen-assets` crate.
//! - [`render`]: finding or installing Blender's Python, and the worker processes that render specs.
//! - [`dataset`]: the on-disk layout, manifest, atomic writes and resumable generation.
//! - [`estimate`]: what a dataset will cost, from a few of its samples rendered here.
//! - [`farm`]: job files for Slurm, Kubernetes and Open Job Description (`stereogen farm`).
//! - [`validate`]: `stereogen stats`: disparity statistics, the check against the recipe's law, plots.

pub mod dataset;
pub mod estimate;
pub mod farm;
pub mod interrupt;
pub mod render;
pub mod validate;

pub use stereogen_assets as assets;
pub use stereogen_plan as plan;
