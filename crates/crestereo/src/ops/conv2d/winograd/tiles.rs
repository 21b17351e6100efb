//! The per-tile transforms of the Winograd convolution: input tiles into the transform domain
//! (`Bᵀ d B`), products back to output tiles (`Aᵀ M A`), and the output gradient into the
//! transform domain (`A dY Aᵀ`, for the weight gradient).
//!
//! Each function handles one block of consecutive tiles (row-major over the tile grid) of one
//! image, on the calling thread, its lanes `block` long ([`Lanebuf`]): within the block each tile position is a
//! lane over the block's tiles, so one axis's transform of all the block's tiles is a small
//! matrix applied to a few lanes ([`apply`]): element-wise, vectorised, one pass. Blocks are
//! small enough that a block's transform domain (C · ξ lanes) stays in cache between the
//! transform and the products that read it.

use rayon::prelude::*;

use super::{Axis, Plan};
use crate::ops::conv2d::Geometry;
use crate::ops::conv2d::scratch::Scratch;
use crate::ops::simd::Isa;

/// The most lanes [`apply`] reads or writes (a 3×3 kernel's 36 transform positions).
pub(super) const MAX_LANES: usize = 36;

/// Elements of a lane handled together in [`apply`]: two AVX registers of float32.
const CHUNK: usize = 16;

/// `count` lanes of a buffer, the i-th starting at `base + i · stride`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Lanes {
    pub base: usize,
    pub stride: usize,
    pub count: usize,
}

impl Lanes {
    pub fn new(base: usize, stride: usize, count: usize) -> Self {
        Lanes {
            base,
            stride,
            count,
        }
    }
}

/// A small dense matrix (k × n) as the non-zero terms of each row, for [`apply`]: built once
/// per convolution, so that applying it to a block's lanes costs only the arithmetic.
#[derive(Debug, Clone)]
pub(super) struct Terms {
    n: usize,
    /// Row i's terms `(source lane, coefficient)` are `terms[starts[i]..starts[i + 1]]`.
    terms: Vec<(usize, f32)>,
    starts: Vec<usize>,
}

impl Terms {
    /// The matrix `coef` (row-major, `n` columns).
    pub(super) fn new(coef: &[f32], n: usize) -> Self {
        assert!(n <= MAX_LANES && coef.len().is_multiple_of(n) && coef.len() / n <= MAX_LANES);
        let mut terms = Vec::new();
        let mut starts = vec![0];
        for row in coef.chunks_exact(n) {
            terms.extend(row.iter().copied().enumerate().filter(|&(_, c)| c != 0.0));
            starts.push(terms.len());
        }
        Terms { n, terms, starts }
    }

    fn rows(&self) -> usize {
        self.starts.len() - 1
    }

    fn row(&self, i: usize) -> &[(usize, f32)] {
        &self.terms[self.starts[i]..self.starts[i + 1]]
    }
}

/// `dst lane i = Σ_k coef[i][k] · src lane k` over the first `len` elements (the lane counts
/// of `src` and `dst` are the matrix's columns and rows), in one pass over chunks of
/// [`CHUNK`] elements, each output chunk summed in registers; zero coefficients are skipped,
/// so each output is the same sum, in the same order, as term-by-term accumulation.
///
/// Compiled for AVX-512, for AVX2+FMA and for the baseline the crate is built for (SSE2 on
/// x86-64); the widest the processor runs is taken ([`crate::ops::simd::isa`]).
pub(super) fn apply(t: &Terms, src: &[f32], s: Lanes, dst: &mut [f32], d: Lanes, len: usize) {
    apply_with(crate::ops::simd::isa(), t, src, s, dst, d, len)
}

