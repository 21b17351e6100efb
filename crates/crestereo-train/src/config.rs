//! The training configuration: one TOML file, every value defaulting to the paper's recipe.
//!
//! A minimal config names only the data:
//!
//! ```toml
//! [[datasets]]
//! path = "/data/stereogen"          # any layout stereo-io reads; relative paths are relative to this file
//! weight = 98
//! # splits = ["train"]              # a WebDataset export's splits (default: train, or its only one)
//! [[datasets]]
//! path = "/data/middlebury2014"
//! format = "middlebury"             # optional: force the layout instead of detecting it
//! weight = 2
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use stereo_io::DatasetFormat;

use crate::augment::AugmentConfig;
use crate::schedule::LrScheduleConfig;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Seeds the model initialisation, the data order and every augmentation.
    pub seed: u64,
    /// Optimiser steps of the whole run (the schedule's `total_steps` follows it unless set).
    pub steps: u64,
    /// Samples per forward/backward pass.
    pub batch_size: usize,
    /// Passes whose gradients are summed before one optimiser step: the effective batch is
    /// `batch_size × accumulate` (the paper: 16).
    pub accumulate: usize,
    /// Refinement iterations in training (the reference: 10 → 5 + 5 + 10 = 20 predictions).
    pub iters: usize,
    /// Weight decay of the sequence loss over predictions (paper 0.9, reference code 0.8).
    pub gamma: f64,
    pub adam: AdamSettings,
    pub schedule: ScheduleSettings,
    pub augment: AugmentConfig,
    pub loader: LoaderSettings,
    /// How WebDataset sources are streamed: part of the data order (unlike `loader`).
    pub webdataset: StreamSettings,
    pub checkpoint: CheckpointSettings,
    pub log: LogSettings,
    /// Start from these weights (a reference `.pt` or a Burn `.mpk`) instead of a random init.
    pub init_weights: Option<PathBuf>,
    pub datasets: Vec<DatasetEntry>,
    pub validation: Option<ValidationSettings>,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            steps: 300_000,
            batch_size: 2,
            accumulate: 8,
            iters: 10,
            gamma: 0.9,
            adam: AdamSettings::default(),
            schedule: ScheduleSettings::default(),
            augment: AugmentConfig::default(),
            loader: LoaderSettings::default(),
            webdataset: StreamSettings::default(),
            checkpoint: CheckpointSettings::default(),
            log: LogSettings::default(),
            init_weights: None,
            datasets: Vec::new(),
            validation: None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdamSettings {
    pub beta1: f64,
    pub beta2: f64,
    /// Set explicitly: Burn's default (1e-5) differs from PyTorch's and the reference's 1e-8.
    pub eps: f64,
}

