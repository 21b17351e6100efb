//! `stereogen generate`: plan, render and finish samples with a pool of Blender workers.
//! Resumable: samples already in the manifest are skipped, half-written files are cleared.
//! Stoppable: [`GenerateOptions::stop`] (set by SIGTERM/SIGINT through [`crate::interrupt`]) ends
//! the run cleanly between samples. Progress goes to a callback ([`Progress`]); drawing it is the
//! caller's business.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use serde::Serialize;
use stereo_io::datasets::stereogen::ShardInfo;

use super::layout::{CreateDataset, DatasetLayout};
use super::lock::DatasetLock;
use super::manifest::{
    FailureRecord, Manifest, SkippedAssetRecord, append_sidecar, read_manifest,
    read_skipped_assets, retain_sidecar,
};
use super::sample::{VERIFY_TIMING, finalize_sample};
use super::shard::ShardId;
use crate::assets::{AssetIndex, SkippedAsset, index_sources};
use crate::interrupt::StopFlag;
use crate::plan::{Recipe, SceneSpec, plan_scene};
use crate::render::FaultPlan;
use crate::render::protocol::{WORKER_START_TIMING, is_wall_timing};
use crate::render::runtime::stereogen_home;
use crate::render::scratch;
use crate::render::{RenderService, Rendered, WorkerConfig, WorkerError, WorkerOptions};

#[derive(Debug, Clone)]
pub struct GenerateOptions {
    pub out: PathBuf,
    pub recipe: Recipe,
    pub seed: u64,
    /// Samples `start .. start + count`.
    pub start: u64,
    pub count: u64,
    /// Render only the shard's indices (`index % n == k`), into `out/shards/KKKK-of-NNNN/`.
    pub shard: Option<ShardId>,
    /// Take the directory's lock even when another process seems to hold it.
    pub break_lock: bool,
    /// Blender worker processes rendering in parallel.
    pub workers: usize,
    /// How each worker is found, started and supervised.
    pub worker_options: WorkerOptions,
    /// Set (by a signal, see [`crate::interrupt::install`]): stop cleanly.
    pub stop: StopFlag,
    /// Faults the workers inject (a test hook, parsed by the binary from STEREOGEN_FAULT).
    pub faults: FaultPlan,
    /// Render only these indices of the range, in this order (`stereogen estimate` renders a
    /// few samples spread over the categories); `None`: the whole range.
    pub only: Option<Vec<u64>>,
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
            break_lock: false,
            workers: 1,
            worker_options: WorkerOptions::default(),
            stop: StopFlag::new(),
            faults: FaultPlan::default(),
            only: None,
        }
    }

    /// The directory this run writes: `out`, or its shard's directory under `out/shards/`.
    pub fn dataset_dir(&self) -> PathBuf {
        match self.shard {
            Some(id) => DatasetLayout::new(&self.out).shard(id).root,
            None => self.out.clone(),
        }
    }

    /// The indices this run is responsible for (its range, less other shards'); the range was
    /// checked by [`check_options`].
    fn indices(&self) -> Vec<u64> {
        let owned = |i: &u64| self.shard.is_none_or(|s| s.owns(*i));
        match &self.only {
            Some(only) => only
                .iter()
                .copied()
                .filter(|i| (self.start..self.start + self.count).contains(i) && owned(i))
                .collect(),
            None => (self.start..self.start + self.count)
                .filter(owned)
                .collect(),
        }
    }
}

/// Keys [`generate`] adds to a manifest entry's `render_timings`, beside the worker's steps
/// ([`WORKER_TIMINGS`](crate::render::protocol::WORKER_TIMINGS)), [`finalize_sample`]'s and
/// the worker's start-up ([`WORKER_START_TIMING`], only on a worker's first sample: paid once
/// per worker): seconds spent planning the scene, and the render request's round trip less the
/// worker's own steps (the spec's JSON out, the pipe, the reply, the scratch folder). Appending
/// the manifest line cannot be in the line itself: it is in
/// [`GenerateSummary::manifest_seconds_per_sample`].
pub const PLAN_TIMING: &str = "plan_s";
pub const REQUEST_TIMING: &str = "request_s";