/// [`apply`] compiled for `set` (which the processor must support).
pub(super) fn apply_with(
    set: Isa,
    t: &Terms,
    src: &[f32],
    s: Lanes,
    dst: &mut [f32],
    d: Lanes,
    len: usize,
) {
    assert!(
        s.count == t.n && d.count == t.rows(),
        "lanes of a {}x{} matrix",
        t.rows(),
        t.n
    );
    assert!(set.supported(), "{} on a processor without it", set.name());
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn avx2(t: &Terms, src: &[f32], s: Lanes, dst: &mut [f32], d: Lanes, len: usize) {
        apply_body(t, src, s, dst, d, len)
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    fn avx512(t: &Terms, src: &[f32], s: Lanes, dst: &mut [f32], d: Lanes, len: usize) {
        apply_body(t, src, s, dst, d, len)
    }
    match set {
        // SAFETY: the processor supports the set (asserted above).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512(t, src, s, dst, d, len) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2(t, src, s, dst, d, len) },
        _ => apply_body(t, src, s, dst, d, len),
    }
}

#[inline(always)]
fn apply_body(t: &Terms, src: &[f32], s: Lanes, dst: &mut [f32], d: Lanes, len: usize) {
    let lane = |l: usize, j: usize| -> &[f32; CHUNK] {
        src[s.base + l * s.stride + j..][..CHUNK]
            .try_into()
            .expect("a chunk")
    };
    let full = len - len % CHUNK;
    for j in (0..full).step_by(CHUNK) {
        for i in 0..d.count {
            let mut acc = [0f32; CHUNK];
            for &(l, c) in t.row(i) {
                for (a, &v) in acc.iter_mut().zip(lane(l, j)) {
                    *a += c * v;
                }
            }
            dst[d.base + i * d.stride + j..][..CHUNK].copy_from_slice(&acc);
        }
    }
    for j in full..len {
        for i in 0..d.count {
            let mut acc = 0f32;
            for &(l, c) in t.row(i) {
                acc += c * src[s.base + l * s.stride + j];
            }
            dst[d.base + i * d.stride + j] = acc;
        }
    }
}

/// Working lanes of the block transforms, allocated once per thread and call.
pub(super) struct Lanebuf {
    block: usize,
    d: Vec<f32>,
    e: Vec<f32>,
    runs: Vec<[usize; 4]>,
}

impl Lanebuf {
    /// Lanes for blocks of up to `block` tiles.
    pub(super) fn new(plan: &Plan, block: usize) -> Self {
        let most = plan.xi().max(plan.y.n * plan.x.m);
        Lanebuf {
            block,
            d: vec![0f32; most * block],
            e: vec![0f32; most * block],
            runs: Vec::new(),
        }
    }
}

/// One channel of the input as the tiles read it, [`split_images`]: `(phases, rows,
/// columns)` = (m_x, rows of the padded map, padded columns ÷ m_x rounded up).
pub(super) fn split_plane(plan: &Plan) -> (usize, usize, usize) {
    let (ay, ax) = (&plan.y, &plan.x);
    let (ph, pw) = (ay.m * plan.rows + ay.r - 1, ax.m * plan.cols + ax.r - 1);
    (ax.m, ph, pw.div_ceil(ax.m))
}

/// Every image of `x` (N, C, H, W) zero-padded (`g.pad` before the map, the rest after) and
/// split by column phase: padded element (y, X) of a channel goes to phase `X mod m_x`, row y,
/// column `X div m_x` ([`split_plane`]). Tiles start every m_x columns, so one tile position
/// across a row of tiles is then one contiguous run, copied instead of gathered.
pub(super) fn split_images(x: &[f32], g: &Geometry, plan: &Plan) -> Scratch {
    let (phases, ph, pq) = split_plane(plan);
    assert!(g.h + g.pad[0] <= ph && g.w + g.pad[1] <= phases * pq);
    let mut split = Scratch::new(g.n * g.cin * phases * ph * pq);
    split
        .par_chunks_mut(phases * ph * pq)
        .zip(x.par_chunks(g.h * g.w))
        .for_each(|(dst, src)| {
            dst.fill(0.0);
            for (iy, row) in src.chunks_exact(g.w).enumerate() {
                let y = iy + g.pad[0];
                if phases == 1 {
                    dst[y * pq + g.pad[1]..][..g.w].copy_from_slice(row);
                    continue;
                }
                // Padded column X = phases·j + k holds input column X − pad.
                for k in 0..phases {
                    let lo = g.pad[1].saturating_sub(k).div_ceil(phases);
                    let hi = (g.pad[1] + g.w - k).div_ceil(phases).min(pq);
                    let dst_row = &mut dst[(k * ph + y) * pq..][..pq];
                    for (jj, value) in dst_row.iter_mut().enumerate().take(hi).skip(lo) {
                        *value = row[phases * jj + k - g.pad[1]];
                    }
                }
            }
        });
    split
}

/// The block's tiles as runs along rows of tiles: `(first tile in the block, tile row, tile
/// column, tiles)`.
fn tile_runs(plan: &Plan, (t0, len): (usize, usize), runs: &mut Vec<[usize; 4]>) {
    runs.clear();
    let mut q = 0;
    while q < len {
        let (i, j) = ((t0 + q) / plan.cols, (t0 + q) % plan.cols);
        let run = (plan.cols - j).min(len - q);
        runs.push([q, i, j, run]);
        q += run;
    }
}

/// `V = B_yᵀ d B_x` of the input tiles `t0 .. t0 + len` of one image, split as
/// [`split_images`] makes it (C_in planes of [`split_plane`]), into `v`, laid out
/// (ξ, C_in, block): position ξ of channel c at `(ξ · C_in + c) · block`.
pub(super) fn transform_input(
    split: &[f32],
    g: &Geometry,
    plan: &Plan,
    (t0, len): (usize, usize),
    v: &mut [f32],
    buf: &mut Lanebuf,
) {
    let (ay, ax) = (&plan.y, &plan.x);
    let (phases, ph, pq) = split_plane(plan);
    tile_runs(plan, (t0, len), &mut buf.runs);
    let bl = buf.block;
    let (d, e) = (&mut buf.d, &mut buf.e);
    for c in 0..g.cin {
        let plane = &split[c * phases * ph * pq..][..phases * ph * pq];
        // d[r·n_x + s][q] = element (r, s) of tile t0 + q: tile (i, j)'s element is padded
        // (m_y·i + r, m_x·j + s), i.e. phase s mod m_x at column j + s div m_x.
        for r in 0..ay.n {
            for s in 0..ax.n {
                let (phase, shift) = (s % phases, s / phases);
                let lane = &mut d[(r * ax.n + s) * bl..][..len];
                for &[q, i, j, run] in &buf.runs {
                    let row = (phase * ph + ay.m * i + r) * pq;
                    lane[q..q + run].copy_from_slice(&plane[row + j + shift..][..run]);
                }
            }
        }
        // B_yᵀ d along the tiles' columns, then (B_yᵀ d) B_x along their rows into v.
        for s in 0..ax.n {
            let lanes = Lanes::new(s * bl, ax.n * bl, ay.n);
            apply(&plan.terms.bt_y, d, lanes, e, lanes, len);
        }
        for r in 0..ay.n {
            let src = Lanes::new(r * ax.n * bl, bl, ax.n);
            let dst = Lanes::new((r * ax.n * g.cin + c) * bl, g.cin * bl, ax.n);
            apply(&plan.terms.bt_x, e, src, v, dst, len);
        }
    }
}

/// Output rows of one image that the blocks write from several threads at once.
pub(super) struct SharedImage {
    ptr: *mut f32,
    len: usize,
}

// SAFETY: the blocks write disjoint elements (each output pixel belongs to one tile, each tile
// to one block); `SharedImage` only hands out runs of its own slice, bounds checked.
unsafe impl Sync for SharedImage {}
unsafe impl Send for SharedImage {}

impl SharedImage {
    pub(super) fn new(image: &mut [f32]) -> Self {
        SharedImage {
            ptr: image.as_mut_ptr(),
            len: image.len(),
        }
    }

    /// The run `at .. at + len` of the image.
    ///
    /// # Safety
    /// No other live reference may overlap the run: callers write only their own tiles.
    #[allow(clippy::mut_from_ref)]
    unsafe fn run(&self, at: usize, len: usize) -> &mut [f32] {
        assert!(at + len <= self.len, "an output run past the image");
        // SAFETY: inside the slice (checked); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(at), len) }
    }
}

/// `Y = A_yᵀ M A_x` of the tiles `t0 .. t0 + len` from `m` (ξ, C_out, block) into one image's
/// output (C_out, ho, wo), tiles reaching past the map cut back.
pub(super) fn transform_output(
    m: &[f32],
    g: &Geometry,
    plan: &Plan,
    (t0, len): (usize, usize),
    y: &SharedImage,
    buf: &mut Lanebuf,
) {
    let (ay, ax) = (&plan.y, &plan.x);
    tile_runs(plan, (t0, len), &mut buf.runs);
    let bl = buf.block;
    let (a, out) = (&mut buf.d, &mut buf.e);
    for k in 0..g.cout {
        // A_yᵀ M along the columns: a[a'·n_x + s]; then (A_yᵀ M) A_x along the rows:
        // out[a'·m_x + b'].
        for s in 0..ax.n {
            let src = Lanes::new((s * g.cout + k) * bl, ax.n * g.cout * bl, ay.n);
            let dst = Lanes::new(s * bl, ax.n * bl, ay.m);
            apply(&plan.terms.at_y, m, src, a, dst, len);
        }
        for a2 in 0..ay.m {
            let src = Lanes::new(a2 * ax.n * bl, bl, ax.n);
            let dst = Lanes::new(a2 * ax.m * bl, bl, ax.m);
            apply(&plan.terms.at_x, a, src, out, dst, len);
        }
        for &[q, i, j, run] in &buf.runs {
            let (y0, x0) = (ay.m * i, ax.m * j);
            let width = (ax.m * run).min(g.wo - x0);
            for a2 in 0..ay.m.min(g.ho - y0) {
                // SAFETY: these tiles' own outputs (see `SharedImage`).
                let row = unsafe { y.run((k * g.ho + y0 + a2) * g.wo + x0, width) };
                let lanes = &out[a2 * ax.m * bl..][..ax.m * bl];
                if ax.m == 1 {
                    row.copy_from_slice(&lanes[q..q + width]);
                    continue;
                }
                for (jj, tile) in row.chunks_mut(ax.m).enumerate() {
                    for (b2, value) in tile.iter_mut().enumerate() {
                        *value = lanes[b2 * bl + q + jj];
                    }
                }
            }
        }
    }
}

/// `A` (n × m, row-major) of an axis: the transpose of its `Aᵀ`.
fn a_matrix(axis: &Axis) -> Vec<f32> {
    (0..axis.n)
        .flat_map(|r| (0..axis.m).map(move |a| axis.at[a * axis.n + r]))
        .collect()
}

/// The tile transforms of both axes as [`Terms`]: `Bᵀ` (input), `Aᵀ` (output), `A` (output
/// gradient).
#[derive(Debug, Clone)]
pub(super) struct TileTerms {
    bt_y: Terms,
    bt_x: Terms,
    at_y: Terms,
    at_x: Terms,
    a_y: Terms,
    a_x: Terms,
}

impl TileTerms {
    pub(super) fn new(y: &Axis, x: &Axis) -> Self {
        TileTerms {
            bt_y: Terms::new(&y.bt, y.n),
            bt_x: Terms::new(&x.bt, x.n),
            at_y: Terms::new(&y.at, y.n),
            at_x: Terms::new(&x.at, x.n),
            a_y: Terms::new(&a_matrix(y), y.m),
            a_x: Terms::new(&a_matrix(x), x.m),
        }
    }
}

/// `dM = A_y dY A_xᵀ` of the output tiles `t0 .. t0 + len` of one image's output gradient
/// (C_out, ho, wo) into `dm`, laid out (ξ, C_out, block): the transpose of
/// [`transform_output`] (outputs past the map count as zero).
pub(super) fn transform_output_grad(
    dy: &[f32],
    g: &Geometry,
    plan: &Plan,
    (t0, len): (usize, usize),
    dm: &mut [f32],
    buf: &mut Lanebuf,
) {
    let (ay, ax) = (&plan.y, &plan.x);
    tile_runs(plan, (t0, len), &mut buf.runs);
    let bl = buf.block;
    let (d, a) = (&mut buf.d, &mut buf.e);
    for k in 0..g.cout {
        let plane = &dy[k * g.ho * g.wo..][..g.ho * g.wo];
        // d[a·m_x + b][q] = output (a, b) of tile t0 + q, zero past the map.
        for a2 in 0..ay.m {
            for b2 in 0..ax.m {
                let lane = &mut d[(a2 * ax.m + b2) * bl..][..len];
                for &[q, i, j, run] in &buf.runs {
                    let (oy, lane) = (ay.m * i + a2, &mut lane[q..q + run]);
                    if oy >= g.ho {
                        lane.fill(0.0);
                        continue;
                    }
                    let row = &plane[oy * g.wo..][..g.wo];
                    for (jj, value) in lane.iter_mut().enumerate() {
                        let ox = ax.m * (j + jj) + b2;
                        *value = if ox < g.wo { row[ox] } else { 0.0 };
                    }
                }
            }
        }
        // A_y dY along the columns: a[r·m_x + b]; then (A_y dY) A_xᵀ along the rows into dm.
        for b2 in 0..ax.m {
            let src = Lanes::new(b2 * bl, ax.m * bl, ay.m);
            let dst = Lanes::new(b2 * bl, ax.m * bl, ay.n);
            apply(&plan.terms.a_y, d, src, a, dst, len);
        }
        for r in 0..ay.n {
            let src = Lanes::new(r * ax.m * bl, bl, ax.m);
            let dst = Lanes::new((r * ax.n * g.cout + k) * bl, g.cout * bl, ax.n);
            apply(&plan.terms.a_x, a, src, dm, dst, len);
        }
    }
}
