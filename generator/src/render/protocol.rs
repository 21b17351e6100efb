//! The line protocol between the orchestrator and `blender_scripts/worker.py`: one JSON
//! [`Request`] per line on the worker's stdin, one JSON [`Reply`] per line on its protocol stream.
//! The worker's first line is [`Reply::Ready`]; every render request then gets exactly one
//! [`Reply::Ok`] or [`Reply::Error`], every geometry export one [`Reply::Geometry`] or
//! [`Reply::Error`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::assets::SkippedAsset;
use crate::plan::SceneSpec;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Device {
    #[default]
    Cpu,
    /// CUDA or OptiX, whichever Cycles finds.
    Gpu,
}

impl Device {
    pub const NAMES: [&str; 2] = ["cpu", "gpu"];

    pub fn as_str(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Gpu => "gpu",
        }
    }
}

impl FromStr for Device {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(Device::Cpu),
            "gpu" => Ok(Device::Gpu),
            other => Err(format!("unknown device {other:?} (cpu, gpu)")),
        }
    }
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The wall-seconds key of the time a worker took to start (process start, Blender's import,
/// the hello), measured by the orchestrator and added to the timings of the sample that started
/// it: a worker's first sample pays it.
pub const WORKER_START_TIMING: &str = "worker_start_s";

/// The names a worker reports its stages under (`timings` of a [`WorkerReport`]): defined here
/// once and sent to the worker when it starts (`--timing-keys`, see [`WorkerTimings::to_arg`]),
/// so `blender_scripts/` use the names they are given and the readers of the manifest's
/// `render_timings` (the estimate, the benches) agree with them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct WorkerTimings {
    /// Clearing the previous scene.
    pub reset: &'static str,
    /// Building the spec's scene.
    pub build: &'static str,
    /// The colour render of each view (Cycles spreads it over threads).
    pub colour: ByView,
    /// The depth render of each view (also threaded).
    pub depth: ByView,
    /// Writing the rendered files, all four together.
    pub save: &'static str,
    /// Writing a spec's geometry (an `export_geometry` request instead of the renders).
    pub export: &'static str,
    /// Every key above ends in this (wall seconds) ...
    pub wall_suffix: &'static str,
    /// ... and a stage's CPU seconds, where STEREOGEN_TIMINGS_CPU is set, go under its key with
    /// `wall_suffix` replaced by this.
    pub cpu_suffix: &'static str,
}

/// A name per stereo view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ByView {
    pub left: &'static str,
    pub right: &'static str,
}

pub const WORKER_TIMINGS: WorkerTimings = WorkerTimings {
    reset: "reset_s",
    build: "build_s",
    colour: ByView {
        left: "colour_left_s",
        right: "colour_right_s",
    },
    depth: ByView {
        left: "depth_left_s",
        right: "depth_right_s",
    },
    save: "save_s",
    export: "export_s",
    wall_suffix: "_s",
    cpu_suffix: "_cpu_s",
};

impl WorkerTimings {
    /// The keys of the renders, the part of a sample Cycles runs on all its threads.
    pub fn renders(&self) -> [&'static str; 4] {
        [
            self.colour.left,
            self.colour.right,
            self.depth.left,
            self.depth.right,
        ]
    }

    /// The command-line value that hands these names to the worker (JSON).
    pub fn to_arg(&self) -> String {
        serde_json::to_string(self).expect("timing keys serialise")
    }
}

/// Whether a timing key is wall seconds (not a stage's CPU seconds).
pub fn is_wall_timing(key: &str) -> bool {
    !key.ends_with(WORKER_TIMINGS.cpu_suffix)
}

/// Failures the worker injects on request, so tests exercise the recovery paths for real.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Fault {
    /// The worker process dies with SIGSEGV.
    Crash,
    /// The worker stops answering.
    Hang,
    /// The scene raises a Python exception (an error reply with a traceback; the worker lives on).
    Raise,
}

