//! Reading WebDataset sources as streams: the loader's side of [`super::stream_order`].
//!
//! Each (dataset, epoch, stream) has one reader: one open shard at a time, samples read front to
//! back in the stream's order, raw (members' bytes, nothing decoded), into a buffer from which
//! the planned samples are taken. Since the planned order is the shuffle buffer's own order
//! replayed, the buffer holds what the shuffle buffer holds: at most `buffer` samples, plus the
//! few that loader threads have asked for ahead of their turn. Decoding and augmentation happen
//! outside the reader, on whichever thread asked, so threads share streams and their number
//! changes nothing but speed.
//!
//! On a resume mid-epoch the samples of that epoch planned before the start are passed over
//! (their bytes not read) rather than buffered.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::{Result, anyhow};
use stereo_io::datasets::webdataset::{RawSample, ShardReader};
use stereo_io::{StereoSample, WebDataset};

use super::share::{Ownership, Share};
use super::stream_order::StreamLayout;
use super::{Planner, SamplePlan, epoch_seed};

/// A streamed dataset: the shards and how they are dealt.
struct Streamed {
    data: Arc<WebDataset>,
    layout: StreamLayout,
    /// The epoch the loader started in and its samples planned before the start.
    started_in: (u64, HashSet<usize>),
}

/// (dataset, epoch, stream).
type StreamKey = (usize, u64, u32);

/// The stream readers of one [`super::Loader`], shared by its threads.
pub struct StreamReaders {
    seed: u64,
    sets: Vec<Option<Streamed>>,
    readers: Mutex<HashMap<StreamKey, Arc<Mutex<StreamReader>>>>,
    /// The samples other replicas read (empty for a run of one).
    ownership: Mutex<Ownership>,
    /// The most samples one reader has held in its buffer.
    peak: AtomicUsize,
}

impl StreamReaders {
    /// The readers for `planner`'s streamed datasets, `planner` standing at the loader's start,
    /// reading `share`'s samples; `None` when no dataset is streamed.
    pub fn new(data: &[Option<Arc<WebDataset>>], planner: &Planner, share: Share) -> Option<Self> {
        let sets: Vec<Option<Streamed>> = (0..planner.layouts.len())
            .map(|d| {
                let layout = planner.layouts[d].clone()?;
                let data = data.get(d)?.clone()?;
                let (epoch, planned) = planner.epoch_progress(d);
                Some(Streamed {
                    data,
                    layout,
                    started_in: (epoch, planned.iter().copied().collect()),
                })
            })
            .collect();
        sets.iter().any(Option::is_some).then(|| Self {
            seed: planner.seed,
            sets,
            readers: Mutex::new(HashMap::new()),
            ownership: Mutex::new(Ownership::new(planner, share)),
            peak: AtomicUsize::new(0),
        })
    }

    /// Planned sample `plan` read from its stream and decoded; `None` when its dataset is not
    /// streamed.
    pub fn sample(&self, plan: &SamplePlan) -> Option<Result<StereoSample>> {
        let set = self.sets.get(plan.dataset)?.as_ref()?;
        let stream = plan.stream?;
        let key = (plan.dataset, plan.epoch, stream);
        let reader = self
            .readers
            .lock()
            .unwrap()
            .entry(key)
            .or_insert_with(|| {
                Arc::new(Mutex::new(self.reader(
                    set,
                    plan.dataset,
                    plan.epoch,
                    stream,
                )))
            })
            .clone();
        let (raw, done) = {
            let mut r = reader.lock().unwrap();
            let raw = r.take(&set.data, plan.index);
            self.peak.fetch_max(r.peak, Ordering::Relaxed);
            (raw, r.left == 0)
        };
        if done {
            self.readers.lock().unwrap().remove(&key);
        }
        Some(raw.and_then(|raw| Ok(set.data.decode(&raw)?)))
    }

    /// Readers open now (finished streams are closed).
    pub fn open_readers(&self) -> usize {
        self.readers.lock().unwrap().len()
    }

    /// The most raw samples one stream has held in its buffer so far.
    pub fn peak_buffered(&self) -> usize {
        self.peak.load(Ordering::Relaxed)
    }

    fn reader(&self, set: &Streamed, dataset: usize, epoch: u64, stream: u32) -> StreamReader {
        let seed = epoch_seed(self.seed, dataset, epoch);
        let shards = set.layout.stream_shards(seed).swap_remove(stream as usize);
        let starts: Vec<usize> = set
            .layout
            .shard_samples
            .iter()
            .scan(0, |n, &c| {
                *n += c;
                Some(*n - c)
            })
            .collect();
        let read: Vec<(usize, usize)> = shards
            .iter()
            .flat_map(|&s| {
                (starts[s]..starts[s] + set.layout.shard_samples[s]).map(move |i| (s, i))
            })
            .collect();
        let others = self.ownership.lock().unwrap().others(dataset, epoch);
        // Passed over unread: samples planned before the loader started, and other replicas'.
        let skip: HashSet<usize> = read
            .iter()
            .map(|&(_, i)| i)
            .filter(|i| {
                (set.started_in.0 == epoch && set.started_in.1.contains(i)) || others.contains(i)
            })
            .collect();
        StreamReader {
            left: read.len() - skip.len(),
            read,
            next: 0,
            skip,
            shard: None,
            buffer: HashMap::new(),
            peak: 0,
        }
    }
}

/// One stream of one epoch, read front to back.
struct StreamReader {
    /// `(shard, sample)` in reading order.
    read: Vec<(usize, usize)>,
    next: usize,
    /// Samples planned before the loader started: passed over, not read.
    skip: HashSet<usize>,
    shard: Option<ShardReader>,
    /// Samples read and not yet taken (a failed read is kept as its error).
    buffer: HashMap<usize, stereo_io::Result<RawSample>>,
    /// Samples still to be taken.
    left: usize,
    /// The most samples `buffer` has held.
    peak: usize,
}

impl StreamReader {
    /// Sample `index`: from the buffer, or by reading on until it comes.
    fn take(&mut self, data: &WebDataset, index: usize) -> Result<RawSample> {
        if let Some(r) = self.buffer.remove(&index) {
            self.left -= 1;
            return Ok(r?);
        }
        while let Some(&(shard, i)) = self.read.get(self.next) {
            self.next += 1;
            if self.skip.remove(&i) {
                continue;
            }
            let r = self.read_one(data, shard, i);
            if i == index {
                self.left -= 1;
                return Ok(r?);
            }
            self.buffer.insert(i, r);
            self.peak = self.peak.max(self.buffer.len());
        }
        Err(anyhow!(
            "sample {index} was planned from a stream that does not hold it (a bug)"
        ))
    }

    fn read_one(
        &mut self,
        data: &WebDataset,
        shard: usize,
        index: usize,
    ) -> stereo_io::Result<RawSample> {
        if self.shard.as_ref().is_none_or(|r| r.shard() != shard) {
            self.shard = None;
            self.shard = Some(data.shard_reader(shard)?);
        }
        self.shard.as_mut().unwrap().read(data, index)
    }
}
