//! `stereogen status OUT`: how far a farm (or a single dataset) has got, read from the files
//! alone — manifests, `failures.jsonl`, lock files and the times the sample files were written —
//! so it runs anywhere the output is mounted, e.g. a login node.
//!
//! Samples per hour: over the last [`RATE_WINDOW`] samples a shard finished (by the times their
//! scene files were written), counting only the current run's samples while it runs, so a pause
//! between runs does not lower the rate. ETA: remaining ÷ rate, per shard and for the farm
//! (the summed rate of the running shards).

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use anyhow::bail;
use stereo_io::datasets::stereogen::{MergeInfo, ShardId, ShardInfo};

use super::layout::DatasetLayout;
use super::lock::{LockState, inspect};
use super::manifest::{ManifestEntry, read_failures, read_manifest};

/// How many of a shard's latest samples its rate is measured over.
pub const RATE_WINDOW: usize = 64;

/// What a shard's lock says about its run.
#[derive(Debug, Clone, PartialEq)]
pub enum RunState {
    NotStarted,
    Running {
        holder: String,
        heartbeat_age: Duration,
    },
    /// The run holding the lock was killed (why in words).
    Killed {
        why: String,
    },
    /// No run holds it.
    Idle,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ShardStatus {
    /// `0003-of-0064`, or the directory's name for a dataset without shards.
    pub name: String,
    pub shard: Option<ShardId>,
    /// Samples the shard must render, when its range is known.
    pub total: Option<u64>,
    pub done: u64,
    /// Failed and not rendered since.
    pub failed: u64,
    pub state: RunState,
    pub samples_per_hour: Option<f64>,
}

impl ShardStatus {
    pub fn remaining(&self) -> Option<u64> {
        self.total.map(|t| t.saturating_sub(self.done))
    }