/// What the orchestrator asks a worker.
#[derive(Debug, Serialize)]
#[serde(tag = "cmd", rename_all = "snake_case")]
pub enum Request<'a> {
    /// Build `spec` and render both views into `out_dir` (a fresh temporary directory). The
    /// spec goes with its render settings resolved ([`SceneSpec::for_worker`]).
    Render {
        #[serde(serialize_with = "spec_for_worker")]
        spec: &'a SceneSpec,
        out_dir: &'a Path,
        #[serde(skip_serializing_if = "Option::is_none")]
        fault: Option<Fault>,
    },
    /// Build `spec` as for a render, but instead of rendering write its evaluated geometry
    /// (world-space triangles of every rendered object, with what decides a hit) into `out_dir`,
    /// for `stereogen audit`.
    ExportGeometry {
        #[serde(serialize_with = "spec_for_worker")]
        spec: &'a SceneSpec,
        out_dir: &'a Path,
    },
    /// Exit cleanly.
    Quit,
}

/// A spec as the worker reads it: every render key present, defaults filled in by Rust.
fn spec_for_worker<S: serde::Serializer>(spec: &&SceneSpec, s: S) -> Result<S::Ok, S::Error> {
    spec.for_worker().serialize(s)
}

impl Request<'_> {
    /// The request as one protocol line.
    pub fn to_line(&self) -> String {
        let mut line = serde_json::to_string(self).expect("requests serialise");
        line.push('\n');
        line
    }
}

/// What a worker answers.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum Reply {
    /// The first line, once `bpy` is imported.
    Ready(Hello),
    /// A rendered spec.
    Ok(RenderOutput),
    /// An exported scene geometry.
    Geometry(GeometryOutput),
    /// A spec (or request line) the worker could not handle; the worker carries on.
    Error(WorkerFailure),
}

/// What a worker says about itself when it starts.
#[derive(Debug, Clone, Deserialize)]
pub struct Hello {
    pub blender: String,
    pub python: String,
    /// The SceneSpec `format_version` its scripts understand (absent in scripts older than 3).
    #[serde(default)]
    pub spec_format_version: Option<u32>,
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

/// A rendered spec.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderOutput {
    pub files: RenderedFiles,
    /// Timings, memory, skipped assets and notes; the timings under the [`WORKER_TIMINGS`] keys
    /// `reset`, `build`, `colour`, `depth` and `save` (and each step's CPU seconds where
    /// STEREOGEN_TIMINGS_CPU is set).
    #[serde(flatten)]
    pub report: WorkerReport,
}

/// What a worker reports beside the files of a request it handled.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct WorkerReport {
    /// Seconds per step, under the [`WORKER_TIMINGS`] keys of the request's steps.
    #[serde(default)]
    pub timings: BTreeMap<String, f64>,
    #[serde(default)]
    pub rss_bytes: Option<u64>,
    /// Mesh or texture files the worker could not use for this spec (it fell back to the next
    /// candidate or a flat colour).
    #[serde(default)]
    pub skipped_assets: Vec<SkippedAsset>,
    /// What the worker did beyond the spec: which mesh candidate it used, objects it dropped.
    #[serde(default)]
    pub notes: Vec<String>,
}

/// The geometry file of one spec (format: `blender_scripts/export_geometry.py`).
#[derive(Debug, Clone, Deserialize)]
pub struct GeometryOutput {
    pub file: PathBuf,
    pub objects: usize,
    pub triangles: usize,
    /// Cycles renders the worker ran while handling the request: 0, as nothing is rendered.
    pub renders: u64,
    /// Timings, memory, skipped assets and notes; the timings under the [`WORKER_TIMINGS`] keys
    /// `build` and `export`.
    #[serde(flatten)]
    pub report: WorkerReport,
}

