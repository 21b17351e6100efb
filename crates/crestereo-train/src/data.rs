//! The training data stream: datasets mixed by weight, decoded and augmented on worker threads
//! ahead of the training step, delivered in a fixed order.
//!
//! Determinism: sample number `k` of a run is a pure function of `(seed, k)` — which dataset and
//! which index come from a sequential [`Planner`] (replayable, so the data position after a
//! resume is just `k`), and the augmentation draws from the named streams of a seed made of
//! `(seed, k)`. Worker count and timing therefore never change what the model sees.
//!
//! A WebDataset source is streamed: its epochs follow [`stream_order`] (shards dealt to streams,
//! each read front to back through a shuffle buffer), which is computed from the index and the
//! seeds alone, and the loader reads each stream's shards sequentially ([`streamed`]).

pub mod share;
mod source;
pub mod stream_order;
pub mod streamed;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::augment::{AugmentConfig, TrainSample, augment_random};
use share::Share;
pub use source::{
    MixedSource, SplitUse, choose_splits, describe, is_webdataset, open_data, open_webdataset,
};
use stream_order::StreamLayout;
use streamed::StreamReaders;

/// One planned sample: its number in the run, where it comes from, and its augmentation seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SamplePlan {
    pub ordinal: u64,
    pub dataset: usize,
    pub index: usize,
    pub seed: u64,
    /// The dataset's epoch this sample belongs to.
    pub epoch: u64,
    /// The stream it is read from, for a streamed dataset.
    pub stream: Option<u32>,
}

/// Chooses the dataset of every sample by weight, and walks each dataset in its own shuffled
/// epochs (every sample once per epoch) so small datasets are not drawn with replacement.
#[derive(Clone)]
pub struct Planner {
    seed: u64,
    weights: Vec<f64>,
    lens: Vec<usize>,
    /// The streamed datasets' layouts (`None`: a full shuffle per epoch).
    layouts: Vec<Option<StreamLayout>>,
    pick: ChaCha8Rng,
    epochs: Vec<DatasetEpoch>,
    next: u64,
}

/// Where one dataset's walk stands: its current epoch's shuffled order and the next position
/// in it.
#[derive(Clone)]
struct DatasetEpoch {
    number: u64,
    order: Vec<usize>,
    /// The stream of each entry of `order` (empty when the dataset is not streamed).
    streams: Vec<u32>,
    next: usize,
}

