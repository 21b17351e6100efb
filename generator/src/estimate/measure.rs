//! Steps 2 and 3 of a measurement: render the picked samples into a temporary dataset
//! ([`render_samples`]), and read what each cost from its manifest line and files
//! ([`read_costs`]).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use super::cost::{Measurement, SampleCost, median};
use crate::dataset::generate::{GenerateOptions, GenerateSummary, Progress};
use crate::dataset::{DatasetLayout, ManifestEntry, TaskArgs, generate, read_manifest};
use crate::interrupt::{Interrupted, StopFlag};
use crate::plan::Recipe;
use crate::render::Device;
use crate::render::protocol::{WORKER_START_TIMING, WORKER_TIMINGS, is_wall_timing};

/// What [`render_samples`] reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum MeasureProgress<'a> {
    /// Rendering starts: `indices` of `recipe`, with `workers` × `threads`, inside `folder`.
    Rendering {
        recipe: &'a str,
        indices: &'a [u64],
        workers: usize,
        threads: u32,
        folder: &'a Path,
    },
    /// What `generate` reports about each sample.
    Sample(Progress<'a>),
}

/// The rendered samples: a temporary dataset (removed when this is dropped) and how it was run.
#[derive(Debug)]
pub struct SampleRun {
    /// Holds the temporary folder the dataset is in.
    folder: tempfile::TempDir,
    /// The dataset, inside `folder`.
    pub dataset: PathBuf,
    /// The indices asked for, in the order the queue handed them out.
    pub indices: Vec<u64>,
    pub workers: usize,
    pub threads: u32,
    /// Cores of this machine.
    pub cores: u32,
    pub device: Device,
    pub summary: GenerateSummary,
}

impl SampleRun {
    /// The temporary folder the dataset is in.
    pub fn folder(&self) -> &Path {
        self.folder.path()
    }
}

