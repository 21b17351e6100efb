//! `crestereo train`: a config file and/or flags → [`crate::train::train`].

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::tensor::backend::AutodiffBackend;

use crate::config::{DatasetEntry, TrainConfig, ValidationSettings};
use crate::interrupt::Interrupted;
use crate::parallel::topology::{ProcessFlags, process_env, resolve};
use crate::parallel::{ParallelOptions, default_timeouts, train_parallel};
use crate::train::{TrainOptions, TrainOutcome, train};

use super::devices::{DeviceList, FromDeviceIndex};

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// The run directory: config copy, logs, TensorBoard events, checkpoints.
    #[arg(long)]
    pub out: PathBuf,
    /// Training config (TOML). Without it the paper's recipe is used; flags below override it.
    /// With --resume and no --config, the run's own config.toml is used.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Training data, repeatable: DIR, DIR:FORMAT or DIR:FORMAT@WEIGHT (e.g. ours@98 and
    /// mb:middlebury@2); a WebDataset export's splits as DIR:webdataset:SPLIT[,SPLIT] (default:
    /// `train`, or the export's only split). Replaces the config's datasets.
    #[arg(long = "data", value_name = "DIR[:FORMAT[:SPLITS]][@WEIGHT]")]
    pub data: Vec<String>,
    /// Held-out data evaluated every --val-every steps: DIR, DIR:FORMAT or
    /// DIR:webdataset:SPLIT[,SPLIT] (default: the export's only split, else `val`, else `test`).
    #[arg(long, value_name = "DIR[:FORMAT[:SPLITS]]")]
    pub val: Option<String>,
    #[arg(long)]
    pub val_every: Option<u64>,
    /// Validation samples at most (0 = all).
    #[arg(long)]
    pub val_limit: Option<usize>,
    /// Continue the run from its newest checkpoint (model, optimiser, schedule, data position).
    #[arg(long)]
    pub resume: bool,
    /// Total optimiser steps of the run (the schedule spans them unless the config fixes it).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Stop after this step, with a checkpoint, leaving the schedule as if the run went on.
    #[arg(long)]
    pub stop_at: Option<u64>,
    #[command(flatten)]
    pub shape: StepShapeArgs,
    #[arg(long)]
    pub accumulate: Option<usize>,
    #[arg(long)]
    pub lr: Option<f64>,
    #[arg(long)]
    pub warmup_steps: Option<u64>,
    #[arg(long)]
    pub decay_start: Option<u64>,
    #[arg(long)]
    pub gamma: Option<f64>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Data loader threads.
    #[arg(long)]
    pub workers: Option<usize>,
    /// Streams a WebDataset source's shards are dealt to each epoch (default 4; 0 = read every
    /// sample by seeking, in a full shuffle). Part of the data order, unlike --workers.
    #[arg(long)]
    pub streams: Option<usize>,
    /// Samples in each stream's shuffle buffer (default 250), held as their files' bytes
    /// (about 2.3 MB for a 960×540 sample of ours).
    #[arg(long)]
    pub shuffle_buffer: Option<usize>,
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Checkpoints kept.
    #[arg(long)]
    pub keep: Option<usize>,
    /// Start from these weights (.pt / .mpk) instead of a random init.
    #[arg(long)]
    pub init_weights: Option<PathBuf>,
    /// Hide the progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Devices of this process, one model replica each: `cuda:0,cuda:1`, `vulkan:0,vulkan:1`,
    /// `cpu,cpu` (CPU replicas share the cores), or a count (`4` = devices 0..4 of --device).
    /// --batch-size is the global batch, split evenly over every replica of every process.
    /// Under Slurm or torchrun, each process is one node's worth of devices (see --nnodes).
    #[arg(long, value_name = "LIST")]
    pub devices: Option<String>,
    #[command(flatten)]
    pub process: ProcessFlags,
    /// Seconds an all-reduce of a data-parallel run may wait for the other replicas before the
    /// run stops as stuck (a process that ends is noticed at once). Covers replica 0's
    /// checkpoint writes.
    #[arg(long, default_value_t = 300, value_name = "SECS")]
    pub collective_timeout: u64,
    /// In a data-parallel run, check that the replicas hold the same weights every N steps
    /// (always checked at checkpoints).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub check_replicas_every: u64,
}

