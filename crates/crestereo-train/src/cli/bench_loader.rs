//! `crestereo bench --what loader`: how many training samples per second the data stream
//! decodes and augments, on 1, 2 and all cores — can it keep a GPU fed?
//!
//! The stream timed is the trainer's own: [`MixedSource`], [`Planner`] and [`Loader`] (hence
//! `load_sample` and `augment_random`) started as `crestereo train` starts them, with the
//! default training config's seed, retries and augmentation (the paper's full CREStereo
//! augmentation at the 384×512 crop). Only the worker count varies, and the prefetch queue is
//! raised to twice the workers where the default (16) would leave workers idle.
//!
//! Each thread count gets a fresh loader; the first sample of every worker is a warm-up
//! (thread start, first file reads), then `--samples` samples are timed as the training step
//! receives them: in order, one by one. The collate of a batch of 8 into tensors on the CPU
//! backend is timed last, from the samples just loaded.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use crestereo::CpuBackend;

use super::train::parse_data;
use crate::augment::TrainSample;
use crate::config::TrainConfig;
use crate::data::{MixedSource, collate};

/// Samples per optimiser step the printed step rate assumes.
const STEP_BATCH: usize = 8;

/// Options of `bench --what loader`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoaderBenchArgs {
    /// `--what loader`: the dataset to read, DIR or DIR:FORMAT (any layout the trainer reads;
    /// the format is detected when absent).
    #[arg(long, value_name = "DIR[:FORMAT]")]
    pub data: Option<String>,
    /// `--what loader`: loader thread counts to time (default 1, 2 and all cores).
    #[arg(long, value_delimiter = ',', value_name = "N,N,...")]
    pub loader_threads: Option<Vec<usize>>,
    /// `--what loader`: samples timed per thread count, after one warm-up sample per thread.
    #[arg(long, default_value_t = 64)]
    pub samples: usize,
}

/// The thread counts to time, ascending and without repeats.
fn thread_counts(chosen: Option<&[usize]>) -> Result<Vec<usize>> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut counts = chosen.map_or_else(|| vec![1, 2, cores], <[usize]>::to_vec);
    if counts.is_empty() || counts.contains(&0) {
        bail!("--loader-threads takes thread counts of at least 1, e.g. 1,2,4");
    }
    counts.sort_unstable();
    counts.dedup();
    Ok(counts)
}

/// What one thread count achieved.
struct Timed {
    secs: f64,
    prefetch: usize,
    skipped: usize,
    /// The first samples of the timed run, kept for the collate timing.
    kept: Vec<TrainSample>,
}

/// Runs the training stream on `workers` threads: one warm-up sample per worker, then
/// `samples` timed ones.
fn time_loader(
    cfg: &TrainConfig,
    source: &Arc<MixedSource>,
    workers: usize,
    samples: usize,
) -> Result<Timed> {
    // The training run's own loader, on `workers` threads with a queue deep enough for them.
    let mut cfg = cfg.clone();
    cfg.loader.workers = workers;
    cfg.loader.prefetch = cfg.loader.prefetch.max(2 * workers);
    let prefetch = cfg.loader.prefetch;
    let mut loader = crate::train::start_loader(&cfg, source.clone(), 0);
    loader.next_batch(workers)?;
    let mut kept = Vec::with_capacity(STEP_BATCH);
    let t0 = Instant::now();
    for _ in 0..samples {
        let s = loader.next_sample()?;
        if kept.len() < STEP_BATCH {
            kept.push(s.sample);
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let skipped = loader.skipped.lock().unwrap().len();
    Ok(Timed {
        secs,
        prefetch,
        skipped,
        kept,
    })
}

/// Median time (seconds) of collating `samples` into CPU tensors, after one untimed run.
fn time_collate(samples: &[TrainSample], repeats: usize) -> Result<f64> {
    let device = Default::default();
    let mut times = Vec::with_capacity(repeats);
    for rep in 0..=repeats {
        let t0 = Instant::now();
        let batch = collate::<CpuBackend>(samples, &device)?;
        let secs = t0.elapsed().as_secs_f64();
        drop(batch);
        if rep > 0 {
            times.push(secs);
        }
    }
    times.sort_by(f64::total_cmp);
    Ok(times[times.len() / 2])
}

/// `bench --what loader`: one line per thread count, then the collate.
pub fn run(args: &LoaderBenchArgs) -> Result<()> {
    let spec = args
        .data
        .as_deref()
        .context("--what loader needs --data DIR[:FORMAT]")?;
    if args.samples == 0 {
        bail!("--samples must be at least 1");
    }
    let counts = thread_counts(args.loader_threads.as_deref())?;
    let cfg = TrainConfig {
        datasets: vec![parse_data(spec)?],
        ..TrainConfig::default()
    };
    let source = Arc::new(MixedSource::open(&cfg.datasets)?);
    let [h, w] = cfg.augment.crop;
    println!(
        "loader: {}, crop {h}x{w}, full CREStereo augmentation (training defaults), {} samples per thread count after one warm-up sample per thread, {} cores",
        source.names[0],
        args.samples,
        std::thread::available_parallelism().map_or(1, |n| n.get()),
    );
    let mut kept = Vec::new();
    for &threads in &counts {
        let t = time_loader(&cfg, &source, threads, args.samples)?;
        let rate = args.samples as f64 / t.secs;
        let ms = 1000.0 * t.secs / args.samples as f64;
        let skipped = if t.skipped > 0 {
            format!(", {} unreadable samples replaced", t.skipped)
        } else {
            String::new()
        };
        println!(
            "threads {threads}: {rate:.2} samples/s, {ms:.1} ms/sample ({:.1} ms per sample per thread), batch-{STEP_BATCH} steps {:.3}/s, prefetch {}{skipped}",
            ms * threads as f64,
            rate / STEP_BATCH as f64,
            t.prefetch,
        );
        kept = t.kept;
    }
    // A batch of 8 from the last run's samples (repeated when fewer were timed).
    let batch: Vec<TrainSample> = kept.iter().cycle().take(STEP_BATCH).cloned().collect();
    let secs = time_collate(&batch, 5)?;
    println!(
        "collate batch {STEP_BATCH} ({h}x{w}) to CPU tensors: {:.2} ms (median of 5), {:.0} samples/s",
        1000.0 * secs,
        STEP_BATCH as f64 / secs
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_spec_and_thread_counts() {
        let d = parse_data("/data/mb:middlebury").unwrap();
        assert_eq!(d.path, std::path::Path::new("/data/mb"));
        assert_eq!(d.format, Some(stereo_io::DatasetFormat::Middlebury));
        assert_eq!(parse_data("/data/ours").unwrap().format, None);
        assert_eq!(thread_counts(Some(&[4, 1, 4, 2])).unwrap(), [1, 2, 4]);
        assert!(thread_counts(Some(&[0, 2])).is_err());
        let all = thread_counts(None).unwrap();
        assert!(all.starts_with(&[1]) && all.windows(2).all(|p| p[0] < p[1]));
    }
}
