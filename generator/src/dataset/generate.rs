//! `stereogen generate`: plan, render and finish samples with a pool of Blender workers.
//! Resumable: samples already in the manifest are skipped, half-written files are cleared.

use std::collections::{BTreeSet, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use fs4::fs_std::FileExt;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use super::layout::DatasetLayout;
use super::manifest::Manifest;
use super::sample::finalize_sample;
use crate::assets::{SkippedAsset, index_sources};
use crate::plan::{Recipe, plan_scene};
use crate::render::protocol::{Device, Fault};
use crate::render::runtime::{discover_or_install, stereogen_home};
use crate::render::scripts::install_scripts;
use crate::render::worker::{RenderService, WorkerConfig};

#[derive(Debug, Clone)]
pub struct GenerateOptions {
    pub out: PathBuf,
    pub recipe: Recipe,
    pub seed: u64,
    /// Samples `start .. start + count`.
    pub start: u64,
    pub count: u64,
    /// Render only indices with `index % n == k` (`Some((k, n))`).
    pub shard: Option<(u64, u64)>,
    pub workers: usize,
    /// Cycles threads per worker; `None` splits the machine's cores between workers.
    pub threads_per_worker: Option<u32>,
    pub device: Device,
    pub blender: Option<PathBuf>,
    pub render_timeout: Duration,
    pub startup_timeout: Duration,
    pub retries: u32,
    pub progress: bool,
}

impl GenerateOptions {
    pub fn new(out: impl Into<PathBuf>, recipe: Recipe, seed: u64, count: u64) -> Self {
        Self {
            out: out.into(),
            recipe,
            seed,
            start: 0,
            count,
            shard: None,
            workers: 1,
            threads_per_worker: None,
            device: Device::Cpu,
            blender: None,
            render_timeout: Duration::from_secs(900),
            startup_timeout: Duration::from_secs(120),
            retries: 2,
            progress: false,
        }
    }
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct GenerateSummary {
    pub rendered: u64,
    pub skipped: u64,
    pub failed: Vec<(u64, String)>,
    pub worker_restarts: u32,
    pub seconds: f64,
    /// Mean wall seconds per rendered sample, per worker.
    pub seconds_per_sample: f64,
}

/// Test hook: `STEREOGEN_FAULT=crash@3,hang@5,crash-always@7` makes the worker crash or hang on
/// those samples (`crash`/`hang`: first attempt only; `-always`: every attempt).
#[derive(Debug, Clone, Default)]
struct FaultPlan(Vec<(u64, Fault, bool)>);

impl FaultPlan {
    fn from_env() -> anyhow::Result<Self> {
        let Ok(text) = std::env::var("STEREOGEN_FAULT") else { return Ok(Self::default()) };
        let mut plan = Vec::new();
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (kind, index) = item.split_once('@').with_context(|| format!("STEREOGEN_FAULT item {item:?} is not kind@index"))?;
            let index: u64 = index.parse().with_context(|| format!("STEREOGEN_FAULT item {item:?}: bad index"))?;
            let (fault, always) = match kind {
                "crash" => (Fault::Crash, false),
                "hang" => (Fault::Hang, false),
                "crash-always" => (Fault::Crash, true),
                "hang-always" => (Fault::Hang, true),
                other => bail!("STEREOGEN_FAULT: unknown fault {other:?} (crash, hang, crash-always, hang-always)"),
            };
            plan.push((index, fault, always));
        }
        Ok(Self(plan))
    }

    fn fault(&self, index: u64, attempt: u32) -> Option<Fault> {
        self.0.iter().find(|(i, _, always)| *i == index && (*always || attempt == 0)).map(|(_, f, _)| *f)
    }
}

fn append_line(path: &std::path::Path, line: &str) {
    use std::io::Write;
    let appended = std::fs::OpenOptions::new().create(true).append(true).open(path).and_then(|mut f| writeln!(f, "{line}"));
    if let Err(e) = appended {
        tracing::error!("cannot append to {}: {e}", path.display());
    }
}

fn append_failure(layout: &DatasetLayout, index: u64, error: &str) {
    append_line(&layout.failures(), &serde_json::json!({ "index": index, "error": error }).to_string());
}

/// Assets the index or a worker refused go to `skipped_assets.jsonl`, once per run and file.
fn record_skipped(layout: &DatasetLayout, seen: &Mutex<BTreeSet<std::path::PathBuf>>, skipped: &[SkippedAsset], index: Option<u64>) {
    let mut seen = seen.lock().unwrap();
    for s in skipped {
        if seen.insert(s.path.clone()) {
            tracing::warn!("skipping asset {}: {}", s.path.display(), s.reason);
            append_line(&layout.skipped_assets(), &serde_json::json!({ "path": s.path, "reason": s.reason, "sample": index }).to_string());
        }
    }
}

/// Runs a generation and returns what happened. Fatal problems (no Blender, unwritable output,
/// a dataset made with another recipe) are errors; a sample that fails is recorded and skipped.
pub fn generate(opts: &GenerateOptions) -> anyhow::Result<GenerateSummary> {
    let started = Instant::now();
    if opts.workers == 0 {
        bail!("--workers must be at least 1");
    }
    if let Some((k, n)) = opts.shard {
        if n == 0 || k >= n {
            bail!("--shard {k}/{n}: need 0 <= k < n");
        }
    }
    let faults = FaultPlan::from_env()?;
    let layout = DatasetLayout::new(&opts.out);
    layout.open_or_create(&opts.recipe, opts.seed)?;
    let lock = std::fs::File::create(layout.lock()).with_context(|| format!("cannot create {}", layout.lock().display()))?;
    if !lock.try_lock_exclusive().unwrap_or(false) {
        bail!("another stereogen process is writing to {}; wait for it or choose another --out", layout.root.display());
    }
    let removed = layout.remove_partial_files();
    if removed > 0 {
        tracing::info!("removed {removed} partial file(s) left by an interrupted run");
    }
    let (manifest, done) = Manifest::open(&layout.manifest())?;
    let done: BTreeSet<u64> = done.iter().map(|e| e.index).collect();

    let indices: Vec<u64> = (opts.start..opts.start + opts.count).filter(|i| opts.shard.is_none_or(|(k, n)| i % n == k)).collect();
    let pending: VecDeque<u64> = indices.iter().copied().filter(|i| !done.contains(i)).collect();
    let mut summary = GenerateSummary { skipped: (indices.len() - pending.len()) as u64, ..Default::default() };
    if pending.is_empty() {
        summary.seconds = started.elapsed().as_secs_f64();
        return Ok(summary);
    }

    let home = stereogen_home();
    let assets = index_sources(&opts.recipe.sources, &home)?;
    let seen_skipped = Mutex::new(BTreeSet::new());
    record_skipped(&layout, &seen_skipped, &assets.skipped, None);
    let runtime = discover_or_install(opts.blender.as_deref(), &home)?;
    let script = install_scripts(&home).with_context(|| format!("cannot write the Blender scripts under {}", home.display()))?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u32;
    let threads = opts.threads_per_worker.unwrap_or_else(|| (cores / opts.workers as u32).max(1));
    let cfg = WorkerConfig {
        runtime,
        script,
        threads,
        device: opts.device,
        startup_timeout: opts.startup_timeout,
        render_timeout: opts.render_timeout,
        retries: opts.retries,
    };

    let bar = if opts.progress { ProgressBar::new(indices.len() as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} samples · {per_sec} · ETA {eta} {msg}")
            .expect("static template"),
    );
    bar.set_position(summary.skipped);
    bar.enable_steady_tick(Duration::from_millis(250));

    let queue = Mutex::new(pending);
    let manifest = Mutex::new(manifest);
    let stop = AtomicBool::new(false);
    let fatal: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let results = Mutex::new((0u64, Vec::new(), 0u32, 0f64));
    let faults = Arc::new(faults);

    std::thread::scope(|s| {
        for _ in 0..opts.workers.min(indices.len()) {
            s.spawn(|| {
                let mut service = RenderService::new(cfg.clone());
                while !stop.load(Ordering::SeqCst) {
                    let Some(index) = queue.lock().unwrap().pop_front() else { break };
                    let spec = plan_scene(&opts.recipe, &assets, opts.seed, index);
                    let t0 = Instant::now();
                    let outcome = service.render(&spec, |attempt| faults.fault(index, attempt));
                    let outcome = outcome.map_err(|e| {
                        if e.is_fatal() {
                            stop.store(true, Ordering::SeqCst);
                        }
                        e
                    });
                    match outcome {
                        Ok(rendered) => {
                            record_skipped(&layout, &seen_skipped, &rendered.reply.skipped_assets, Some(index));
                            let seconds = t0.elapsed().as_secs_f64();
                            let files = rendered.reply.files.as_ref().expect("ok replies carry files");
                            let finished = finalize_sample(&layout, &spec, files, &rendered.reply.notes, seconds).and_then(|entry| manifest.lock().unwrap().append(&entry));
                            match finished {
                                Ok(()) => {
                                    let mut r = results.lock().unwrap();
                                    r.0 += 1;
                                    r.3 += seconds;
                                }
                                Err(e) => {
                                    // A write failure (disk full, permissions) will hit every sample.
                                    stop.store(true, Ordering::SeqCst);
                                    fatal.lock().unwrap().get_or_insert(e.context(format!("sample {}", spec.id)));
                                }
                            }
                        }
                        Err(e) if e.is_fatal() => {
                            fatal.lock().unwrap().get_or_insert(anyhow::Error::new(e));
                        }
                        Err(e) => {
                            let msg = e.to_string();
                            bar.println(format!("sample {} failed: {msg}", spec.id));
                            append_failure(&layout, index, &msg);
                            results.lock().unwrap().1.push((index, msg));
                        }
                    }
                    bar.inc(1);
                }
                results.lock().unwrap().2 += service.restarts;
                service.shutdown();
            });
        }
    });
    bar.finish_and_clear();
    if let Some(e) = fatal.into_inner().unwrap() {
        return Err(e);
    }
    let (rendered, failed, restarts, busy) = results.into_inner().unwrap();
    summary.rendered = rendered;
    summary.failed = failed;
    summary.worker_restarts = restarts;
    summary.seconds = started.elapsed().as_secs_f64();
    summary.seconds_per_sample = if rendered > 0 { busy / rendered as f64 } else { 0.0 };
    Ok(summary)
}