/// Where data is: a directory, its layout, and for a WebDataset export the splits to read.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct DataLocation {
    pub path: PathBuf,
    pub format: Option<stereo_io::DatasetFormat>,
    pub splits: Option<Vec<String>>,
}

/// `DIR`, `DIR:FORMAT` or `DIR:webdataset:SPLIT[,SPLIT]` (`flag` names the option in errors).
/// An existing directory is taken as it is; a `:` followed by a path is part of the directory.
pub(super) fn parse_location(spec: &str, flag: &str) -> Result<DataLocation> {
    let literal = |p: &str| -> Result<DataLocation> {
        Ok(DataLocation {
            path: std::path::absolute(p).with_context(|| format!("{flag} {spec}"))?,
            format: None,
            splits: None,
        })
    };
    if Path::new(spec).is_dir() {
        return literal(spec);
    }
    let Some((head, last)) = spec.rsplit_once(':').filter(|(_, l)| !l.contains('/')) else {
        return literal(spec);
    };
    let (path, format, splits) = match head.rsplit_once(':') {
        Some((dir, f)) if f == stereo_io::DatasetFormat::WebDataset.name() => {
            let splits: Vec<String> = last.split(',').map(|s| s.trim().to_string()).collect();
            if splits.iter().any(String::is_empty) {
                bail!("{flag} {spec}: an empty split name (DIR:webdataset:SPLIT[,SPLIT])");
            }
            (dir, stereo_io::DatasetFormat::WebDataset, Some(splits))
        }
        _ => {
            let format = last.parse().map_err(|e: String| {
                anyhow::anyhow!(
                    "{flag} {spec}: {e} (splits go after the layout: DIR:webdataset:SPLIT)"
                )
            })?;
            (head, format, None)
        }
    };
    Ok(DataLocation {
        format: Some(format),
        splits,
        ..literal(path)?
    })
}

/// `DIR`, `DIR:FORMAT`, `DIR:webdataset:SPLIT[,SPLIT]` or any of them with `@WEIGHT`.
pub(super) fn parse_data(spec: &str) -> Result<DatasetEntry> {
    let (rest, weight) = match spec.rsplit_once('@') {
        Some((r, w)) if !Path::new(spec).is_dir() => (
            r,
            w.parse::<f64>()
                .with_context(|| format!("--data {spec}: weight `{w}` is not a number"))?,
        ),
        _ => (spec, 1.0),
    };
    let at = parse_location(rest, "--data")?;
    Ok(DatasetEntry {
        path: at.path,
        format: at.format,
        weight,
        splits: at.splits,
    })
}

/// The shape of a training step, as flags over a config's (`train` and `warmup`).
#[derive(Debug, Default, clap::Args)]
pub struct StepShapeArgs {
    /// Samples per forward/backward pass (before the split over replicas).
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// Training crop, HxW (multiples of 16).
    #[arg(long, value_name = "HxW")]
    pub crop: Option<String>,
    /// Refinement iterations of a training step.
    #[arg(long)]
    pub iters: Option<usize>,
}

impl StepShapeArgs {
    /// Sets the config's batch, crop and iterations where a flag names them.
    pub fn apply(&self, cfg: &mut TrainConfig) -> Result<()> {
        if let Some(b) = self.batch_size {
            cfg.batch_size = b;
        }
        if let Some(c) = &self.crop {
            cfg.augment.crop = parse_crop(c)?;
        }
        if let Some(i) = self.iters {
            cfg.iters = i;
        }
        Ok(())
    }
}

pub fn parse_crop(s: &str) -> Result<[usize; 2]> {
    let (h, w) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--crop {s}: expected HxW, e.g. 384x512"))?;
    Ok([
        h.trim().parse().with_context(|| format!("--crop {s}"))?,
        w.trim().parse().with_context(|| format!("--crop {s}"))?,
    ])
}

