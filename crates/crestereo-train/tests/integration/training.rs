//! The training loop on Flex with real data files: the loader's determinism, exact resume,
//! checkpoint pruning, the non-finite guard, and that the network learns (overfitting).
//!
//! Sizes are small (64×128 crops, few iterations) so the suite stays within CI's budget; the
//! code paths are the ones a full-size run takes.

use std::path::Path;
use std::sync::Arc;

use crate::loss_columns;

use crestereo::weights::{load_record, named_parameters};
use crestereo::{CREStereoConfig, CpuAutodiffBackend, CpuBackend};
use crestereo_train::augment::AugmentConfig;
use crestereo_train::checkpoint::list_checkpoints;
use crestereo_train::config::{DatasetEntry, TrainConfig};
use crestereo_train::data::{Loader, MixedSource, Planner};
use crestereo_train::synthetic::write_crestereo_dataset;
use crestereo_train::train::{TrainOptions, TrainOutcome, train};

fn dataset(dir: &Path, count: usize) {
    write_crestereo_dataset(dir, count, 128, 64, 11).unwrap();
}

/// A tiny run: 32×64 crops of 64×128 pairs with the paper's augmentation, batch 1 × 2
/// accumulated, 2 iterations.
fn tiny_config(data: &Path, steps: u64) -> TrainConfig {
    let mut cfg = TrainConfig {
        datasets: vec![DatasetEntry::new(data.to_path_buf())],
        steps,
        batch_size: 1,
        accumulate: 2,
        iters: 2,
        ..TrainConfig::default()
    };
    cfg.augment.crop = [32, 64];
    cfg.schedule.warmup_steps = 4;
    cfg.schedule.decay_start = steps / 2;
    cfg.loader.workers = 2;
    cfg.loader.prefetch = 4;
    cfg.checkpoint.every = 5;
    cfg.checkpoint.keep = 2;
    cfg
}

/// Trains `cfg` on Flex with default options into a new temporary run folder.
fn train_in_new_folder(cfg: &TrainConfig) -> (tempfile::TempDir, TrainOutcome) {
    let run = tempfile::tempdir().unwrap();
    let out = train::<CpuAutodiffBackend>(
        cfg,
        run.path(),
        &TrainOptions::default(),
        &Default::default(),
    )
    .unwrap();
    (run, out)
}

fn weights(checkpoint: &Path) -> Vec<(String, Vec<f32>)> {
    let device = Default::default();
    let model = load_record(
        CREStereoConfig::new().init::<CpuBackend>(&device),
        checkpoint.join("model.mpk"),
        &device,
    )
    .unwrap();
    named_parameters(&model)
        .into_iter()
        .map(|p| (p.name, p.data))
        .collect()
}

#[test]
fn loader_order_does_not_depend_on_threads_and_resumes_mid_stream() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path(), 6);
    let cfg = tiny_config(dir.path(), 1);
    let source = Arc::new(MixedSource::open(&cfg.datasets).unwrap());
    let planner = || Planner::new(5, &source.weights, &[source.datasets[0].len()]);
    let take = |start: u64, workers: usize, n: usize| {
        let mut l = Loader::start(
            source.clone(),
            planner(),
            start,
            cfg.augment.clone(),
            workers,
            3,
            2,
        );
        (0..n).map(|_| l.next_sample().unwrap()).collect::<Vec<_>>()
    };
    let one = take(0, 1, 14);
    let many = take(0, 4, 14);
    let resumed = take(9, 3, 5);
    for (a, b) in one.iter().zip(&many) {
        assert_eq!((a.plan, a.index), (b.plan, b.index));
        assert_eq!(
            a.sample, b.sample,
            "sample {} differs with 4 workers",
            a.plan.ordinal
        );
    }
    for (a, b) in one[9..].iter().zip(&resumed) {
        assert_eq!(
            a.sample, b.sample,
            "resumed stream differs at {}",
            a.plan.ordinal
        );
    }
    // Every sample is augmented differently (different seeds), and an epoch covers all 6.
    assert_ne!(one[0].sample, one[6].sample);
    let mut first: Vec<usize> = one[..6].iter().map(|s| s.index).collect();
    first.sort();
    assert_eq!(first, (0..6).collect::<Vec<_>>());
    assert_eq!(one[0].sample.left.len(), 3 * 32 * 64);
}