    fn eta(&self) -> Option<Duration> {
        let rate = self.samples_per_hour.filter(|r| *r > 0.0)?;
        let remaining = self.remaining()?;
        matches!(self.state, RunState::Running { .. })
            .then(|| Duration::from_secs_f64(remaining as f64 / rate * 3600.0))
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct FarmStatus {
    pub root: PathBuf,
    pub shards: Vec<ShardStatus>,
    pub merged: Option<MergeInfo>,
}

/// Reads the status of `root`: a farm's output (its `shards/`) or one dataset directory.
pub fn farm_status(root: &Path) -> anyhow::Result<FarmStatus> {
    let out = DatasetLayout::new(root);
    let found = out.shard_dirs()?.shards;
    let merged = out.read_merge_info().ok();
    if found.is_empty() {
        if !out.info().is_file() {
            bail!(
                "{}: neither a stereogen dataset (no dataset.json) nor a farm's output (no shards/)",
                root.display()
            );
        }
        let name = root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| root.display().to_string());
        return Ok(FarmStatus {
            root: root.to_path_buf(),
            shards: vec![shard_status(&out, name, None, None)?],
            merged,
        });
    }
    // The farm's size and range: from the shards' own descriptions.
    let ranges: Vec<ShardInfo> = found
        .iter()
        .filter_map(|(_, l)| l.read_shard_info().ok())
        .collect();
    let count = ranges
        .first()
        .map(|r| r.shard.count)
        .unwrap_or(found[0].0.count);
    let mut shards = Vec::new();
    for index in 0..count {
        let id = ShardId { index, count };
        let total = ranges
            .first()
            .map(|r| (r.start..r.start + r.count).filter(|&i| id.owns(i)).count() as u64);
        match found.iter().find(|(f, _)| *f == id) {
            Some((_, layout)) => shards.push(shard_status(layout, id.dir_name(), Some(id), total)?),
            None => shards.push(ShardStatus {
                name: id.dir_name(),
                shard: Some(id),
                total,
                done: 0,
                failed: 0,
                state: RunState::NotStarted,
                samples_per_hour: None,
            }),
        }
    }
    Ok(FarmStatus {
        root: root.to_path_buf(),
        shards,
        merged,
    })
}

fn shard_status(
    layout: &DatasetLayout,
    name: String,
    shard: Option<ShardId>,
    total: Option<u64>,
) -> anyhow::Result<ShardStatus> {
    let entries = if layout.manifest().is_file() {
        read_manifest(&layout.manifest())?.entries
    } else {
        Vec::new()
    };
    let done: std::collections::BTreeSet<u64> = entries.iter().map(|e| e.index).collect();
    let failed = failed_not_done(layout, &done)?;
    let (state, run_started) = match inspect(&layout.lock()) {
        LockState::Held {
            holder,
            heartbeat_age,
        } => {
            let started = SystemTime::UNIX_EPOCH + Duration::from_secs(holder.started_unix_s);
            (
                RunState::Running {
                    holder: holder.describe(),
                    heartbeat_age,
                },
                Some(started),
            )
        }
        LockState::LegacyHeld => (
            RunState::Running {
                holder: "an older stereogen".into(),
                heartbeat_age: Duration::ZERO,
            },
            None,
        ),
        LockState::Stale { holder, why } => (
            RunState::Killed {
                why: holder
                    .map(|h| format!("{}: {why}", h.describe()))
                    .unwrap_or(why),
            },
            None,
        ),
        LockState::Free => (RunState::Idle, None),
    };
    let samples_per_hour = rate(layout, &entries, run_started);
    Ok(ShardStatus {
        name,
        shard,
        total,
        done: done.len() as u64,
        failed,
        state,
        samples_per_hour,
    })
}

/// Samples `failures.jsonl` lists that are not finished since.
fn failed_not_done(
    layout: &DatasetLayout,
    done: &std::collections::BTreeSet<u64>,
) -> stereo_io::Result<u64> {
    let failed: std::collections::BTreeSet<u64> = read_failures(&layout.failures())?
        .records
        .iter()
        .map(|r| r.index)
        .filter(|i| !done.contains(i))
        .collect();
    Ok(failed.len() as u64)
}

/// Samples per hour over the latest finished samples (of the current run, while one runs).
fn rate(
    layout: &DatasetLayout,
    entries: &[ManifestEntry],
    run_started: Option<SystemTime>,
) -> Option<f64> {
    let written = |e: &ManifestEntry| {
        std::fs::metadata(layout.abs(&e.files.scene))
            .and_then(|m| m.modified())
            .ok()
    };
    let mut times: Vec<SystemTime> = entries
        .iter()
        .rev()
        .take(RATE_WINDOW)
        .filter_map(written)
        .collect();
    if let Some(start) = run_started {
        times.retain(|t| *t >= start);
        // The run's start counts as a point: the first sample of a run took time too.
        times.push(start);
    }
    times.sort();
    let span = times
        .last()?
        .duration_since(*times.first()?)
        .ok()?
        .as_secs_f64();
    let samples = if run_started.is_some() {
        times.len() - 1
    } else {
        times.len().saturating_sub(1)
    };
    (samples > 0 && span > 0.0).then(|| samples as f64 / span * 3600.0)
}

fn human(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..=99 => format!("{s} s"),
        100..=5999 => format!("{} min", (s + 30) / 60),
        _ => format!("{:.1} h", s as f64 / 3600.0),
    }
}

/// The table `stereogen status` prints: one line per shard, then the farm's totals.
pub fn status_lines(status: &FarmStatus) -> Vec<String> {
    let mut lines = vec![format!(
        "{:<16} {:>8} {:>7} {:>10} {:>10} {:>9}  state",
        "shard", "done", "failed", "remaining", "samples/h", "ETA"
    )];
    let num = |v: Option<u64>| v.map_or("?".to_string(), |v| v.to_string());
    let rate = |r: Option<f64>| r.map_or("-".to_string(), |r| format!("{r:.0}"));
    for s in &status.shards {
        let state = match &s.state {
            RunState::NotStarted => "not started".to_string(),
            RunState::Running {
                holder,
                heartbeat_age,
            } => format!(
                "running: {holder} (heartbeat {} ago)",
                human(*heartbeat_age)
            ),
            RunState::Killed { why } => format!("killed ({why}); re-run its task to resume"),
            RunState::Idle if s.remaining() == Some(0) && s.failed == 0 => "finished".to_string(),
            RunState::Idle => "stopped".to_string(),
        };
        let eta = s.eta().map_or("-".to_string(), human);
        lines.push(format!(
            "{:<16} {:>8} {:>7} {:>10} {:>10} {:>9}  {state}",
            s.name,
            s.done,
            s.failed,
            num(s.remaining()),
            rate(s.samples_per_hour),
            eta
        ));
    }
    let done: u64 = status.shards.iter().map(|s| s.done).sum();
    let failed: u64 = status.shards.iter().map(|s| s.failed).sum();
    let remaining: Option<u64> = status.shards.iter().map(ShardStatus::remaining).sum();
    let running: Vec<&ShardStatus> = status
        .shards
        .iter()
        .filter(|s| matches!(s.state, RunState::Running { .. }))
        .collect();
    let farm_rate: Option<f64> = running
        .iter()
        .map(|s| s.samples_per_hour)
        .sum::<Option<f64>>()
        .filter(|r| *r > 0.0);
    let eta = match (remaining, farm_rate) {
        (Some(0), _) => "-".to_string(),
        (Some(r), Some(rate)) => human(Duration::from_secs_f64(r as f64 / rate * 3600.0)),
        _ => "?".to_string(),
    };
    let count = |f: fn(&RunState) -> bool| status.shards.iter().filter(|s| f(&s.state)).count();
    let summary = format!(
        "{} running, {} killed, {} not started",
        running.len(),
        count(|s| matches!(s, RunState::Killed { .. })),
        count(|s| matches!(s, RunState::NotStarted))
    );
    lines.push(format!(
        "{:<16} {:>8} {:>7} {:>10} {:>10} {:>9}  {summary}",
        "all",
        done,
        failed,
        num(remaining),
        rate(farm_rate),
        eta
    ));
    lines.push(match &status.merged {
        Some(m) => format!("merged: {} samples of {} shards ({} checksums) — `stereogen merge` again after new samples", m.count, m.shards, if m.checksums == stereo_io::datasets::stereogen::ChecksumCheck::All { "all" } else { "sampled" }),
        None if status.shards.iter().any(|s| s.shard.is_some()) => format!("not merged yet: `stereogen merge {}` when every shard is finished", status.root.display()),
        None => String::new(),
    });
    lines.retain(|l| !l.is_empty());
    lines
}