/// The config a run uses: file (or the run's stored one on resume) then flags.
pub fn build_config(a: &TrainArgs) -> Result<TrainConfig> {
    let mut cfg = match &a.config {
        Some(path) => TrainConfig::from_file(path)?,
        None if a.resume => TrainConfig::stored(&a.out)?.unwrap_or_default(),
        None => TrainConfig::default(),
    };
    if !a.data.is_empty() {
        cfg.datasets = a
            .data
            .iter()
            .map(|s| parse_data(s))
            .collect::<Result<_>>()?;
    }
    apply_validation_flags(&mut cfg, a)?;
    apply_recipe_flags(&mut cfg, a)?;
    if a.steps.is_some()
        && a.config.is_none()
        && a.decay_start.is_none()
        && cfg.schedule.decay_start > cfg.steps
    {
        scale_schedule(&mut cfg, a.warmup_steps);
    }
    cfg.validate()?;
    Ok(cfg)
}

/// `--val`, `--val-every`, `--val-limit`.
fn apply_validation_flags(cfg: &mut TrainConfig, a: &TrainArgs) -> Result<()> {
    if let Some(v) = &a.val {
        let at = parse_location(v, "--val")?;
        let mut val = match cfg.validation.take() {
            Some(old) => ValidationSettings {
                path: at.path,
                ..old
            },
            None => ValidationSettings::new(at.path),
        };
        // What the flag names replaces the config's; what it leaves out is kept.
        if at.format.is_some() {
            val.format = at.format;
        }
        if at.splits.is_some() {
            val.splits = at.splits;
        }
        cfg.validation = Some(val);
    }
    if let Some(val) = cfg.validation.as_mut() {
        if let Some(e) = a.val_every {
            val.every = e;
        }
        if let Some(l) = a.val_limit {
            val.limit = l;
        }
    } else if a.val_every.is_some() || a.val_limit.is_some() {
        bail!(
            "--val-every / --val-limit need validation data (--val DIR or [validation] in the config)"
        );
    }
    Ok(())
}

/// The flags that override single config values.
fn apply_recipe_flags(cfg: &mut TrainConfig, a: &TrainArgs) -> Result<()> {
    macro_rules! set {
        ($field:expr, $flag:expr) => {
            if let Some(v) = $flag {
                $field = v;
            }
        };
    }
    set!(cfg.steps, a.steps);
    a.shape.apply(cfg)?;
    set!(cfg.accumulate, a.accumulate);
    set!(cfg.gamma, a.gamma);
    set!(cfg.seed, a.seed);
    set!(cfg.schedule.lr, a.lr);
    set!(cfg.schedule.warmup_steps, a.warmup_steps);
    set!(cfg.schedule.decay_start, a.decay_start);
    set!(cfg.loader.workers, a.workers);
    set!(cfg.webdataset.streams, a.streams);
    set!(cfg.webdataset.shuffle_buffer, a.shuffle_buffer);
    set!(cfg.checkpoint.every, a.checkpoint_every);
    set!(cfg.checkpoint.keep, a.keep);
    if let Some(w) = &a.init_weights {
        cfg.init_weights = Some(std::path::absolute(w)?);
    }
    Ok(())
}

/// A shortened run keeps the paper's phases in proportion rather than failing validation.
fn scale_schedule(cfg: &mut TrainConfig, warmup_flag: Option<u64>) {
    let s = cfg.steps as f64;
    cfg.schedule.warmup_steps = warmup_flag.unwrap_or((s * 0.02).round() as u64);
    cfg.schedule.decay_start = (s * 0.6).round() as u64;
    tracing::info!(
        "schedule scaled to {} steps: warm-up {}, decay from {} (the paper's 6k/180k of 300k)",
        cfg.steps,
        cfg.schedule.warmup_steps,
        cfg.schedule.decay_start
    );
}