/// What [`generate`] reports as it goes; called from the worker threads.
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// Rendering starts: `total` samples in this run's range, `done` of them finished before.
    Started { total: u64, done: u64 },
    /// A sample is in the dataset.
    Rendered { index: u64, seconds: f64 },
    /// A sample failed (it is listed in `failures.jsonl`); the run goes on.
    Failed {
        index: u64,
        id: &'a str,
        error: &'a str,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FailedSample {
    pub index: u64,
    pub error: String,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct GenerateSummary {
    pub rendered: u64,
    /// Samples of the range that were already in the manifest.
    pub skipped: u64,
    pub failed: Vec<FailedSample>,
    pub worker_restarts: u32,
    pub seconds: f64,
    /// Mean wall seconds per rendered sample, per worker.
    pub seconds_per_sample: f64,
    /// Mean seconds per rendered sample spent reading its files back to verify them.
    pub verify_seconds_per_sample: f64,
    /// Mean seconds per rendered sample spent appending (and syncing) its manifest line.
    pub manifest_seconds_per_sample: f64,
    /// The run stopped early on [`GenerateOptions::stop`]; samples it did not finish are left
    /// for the next run.
    pub interrupted: bool,
    /// Scratch folders of dead processes removed at the start.
    pub orphaned_scratch_removed: usize,
}

/// Logs a sidecar log that cannot be updated: the run goes on (the samples are what matters).
fn log_unwritable(written: stereo_io::Result<impl Sized>) {
    if let Err(e) = written {
        tracing::error!("cannot update {e}");
    }
}

/// One line of `failures.jsonl`: the sample, the error, and the worker's traceback if it sent one.
/// The logs are written by one process (the dataset's lock holder), one thread at a time (`guard`).
fn append_failure(guard: &Mutex<()>, layout: &DatasetLayout, index: u64, error: &WorkerError) {
    let record = FailureRecord::new(index, error.to_string(), error.traceback().map(Into::into));
    let _guard = guard.lock().unwrap();
    log_unwritable(append_sidecar(&layout.failures(), &[record]));
}

/// Drops from `failures.jsonl` the samples that are now in the manifest (a later run rendered
/// them), so the file lists exactly the samples still missing.
fn forget_finished_failures(guard: &Mutex<()>, layout: &DatasetLayout) {
    if !layout.failures().exists() {
        return;
    }
    let Ok(done) = read_manifest(&layout.manifest()) else {
        return;
    };
    let done: BTreeSet<u64> = done.entries.iter().map(|e| e.index).collect();
    let _guard = guard.lock().unwrap();
    log_unwritable(retain_sidecar(&layout.failures(), |r: &FailureRecord| {
        !done.contains(&r.index)
    }));
}

/// Assets the index or a worker refused go to `skipped_assets.jsonl`, once per dataset and file.
fn record_skipped(
    guard: &Mutex<()>,
    layout: &DatasetLayout,
    seen: &Mutex<BTreeSet<PathBuf>>,
    skipped: &[SkippedAsset],
    index: Option<u64>,
) {
    let mut seen = seen.lock().unwrap();
    let mut records = Vec::new();
    for s in skipped {
        if seen.insert(s.path.clone()) {
            tracing::warn!("skipping asset {}: {}", s.path.display(), s.reason);
            records.push(SkippedAssetRecord::new(&s.path, &s.reason, index));
        }
    }
    let _guard = guard.lock().unwrap();
    log_unwritable(append_sidecar(&layout.skipped_assets(), &records));
}

/// Assets `skipped_assets.jsonl` already lists (warned about by an earlier run).
fn already_skipped(layout: &DatasetLayout) -> anyhow::Result<BTreeSet<PathBuf>> {
    Ok(read_skipped_assets(&layout.skipped_assets())?
        .records
        .into_iter()
        .map(|r| r.path)
        .collect())
}

/// The most samples one `generate` run (or one farm task) takes on: its indices are listed in
/// memory (8 bytes each, within the limits policy's one buffer), and at a minute a sample a run
/// of this many would take centuries on one machine; a farm splits a larger set into shards.
pub const MAX_RUN_SAMPLES: u64 = 100_000_000;

fn check_options(opts: &GenerateOptions) -> anyhow::Result<()> {
    if opts.workers == 0 {
        bail!("--workers must be at least 1");
    }
    let shards = opts.shard.map_or(1, |s| s.count);
    // With `only` (what `estimate` renders) the run lists just those indices.
    if opts.only.is_none() && opts.count.div_ceil(shards) > MAX_RUN_SAMPLES {
        bail!(
            "--count {}: more than {MAX_RUN_SAMPLES} samples for one run; split it over a farm (--shard K/N with N of at least {})",
            opts.count,
            opts.count.div_ceil(MAX_RUN_SAMPLES)
        );
    }
    if opts.start.checked_add(opts.count).is_none() {
        bail!(
            "--start {} --count {}: the range ends past the largest index {}",
            opts.start,
            opts.count,
            u64::MAX
        );
    }
    if opts.worker_options.render_timeout.is_zero() {
        bail!("--timeout must be at least 1 second");
    }
    Ok(())
}

/// A dataset directory opened for writing: locked against other processes, cleared of partial
/// files, its manifest open for appending.
struct OpenDataset {
    layout: DatasetLayout,
    manifest: Manifest,
    /// Indices already in the manifest, or replaced by a finished curation round.
    done: BTreeSet<u64>,
    /// Held until the run ends.
    _lock: DatasetLock,
}

/// A farm's output and a plain dataset do not mix: shards go under `out/shards/`, which an
/// unsharded run (or a merged manifest) must not share.
fn check_output_kind(opts: &GenerateOptions) -> anyhow::Result<()> {
    let out = DatasetLayout::new(&opts.out);
    match opts.shard {
        None if out.shards_dir().is_dir() => bail!(
            "{} holds a farm's shards ({}); render into it with --shard K/N or --shard auto, or choose another --out",
            out.root.display(),
            out.shards_dir().display()
        ),
        Some(_) if out.manifest().is_file() && !out.merge_info().is_file() => {
            bail!(
                "{} is a dataset rendered without --shard; a farm's shards need an --out of their own",
                out.root.display()
            )
        }
        _ => Ok(()),
    }
}

/// `shard.json`: the shard's place in the whole range; a re-run with another range rewrites it
/// (merge then reports shards that have not caught up).
fn record_shard(
    layout: &DatasetLayout,
    opts: &GenerateOptions,
    shard: ShardId,
) -> anyhow::Result<()> {
    let info = ShardInfo {
        shard,
        start: opts.start,
        count: opts.count,
    };
    let old = layout.read_shard_info().ok();
    if old != Some(info) {
        if let Some(old) = old {
            tracing::info!(
                "{}: the farm's range changes from {}..{} to {}..{}",
                layout.root.display(),
                old.start,
                old.start + old.count,
                info.start,
                info.start + info.count
            );
        }
        layout.write_shard_info(&info)?;
    }
    Ok(())
}

fn open_dataset(opts: &GenerateOptions) -> anyhow::Result<OpenDataset> {
    check_output_kind(opts)?;
    let layout = DatasetLayout::new(opts.dataset_dir());
    std::fs::create_dir_all(&layout.root)
        .with_context(|| format!("cannot create output directory {}", layout.root.display()))?;
    let lock = DatasetLock::acquire(&layout.lock(), opts.break_lock)?;
    let info = layout.open_or_create(&opts.recipe, opts.seed)?;
    if let Some(shard) = opts.shard {
        record_shard(&layout, opts, shard)?;
    }
    let removed = layout.remove_partial_files();
    if removed > 0 {
        tracing::info!("removed {removed} partial file(s) left by an interrupted run");
    }
    // Without a lock holder, whatever is in the dataset's own scratch folder is left over.
    let _ = std::fs::remove_dir_all(layout.root.join(scratch::DATASET_SCRATCH_DIR));
    let (manifest, contents) = Manifest::open(&layout.manifest())?;
    if contents.has_unfinished_line() {
        tracing::warn!(
            "{}: dropped a torn last line left by an interrupted run",
            layout.manifest().display()
        );
    }
    let mut done: BTreeSet<u64> = contents.entries.iter().map(|e| e.index).collect();
    // A sample `curate` replaced is done for good: rendering it again would undo the curation.
    done.extend(super::curate::apply::replaced_indices(
        &layout,
        &info.curation,
    )?);
    Ok(OpenDataset {
        layout,
        manifest,
        done,
        _lock: lock,
    })
}

/// What the worker threads add up.
#[derive(Debug, Default)]
struct Totals {
    rendered: u64,
    failed: Vec<FailedSample>,
    restarts: u32,
    /// Wall seconds spent on rendered samples, summed over workers.
    busy_seconds: f64,
    /// Seconds spent reading samples back to verify them.
    verify_seconds: f64,
    /// Seconds spent appending manifest lines.
    manifest_seconds: f64,
}

/// State the worker threads share during one run.
struct Run<'a> {
    opts: &'a GenerateOptions,
    layout: &'a DatasetLayout,
    assets: AssetIndex,
    progress: &'a (dyn Fn(Progress<'_>) + Sync),
    queue: Mutex<VecDeque<u64>>,
    /// `None` once an append failed: a torn line must not get another one appended to it.
    manifest: Mutex<Option<Manifest>>,
    seen_skipped: Mutex<BTreeSet<PathBuf>>,
    /// One writer at a time for the small JSON-lines logs.
    logs: Mutex<()>,
    /// Set on a fatal error: the workers stop taking samples.
    stop: AtomicBool,
    fatal: Mutex<Option<anyhow::Error>>,
    totals: Mutex<Totals>,
}

