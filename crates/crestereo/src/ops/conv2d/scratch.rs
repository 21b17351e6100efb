//! Working buffers of the convolution kernels, kept between calls.
//!
//! A convolution's transient buffers (the Winograd transform domain, widened rows, im2col
//! columns) are as large as its input and output maps and are needed again, at the same sizes,
//! on the next refinement iteration. Freshly allocated, each would be zeroed and page-faulted
//! in on every call (measured: 6 ms of a 60 ms 3×3 convolution at 64×80); taken from this
//! pool they are written in place. Contents are unspecified: every user overwrites what it
//! reads.

use std::cell::RefCell;
use std::ops::{Deref, DerefMut};

/// The most bytes the pool of one thread keeps between calls; larger leftovers are freed.
const MAX_POOLED_BYTES: usize = 256 << 20;

thread_local! {
    static POOL: RefCell<Vec<Vec<f32>>> = const { RefCell::new(Vec::new()) };
}

/// A float32 buffer of a given length with unspecified contents, returned to this thread's
/// pool when dropped.
pub(crate) struct Scratch {
    buf: Vec<f32>,
    len: usize,
}

impl Scratch {
    /// A buffer of `len` elements: the smallest pooled one that fits, else the largest grown.
    pub(crate) fn new(len: usize) -> Self {
        let mut buf = POOL.with_borrow_mut(|pool| {
            let fits = (0..pool.len())
                .filter(|&i| pool[i].len() >= len)
                .min_by_key(|&i| pool[i].len());
            let pick = fits.or_else(|| (0..pool.len()).max_by_key(|&i| pool[i].len()));
            pick.map(|i| pool.swap_remove(i)).unwrap_or_default()
        });
        if buf.len() < len {
            buf.resize(len, 0.0);
        }
        Scratch { buf, len }
    }
}

impl Deref for Scratch {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        &self.buf[..self.len]
    }
}

impl DerefMut for Scratch {
    fn deref_mut(&mut self) -> &mut [f32] {
        &mut self.buf[..self.len]
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let buf = std::mem::take(&mut self.buf);
        // A panicking thread may be tearing its pool down: then the buffer is just freed.
        let _ = POOL.try_with(|pool| {
            let mut pool = pool.borrow_mut();
            pool.push(buf);
            pool.sort_by_key(|b| std::cmp::Reverse(b.len()));
            let mut kept = 0;
            pool.retain(|b| {
                kept += b.len() * size_of::<f32>();
                kept <= MAX_POOLED_BYTES
            });
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_are_reused_and_sized() {
        let ptr = {
            let mut a = Scratch::new(1000);
            a.fill(1.0);
            a.as_ptr()
        };
        let b = Scratch::new(600);
        assert_eq!(b.len(), 600);
        assert_eq!(b.as_ptr(), ptr, "the pooled buffer is taken again");
        let c = Scratch::new(2000);
        assert_eq!(c.len(), 2000);
        assert_ne!(c.as_ptr(), b.as_ptr());
    }

    /// What a pooled buffer held before never reaches a result: a training step's gradients
    /// are the same bits after every pool thread's buffers were filled with NaN. (Contents left
    /// by another run at other sizes once made runs in one process differ.)
    #[test]
    fn leftover_contents_never_reach_a_result() {
        use crate::{CREStereoConfig, CpuAutodiffBackend};
        type B = CpuAutodiffBackend;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("a thread pool");
        // One model for both steps: Burn draws initial weights from one process-wide RNG that
        // the crate's other tests draw from at the same time.
        let device = Default::default();
        let model = CREStereoConfig::new().init::<B>(&device);
        let _ = crate::weights::named_parameters(&model);
        let step = || pool.install(|| crate::test_util::fixed_step_gradients(&model));
        let clean = step();
        // NaN, and a finite value too: a NaN read through a ReLU (`f32::max`) would vanish.
        for poison in [f32::NAN, 1.0e4] {
            pool.broadcast(|_| {
                let mut held: Vec<Scratch> = (8..24).map(|b| Scratch::new(1 << b)).collect();
                for s in &mut held {
                    s.fill(poison);
                }
            });
            let poisoned = step();
            let differ = crate::test_util::differing_gradients(&clean, &poisoned);
            assert!(
                differ.is_empty(),
                "gradients that read leftovers ({poison}): {differ:?}"
            );
        }
    }
}