#[test]
fn an_unreadable_sample_is_replaced_and_listed() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path(), 4);
    std::fs::write(dir.path().join("pair002_left.jpg"), b"not a jpeg").unwrap();
    let cfg = tiny_config(dir.path(), 1);
    let source = Arc::new(MixedSource::open(&cfg.datasets).unwrap());
    let mut l = Loader::start(
        source.clone(),
        Planner::new(1, &source.weights, &[4]),
        0,
        AugmentConfig::none([64, 128]),
        2,
        4,
        3,
    );
    let got: Vec<_> = (0..8).map(|_| l.next_sample().unwrap()).collect();
    assert!(
        got.iter().all(|s| s.index != 2),
        "the corrupt sample was used"
    );
    assert!(
        got.iter().any(|s| s.plan.index == 2),
        "the corrupt sample was never drawn"
    );
    let skipped = l.skipped.lock().unwrap().clone();
    assert!(
        !skipped.is_empty() && skipped[0].id.contains("pair002"),
        "{skipped:?}"
    );
    // A dataset where nothing can be read stops with a clear error instead of spinning.
    for f in std::fs::read_dir(dir.path()).unwrap() {
        let p = f.unwrap().path();
        if p.to_string_lossy().ends_with("_left.jpg") {
            std::fs::write(&p, b"broken").unwrap();
        }
    }
    let mut l = Loader::start(
        source.clone(),
        Planner::new(1, &source.weights, &[4]),
        0,
        AugmentConfig::none([64, 128]),
        1,
        2,
        3,
    );
    let e = l.next_sample().unwrap_err().to_string();
    assert!(e.contains("4 consecutive unreadable samples"), "{e}");
}

#[test]
fn resumed_run_matches_a_straight_run_exactly() {
    let data = tempfile::tempdir().unwrap();
    dataset(data.path(), 5);
    let cfg = tiny_config(data.path(), 20);
    let device = Default::default();
    let straight = tempfile::tempdir().unwrap();
    let quiet = TrainOptions {
        progress: false,
        ..TrainOptions::default()
    };
    let a = train::<CpuAutodiffBackend>(&cfg, straight.path(), &quiet, &device).unwrap();
    assert_eq!(a.step, 20);
    let split = tempfile::tempdir().unwrap();
    let b1 = train::<CpuAutodiffBackend>(
        &cfg,
        split.path(),
        &TrainOptions {
            stop_at: Some(10),
            ..quiet.clone()
        },
        &device,
    )
    .unwrap();
    assert_eq!(b1.step, 10);
    // Without --resume a run with checkpoints is refused rather than overwritten.
    let e = train::<CpuAutodiffBackend>(&cfg, split.path(), &quiet, &device)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--resume"), "{e}");
    let b2 = train::<CpuAutodiffBackend>(
        &cfg,
        split.path(),
        &TrainOptions {
            resume: true,
            ..quiet.clone()
        },
        &device,
    )
    .unwrap();
    assert_eq!((b2.resumed_from, b2.step), (Some(10), 20));

    let wa = weights(&a.checkpoint.unwrap());
    let wb = weights(&b2.checkpoint.unwrap());
    assert_eq!(wa.len(), wb.len());
    let mut moved = 0.0f64;
    for ((name, x), (_, y)) in wa.iter().zip(&wb) {
        assert!(
            x == y,
            "{name} differs between the straight and the resumed run"
        );
        moved += x.iter().map(|v| f64::from(v.abs())).sum::<f64>();
    }
    assert!(moved.is_finite() && moved > 0.0);
    // The logs continue the same curve: identical loss columns.
    assert_eq!(loss_columns(straight.path()), loss_columns(split.path()));
    assert_eq!(loss_columns(straight.path()).len(), 21);
    // Checkpoints every 5 steps, the newest 2 kept, no temp directories left.
    let kept: Vec<u64> = list_checkpoints(straight.path())
        .unwrap()
        .into_iter()
        .map(|c| c.step)
        .collect();
    assert_eq!(kept, [15, 20]);
    let names: Vec<String> = std::fs::read_dir(straight.path().join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    // TensorBoard events were written for every step.
    let tb = std::fs::read_dir(straight.path().join("tensorboard"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let scalars = crestereo_train::tensorboard::read_scalars(&tb).unwrap();
    assert_eq!(scalars.iter().filter(|s| s.tag == "train/loss").count(), 20);
}

/// Two runs of the same config give the same bits while other work competes for the CPU pool
/// the network's kernels run on (partial sums are combined in a fixed order, never in the order
/// work-stealing happened to produce).
///
/// It runs beside the other tests of this file, which build and train networks of their own in
/// this process at the same time: the initial weights must not depend on them either. Each run
/// goes to a pool shared only with the busy work, not to the global pool the other tests' kernels
/// use (see [`crestereo::ops::threads::on_pool`] for the deadlock that would risk).
#[test]
fn a_run_repeats_bit_for_bit_while_the_pool_is_busy() {
    use rayon::prelude::*;
    let data = tempfile::tempdir().unwrap();
    dataset(data.path(), 4);
    let cfg = tiny_config(data.path(), 8);
    let device = Default::default();
    let quiet = TrainOptions {
        progress: false,
        stop_at: Some(3),
        ..TrainOptions::default()
    };
    let pool = || {
        rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
    };
    let calm = tempfile::tempdir().unwrap();
    let a =
        pool().install(|| train::<CpuAutodiffBackend>(&cfg, calm.path(), &quiet, &device).unwrap());
    let busy = tempfile::tempdir().unwrap();
    let busy_pool = pool();
    let stop = std::sync::atomic::AtomicBool::new(false);
    let b = std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let v: f64 = busy_pool.install(|| {
                        (0..50_000u32)
                            .into_par_iter()
                            .map(|i| f64::from(i).sqrt())
                            .sum()
                    });
                    std::hint::black_box(v);
                }
            });
        }
        let b = busy_pool
            .install(|| train::<CpuAutodiffBackend>(&cfg, busy.path(), &quiet, &device).unwrap());
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        b
    });
    assert_eq!(a.first_loss, b.first_loss);
    assert_eq!(a.last_loss, b.last_loss);
    for ((name, x), (_, y)) in weights(&a.checkpoint.unwrap())
        .iter()
        .zip(&weights(&b.checkpoint.unwrap()))
    {
        assert!(
            x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()),
            "{name} differs between a calm and a busy run"
        );
    }
}

