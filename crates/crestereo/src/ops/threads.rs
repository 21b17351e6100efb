//! Where the network's CPU work runs: on the rayon pool's own threads.
//!
//! Every parallel kernel (Flex's, `gemm`'s, ours) runs on rayon's global pool. Called from a
//! thread outside the pool, each one is handed over cold: the caller queues it, blocks on a
//! lock until a worker has finished it, and is woken again, two context switches per kernel.
//! A training step at 192×256 runs thousands of kernels, most of them short, and measured
//! ~22,000 context switches that way (PyTorch's OpenMP threads, which spin between regions:
//! ~200). Run from inside the pool instead, the calling thread is itself a worker: it takes
//! its share of each kernel and only the other workers are signalled.
//!
//! Partial results of a parallel kernel are kept per fixed chunk ([`chunk_len`]) and added in
//! chunk order ([`sum_in_order`]), so a run's bits never depend on the load on the pool.

use rayon::prelude::*;

/// Runs `work` on a thread of rayon's global pool (building the pool if it does not exist yet)
/// and returns its result; already on a pool thread, it simply calls it.
///
/// Meant for a program's one long job (a training, an evaluation), started before other threads
/// use the pool. Queued while they do, it may be picked up by a worker waiting inside one of
/// their joins, and that join cannot return until `work` ends: should `work` wait for something
/// the joining thread holds (Burn's autodiff makes each backward pass lock every graph in the
/// process), both wait for ever. Two trainings in one process started this way hung so.
pub fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}

/// The length of the chunks that cut `items` into one contiguous run per thread of the current
/// pool (at least one item each). Kernels that keep partial results per chunk use it: the cut
/// depends on the data's size and the configured thread count only.
pub fn chunk_len(items: usize) -> usize {
    items.div_ceil(rayon::current_num_threads().max(1)).max(1)
}

/// The element-wise sum of `parts`, added in the order of `parts` (parallel over elements, never
/// over parts).
///
/// Why not rayon's `fold` + `reduce`: rayon splits a parallel iterator adaptively (a stolen job
/// splits again), so which items share a partial sum, and the order partials are combined in,
/// change from run to run with the load on the pool; float addition is not associative, so the
/// bits of a gradient did too. Partials made per [`chunk_len`] chunk and combined here give the
/// same bits under any load.
pub fn sum_in_order(parts: Vec<Vec<f32>>) -> Vec<f32> {
    const BLOCK: usize = 1 << 14;
    let mut parts = parts.into_iter();
    let Some(mut total) = parts.next() else {
        return Vec::new();
    };
    let rest: Vec<Vec<f32>> = parts.collect();
    if rest.is_empty() {
        return total;
    }
    assert!(
        rest.iter().all(|p| p.len() == total.len()),
        "partial sums of different lengths"
    );
    total
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(b, dst)| {
            let (at, len) = (b * BLOCK, dst.len());
            for part in &rest {
                for (d, s) in dst.iter_mut().zip(&part[at..at + len]) {
                    *d += s;
                }
            }
        });
    total
}

/// Test support: runs `run` once on a quiet pool of `threads` threads, then `rounds` more times
/// while `threads - 1` chains of jobs keep that pool busy with parallel work of their own (so jobs are stolen and
/// split differently each time), and returns the first round whose outputs' bits differ from
/// the quiet run's. The busy jobs stop on every exit, a panic included, so a failure reports
/// instead of hanging the pool.
#[cfg(test)]
pub(crate) fn first_round_that_differs_under_load(
    threads: usize,
    rounds: usize,
    run: impl Fn() -> Vec<Vec<f32>> + Send + Sync,
) -> Option<usize> {
    use std::sync::atomic::{AtomicBool, Ordering};
    struct StopOnDrop<'a>(&'a AtomicBool);
    impl Drop for StopOnDrop<'_> {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Relaxed);
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool");
    let quiet = pool.install(&run);
    let stop = AtomicBool::new(false);
    let mut changed_at = None;
    // A busy job is short and queues its successor: a worker that steals one while it waits on
    // a join of the measured run gets back to that run, where a job looping until the end of
    // the test would hold the worker and deadlock it.
    fn keep_busy<'s>(scope: &rayon::Scope<'s>, stop: &'s AtomicBool) {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        let v: f64 = (0..20_000u32)
            .into_par_iter()
            .map(|i| f64::from(i).sqrt())
            .sum();
        std::hint::black_box(v);
        scope.spawn(move |s| keep_busy(s, stop));
    }
    pool.in_place_scope(|scope| {
        let _stop = StopOnDrop(&stop);
        // One worker fewer than the pool has: busy chains refill their workers' own queues
        // first, and a pool they all occupied would never take the measured run's job.
        for _ in 0..threads.saturating_sub(1).max(1) {
            scope.spawn(|s| keep_busy(s, &stop));
        }
        for round in 0..rounds {
            let busy = pool.install(&run);
            let same = quiet.len() == busy.len()
                && quiet.iter().zip(&busy).all(|(q, b)| {
                    q.len() == b.len() && q.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
                });
            if !same {
                changed_at = Some(round);
                break;
            }
        }
    });
    changed_at
}

#[cfg(test)]
mod tests {
    #[test]
    fn work_runs_on_a_pool_thread_and_returns_its_result() {
        assert_eq!(
            rayon::current_thread_index(),
            None,
            "tests start outside the pool"
        );
        let (index, value) = super::on_pool(|| (rayon::current_thread_index(), 41 + 1));
        assert!(index.is_some(), "on_pool ran its work outside rayon's pool");
        assert_eq!(value, 42);
        // Nested: already on the pool, the work runs on the same thread.
        let same = super::on_pool(|| {
            let outer = rayon::current_thread_index();
            super::on_pool(|| rayon::current_thread_index() == outer)
        });
        assert!(same);
    }

    #[test]
    fn partial_sums_are_added_in_part_order() {
        // Values whose sum depends on the order of addition in f32.
        let parts: Vec<Vec<f32>> = (0..5)
            .map(|p| {
                (0..40_000)
                    .map(|i| {
                        ((i * 7 + p * 13) % 101) as f32 * 1e-3 + if p == 2 { 1e7 } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let expected: Vec<f32> = (0..40_000)
            .map(|i| parts.iter().fold(0f32, |acc, p| acc + p[i]))
            .collect();
        let summed = super::sum_in_order(parts.clone());
        assert_eq!(summed.len(), expected.len());
        assert!(
            summed
                .iter()
                .zip(&expected)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        assert_eq!(super::sum_in_order(Vec::new()), Vec::<f32>::new());
        assert_eq!(super::sum_in_order(vec![vec![1.0, 2.0]]), vec![1.0, 2.0]);
        assert!(super::chunk_len(0) >= 1);
        let n = rayon::current_num_threads();
        assert_eq!(super::chunk_len(10 * n), 10);
    }
}
