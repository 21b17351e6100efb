//! Per-sample scores of a dataset under one model (`crestereo score`): for each sample the
//! metrics of `crestereo eval`'s per-image report (computed by the same
//! [`crate::eval::evaluate_sample`]), one JSON line each, so that a dataset can be sliced or
//! curated by how hard its samples are for a trained network.
//!
//! The file is resumable. Its first line states what made the scores (dataset, weights and their
//! CRC-32C, iterations, stages); each further line is one sample, appended with one write and
//! synced before the next sample starts. A run that finds the file continues: the samples it
//! already holds are skipped, an unfinished last line (a kill during the append) is cut off, and a
//! file made with other weights or options is refused rather than mixed.

use std::collections::HashSet;
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use crestereo::CREStereo;
use serde_json::{Value, json};
use stereo_io::StereoDataset;

use crate::eval::{EvalOptions, ImageResult, evaluate_sample};

/// What made a scores file: its first line.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ScoreHeader {
    /// Always `crestereo-scores`: a file of another kind is never taken for one.
    pub scores: &'static str,
    pub dataset: String,
    pub weights: String,
    /// CRC-32C of the weights file's bytes (`untrained (seed N)` for a seeded start).
    pub weights_crc32c: String,
    pub iters: usize,
    pub stages: usize,
    pub lr_tolerance_px: f32,
}

impl ScoreHeader {
    pub fn new(
        dataset: &dyn StereoDataset,
        weights: &str,
        fingerprint: String,
        opts: &EvalOptions,
    ) -> Self {
        Self {
            scores: "crestereo-scores",
            dataset: dataset.root().display().to_string(),
            weights: weights.to_string(),
            weights_crc32c: fingerprint,
            iters: opts.iters,
            stages: opts.stages,
            lr_tolerance_px: opts.lr_tolerance_px,
        }
    }
}

/// The CRC-32C of a weights file, as a scores file's header states it.
pub fn weights_fingerprint(path: &Path) -> Result<String> {
    let mut file = File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (mut crc, mut buf) = (0u32, vec![0u8; 1 << 20]);
    loop {
        let n = file
            .read(&mut buf)
            .with_context(|| format!("cannot read {}", path.display()))?;
        if n == 0 {
            return Ok(format!("{crc:08x}"));
        }
        crc = crc32c::crc32c_append(crc, &buf[..n]);
    }
}

/// How a scoring run went.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoreOutcome {
    /// Samples scored by this run.
    pub scored: usize,
    /// Samples the file already held.
    pub resumed: usize,
    /// Samples that could not be read (a line with their error).
    pub failed: usize,
    /// Samples per second of this run.
    pub rate: f64,
}

/// The scores file opened for appending, with the sample indices it already holds.
struct ScoreFile {
    file: File,
    done: HashSet<usize>,
}

fn open(out: &Path, header: &Value) -> Result<ScoreFile> {
    let mut file = OpenOptions::new()
        .create(true)
        .read(true)
        .append(true)
        .open(out)
        .with_context(|| format!("cannot open {}", out.display()))?;
    let mut text = String::new();
    file.read_to_string(&mut text)
        .with_context(|| format!("{} is not a scores file (not text)", out.display()))?;
    // Everything after the last newline is an append a kill cut short: never a record.
    let whole = text.rfind('\n').map_or(0, |i| i + 1);
    if whole < text.len() {
        file.set_len(whole as u64)
            .and_then(|_| file.seek(SeekFrom::End(0)).map(|_| ()))
            .with_context(|| format!("cannot cut the unfinished last line of {}", out.display()))?;
    }
    let mut lines = text[..whole].lines().enumerate();
    let mut done = HashSet::new();
    match lines.next() {
        None => append(&mut file, out, header)?,
        Some((_, first)) => {
            let found: Value = serde_json::from_str(first)
                .with_context(|| format!("{}: line 1 is not JSON", out.display()))?;
            if found.get("scores").and_then(Value::as_str) != Some("crestereo-scores") {
                bail!(
                    "{} is not a scores file of `crestereo score`",
                    out.display()
                );
            }
            if &found != header {
                bail!(
                    "{} holds scores made otherwise ({first}); now: {header}. Choose another --out, or remove it to start again",
                    out.display()
                );
            }
        }
    }
    for (i, line) in lines {
        let index = serde_json::from_str::<Value>(line)
            .ok()
            .and_then(|v| v.get("index").and_then(Value::as_u64));
        match index {
            Some(index) => done.insert(index as usize),
            None => bail!("{}: line {} is not a sample's scores", out.display(), i + 1),
        };
    }
    Ok(ScoreFile { file, done })
}

/// Appends one line with one write, and syncs it.
fn append(file: &mut File, out: &Path, record: &Value) -> Result<()> {
    let mut line = record.to_string();
    line.push('\n');
    file.write_all(line.as_bytes())
        .and_then(|_| file.sync_data())
        .with_context(|| format!("cannot write {}", out.display()))
}

/// Scores samples `0..opts.count(len)` of `dataset` into `out` (see the module's doc), skipping
/// those the file already holds; `progress(done, total, result)` after each scored sample.
pub fn score<B: Backend>(
    model: &CREStereo<B>,
    dataset: &dyn StereoDataset,
    header: &ScoreHeader,
    opts: &EvalOptions,
    out: &Path,
    device: &B::Device,
    mut progress: impl FnMut(usize, usize, &ImageResult),
) -> Result<ScoreOutcome> {
    let header = serde_json::to_value(header)?;
    let ScoreFile { mut file, done } = open(out, &header)?;
    let n = opts.count(dataset.len());
    let resumed = (0..n).filter(|i| done.contains(i)).count();
    let (mut scored, mut failed, t0) = (0, 0, Instant::now());
    for i in (0..n).filter(|i| !done.contains(i)) {
        let id = dataset.id(i).unwrap_or("?").to_string();
        let result = dataset
            .sample(i)
            .map_err(anyhow::Error::from)
            .and_then(|s| evaluate_sample(model, &s, &id, opts, device));
        let record = match &result {
            Ok(r) => {
                let mut v = serde_json::to_value(r)?;
                v["index"] = json!(i);
                v
            }
            Err(e) => {
                tracing::warn!("scoring skips {id}: {e:#}");
                failed += 1;
                json!({ "index": i, "id": id, "error": format!("{e:#}") })
            }
        };
        append(&mut file, out, &record)?;
        scored += 1;
        if let Ok(r) = &result {
            progress(resumed + scored, n, r);
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    Ok(ScoreOutcome {
        scored,
        resumed,
        failed,
        rate: if seconds > 0.0 {
            scored as f64 / seconds
        } else {
            0.0
        },
    })
}