#[test]
fn non_finite_losses_skip_the_step_and_are_logged() {
    let data = tempfile::tempdir().unwrap();
    dataset(data.path(), 2);
    let mut cfg = tiny_config(data.path(), 4);
    cfg.accumulate = 1;
    // An absurd learning rate: the first update throws the weights to ±3e38 (instance norm
    // would absorb a mere 1e30), the next forward overflows to inf/NaN, and every later step
    // must be skipped rather than written into the weights.
    cfg.schedule.lr = 3e38;
    cfg.schedule.warmup_steps = 0;
    cfg.schedule.floor_fraction = 1.0;
    let (run, out) = train_in_new_folder(&cfg);
    assert_eq!(out.step, 4);
    assert_eq!(out.skipped_steps, 3, "{out:?}");
    let csv = std::fs::read_to_string(run.path().join("train_log.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert!(
        rows[0]
            .split(',')
            .nth(3)
            .unwrap()
            .parse::<f64>()
            .unwrap()
            .is_finite()
    );
    // Rows 2..4: loss NaN, skipped_steps = step − 1.
    for r in &rows[1..] {
        let cells: Vec<&str> = r.split(',').collect();
        let step: u64 = cells[0].parse().unwrap();
        assert_eq!(
            (cells[3], cells[7]),
            ("NaN", (step - 1).to_string().as_str()),
            "{csv}"
        );
    }
    // The saved weights are the finite ones from before the blow-up.
    let w = weights(&out.checkpoint.unwrap());
    assert!(w.iter().all(|(_, v)| v.iter().all(|x| x.is_finite())));
}

#[test]
fn overfits_a_single_batch() {
    let data = tempfile::tempdir().unwrap();
    dataset(data.path(), 1);
    // 200 steps: at 150 the loss ended at 9.3-10.7% of the start across runs (float sums on a
    // shared pool vary in their last bits with scheduling), too close to the bar to test it.
    let mut cfg = tiny_config(data.path(), 200);
    cfg.batch_size = 1;
    cfg.accumulate = 1;
    // One fixed batch: no augmentation, the full 64×128 image every step.
    cfg.augment = AugmentConfig::none([64, 128]);
    cfg.schedule.lr = 1e-3;
    cfg.schedule.warmup_steps = 0;
    cfg.schedule.decay_start = 200;
    cfg.checkpoint.every = 1000;
    let (run, out) = train_in_new_folder(&cfg);
    let csv = std::fs::read_to_string(run.path().join("train_log.csv")).unwrap();
    let losses: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(3).unwrap().parse().unwrap())
        .collect();
    let start = losses[0];
    let end = losses[losses.len() - 5..].iter().sum::<f64>() / 5.0;
    eprintln!(
        "overfit: loss {start:.3} → {end:.3} ({:.1}%) over {} steps, {:.2} samples/s",
        100.0 * end / start,
        losses.len(),
        out.samples_per_s
    );
    assert_eq!(out.skipped_steps, 0);
    assert!(
        end < 0.1 * start,
        "loss {start} → {end}: not below 10% of the start"
    );
}

