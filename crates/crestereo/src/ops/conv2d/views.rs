//! Matrix products on strided views of plain slices (the `gemm` crate Flex itself uses), for
//! the convolution paths that multiply views of padded or transformed maps in place.

use gemm::{Parallelism, gemm};

/// A strided matrix view into a slice: element (i, j) at `offset + i·rs + j·cs`.
#[derive(Clone, Copy)]
pub(super) struct View {
    pub(super) offset: usize,
    pub(super) rs: usize,
    pub(super) cs: usize,
}

impl View {
    pub(super) fn new(offset: usize, rs: usize, cs: usize) -> Self {
        View { offset, rs, cs }
    }

    fn last(&self, rows: usize, cols: usize) -> usize {
        self.offset + (rows - 1) * self.rs + (cols - 1) * self.cs
    }
}

/// How a matrix product uses threads.
#[derive(Clone, Copy)]
pub(super) enum Threads {
    /// Large products (m·n·k ≥ 2^18) split over the thread pool, small ones on this thread.
    Pool,
    /// This thread only: for callers already parallel over blocks.
    One,
}

/// `dst (m × n) = [dst +] lhs (m × k) · rhs (k × n)` on strided views, bounds checked.
#[allow(clippy::too_many_arguments)]
pub(super) fn matmul_into(
    threads: Threads,
    (m, n, k): (usize, usize, usize),
    dst: &mut [f32],
    d: View,
    accumulate: bool,
    lhs: &[f32],
    l: View,
    rhs: &[f32],
    r: View,
) {
    let parallelism = match threads {
        Threads::Pool if m * n * k >= 1 << 18 => Parallelism::Rayon(0),
        _ => Parallelism::None,
    };
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    assert!(
        d.last(m, n) < dst.len() && l.last(m, k) < lhs.len() && r.last(k, n) < rhs.len(),
        "convolution: a matrix view reaches past its buffer"
    );
    // SAFETY: the three views lie inside their slices (checked above); `dst` is borrowed
    // mutably and does not alias `lhs` or `rhs`.
    unsafe {
        gemm(
            m,
            n,
            k,
            dst.as_mut_ptr().add(d.offset),
            d.cs as isize,
            d.rs as isize,
            accumulate,
            lhs.as_ptr().add(l.offset),
            l.cs as isize,
            l.rs as isize,
            rhs.as_ptr().add(r.offset),
            r.cs as isize,
            r.rs as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            parallelism,
        );
    }
}