/// SplitMix64 finaliser: decorrelates nearby integers into seeds.
pub fn mix_seed(a: u64, b: u64) -> u64 {
    let mut z = a.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ b.wrapping_add(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The seed of epoch `epoch` of dataset `dataset`.
pub fn epoch_seed(seed: u64, dataset: usize, epoch: u64) -> u64 {
    mix_seed(mix_seed(seed, dataset as u64 + 1), epoch)
}

impl Planner {
    /// Every dataset walked in full shuffles (random access).
    pub fn new(seed: u64, weights: &[f64], lens: &[usize]) -> Self {
        Self::with_layouts(seed, weights, lens, vec![None; lens.len()])
    }

    /// Datasets with a layout are walked in [`stream_order`]'s epochs, the others in full
    /// shuffles.
    pub fn with_layouts(
        seed: u64,
        weights: &[f64],
        lens: &[usize],
        layouts: Vec<Option<StreamLayout>>,
    ) -> Self {
        assert_eq!(weights.len(), lens.len());
        assert_eq!(layouts.len(), lens.len());
        for (l, &n) in layouts.iter().zip(lens) {
            assert!(
                l.as_ref().is_none_or(|l| l.len() == n),
                "layout of another length"
            );
        }
        let mut p = Self {
            seed,
            weights: weights.to_vec(),
            lens: lens.to_vec(),
            layouts,
            pick: ChaCha8Rng::seed_from_u64(mix_seed(seed, 0x5EED)),
            epochs: Vec::new(),
            next: 0,
        };
        p.epochs = (0..lens.len()).map(|d| p.epoch(d, 0)).collect();
        p
    }

    /// Epoch `number` of `dataset`: every index once, in an order of its own.
    fn epoch(&self, dataset: usize, number: u64) -> DatasetEpoch {
        let seed = epoch_seed(self.seed, dataset, number);
        if let Some(layout) = &self.layouts[dataset] {
            let o = layout.epoch_order(seed);
            return DatasetEpoch {
                number,
                order: o.indices,
                streams: o.streams,
                next: 0,
            };
        }
        let mut order: Vec<usize> = (0..self.lens[dataset]).collect();
        order.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
        DatasetEpoch {
            number,
            order,
            streams: Vec::new(),
            next: 0,
        }
    }

    /// `dataset`'s current epoch and the indices planned from it so far.
    pub fn epoch_progress(&self, dataset: usize) -> (u64, &[usize]) {
        let e = &self.epochs[dataset];
        (e.number, &e.order[..e.next])
    }

    /// Whether every sample of `dataset`'s epoch `epoch` has been planned.
    pub fn epoch_complete(&self, dataset: usize, epoch: u64) -> bool {
        let e = &self.epochs[dataset];
        e.number > epoch || (e.number == epoch && e.next >= self.lens[dataset])
    }

    /// The ordinal of the sample [`Self::next_plan`] returns next.
    pub fn position(&self) -> u64 {
        self.next
    }

    /// A dataset drawn by weight.
    fn pick_dataset(&mut self) -> usize {
        let u: f64 = self.pick.random();
        let mut acc = 0.0;
        for (d, w) in self.weights.iter().enumerate() {
            acc += w;
            if u < acc {
                return d;
            }
        }
        self.weights.len() - 1
    }

    /// The next index of `dataset`'s walk (with its epoch and stream), starting its next epoch
    /// when this one is used up.
    fn next_index(&mut self, dataset: usize) -> (usize, u64, Option<u32>) {
        if self.epochs[dataset].next == self.lens[dataset] {
            self.epochs[dataset] = self.epoch(dataset, self.epochs[dataset].number + 1);
        }
        let epoch = &mut self.epochs[dataset];
        epoch.next += 1;
        let at = epoch.next - 1;
        (
            epoch.order[at],
            epoch.number,
            epoch.streams.get(at).copied(),
        )
    }

    pub fn next_plan(&mut self) -> SamplePlan {
        let dataset = self.pick_dataset();
        let (index, epoch, stream) = self.next_index(dataset);
        let ordinal = self.next;
        self.next += 1;
        SamplePlan {
            ordinal,
            dataset,
            index,
            seed: mix_seed(self.seed ^ 0xA06_u64, ordinal),
            epoch,
            stream,
        }
    }

    /// Replays the plan up to sample `ordinal` (cheap: no decoding), for resuming.
    pub fn skip_to(&mut self, ordinal: u64) {
        assert!(ordinal >= self.next, "cannot rewind a planner");
        while self.next < ordinal {
            self.next_plan();
        }
    }
}

/// A decoded, augmented sample and where it came from.
#[derive(Debug, Clone)]
pub struct LoadedSample {
    pub plan: SamplePlan,
    /// The sample actually used (differs from `plan.index` when that one was unreadable).
    pub index: usize,
    pub sample: TrainSample,
}

/// Samples that could not be read and were replaced by a neighbour.
#[derive(Debug, Clone)]
pub struct SkippedSample {
    pub dataset: String,
    pub id: String,
    pub error: String,
}

/// Decodes one plan (a streamed dataset's from its stream in `streams`); an unreadable sample
/// is replaced by the next index of the same dataset (deterministically, read by random
/// access), up to `retries` times.
pub fn load_sample(
    source: &MixedSource,
    streams: Option<&StreamReaders>,
    plan: SamplePlan,
    augment: &AugmentConfig,
    retries: usize,
    skipped: &Mutex<Vec<SkippedSample>>,
) -> Result<LoadedSample> {
    let ds = &source.datasets[plan.dataset];
    let mut errors = Vec::new();
    for attempt in 0..=retries {
        let index = (plan.index + attempt) % ds.len();
        let streamed = streams
            .filter(|_| attempt == 0)
            .and_then(|s| s.sample(&plan));
        let read = streamed.unwrap_or_else(|| Ok(ds.sample(index)?));
        match read {
            Ok(sample) => {
                let sample = augment_random(&sample, augment, plan.seed);
                return Ok(LoadedSample {
                    plan,
                    index,
                    sample,
                });
            }
            Err(e) => {
                let id = ds.id(index).unwrap_or("?").to_string();
                tracing::warn!(
                    "skipping unreadable training sample {id} of {}: {e}",
                    source.names[plan.dataset]
                );
                skipped.lock().unwrap().push(SkippedSample {
                    dataset: source.names[plan.dataset].clone(),
                    id,
                    error: e.to_string(),
                });
                errors.push(e.to_string());
            }
        }
    }
    bail!(
        "{} consecutive unreadable samples in {} from index {} — last error: {}",
        retries + 1,
        source.names[plan.dataset],
        plan.index,
        errors.last().map(String::as_str).unwrap_or("?")
    )
}

/// A worker's answer: the plan's ordinal (a failure needs it too) and what came of it.
struct Decoded {
    ordinal: u64,
    result: Result<LoadedSample>,
}

/// One decoding thread: plans in, decoded and augmented samples out.
struct Worker {
    jobs: Arc<Mutex<Receiver<SamplePlan>>>,
    results: SyncSender<Decoded>,
    source: Arc<MixedSource>,
    streams: Option<Arc<StreamReaders>>,
    augment: AugmentConfig,
    retries: usize,
    stop: Arc<AtomicBool>,
    skipped: Arc<Mutex<Vec<SkippedSample>>>,
}

impl Worker {
    fn run(self) {
        loop {
            let Ok(plan) = self.jobs.lock().unwrap().recv() else {
                return;
            };
            if self.stop.load(Ordering::Relaxed) {
                return;
            }
            let result = load_sample(
                &self.source,
                self.streams.as_deref(),
                plan,
                &self.augment,
                self.retries,
                &self.skipped,
            );
            if self
                .results
                .send(Decoded {
                    ordinal: plan.ordinal,
                    result,
                })
                .is_err()
            {
                return;
            }
        }
    }
}

/// How the loader decodes: augmentation, threads, look-ahead, retries of unreadable samples.
#[derive(Debug, Clone)]
pub struct LoaderSettings {
    pub augment: AugmentConfig,
    pub workers: usize,
    pub prefetch: usize,
    pub retries: usize,
}

/// Background decoding: a planner thread hands out plans, `workers` threads decode and augment,
/// and [`Loader::next_sample`] returns results in plan order. At most `prefetch` samples exist
/// ahead of the consumer (planned, in progress or waiting), so memory stays bounded.
pub struct Loader {
    results: Receiver<Decoded>,
    waiting: BTreeMap<u64, Result<LoadedSample>>,
    /// This replica's next sample.
    next: u64,
    share: Share,
    /// How far (in ordinals) the planner may run ahead of `next`.
    ahead: u64,
    credit: Arc<(Mutex<u64>, Condvar)>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    pub skipped: Arc<Mutex<Vec<SkippedSample>>>,
    /// The readers of the streamed datasets, if any.
    pub streams: Option<Arc<StreamReaders>>,
}

impl Loader {
    /// Starts the stream at sample `start` of `planner`'s sequence.
    pub fn start(
        source: Arc<MixedSource>,
        planner: Planner,
        start: u64,
        augment: AugmentConfig,
        workers: usize,
        prefetch: usize,
        retries: usize,
    ) -> Self {
        let settings = LoaderSettings {
            augment,
            workers,
            prefetch,
            retries,
        };
        Self::start_share(source, planner, start, settings, Share::whole())
    }

    /// Starts the stream of `share`'s samples at sample `start` (a global position) of
    /// `planner`'s sequence: the plans of other replicas are made (plans are cheap) but not
    /// loaded, and their samples of a streamed source are passed over unread.
    pub fn start_share(
        source: Arc<MixedSource>,
        mut planner: Planner,
        start: u64,
        settings: LoaderSettings,
        share: Share,
    ) -> Self {
        let LoaderSettings {
            augment,
            workers,
            prefetch,
            retries,
        } = settings;
        planner.skip_to(start);
        let streams = StreamReaders::new(&source.webdatasets, &planner, share).map(Arc::new);
        let workers = workers.max(1);
        // Ordinals the planner may run ahead: `prefetch` of this replica's samples.
        let ahead = (prefetch.max(1) * share.replicas) as u64;
        let stop = Arc::new(AtomicBool::new(false));
        let first = share.first_owned_from(start);
        // `credit` = the highest ordinal (exclusive) the planner may hand out.
        let credit = Arc::new((Mutex::new(first + ahead), Condvar::new()));
        let skipped = Arc::new(Mutex::new(Vec::new()));
        let (job_tx, job_rx) = sync_channel::<SamplePlan>(workers);
        let jobs = Arc::new(Mutex::new(job_rx));
        let (res_tx, res_rx) = sync_channel(prefetch.max(1) + workers);
        let mut threads = Vec::new();
        {
            let (credit, stop) = (credit.clone(), stop.clone());
            threads.push(std::thread::spawn(move || {
                plan_loop(planner, share, job_tx, &credit, &stop)
            }));
        }
        for _ in 0..workers {
            let worker = Worker {
                jobs: jobs.clone(),
                results: res_tx.clone(),
                source: source.clone(),
                streams: streams.clone(),
                augment: augment.clone(),
                retries,
                stop: stop.clone(),
                skipped: skipped.clone(),
            };
            threads.push(std::thread::spawn(move || worker.run()));
        }
        Self {
            results: res_rx,
            waiting: BTreeMap::new(),
            next: first,
            share,
            ahead,
            credit,
            stop,
            threads,
            skipped,
            streams,
        }
    }

    /// The ordinal of the next sample [`Self::next_sample`] returns (for a loader of the whole
    /// run: the data position to store in a checkpoint).
    pub fn position(&self) -> u64 {
        self.next
    }

    pub fn next_sample(&mut self) -> Result<LoadedSample> {
        loop {
            if let Some(r) = self.waiting.remove(&self.next) {
                self.next = self.share.first_owned_from(self.next + 1);
                let (lock, cv) = &*self.credit;
                *lock.lock().unwrap() = self.next + self.ahead;
                cv.notify_all();
                return r;
            }
            let decoded = self
                .results
                .recv()
                .context("the data loader threads stopped")?;
            self.waiting.insert(decoded.ordinal, decoded.result);
        }
    }

    /// The next `n` samples.
    pub fn next_batch(&mut self, n: usize) -> Result<Vec<LoadedSample>> {
        (0..n).map(|_| self.next_sample()).collect()
    }
}

fn plan_loop(
    mut planner: Planner,
    share: Share,
    jobs: SyncSender<SamplePlan>,
    credit: &(Mutex<u64>, Condvar),
    stop: &AtomicBool,
) {
    let (lock, cv) = credit;
    loop {
        {
            let mut limit = lock.lock().unwrap();
            while planner.position() >= *limit && !stop.load(Ordering::Relaxed) {
                limit = cv.wait(limit).unwrap();
            }
        }
        if stop.load(Ordering::Relaxed) {
            return;
        }
        let plan = planner.next_plan();
        if share.owns(plan.ordinal) && jobs.send(plan).is_err() {
            return;
        }
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.credit.1.notify_all();
        // Dropping the receiver ends any worker blocked in `send` (and with the workers gone,
        // a planner blocked in `send`); a waiting planner exits on `stop`.
        let (_, dead) = sync_channel(1);
        drop(std::mem::replace(&mut self.results, dead));
        for t in std::mem::take(&mut self.threads) {
            let _ = t.join();
        }
    }
}

/// A training batch as tensors: images (N, 3, H, W) BGR 0..255, disparity and validity (N, H, W).
pub struct Batch<B: Backend> {
    pub left: Tensor<B, 4>,
    pub right: Tensor<B, 4>,
    pub disp: Tensor<B, 3>,
    pub valid: Tensor<B, 3>,
}

/// Stacks samples of one size into tensors.
pub fn collate<B: Backend>(samples: &[TrainSample], device: &B::Device) -> Result<Batch<B>> {
    let first = samples.first().context("empty batch")?;
    let (h, w, n) = (first.height, first.width, samples.len());
    let mut left = Vec::with_capacity(n * 3 * h * w);
    let mut right = Vec::with_capacity(n * 3 * h * w);
    let mut disp = Vec::with_capacity(n * h * w);
    let mut valid = Vec::with_capacity(n * h * w);
    for s in samples {
        if (s.height, s.width) != (h, w) {
            bail!(
                "batch mixes sample sizes {}x{} and {}x{}",
                h,
                w,
                s.height,
                s.width
            );
        }
        left.extend_from_slice(&s.left);
        right.extend_from_slice(&s.right);
        disp.extend_from_slice(&s.disp);
        valid.extend_from_slice(&s.valid);
    }
    Ok(Batch {
        left: Tensor::from_data(TensorData::new(left, [n, 3, h, w]), device),
        right: Tensor::from_data(TensorData::new(right, [n, 3, h, w]), device),
        disp: Tensor::from_data(TensorData::new(disp, [n, h, w]), device),
        valid: Tensor::from_data(TensorData::new(valid, [n, h, w]), device),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planner_mixes_by_weight_and_covers_each_epoch() {
        let mut p = Planner::new(7, &[0.98, 0.02], &[50, 3]);
        let plans: Vec<_> = (0..20_000).map(|_| p.next_plan()).collect();
        let small = plans.iter().filter(|s| s.dataset == 1).count() as f64 / plans.len() as f64;
        assert!((small - 0.02).abs() < 0.005, "share {small}");
        // The first 50 draws of dataset 0 are one permutation of its indices.
        let mut first: Vec<usize> = plans
            .iter()
            .filter(|s| s.dataset == 0)
            .take(50)
            .map(|s| s.index)
            .collect();
        first.sort();
        assert_eq!(first, (0..50).collect::<Vec<_>>());
        assert!(plans.iter().enumerate().all(|(k, s)| s.ordinal == k as u64));
    }

    #[test]
    fn planner_replays_and_depends_on_the_seed() {
        let mut a = Planner::new(3, &[0.5, 0.5], &[10, 20]);
        let all: Vec<_> = (0..100).map(|_| a.next_plan()).collect();
        let mut b = Planner::new(3, &[0.5, 0.5], &[10, 20]);
        b.skip_to(60);
        let tail: Vec<_> = (0..40).map(|_| b.next_plan()).collect();
        assert_eq!(&all[60..], &tail[..]);
        let mut c = Planner::new(4, &[0.5, 0.5], &[10, 20]);
        let other: Vec<_> = (0..100).map(|_| c.next_plan()).collect();
        assert_ne!(all, other);
    }
}
