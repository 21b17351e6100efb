//! Where the network's CPU work runs: on the rayon pool's own threads.
//!
//! Every parallel kernel (Flex's, `gemm`'s, ours) runs on rayon's global pool. Called from a
//! thread outside the pool, each one is handed over cold: the caller queues it, blocks on a
//! lock until a worker has finished it, and is woken again, two context switches per kernel.
//! A training step at 192×256 runs thousands of kernels, most of them short, and measured
//! ~22,000 context switches that way (PyTorch's OpenMP threads, which spin between regions:
//! ~200). Run from inside the pool instead, the calling thread is itself a worker: it takes
//! its share of each kernel and only the other workers are signalled.

/// Runs `work` on a thread of rayon's global pool (building the pool if it does not exist yet)
/// and returns its result; already on a pool thread, it simply calls it.
pub fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
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
}
