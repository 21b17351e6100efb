//! The order in which a WebDataset source's samples are streamed in one epoch, computed from the
//! seeds and the index alone (the shard list and each shard's sample count), never from data.
//!
//! Epoch `e` of a dataset: its shards are permuted, then dealt round-robin to `streams` streams;
//! each stream reads its shards front to back through a shuffle buffer of `buffer` samples (a
//! sample read goes into the buffer; once the buffer holds `buffer` samples, one drawn uniformly
//! from it is emitted; at the stream's end the rest are drawn out), with a generator seeded from
//! (seed, dataset, epoch, stream); the epoch's order takes one sample from each stream in turn
//! (streams that have run out are passed over). Every sample comes once per epoch.
//!
//! Since the order depends only on the index and seeds, sample `k` of a run is still a pure
//! function of `(seed, k)`: a resumed run recomputes its position without reading any shard, and
//! the number of loader threads (which only decide who reads and decodes) changes nothing.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::mix_seed;

/// How a dataset's shards are streamed: its index's shard sizes and the order settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StreamLayout {
    /// Samples per shard, shards in index order (shard `n` holds the samples numbered from the
    /// sum of the counts before it).
    pub shard_samples: Vec<usize>,
    /// Streams the shards are dealt to (at least 1).
    pub streams: usize,
    /// Samples in each stream's shuffle buffer (at least 1; 1 = the order as read).
    pub buffer: usize,
}

/// One epoch's order: sample indices, and the stream each one comes from.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct EpochOrder {
    pub indices: Vec<usize>,
    pub streams: Vec<u32>,
}

impl StreamLayout {
    /// Samples in all shards.
    pub fn len(&self) -> usize {
        self.shard_samples.iter().sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The first sample index of each shard.
    fn shard_starts(&self) -> Vec<usize> {
        self.shard_samples
            .iter()
            .scan(0, |next, &n| {
                let start = *next;
                *next += n;
                Some(start)
            })
            .collect()
    }

    /// The shards of each stream in epoch `epoch_seed`, in the order the stream reads them.
    pub fn stream_shards(&self, epoch_seed: u64) -> Vec<Vec<usize>> {
        let mut shards: Vec<usize> = (0..self.shard_samples.len()).collect();
        rand::seq::SliceRandom::shuffle(
            &mut shards[..],
            &mut ChaCha8Rng::seed_from_u64(mix_seed(epoch_seed, 0x5348_4152)),
        );
        let streams = self.streams.max(1);
        (0..streams)
            .map(|s| shards.iter().skip(s).step_by(streams).copied().collect())
            .collect()
    }

    /// The sample indices a stream reads, in order, from its shards.
    pub fn read_order(&self, shards: &[usize]) -> Vec<usize> {
        let starts = self.shard_starts();
        shards
            .iter()
            .flat_map(|&n| starts[n]..starts[n] + self.shard_samples[n])
            .collect()
    }

    /// The shuffle buffer's generator of stream `stream` in epoch `epoch_seed`.
    pub fn buffer_rng(epoch_seed: u64, stream: usize) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(mix_seed(epoch_seed, 0x4255_4600 + stream as u64))
    }

    /// The order in which stream `stream`'s samples (read in `read` order) leave its buffer.
    fn stream_emits(&self, read: &[usize], epoch_seed: u64, stream: usize) -> Vec<usize> {
        let mut rng = Self::buffer_rng(epoch_seed, stream);
        let cap = self.buffer.max(1);
        let mut buf = Vec::with_capacity(cap.min(read.len()));
        let mut out = Vec::with_capacity(read.len());
        for &i in read {
            buf.push(i);
            if buf.len() >= cap {
                out.push(buf.swap_remove(rng.random_range(0..buf.len())));
            }
        }
        while !buf.is_empty() {
            out.push(buf.swap_remove(rng.random_range(0..buf.len())));
        }
        out
    }

    /// The whole order of the epoch seeded by `epoch_seed`: every sample once.
    pub fn epoch_order(&self, epoch_seed: u64) -> EpochOrder {
        let emits: Vec<Vec<usize>> = self
            .stream_shards(epoch_seed)
            .iter()
            .enumerate()
            .map(|(s, shards)| self.stream_emits(&self.read_order(shards), epoch_seed, s))
            .collect();
        let mut order = EpochOrder {
            indices: Vec::with_capacity(self.len()),
            streams: Vec::with_capacity(self.len()),
        };
        let longest = emits.iter().map(Vec::len).max().unwrap_or(0);
        for round in 0..longest {
            for (s, e) in emits.iter().enumerate() {
                if let Some(&i) = e.get(round) {
                    order.indices.push(i);
                    order.streams.push(s as u32);
                }
            }
        }
        order
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(shards: &[usize], streams: usize, buffer: usize) -> StreamLayout {
        StreamLayout {
            shard_samples: shards.to_vec(),
            streams,
            buffer,
        }
    }

    #[test]
    fn streams_split_the_shards_and_a_buffer_of_one_keeps_the_read_order() {
        let l = layout(&[3, 2, 4, 1, 5], 2, 1);
        let shards = l.stream_shards(9);
        let mut all: Vec<usize> = shards.concat();
        all.sort();
        assert_eq!(all, [0, 1, 2, 3, 4]);
        assert_eq!((shards[0].len(), shards[1].len()), (3, 2));
        // Buffer 1: each stream emits its samples as read; the epoch alternates the streams.
        let order = l.epoch_order(9);
        let reads: Vec<Vec<usize>> = shards.iter().map(|s| l.read_order(s)).collect();
        for (s, read) in reads.iter().enumerate() {
            let emitted: Vec<usize> = order
                .indices
                .iter()
                .zip(&order.streams)
                .filter(|&(_, &st)| st as usize == s)
                .map(|(&i, _)| i)
                .collect();
            assert_eq!(&emitted, read);
        }
        assert_eq!(order.streams[..4], [0, 1, 0, 1]);
    }

    #[test]
    fn more_streams_than_shards_leave_some_empty() {
        let l = layout(&[2, 3], 5, 4);
        let order = l.epoch_order(1);
        let mut sorted = order.indices.clone();
        sorted.sort();
        assert_eq!(sorted, [0, 1, 2, 3, 4]);
        assert!(order.streams.iter().all(|&s| s < 2));
    }
}