impl Run<'_> {
    /// One worker thread: takes samples from the queue until it is empty or the run stops.
    fn worker_loop(&self, cfg: WorkerConfig) {
        let mut service = RenderService::new(cfg);
        while !self.stop.load(Ordering::SeqCst) && !self.opts.stop.is_set() {
            let Some(index) = self.queue.lock().unwrap().pop_front() else {
                break;
            };
            let t0 = Instant::now();
            let spec = plan_scene(&self.opts.recipe, &self.assets, self.opts.seed, index);
            let plan_s = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            match service.render(&spec, |attempt| self.opts.faults.fault(index, attempt)) {
                Ok(rendered) => {
                    let timings = stage_timings(&rendered, plan_s, t1.elapsed().as_secs_f64());
                    self.finish_sample(&spec, &rendered, &timings, t0)
                }
                // Abandoned: its scratch is gone with `service.render`, it stays pending.
                Err(WorkerError::Interrupted) => break,
                Err(e) if e.is_fatal() => self.fail_run(anyhow::Error::new(e)),
                Err(e) => self.record_failure(&spec, &e),
            }
        }
        self.totals.lock().unwrap().restarts += service.restarts;
        service.shutdown();
    }

    /// Writes a rendered sample into the dataset and appends its manifest line. `t0`: when its
    /// planning began; `timings`: its stages so far.
    fn finish_sample(
        &self,
        spec: &SceneSpec,
        rendered: &Rendered,
        timings: &BTreeMap<String, f64>,
        t0: Instant,
    ) {
        let reply = &rendered.reply;
        record_skipped(
            &self.logs,
            self.layout,
            &self.seen_skipped,
            &reply.report.skipped_assets,
            Some(spec.index),
        );
        let finished = finalize_sample(
            self.layout,
            spec,
            &reply.files,
            &reply.report.notes,
            t0.elapsed().as_secs_f64(),
            timings,
        )
        .and_then(|entry| {
            let t = Instant::now();
            self.append(&entry)?;
            Ok((entry, t.elapsed().as_secs_f64()))
        });
        match finished {
            Ok((entry, manifest_s)) => {
                tracing::debug!(
                    "sample {}: manifest line appended in {manifest_s:.4} s",
                    spec.id
                );
                let mut totals = self.totals.lock().unwrap();
                totals.rendered += 1;
                totals.manifest_seconds += manifest_s;
                totals.busy_seconds += entry.render_seconds;
                totals.verify_seconds += entry
                    .render_timings
                    .get(VERIFY_TIMING)
                    .copied()
                    .unwrap_or(0.0);
                drop(totals);
                (self.progress)(Progress::Rendered {
                    index: spec.index,
                    seconds: entry.render_seconds,
                });
            }
            // A write failure (disk full, permissions) will hit every sample.
            Err(e) => self.fail_run(e.context(format!("sample {}", spec.id))),
        }
    }

    /// Appends a finished sample's line. After a failed append the manifest is closed for the
    /// rest of the run: its torn last line is cut off by the next run's open.
    fn append(&self, entry: &super::manifest::ManifestEntry) -> anyhow::Result<()> {
        let mut manifest = self.manifest.lock().unwrap();
        let Some(m) = manifest.as_mut() else {
            bail!("the manifest is closed after a failed append")
        };
        if let Err(e) = m.append(entry) {
            *manifest = None;
            return Err(e.into());
        }
        Ok(())
    }

    fn record_failure(&self, spec: &SceneSpec, error: &WorkerError) {
        let message = error.to_string();
        append_failure(&self.logs, self.layout, spec.index, error);
        (self.progress)(Progress::Failed {
            index: spec.index,
            id: &spec.id,
            error: &message,
        });
        self.totals.lock().unwrap().failed.push(FailedSample {
            index: spec.index,
            error: message,
        });
    }

    fn fail_run(&self, error: anyhow::Error) {
        self.stop.store(true, Ordering::SeqCst);
        self.fatal.lock().unwrap().get_or_insert(error);
    }
}

