//! Which samples one replica of a data-parallel run reads.
//!
//! Sample `k` of a run is a pure function of `(seed, k)` whatever the number of replicas; the
//! replicas only divide the samples between them. Step after step the run consumes global
//! micro-batches of `batch` consecutive ordinals (`[m·batch, (m+1)·batch)`); replica `r` of `R`
//! takes the `batch / R` ordinals at offset `r · batch / R` of each. So at every step the
//! replicas together draw exactly the samples a one-replica run with the whole batch draws, a
//! resume needs nothing but the global position, and the replica count may change between
//! sessions of a run (the global batch may not).
//!
//! A streamed (WebDataset) source must not be read by every replica: its shuffle buffer emits
//! samples long after they are read, so a replica cannot learn from the plan alone, in time,
//! which of the samples it reads ahead are its own. [`Ownership`] therefore plans each
//! epoch of a streamed dataset ahead of the loader (plans are cheap: no data is read) and lists
//! the samples that belong to other replicas; the stream readers pass over them unread, so each
//! sample's bytes are read by one replica only.

use std::collections::{HashMap, HashSet};

use super::Planner;

/// The part of the samples one replica takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Share {
    pub replica: usize,
    pub replicas: usize,
    /// The global micro-batch: samples all replicas take together per forward pass.
    pub batch: usize,
}

impl Share {
    /// Everything: a run of one replica.
    pub fn whole() -> Self {
        Self {
            replica: 0,
            replicas: 1,
            batch: 1,
        }
    }

    /// Replica `replica` of `replicas` with a global micro-batch of `batch` (a multiple of
    /// `replicas`).
    pub fn new(replica: usize, replicas: usize, batch: usize) -> Self {
        assert!(replicas > 0 && replica < replicas, "replica out of range");
        assert!(
            batch > 0 && batch.is_multiple_of(replicas),
            "the batch is split evenly"
        );
        Self {
            replica,
            replicas,
            batch,
        }
    }

    pub fn is_whole(&self) -> bool {
        self.replicas == 1
    }

    /// Whether sample number `ordinal` of the run is this replica's.
    pub fn owns(&self, ordinal: u64) -> bool {
        if self.replicas == 1 {
            return true;
        }
        let per = (self.batch / self.replicas) as u64;
        (ordinal % self.batch as u64) / per == self.replica as u64
    }

    /// This replica's first sample at or after `ordinal`.
    pub fn first_owned_from(&self, ordinal: u64) -> u64 {
        let mut k = ordinal;
        while !self.owns(k) {
            k += 1;
        }
        k
    }
}

/// The samples of a streamed dataset's epoch that other replicas take, found by planning ahead.
pub struct Ownership {
    share: Share,
    lookahead: Planner,
    /// (dataset, epoch) → indices of other replicas, for the streamed datasets.
    others: HashMap<(usize, u64), HashSet<usize>>,
}

impl Ownership {
    /// `planner` standing at the loader's start.
    pub fn new(planner: &Planner, share: Share) -> Self {
        Self {
            share,
            lookahead: planner.clone(),
            others: HashMap::new(),
        }
    }

    /// The indices of `dataset`'s epoch `epoch` that other replicas take (planned as far as
    /// needed). Epochs two or more before `epoch` are forgotten: the loader has opened all their
    /// streams by then (it reads in plan order, a few samples at once).
    pub fn others(&mut self, dataset: usize, epoch: u64) -> HashSet<usize> {
        if self.share.is_whole() {
            return HashSet::new();
        }
        self.others
            .retain(|&(d, e), _| d != dataset || e + 2 > epoch);
        while !self.lookahead.epoch_complete(dataset, epoch) {
            let plan = self.lookahead.next_plan();
            if plan.stream.is_some() && !self.share.owns(plan.ordinal) {
                self.others
                    .entry((plan.dataset, plan.epoch))
                    .or_default()
                    .insert(plan.index);
            }
        }
        self.others
            .get(&(dataset, epoch))
            .cloned()
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replicas_split_every_micro_batch_evenly_and_completely() {
        let batch = 6;
        let shares: Vec<Share> = (0..3).map(|r| Share::new(r, 3, batch)).collect();
        for k in 0..60u64 {
            let owners: Vec<usize> = shares
                .iter()
                .filter(|s| s.owns(k))
                .map(|s| s.replica)
                .collect();
            assert_eq!(owners.len(), 1, "sample {k} has owners {owners:?}");
            // Two consecutive ordinals per replica per micro-batch, in replica order.
            assert_eq!(owners[0] as u64, (k % 6) / 2);
        }
        assert_eq!(shares[1].first_owned_from(0), 2);
        assert_eq!(shares[1].first_owned_from(4), 8);
        assert!((0..10).all(|k| Share::whole().owns(k)));
    }
}