#[test]
fn accumulating_two_halves_equals_one_full_batch() {
    let data = tempfile::tempdir().unwrap();
    dataset(data.path(), 2);
    let run_with = |batch: usize, accumulate: usize| {
        let mut cfg = tiny_config(data.path(), 1);
        cfg.batch_size = batch;
        cfg.accumulate = accumulate;
        cfg.augment = AugmentConfig::none([64, 128]);
        cfg.schedule.warmup_steps = 0;
        cfg.schedule.decay_start = 1;
        let (_run, out) = train_in_new_folder(&cfg);
        (out.first_loss.unwrap(), weights(&out.checkpoint.unwrap()))
    };
    let (loss_full, full) = run_with(2, 1);
    let (loss_acc, acc) = run_with(1, 2);
    // The same two samples either way: the mean loss and the Adam step must agree.
    assert!(
        (loss_full - loss_acc).abs() <= 1e-5 * loss_full,
        "{loss_full} vs {loss_acc}"
    );
    // Adam's first step moves each weight by lr·g/(|g|+eps) (lr = 4e-4). Equal gradients up to
    // float summation order give equal steps, except where a gradient is within rounding of 0;
    // a missing or doubled step would move every weight.
    let (mut differ, mut total) = (0usize, 0usize);
    for ((name, a), (_, b)) in full.iter().zip(&acc) {
        assert_eq!(a.len(), b.len(), "{name}");
        for (x, y) in a.iter().zip(b) {
            total += 1;
            differ += usize::from((x - y).abs() > 1e-6);
        }
    }
    assert!(
        differ * 1000 <= total,
        "{differ} of {total} weights differ by more than 0.25% of the step"
    );
}

/// A real dataset that counts the samples decoded from it.
struct Counting {
    inner: Box<dyn stereo_io::StereoDataset>,
    decoded: Arc<std::sync::atomic::AtomicUsize>,
}

impl stereo_io::StereoDataset for Counting {
    fn format(&self) -> stereo_io::DatasetFormat {
        self.inner.format()
    }
    fn root(&self) -> &Path {
        self.inner.root()
    }
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn id(&self, index: usize) -> Option<&str> {
        self.inner.id(index)
    }
    fn sample(&self, index: usize) -> stereo_io::Result<stereo_io::StereoSample> {
        self.decoded
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        self.inner.sample(index)
    }
}

#[test]
fn loader_stays_within_its_prefetch_bound() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path(), 4);
    let decoded = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let inner = stereo_io::open_dataset(dir.path(), None).unwrap();
    let source = Arc::new(MixedSource {
        datasets: vec![Box::new(Counting {
            inner,
            decoded: decoded.clone(),
        })],
        names: vec!["counted".into()],
        weights: vec![1.0],
        webdatasets: vec![None],
    });
    let mut l = Loader::start(
        source,
        Planner::new(0, &[1.0], &[4]),
        0,
        AugmentConfig::none([32, 64]),
        3,
        5,
        0,
    );
    let settle = |n: usize| {
        for _ in 0..200 {
            if decoded.load(std::sync::atomic::Ordering::SeqCst) >= n {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        std::thread::sleep(std::time::Duration::from_millis(300));
        decoded.load(std::sync::atomic::Ordering::SeqCst)
    };
    // Nothing consumed: exactly `prefetch` samples are decoded ahead, then the workers wait.
    assert_eq!(settle(5), 5);
    for _ in 0..3 {
        l.next_sample().unwrap();
    }
    assert_eq!(settle(8), 8);
    drop(l); // joins every thread
}