/// The worker's steps plus the generator's own before finishing: [`PLAN_TIMING`],
/// [`WORKER_START_TIMING`] (where this render started a worker) and [`REQUEST_TIMING`], what of
/// the render's `render_s` wall seconds neither the start nor a worker step accounts for.
fn stage_timings(rendered: &Rendered, plan_s: f64, render_s: f64) -> BTreeMap<String, f64> {
    let mut timings = rendered.reply.report.timings.clone();
    let worker_steps: f64 = timings
        .iter()
        .filter(|(k, _)| is_wall_timing(k))
        .map(|(_, v)| v)
        .sum();
    let start = rendered.worker_start_s.unwrap_or(0.0);
    timings.insert(PLAN_TIMING.to_string(), plan_s);
    if let Some(s) = rendered.worker_start_s {
        timings.insert(WORKER_START_TIMING.to_string(), s);
    }
    timings.insert(
        REQUEST_TIMING.to_string(),
        (render_s - start - worker_steps).max(0.0),
    );
    timings
}

/// Runs a generation and returns what happened. Fatal problems (no Blender, unwritable output,
/// a dataset made with another recipe) are errors; a sample that fails is recorded and skipped.
pub fn generate(
    opts: &GenerateOptions,
    progress: &(dyn Fn(Progress<'_>) + Sync),
) -> anyhow::Result<GenerateSummary> {
    let started = Instant::now();
    check_options(opts)?;
    let dataset = open_dataset(opts)?;
    let orphaned_scratch_removed =
        scratch::remove_orphans(&scratch::candidate_bases(Some(&dataset.layout.root)));
    if orphaned_scratch_removed > 0 {
        tracing::info!(
            "removed {orphaned_scratch_removed} scratch folder(s) of runs that are no longer running"
        );
    }
    let logs = Mutex::new(());
    forget_finished_failures(&logs, &dataset.layout);
    let indices = opts.indices();
    let pending: VecDeque<u64> = indices
        .iter()
        .copied()
        .filter(|i| !dataset.done.contains(i))
        .collect();
    let skipped = (indices.len() - pending.len()) as u64;
    if pending.is_empty() || opts.stop.is_set() {
        let interrupted = !pending.is_empty();
        return Ok(GenerateSummary {
            skipped,
            seconds: started.elapsed().as_secs_f64(),
            interrupted,
            orphaned_scratch_removed,
            ..Default::default()
        });
    }

    let assets = index_sources(&opts.recipe.sources, &stereogen_home())?;
    dataset.layout.check_assets(assets.fingerprint.as_deref())?;
    let seen_skipped = Mutex::new(already_skipped(&dataset.layout)?);
    record_skipped(&logs, &dataset.layout, &seen_skipped, &assets.skipped, None);
    let mut cfg = opts.worker_options.resolve(opts.workers)?;
    cfg.scratch = scratch::choose_base(
        Some(&dataset.layout.root),
        opts.workers,
        scratch::bytes_per_render(opts.recipe.camera.width, opts.recipe.camera.height),
    );
    cfg.stop = opts.stop.clone();
    let threads = opts.workers.min(pending.len());
    let run = Run {
        opts,
        layout: &dataset.layout,
        assets,
        progress,
        queue: Mutex::new(pending),
        manifest: Mutex::new(Some(dataset.manifest)),
        seen_skipped,
        logs,
        stop: AtomicBool::new(false),
        fatal: Mutex::new(None),
        totals: Mutex::new(Totals::default()),
    };
    progress(Progress::Started {
        total: indices.len() as u64,
        done: skipped,
    });
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| run.worker_loop(cfg.clone()));
        }
    });
    forget_finished_failures(&run.logs, &dataset.layout);
    let _ = std::fs::remove_dir(dataset.layout.root.join(scratch::DATASET_SCRATCH_DIR));
    if let Some(e) = run.fatal.into_inner().unwrap() {
        return Err(e);
    }
    let totals = run.totals.into_inner().unwrap();
    let per_sample = |s: f64| {
        if totals.rendered > 0 {
            s / totals.rendered as f64
        } else {
            0.0
        }
    };
    let interrupted = opts.stop.is_set()
        && totals.rendered + skipped + (totals.failed.len() as u64) < indices.len() as u64;
    Ok(GenerateSummary {
        rendered: totals.rendered,
        skipped,
        seconds_per_sample: per_sample(totals.busy_seconds),
        verify_seconds_per_sample: per_sample(totals.verify_seconds),
        manifest_seconds_per_sample: per_sample(totals.manifest_seconds),
        failed: totals.failed,
        worker_restarts: totals.restarts,
        seconds: started.elapsed().as_secs_f64(),
        interrupted,
        orphaned_scratch_removed,
    })
}