/// Why the worker could not render a spec.
#[derive(Debug, Clone, Deserialize)]
pub struct WorkerFailure {
    pub error: String,
    /// The Python traceback, when an exception caused it.
    #[serde(default)]
    pub traceback: Option<String>,
    #[serde(default)]
    pub rss_bytes: Option<u64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replies_parse_by_status() {
        let hello: Reply = serde_json::from_str(r#"{"status":"ready","blender":"4.5.1","python":"3.11.9","spec_format_version":3,"rss_bytes":5}"#).unwrap();
        assert!(matches!(
            hello,
            Reply::Ready(Hello {
                spec_format_version: Some(3),
                ..
            })
        ));
        let err: Reply = serde_json::from_str(r#"{"status":"error","error":"ValueError: x","traceback":"Traceback ...","rss_bytes":null}"#).unwrap();
        assert!(matches!(
            err,
            Reply::Error(WorkerFailure {
                traceback: Some(_),
                ..
            })
        ));
        let files =
            r#"{"left_png":"a","right_png":"b","left_depth_exr":"c","right_depth_exr":"d"}"#;
        let ok: Reply = serde_json::from_str(&format!(
            r#"{{"status":"ok","files":{files},"timings":{{"build_s":0.5}}}}"#
        ))
        .unwrap();
        assert!(
            matches!(ok, Reply::Ok(RenderOutput { ref report, .. }) if report.timings["build_s"] == 0.5)
        );
        assert!(
            serde_json::from_str::<Reply>(r#"{"status":"ok"}"#).is_err(),
            "an ok reply without files"
        );
        assert!(serde_json::from_str::<Reply>(r#"{"status":"pong"}"#).is_err());
        let geometry: Reply = serde_json::from_str(r#"{"status":"geometry","file":"g.bin","objects":3,"triangles":40,"renders":0,"timings":{"export_s":0.1}}"#).unwrap();
        assert!(matches!(
            geometry,
            Reply::Geometry(GeometryOutput {
                objects: 3,
                renders: 0,
                ..
            })
        ));
    }

    #[test]
    fn timing_keys_reach_the_worker_as_json_and_name_the_renders() {
        let sent: serde_json::Value = serde_json::from_str(&WORKER_TIMINGS.to_arg()).unwrap();
        assert_eq!(sent["colour"]["left"], "colour_left_s");
        assert_eq!(sent["depth"]["right"], "depth_right_s");
        assert_eq!(sent["cpu_suffix"], "_cpu_s");
        let renders = WORKER_TIMINGS.renders();
        assert!(renders.contains(&"depth_left_s") && !renders.contains(&"save_s"));
        // Every wall key ends in the suffix the worker replaces for its CPU seconds.
        for key in renders.iter().chain(&[
            WORKER_TIMINGS.reset,
            WORKER_TIMINGS.build,
            WORKER_TIMINGS.save,
            WORKER_TIMINGS.export,
            WORKER_START_TIMING,
        ]) {
            assert!(key.ends_with(WORKER_TIMINGS.wall_suffix) && is_wall_timing(key));
        }
        assert!(!is_wall_timing("colour_left_cpu_s"));
    }

    #[test]
    fn requests_are_tagged_by_cmd() {
        assert_eq!(Request::Quit.to_line(), "{\"cmd\":\"quit\"}\n");
        let spec = crate::plan::plan_scene(
            &crate::plan::Recipe::preset("tree").unwrap(),
            &Default::default(),
            0,
            0,
        );
        let line = Request::ExportGeometry {
            spec: &spec,
            out_dir: Path::new("/tmp/x"),
        }
        .to_line();
        assert!(
            line.starts_with("{\"cmd\":\"export_geometry\",\"spec\":{")
                && line.ends_with("\"out_dir\":\"/tmp/x\"}\n"),
            "{line}"
        );
        assert_eq!("gpu".parse::<Device>(), Ok(Device::Gpu));
        assert!("tpu".parse::<Device>().unwrap_err().contains("tpu"));
    }
}
