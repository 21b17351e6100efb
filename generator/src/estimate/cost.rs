//! What a measurement holds: each rendered sample's cost and the run's own.

use serde::Serialize;

use crate::render::Device;

/// One measured sample.
#[derive(Debug, Clone, Serialize)]
pub struct SampleCost {
    pub index: u64,
    pub category: String,
    /// Wall seconds of the sample on one worker, worker start-up excluded.
    pub seconds: f64,
    /// The part of `seconds` in the colour and depth renders.
    pub parallel_seconds: f64,
    /// Its files (images, disparities, scene) and their bytes.
    pub files: u64,
    pub bytes: u64,
    /// Bytes of its manifest line.
    pub manifest_bytes: u64,
}

/// What rendering the samples here measured.
#[derive(Debug, Clone, Serialize)]
pub struct Measurement {
    pub samples: Vec<SampleCost>,
    /// Blender start-up of each worker (seconds), out of its first sample.
    pub worker_start_s: Vec<f64>,
    /// Wall seconds of the run not spent on samples (asset index, dataset, start-up, shutdown).
    pub task_fixed_s: f64,
    pub workers: usize,
    pub threads: u32,
    /// Cores (CPU) or GPUs one worker had here.
    pub units_per_worker: f64,
    pub device: Device,
    /// The machine: CPU model and cores (or "GPU").
    pub machine: String,
    pub worker_restarts: u32,
    pub failed: usize,
    /// Files of a dataset besides its samples' (dataset.json, manifest.jsonl) and their bytes
    /// (the manifest counted in its lines, per sample).
    pub dataset_files: u64,
    pub dataset_bytes: u64,
}

/// Median of `v` (0 for none).
pub(super) fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}