/// Renders `indices` of the dataset `task` names (with `recipe`, loaded from it) through
/// [`generate`], with the task's workers and threads, into a fresh temporary folder inside `work`.
pub fn render_samples(
    task: &TaskArgs,
    recipe: Recipe,
    indices: &[u64],
    work: &Path,
    stop: StopFlag,
    progress: &(dyn Fn(MeasureProgress<'_>) + Sync),
) -> anyhow::Result<SampleRun> {
    std::fs::create_dir_all(work).with_context(|| format!("cannot create {}", work.display()))?;
    let folder = tempfile::Builder::new()
        .prefix("stereogen-estimate-")
        .tempdir_in(work)
        .with_context(|| format!("cannot make a temporary folder in {}", work.display()))?;
    let dataset = folder.path().join("dataset");
    let mut opts = GenerateOptions::new(&dataset, recipe, task.seed, task.count);
    opts.start = task.start;
    opts.workers = task.workers;
    opts.worker_options = task.runtime.worker_options();
    opts.only = Some(indices.to_vec());
    opts.stop = stop;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u32;
    let workers = task.workers.max(1);
    // What `WorkerOptions::resolve` gives each worker, for the record.
    let threads = task
        .runtime
        .threads
        .unwrap_or_else(|| (cores / workers as u32).max(1));
    progress(MeasureProgress::Rendering {
        recipe: &opts.recipe.name,
        indices,
        workers,
        threads,
        folder: folder.path(),
    });
    let summary = generate(&opts, &|event| progress(MeasureProgress::Sample(event)))?;
    if summary.interrupted {
        return Err(Interrupted::now().into());
    }
    Ok(SampleRun {
        folder,
        dataset,
        indices: indices.to_vec(),
        workers,
        threads,
        cores,
        device: task.runtime.device,
        summary,
    })
}

/// Each rendered sample's cost, from its manifest line and its files, and the run's own costs
/// (worker start-ups, per-task fixed time, the dataset's files besides the samples').
pub fn read_costs(run: &SampleRun) -> anyhow::Result<Measurement> {
    let layout = DatasetLayout::new(&run.dataset);
    let manifest_path = layout.manifest();
    let entries = read_manifest(&manifest_path)?.entries;
    if entries.is_empty() {
        bail!(
            "no sample rendered ({} failed: {}); nothing to estimate from",
            run.summary.failed.len(),
            run.summary.failed.first().map_or("", |f| f.error.as_str())
        );
    }
    // Manifest lines are in the entries' order, one each.
    let raw = std::fs::read_to_string(&manifest_path)?;
    let line_bytes: Vec<u64> = raw.lines().map(|l| l.len() as u64 + 1).collect();

    // A sample that started its worker says so (`WORKER_START_TIMING` among its timings); where
    // a worker does not, each worker's first sample (the queue hands out `indices` in order)
    // carries its start-up in the time its stages do not cover.
    let firsts: BTreeSet<u64> = run.indices.iter().copied().take(run.workers).collect();
    let usual = median(
        &entries
            .iter()
            .filter(|e| !firsts.contains(&e.index))
            .map(uncovered_seconds)
            .collect::<Vec<_>>(),
    );
    let renders = WORKER_TIMINGS.renders();
    let mut worker_start_s = Vec::new();
    let mut samples = Vec::new();
    for (e, manifest_bytes) in entries.iter().zip(line_bytes) {
        let mut seconds = e.render_seconds;
        let start = match e.render_timings.get(WORKER_START_TIMING) {
            Some(&s) => Some(s),
            None if firsts.contains(&e.index) => Some((uncovered_seconds(e) - usual).max(0.0)),
            None => None,
        };
        if let Some(start) = start {
            worker_start_s.push(start);
            seconds -= start;
        }
        let parallel_seconds: f64 = e
            .render_timings
            .iter()
            .filter(|(k, _)| renders.contains(&k.as_str()))
            .map(|(_, v)| v)
            .sum();
        let (mut files, mut bytes) = (0, 0);
        for (_, rel) in e.files.all() {
            let p = layout.abs(rel);
            bytes += std::fs::metadata(&p)
                .with_context(|| format!("{}", p.display()))?
                .len();
            files += 1;
        }
        samples.push(SampleCost {
            index: e.index,
            category: e.category.clone(),
            seconds,
            parallel_seconds: parallel_seconds.min(seconds),
            files,
            bytes,
            manifest_bytes,
        });
    }
    let (mut dataset_files, mut dataset_bytes) = (0, 0);
    for f in std::fs::read_dir(&run.dataset)? {
        let f = f?;
        if f.file_type()?.is_file() && !f.file_name().to_string_lossy().starts_with('.') {
            dataset_files += 1;
            if f.path() != manifest_path {
                dataset_bytes += f.metadata()?.len();
            }
        }
    }
    let busy: f64 = samples.iter().map(|s| s.seconds).sum();
    let workers = run.workers;
    let task_fixed_s = (run.summary.seconds - busy / workers.min(samples.len()) as f64).max(0.0);
    let units_per_worker = match run.device {
        Device::Cpu => f64::from(run.threads).min(f64::from(run.cores) / workers as f64),
        Device::Gpu => 1.0 / workers as f64,
    };
    Ok(Measurement {
        samples,
        worker_start_s,
        task_fixed_s,
        workers,
        threads: run.threads,
        units_per_worker,
        device: run.device,
        machine: machine(run.device),
        worker_restarts: run.summary.worker_restarts,
        failed: run.summary.failed.len(),
        dataset_files,
        dataset_bytes,
    })
}

/// A sample's wall seconds its wall-time stages do not cover.
fn uncovered_seconds(e: &ManifestEntry) -> f64 {
    e.render_seconds
        - e.render_timings
            .iter()
            .filter(|(k, _)| is_wall_timing(k))
            .map(|(_, v)| v)
            .sum::<f64>()
}

/// The CPU model and core count here, e.g. `AMD EPYC 9B14 (2 cores)`.
fn machine(device: Device) -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    match device {
        Device::Cpu => format!("{model} ({cores} cores)"),
        Device::Gpu => format!("the GPU Cycles picked, host {model} ({cores} cores)"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::SamplePaths;
    use crate::dataset::generate::FailedSample;

    /// A dataset folder as a run leaves it: `dataset.json`, each sample's five files (of
    /// `bytes` each) and its manifest line with these render seconds and timings.
    fn dataset_with(samples: &[(u64, &str, f64, serde_json::Value)], bytes: usize) -> SampleRun {
        let folder = tempfile::tempdir().unwrap();
        let dataset = folder.path().join("dataset");
        std::fs::create_dir_all(&dataset).unwrap();
        std::fs::write(dataset.join("dataset.json"), "{\"name\":\"x\"}\n").unwrap();
        let mut manifest = String::new();
        for (index, category, seconds, timings) in samples {
            let id = format!("{index:08}");
            let files = SamplePaths::new(category, &id);
            for (_, rel) in files.all() {
                let p = dataset.join(rel);
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::write(p, vec![7u8; bytes]).unwrap();
            }
            let line = serde_json::json!({
                "id": id, "category": category, "index": index, "files": files,
                "width": 64, "height": 48, "f_px": 50.0, "baseline_m": 0.1, "cx": 32.0, "cy": 24.0,
                "render_seconds": seconds, "render_timings": timings,
            });
            manifest += &format!("{line}\n");
        }
        std::fs::write(dataset.join("manifest.jsonl"), manifest).unwrap();
        SampleRun {
            folder,
            dataset,
            indices: samples.iter().map(|s| s.0).collect(),
            workers: 1,
            threads: 2,
            cores: 2,
            device: Device::Cpu,
            summary: GenerateSummary {
                rendered: samples.len() as u64,
                seconds: 40.0,
                ..Default::default()
            },
        }
    }

    #[test]
    fn costs_take_the_worker_start_out_and_split_renders_from_the_rest() {
        let w = WORKER_TIMINGS;
        let timings = |start: Option<f64>| {
            let mut t = serde_json::json!({
                w.build: 1.0, w.colour.left: 2.0, w.colour.right: 2.0,
                w.depth.left: 0.5, w.depth.right: 0.5, w.save: 0.25,
                // CPU seconds are not wall seconds: neither render time nor covered time.
                "colour_left_cpu_s": 3.9,
            });
            if let Some(s) = start {
                t[WORKER_START_TIMING] = s.into();
            }
            t
        };
        let run = dataset_with(
            &[
                (5, "tree", 13.0, timings(Some(6.0))),
                (9, "hole", 7.5, timings(None)),
            ],
            100,
        );
        let m = read_costs(&run).unwrap();
        assert_eq!(m.worker_start_s, vec![6.0]);
        let (first, second) = (&m.samples[0], &m.samples[1]);
        assert_eq!((first.index, first.category.as_str()), (5, "tree"));
        assert_eq!(first.seconds, 7.0, "the worker's start-up is taken out");
        assert_eq!(
            first.parallel_seconds, 5.0,
            "colour and depth of both views"
        );
        assert_eq!(second.seconds, 7.5);
        assert_eq!((first.files, first.bytes), (5, 500));
        let line = std::fs::read_to_string(run.dataset.join("manifest.jsonl")).unwrap();
        let first_line = line.lines().next().unwrap();
        assert_eq!(first.manifest_bytes, first_line.len() as u64 + 1);
        // dataset.json and the manifest; the manifest's bytes are counted per sample.
        assert_eq!((m.dataset_files, m.dataset_bytes), (2, 13));
        // The run's 40 s less the samples' 14.5 s on one worker.
        assert_eq!(m.task_fixed_s, 25.5);
        assert_eq!(m.units_per_worker, 2.0);
    }

    #[test]
    fn a_first_sample_without_its_start_up_timing_pays_what_its_stages_leave_uncovered() {
        // Stages cover 6.25 s of each sample; the usual rest is 0.75 s, the first sample's 4.75 s.
        let stages = serde_json::json!({
            WORKER_TIMINGS.build: 1.0, WORKER_TIMINGS.colour.left: 4.0,
            WORKER_TIMINGS.depth.left: 1.0, WORKER_TIMINGS.save: 0.25,
        });
        let run = dataset_with(
            &[
                (3, "tree", 11.0, stages.clone()),
                (4, "tree", 7.0, stages.clone()),
                (8, "tree", 7.0, stages),
            ],
            10,
        );
        let m = read_costs(&run).unwrap();
        assert_eq!(m.worker_start_s, vec![4.0]);
        assert_eq!(m.samples[0].seconds, 7.0);
    }

    #[test]
    fn a_run_that_rendered_nothing_says_why() {
        let mut run = dataset_with(&[], 0);
        run.summary.failed = vec![FailedSample {
            index: 1,
            error: "scene failed in Blender: boom".into(),
        }];
        let e = read_costs(&run).unwrap_err().to_string();
        assert!(e.contains("1 failed: scene failed in Blender: boom"), "{e}");
    }
}
