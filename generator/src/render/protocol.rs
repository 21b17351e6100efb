//! The line protocol between the orchestrator and `blender_scripts/worker.py`: one JSON request
//! per line on the worker's stdin, one JSON reply per line on its protocol stream.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::plan::SceneSpec;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Device {
    #[default]
    Cpu,
    /// CUDA or OptiX, whichever Cycles finds.
    Gpu,
}

/// Failures the worker injects on request, so tests exercise the recovery paths for real.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Fault {
    /// The worker process dies with SIGSEGV.
    Crash,
    /// The worker stops answering.
    Hang,
}

#[derive(Debug, Serialize)]
pub struct RenderRequest<'a> {
    pub cmd: &'static str,
    pub spec: &'a SceneSpec,
    /// Where the worker writes its intermediate files (a fresh temporary directory).
    pub out_dir: PathBuf,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<Fault>,
}

/// The first line a worker prints once `bpy` is imported.
#[derive(Debug, Clone, Deserialize)]
pub struct Hello {
    pub status: String,
    pub blender: String,
    pub python: String,
    pub rss_bytes: Option<u64>,
}

/// Files the worker wrote for one spec, inside the request's `out_dir`.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedFiles {
    pub left_png: PathBuf,
    pub right_png: PathBuf,
    pub left_depth_exr: PathBuf,
    pub right_depth_exr: PathBuf,
}

#[derive(Debug, Clone, Deserialize)]
pub struct RenderReply {
    pub status: String,
    #[serde(default)]
    pub files: Option<RenderedFiles>,
    #[serde(default)]
    pub timings: BTreeMap<String, f64>,
    #[serde(default)]
    pub rss_bytes: Option<u64>,
    #[serde(default)]
    pub error: Option<String>,
    /// Mesh or texture files the worker could not use for this spec (it fell back to the next
    /// candidate or a flat colour).
    #[serde(default)]
    pub skipped_assets: Vec<crate::assets::SkippedAsset>,
    /// What the worker did beyond the spec: which mesh candidate it used, objects it dropped.
    #[serde(default)]
    pub notes: Vec<String>,
}