impl Default for AdamSettings {
    fn default() -> Self {
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// The learning-rate schedule in config form; `total_steps` defaults to the run's `steps`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScheduleSettings {
    pub lr: f64,
    pub floor_fraction: f64,
    pub warmup_steps: u64,
    pub decay_start: u64,
    pub total_steps: Option<u64>,
}

impl Default for ScheduleSettings {
    fn default() -> Self {
        let paper = LrScheduleConfig::default();
        Self {
            lr: paper.base_lr,
            floor_fraction: paper.floor_fraction,
            warmup_steps: paper.warmup_steps,
            decay_start: paper.decay_start,
            total_steps: None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoaderSettings {
    /// Decoding + augmentation threads (0 = one per core, at most 8).
    pub workers: usize,
    /// Samples decoded ahead of the training step (the bounded prefetch queue).
    pub prefetch: usize,
    /// Attempts on neighbouring samples when one cannot be read, before the run stops.
    pub max_bad_retries: usize,
}

impl Default for LoaderSettings {
    fn default() -> Self {
        Self {
            workers: 0,
            prefetch: 16,
            max_bad_retries: 8,
        }
    }
}

/// How a WebDataset source is read in training (`[webdataset]`): each epoch its shards are
/// permuted and dealt round-robin to `streams` streams, each read front to back through a
/// shuffle buffer of `shuffle_buffer` samples. These settings decide the data order (a resumed
/// run must keep them); the loader's threads do not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamSettings {
    /// Streams a WebDataset's shards are dealt to each epoch (0 = no streaming: every sample
    /// read by seeking, in a full shuffle per epoch).
    pub streams: usize,
    /// Samples in each stream's shuffle buffer, held as their files' bytes (a 960×540 sample of
    /// ours: about 2.3 MB), so at most `streams × shuffle_buffer` samples are in memory.
    pub shuffle_buffer: usize,
}

impl Default for StreamSettings {
    fn default() -> Self {
        // 4 × 250: the 1000 samples of WebDataset's usual shuffle buffer, about 2.3 GB at 960×540.
        Self {
            streams: 4,
            shuffle_buffer: 250,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheckpointSettings {
    /// Save every this many optimiser steps (and always at the end).
    pub every: u64,
    /// Checkpoints kept; older ones are deleted after a new one is complete.
    pub keep: usize,
}

impl Default for CheckpointSettings {
    fn default() -> Self {
        Self {
            every: 1000,
            keep: 3,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogSettings {
    /// Write a CSV / TensorBoard row every this many steps.
    pub every: u64,
    /// Also write TensorBoard event files under `<run>/tensorboard/`.
    pub tensorboard: bool,
}

impl Default for LogSettings {
    fn default() -> Self {
        Self {
            every: 1,
            tensorboard: true,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetEntry {
    pub path: PathBuf,
    /// A stereo-io layout (`stereogen`, `crestereo`, `sceneflow`, `middlebury`, `webdataset`, …);
    /// detected from the files when absent. Checked when the file is read.
    #[serde(default, with = "format_name")]
    pub format: Option<DatasetFormat>,
    /// Relative sampling weight (any positive number; normalised over the list).
    #[serde(default = "one")]
    pub weight: f64,
    /// The splits of a WebDataset export to train on (`<split>.index.json`); absent: `train`
    /// where the export has one, its only split where it has one, else an error asking. A run
    /// stores the splits it chose, so they are part of its identity on `--resume`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splits: Option<Vec<String>>,
}

impl DatasetEntry {
    /// `path` at weight 1, its layout detected, a WebDataset's default split.
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            format: None,
            weight: 1.0,
            splits: None,
        }
    }
}

fn one() -> f64 {
    1.0
}

/// Held-out data evaluated during training (metrics go to the CSV and TensorBoard).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidationSettings {
    pub path: PathBuf,
    #[serde(default, with = "format_name")]
    pub format: Option<DatasetFormat>,
    /// The splits of a WebDataset export to evaluate; absent: its only split, else `val`, else
    /// `test`, else an error asking.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splits: Option<Vec<String>>,
    /// Evaluate every this many steps (and at the end).
    #[serde(default = "default_val_every")]
    pub every: u64,
    /// At most this many samples (0 = all).
    #[serde(default)]
    pub limit: usize,
    #[serde(default = "default_val_iters")]
    pub iters: usize,
    #[serde(default = "default_val_stages")]
    pub stages: usize,
}

impl ValidationSettings {
    /// Validation on `path` with the defaults a `[validation]` table gets.
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            format: None,
            splits: None,
            every: default_val_every(),
            limit: 0,
            iters: default_val_iters(),
            stages: default_val_stages(),
        }
    }
}

fn default_val_every() -> u64 {
    5000
}
fn default_val_iters() -> usize {
    20
}
fn default_val_stages() -> usize {
    2
}

/// A split list, where given, names at least one split, none of them empty.
fn check_split_names(splits: Option<&[String]>, key: &str) -> Result<()> {
    if let Some(s) = splits
        && (s.is_empty() || s.iter().any(|n| n.trim().is_empty()))
    {
        bail!("{key} must name at least one split, none empty, got {s:?}");
    }
    Ok(())
}

/// A layout in the config as its stereo-io name; an unknown name fails the read of the file.
mod format_name {
    use serde::{Deserialize, Deserializer, Serializer};
    use stereo_io::DatasetFormat;

    pub fn serialize<S: Serializer>(f: &Option<DatasetFormat>, s: S) -> Result<S::Ok, S::Error> {
        match f {
            Some(f) => s.serialize_str(f.name()),
            None => s.serialize_none(),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<DatasetFormat>, D::Error> {
        Option::<String>::deserialize(d)?
            .map(|name| name.parse().map_err(serde::de::Error::custom))
            .transpose()
    }
}

/// Reads a config's text: a value that does not parse or check is one line naming its key
/// path (`datasets[1].format`) and line.
pub fn parse_config(text: &str) -> Result<TrainConfig> {
    let cfg: TrainConfig = toml::from_str(text).map_err(|e| {
        let at = e.span().map(|s| s.start.min(text.len()));
        let line = at.map(|a| text[..a].lines().count().max(1));
        let key = at.and_then(|a| key_path_at(text, a));
        let place = match (line, key) {
            (Some(l), Some(k)) => format!(" (line {l}, {k})"),
            (Some(l), None) => format!(" (line {l})"),
            _ => String::new(),
        };
        anyhow::anyhow!("{}{place}", e.message().trim())
    })?;
    cfg.validate()?;
    Ok(cfg)
}

/// The key path of the `key = value` line holding byte `at`: its table header (`[[datasets]]`
/// counted into `datasets[i]`) and key.
fn key_path_at(text: &str, at: usize) -> Option<String> {
    let line_start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?;
    let key = line.split_once('=')?.0.trim();
    let mut table: Option<String> = None;
    let mut counts = std::collections::HashMap::<&str, usize>::new();
    for header in text[..line_start].lines().map(str::trim) {
        if let Some(name) = header.strip_prefix("[[").and_then(|h| h.strip_suffix("]]")) {
            let n = counts.entry(name.trim()).or_insert(0);
            table = Some(format!("{}[{}]", name.trim(), *n));
            *n += 1;
        } else if let Some(name) = header.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
            table = Some(name.trim().to_string());
        }
    }
    Some(table.map_or_else(|| key.to_string(), |t| format!("{t}.{key}")))
}

impl TrainConfig {
    /// Reads a config file; relative dataset paths are resolved against its directory.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read training config {}", path.display()))?;
        let mut cfg =
            parse_config(&text).with_context(|| format!("training config {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        cfg.resolve_paths(base);
        Ok(cfg)
    }

    /// The config a run directory was started with (`<run>/config.toml`), if any.
    pub fn stored(run: &Path) -> Result<Option<Self>> {
        let path = run.join("config.toml");
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        Ok(Some(
            toml::from_str(&text).with_context(|| format!("corrupt {}", path.display()))?,
        ))
    }

    /// Makes every path absolute relative to `base`, so a copy of the config stored in the run
    /// directory means the same data.
    pub fn resolve_paths(&mut self, base: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = std::path::absolute(base.join(&*p)).unwrap_or_else(|_| base.join(&*p));
            }
        };
        for d in &mut self.datasets {
            fix(&mut d.path);
        }
        if let Some(v) = &mut self.validation {
            fix(&mut v.path);
        }
        if let Some(w) = &mut self.init_weights {
            fix(w);
        }
    }

    pub fn schedule(&self) -> LrScheduleConfig {
        let s = self.schedule;
        LrScheduleConfig {
            base_lr: s.lr,
            floor_fraction: s.floor_fraction,
            warmup_steps: s.warmup_steps,
            decay_start: s.decay_start,
            total_steps: s.total_steps.unwrap_or(self.steps),
        }
    }

    /// Checks every value; the message names the key.
    pub fn validate(&self) -> Result<()> {
        self.validate_datasets()?;
        self.validate_recipe()?;
        self.validate_run_settings()
    }

    fn validate_datasets(&self) -> Result<()> {
        if self.datasets.is_empty() {
            bail!("no training data: add at least one [[datasets]] entry (or pass --data)");
        }
        for (i, d) in self.datasets.iter().enumerate() {
            if !(d.weight > 0.0 && d.weight.is_finite()) {
                bail!(
                    "datasets[{i}].weight must be a positive number, got {}",
                    d.weight
                );
            }
            check_split_names(d.splits.as_deref(), &format!("datasets[{i}].splits"))?;
        }
        if let Some(v) = &self.validation {
            check_split_names(v.splits.as_deref(), "validation.splits")?;
        }
        Ok(())
    }

    /// What defines the loss curve: steps, batch, iterations, loss, optimiser, schedule and
    /// augmentation.
    fn validate_recipe(&self) -> Result<()> {
        if self.steps == 0 {
            bail!("steps must be at least 1");
        }
        if self.batch_size == 0 || self.accumulate == 0 {
            bail!("batch_size and accumulate must be at least 1");
        }
        if self.iters < 2 || !self.iters.is_multiple_of(2) {
            bail!(
                "iters must be an even number ≥ 2 (half run at 1/16 and half at 1/8), got {}",
                self.iters
            );
        }
        if !(self.gamma > 0.0 && self.gamma <= 1.0) {
            bail!("gamma must be in (0, 1], got {}", self.gamma);
        }
        let a = self.adam;
        if !((0.0..1.0).contains(&a.beta1) && (0.0..1.0).contains(&a.beta2) && a.eps > 0.0) {
            bail!("adam: need 0 ≤ beta1, beta2 < 1 and eps > 0");
        }
        self.schedule()
            .validate()
            .map_err(|e| anyhow::anyhow!("schedule: {e}"))?;
        self.augment
            .validate()
            .map_err(|e| anyhow::anyhow!("augment: {e}"))?;
        let [h, w] = self.augment.crop;
        if h % 16 != 0 || w % 16 != 0 {
            bail!(
                "augment.crop {h}x{w}: both sides must be multiples of 16 (the network's 1/16 level)"
            );
        }
        Ok(())
    }

    /// Loader, checkpoint, log and validation settings.
    fn validate_run_settings(&self) -> Result<()> {
        if self.loader.prefetch == 0 {
            bail!("loader.prefetch must be at least 1");
        }
        if self.webdataset.shuffle_buffer == 0 {
            bail!("webdataset.shuffle_buffer must be at least 1 (1 = the order of the shards)");
        }
        if self.checkpoint.every == 0 || self.checkpoint.keep == 0 {
            bail!("checkpoint.every and checkpoint.keep must be at least 1");
        }
        if self.log.every == 0 {
            bail!("log.every must be at least 1");
        }
        if let Some(v) = &self.validation
            && (v.every == 0 || v.iters == 0 || !(1..=3).contains(&v.stages))
        {
            bail!("validation: every and iters must be ≥ 1 and stages in 1..=3");
        }
        Ok(())
    }

    /// Loader threads actually used.
    pub fn workers(&self) -> usize {
        if self.loader.workers > 0 {
            self.loader.workers
        } else {
            std::thread::available_parallelism()
                .map_or(2, |n| n.get())
                .min(8)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The message of the error `text` is refused with.
    fn parse_error(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    fn parse(text: &str) -> Result<TrainConfig> {
        parse_config(text)
    }

    #[test]
    fn minimal_config_is_the_paper_recipe() {
        let cfg = parse("[[datasets]]\npath = \"a\"\n").unwrap();
        assert_eq!(cfg.batch_size * cfg.accumulate, 16);
        assert_eq!(cfg.augment.crop, [384, 512]);
        assert_eq!(cfg.adam.eps, 1e-8);
        assert_eq!(cfg.gamma, 0.9);
        let s = cfg.schedule();
        assert_eq!(
            (s.base_lr, s.warmup_steps, s.decay_start, s.total_steps),
            (4e-4, 6000, 180_000, 300_000)
        );
        assert_eq!(cfg.datasets[0].weight, 1.0);
    }

    #[test]
    fn bad_keys_and_values_are_named() {
        let e = parse_error("stepz = 3\n[[datasets]]\npath = \"a\"\n");
        assert!(e.contains("stepz"), "{e}");
        let e = parse_error("[[datasets]]\npath = \"a\"\nweight = -1\n");
        assert!(e.contains("datasets[0].weight"), "{e}");
        let e = parse_error("[[datasets]]\npath = \"a\"\nformat = \"nope\"\n");
        assert!(e.contains("datasets[0].format"), "{e}");
        // Typed when read: the entry it is in, counted, and the validation table too.
        let e = parse_error(
            "[[datasets]]\npath = \"a\"\n[[datasets]]\npath = \"b\"\nformat = \"kitty\"\n",
        );
        assert!(
            e.contains("datasets[1].format") && e.contains("kitty"),
            "{e}"
        );
        let e =
            parse_error("[[datasets]]\npath = \"a\"\n[validation]\npath = \"v\"\nformat = \"x\"\n");
        assert!(
            e.contains("validation.format") && e.contains("line 5"),
            "{e}"
        );
        let cfg = parse("[[datasets]]\npath = \"a\"\nformat = \"webdataset\"\n").unwrap();
        assert_eq!(
            cfg.datasets[0].format,
            Some(stereo_io::DatasetFormat::WebDataset)
        );
        let e = parse_error("iters = 3\n[[datasets]]\npath = \"a\"\n");
        assert!(e.contains("iters"), "{e}");
        let e = parse_error("[augment]\ncrop = [100, 128]\n[[datasets]]\npath = \"a\"\n");
        assert!(e.contains("multiples of 16"), "{e}");
        let e = parse_error("");
        assert!(e.contains("no training data"), "{e}");
        let e =
            parse_error("steps = 100\n[schedule]\ndecay_start = 500\n[[datasets]]\npath = \"a\"\n");
        assert!(e.contains("schedule"), "{e}");
    }

    #[test]
    fn relative_paths_follow_the_config_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("train.toml");
        std::fs::write(
            &file,
            "[[datasets]]\npath = \"data/ours\"\n[[datasets]]\npath = \"/abs/mb\"\nweight = 2\n",
        )
        .unwrap();
        let cfg = TrainConfig::from_file(&file).unwrap();
        assert_eq!(cfg.datasets[0].path, dir.path().join("data/ours"));
        assert_eq!(cfg.datasets[1].path, PathBuf::from("/abs/mb"));
    }
}
