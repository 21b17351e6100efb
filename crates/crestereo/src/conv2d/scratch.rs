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
}