/// Runs `crestereo train`: on `device`, or with `devices` (from --devices) as a data-parallel
/// run, in this process or as one rank of several (flags, torchrun's or Slurm's environment).
pub fn run<B: AutodiffBackend>(
    a: &TrainArgs,
    device: &B::Device,
    devices: Option<&DeviceList>,
) -> Result<()>
where
    B::Device: FromDeviceIndex,
{
    let cfg = build_config(a)?;
    let group = resolve(&a.process, &process_env)?;
    let leads = group.as_ref().is_none_or(|g| g.rank == 0);
    let eff = cfg.batch_size * cfg.accumulate;
    if leads {
        tracing::info!(
            "training {} steps, batch {} × {} = {eff}, crop {}x{}, iters {}, lr {:e}, run {}",
            cfg.steps,
            cfg.batch_size,
            cfg.accumulate,
            cfg.augment.crop[0],
            cfg.augment.crop[1],
            cfg.iters,
            cfg.schedule.lr,
            a.out.display()
        );
    }
    crate::interrupt::install().context("cannot install the SIGTERM/SIGINT handlers")?;
    let opts = TrainOptions {
        resume: a.resume,
        progress: !a.no_progress,
        stop_at: a.stop_at,
        check_replicas_every: a.check_replicas_every,
    };
    let out = if devices.is_some() || group.is_some() {
        let list: Vec<B::Device> = match devices {
            Some(l) => l
                .devices
                .iter()
                .map(|&d| B::Device::from_index(d))
                .collect::<Result<_>>()?,
            None => vec![device.clone()],
        };
        let options = ParallelOptions {
            group,
            timeouts: default_timeouts(a.collective_timeout),
        };
        train_parallel::<B>(&cfg, &a.out, &opts, &list, &options)?
    } else {
        crate::oom::on_device(
            || train::<B>(&cfg, &a.out, &opts, device),
            "training",
            crate::oom::TRAINING_ADVICE,
        )?
    };
    if leads {
        report(&cfg, &out);
    }
    if out.interrupted {
        return Err(Interrupted {
            step: out.step,
            checkpoint: out.checkpoint,
        }
        .into());
    }
    Ok(())
}

fn report(cfg: &TrainConfig, out: &TrainOutcome) {
    let steps = out.session_steps.max(1) as f64;
    let sync = if out.sync_s > 0.0 {
        format!(
            ", {:.3} s per step of which all-reduce {:.3} s ({:.1}%)",
            out.session_s / steps,
            out.sync_s / steps,
            100.0 * out.sync_s / out.session_s.max(1e-9)
        )
    } else {
        String::new()
    };
    eprintln!(
        "step {} of {}: loss {} → {}, {:.2} samples/s{sync}, {} skipped steps{}",
        out.step,
        cfg.steps,
        out.first_loss.map_or("-".into(), |l| format!("{l:.4}")),
        out.last_loss.map_or("-".into(), |l| format!("{l:.4}")),
        out.samples_per_s,
        out.skipped_steps,
        out.checkpoint
            .as_ref()
            .map_or(String::new(), |c| format!(", checkpoint {}", c.display()))
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_specs() {
        let d = parse_data("/x/ours@98").unwrap();
        assert_eq!(
            (d.path, d.format, d.weight),
            (PathBuf::from("/x/ours"), None, 98.0)
        );
        let d = parse_data("/x/mb:middlebury@2").unwrap();
        assert_eq!(
            (d.format, d.weight),
            (Some(stereo_io::DatasetFormat::Middlebury), 2.0)
        );
        assert!(
            parse_data("/x@abc")
                .unwrap_err()
                .to_string()
                .contains("weight")
        );
        // A WebDataset export's splits follow its layout; an existing directory is as it is.
        let d = parse_data("/x/wds:webdataset:val@3").unwrap();
        assert_eq!(
            (d.path, d.format, d.splits, d.weight),
            (
                PathBuf::from("/x/wds"),
                Some(stereo_io::DatasetFormat::WebDataset),
                Some(vec!["val".to_string()]),
                3.0
            )
        );
        let d = parse_data("/x/wds:webdataset:train, extra").unwrap();
        assert_eq!(d.splits, Some(vec!["train".into(), "extra".into()]));
        assert_eq!(parse_data("/x/wds:webdataset").unwrap().splits, None);
        for bad in ["/x/wds:webdataset:", "/x/wds:webdataset:a,,b"] {
            let e = parse_data(bad).unwrap_err().to_string();
            assert!(e.contains("empty split"), "{e}");
        }
        let e = parse_data("/x/mb:middlebury:val").unwrap_err().to_string();
        assert!(e.contains("DIR:webdataset:SPLIT"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let odd = dir.path().join("a:b@2");
        std::fs::create_dir(&odd).unwrap();
        let d = parse_data(odd.to_str().unwrap()).unwrap();
        assert_eq!((d.path, d.format, d.weight), (odd.clone(), None, 1.0));
        let at = parse_location(odd.to_str().unwrap(), "--val").unwrap();
        assert_eq!((at.path, at.format), (odd, None));
        assert_eq!(parse_crop("128x256").unwrap(), [128, 256]);
        assert!(parse_crop("128").is_err());
    }
}
