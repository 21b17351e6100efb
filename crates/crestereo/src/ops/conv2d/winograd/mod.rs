//! Stride-1 convolutions by Winograd's minimal filtering, one axis at a time.
//!
//! Along an axis with kernel extent `r`, F(m, r) computes `m` outputs of the correlation from a
//! tile of `n = m + r − 1` inputs with `n` products instead of `m·r`: the tile and the kernel are
//! mapped into an `n`-point "transform domain" (`Bᵀ d`, `G g`), multiplied element by element
//! and mapped back (`Aᵀ`). A 2-D kernel takes one such transform per axis (extent 1 is the
//! identity), so a tile has `n_y · n_x` transform positions ξ, and summed over input channels
//! each position is one matrix product
//!
//! ```text
//! M_ξ (C_out × tiles) = U_ξ (C_out × C_in) · V_ξ (C_in × tiles)
//! ```
//!
//! The transforms are built by Toom–Cook at small points (0, ±1, ±2, ±½ and infinity), the
//! Lagrange denominators folded into `G` so that `Bᵀ` and `Aᵀ` hold small integers and powers
//! of two; the kernel transform runs in float64. Used: F(4, 3) per axis for 3×3 kernels in
//! inference (4× fewer products) and F(2, 3) in training (2.25×, more accurate gradients, see
//! [`Axis::for_extent`]), F(4, 5) for the GRU's 1×5 and 5×1 (2.5× fewer); the unit tests
//! compare every case with Burn's convolution.
//!
//! The input gradient of such a convolution is itself one (kernel flipped, channel axes
//! swapped, padding `k − 1 − p`), so the backward reuses the forward; the weight gradient is
//! computed in the transform domain too ([`weight_grad`]). Measured against Burn's direct
//! convolution on 64 → 32 channels, 2×48×64 maps (gradients of magnitude ~300): weight-gradient
//! error 2.5e-4 (3×3) and 8e-4 (1×5) against 2e-4 and 1.5e-4 for the shifted-view products,
//! i.e. ≤ 3e-6 of the gradient's scale.

use rayon::prelude::*;

use super::Geometry;
use super::scratch::Scratch;
use super::views::{Threads, View, matmul_into};
use tiles::{
    Lanebuf, Lanes, SharedImage, Terms, TileTerms, apply, split_images, split_plane,
    transform_input, transform_output, transform_output_grad,
};

mod tiles;

/// Below these sizes the products are too thin or too few for the transforms to pay.
const MIN_CIN: usize = 16;
const MIN_COUT: usize = 16;
const MIN_OUTPUTS: usize = 256;

/// One axis of the transform: F(m, r) with `n = m + r − 1` points, matrices row-major.
#[derive(Debug, Clone)]
struct Axis {
    m: usize,
    r: usize,
    n: usize,
    /// Bᵀ (n × n).
    bt: Vec<f32>,
    /// G (n × r), float64 until the two axes' coefficients are multiplied.
    g: Vec<f64>,
    /// Aᵀ (m × n).
    at: Vec<f32>,
}

/// Coefficients (lowest degree first) of `Π (x − p)` over `points`.
fn monic(points: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut c = vec![1.0];
    for p in points {
        let mut next = vec![0.0; c.len() + 1];
        for (k, &ck) in c.iter().enumerate() {
            next[k + 1] += ck;
            next[k] -= p * ck;
        }
        c = next;
    }
    c
}

impl Axis {
    /// F(m, r) by Toom–Cook at `points` (n − 1 finite points) and infinity.
    ///
    /// The correlation is the transpose of the linear convolution of an m-vector with the
    /// kernel, whose Toom–Cook form is `y = C · ((H g) ⊙ (D a))` (D, H: evaluation at the points,
    /// the last row taking the leading coefficient; C: interpolation, Lagrange polynomials plus
    /// `Π (x − p)` for infinity). Transposed: `Aᵀ = Dᵀ`, `G = H`, `Bᵀ = Cᵀ`; each Lagrange
    /// denominator moves from `Bᵀ`'s row into `G`'s.
    fn new(m: usize, r: usize, points: &[f64]) -> Self {
        let n = m + r - 1;
        assert_eq!(
            points.len(),
            n - 1,
            "F({m}, {r}) needs {} finite points",
            n - 1
        );
        let eval = |len: usize, i: usize, j: usize| match points.get(i) {
            Some(p) => p.powi(j as i32),
            None => f64::from(u8::from(j == len - 1)),
        };
        let mut bt = vec![0f32; n * n];
        let mut g = vec![0f64; n * r];
        for i in 0..n {
            let (row, den) = if i < n - 1 {
                let others = || points.iter().enumerate().filter(|&(l, _)| l != i);
                let den: f64 = others().map(|(_, &p)| points[i] - p).product();
                (monic(others().map(|(_, &p)| p)), den)
            } else {
                (monic(points.iter().copied()), 1.0)
            };
            for (k, &c) in row.iter().enumerate() {
                bt[i * n + k] = c as f32;
            }
            for k in 0..r {
                g[i * r + k] = eval(r, i, k) / den;
            }
        }
        let at = (0..m)
            .flat_map(|j| (0..n).map(move |i| (j, i)))
            .map(|(j, i)| eval(m, i, j) as f32)
            .collect();
        Axis { m, r, n, bt, g, at }
    }

    /// The transform for a kernel of extent `r` along this axis, if there is one.
    ///
    /// Extent 3 takes F(4, 3) for inference (4× fewer products than direct in 2-D, against
    /// 2.25× for F(2, 3)) and F(2, 3) for training: F(4, 3)'s larger coefficients raise a
    /// forward's rounding error ~4× (relative RMS 1.6e-6 against 0.36e-6 on 128 input
    /// channels), which inference's parity bounds absorb, but in training the error of every
    /// update-block forward and input gradient flows into the weight gradients: measured against
    /// the float64 reference gradients, the update block's worst relative L2 went from 1.9e-5
    /// to 4.8e-4. The points {0, ±1, ½, −2} are the most accurate F(4, 3) set we tried
    /// ({0, ±1, ±2}: 2.4e-6, {0, ±1, ±½}: 2.4e-6).
    fn for_extent(r: usize, use_: Use) -> Option<Self> {
        match (r, use_) {
            (1, _) => Some(Axis::new(1, 1, &[])),
            (3, Use::Inference) => Some(Axis::new(4, 3, &[0.0, 1.0, -1.0, 0.5, -2.0])),
            (3, Use::Training) => Some(Axis::new(2, 3, &[0.0, 1.0, -1.0])),
            (5, _) => Some(Axis::new(4, 5, &[0.0, 1.0, -1.0, 2.0, -2.0, 0.5, -0.5])),
            _ => None,
        }
    }
}

/// Which transforms a convolution takes (see [`Axis::for_extent`]): an inference forward, or
/// the forward and gradients of a training step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Use {
    Inference,
    Training,
}

/// The two axes of a convolution's transform and its grid of output tiles per image.
struct Plan {
    y: Axis,
    x: Axis,
    terms: TileTerms,
    rows: usize,
    cols: usize,
}

impl Plan {
    fn new(g: &Geometry, use_: Use) -> Option<Self> {
        let (y, x) = (Axis::for_extent(g.kh, use_)?, Axis::for_extent(g.kw, use_)?);
        Some(Plan {
            rows: g.ho.div_ceil(y.m),
            cols: g.wo.div_ceil(x.m),
            terms: TileTerms::new(&y, &x),
            y,
            x,
        })
    }

    fn tiles(&self) -> usize {
        self.rows * self.cols
    }

    /// Transform positions per tile.
    fn xi(&self) -> usize {
        self.y.n * self.x.n
    }

    /// The kernel transform as one (ξ × taps) matrix, rounded once:
    /// `coef[ξ][tap] = G_y[i][a] · G_x[s][l]` for ξ = (i, s), tap = (a, l).
    fn kernel_coefficients(&self) -> Vec<f32> {
        let (ay, ax) = (&self.y, &self.x);
        (0..ay.n)
            .flat_map(|i| (0..ax.n).map(move |s| (i, s)))
            .flat_map(|(i, s)| {
                (0..ay.r).flat_map(move |a| {
                    (0..ax.r).map(move |l| (ay.g[i * ay.r + a] * ax.g[s * ax.r + l]) as f32)
                })
            })
            .collect()
    }
}

/// Whether the forward of `g` takes this path: 3×3, 1×5 or 5×1, stride 1, no dilation, and
/// enough channels and outputs.
pub(super) fn applies(g: &Geometry) -> bool {
    g.stride == [1, 1]
        && g.dil == [1, 1]
        && g.kh * g.kw > 1
        && g.cin >= MIN_CIN
        && g.cout >= MIN_COUT
        && g.ho * g.wo >= MIN_OUTPUTS
        && [g.kh, g.kw].into_iter().all(|k| {
            Axis::for_extent(k, Use::Inference).is_some()
                && Axis::for_extent(k, Use::Training).is_some()
        })
}

/// Whether the input gradient of `g` takes this path (as the forward of [`transposed`]).
pub(super) fn applies_to_input_grad(g: &Geometry) -> bool {
    applies(g) && g.pad[0] < g.kh && g.pad[1] < g.kw && applies(&transposed(g))
}

/// The convolution whose forward is the input gradient of `g`: output gradient in, input
/// gradient out, padding `k − 1 − p` (only for `applies(g)` and p < k).
fn transposed(g: &Geometry) -> Geometry {
    Geometry {
        n: g.n,
        cin: g.cout,
        h: g.ho,
        w: g.wo,
        cout: g.cin,
        kh: g.kh,
        kw: g.kw,
        ho: g.h,
        wo: g.w,
        stride: [1, 1],
        pad: [g.kh - 1 - g.pad[0], g.kw - 1 - g.pad[1]],
        dil: [1, 1],
    }
}

/// Tiles per block of the forward: long enough lanes for vectorised loops and wide enough
/// products, short enough for a block's transform domain to stay in the processor's cache.
const FORWARD_BLOCK: usize = 64;

/// Tiles per block of the weight gradient, whose products sum over the block's tiles into the
/// whole (C_out × ξ × C_in) dU: longer blocks, so that reading and writing dU stays small
/// beside the products (at 64 tiles it was ~40 % of the weight gradient).
const WEIGHT_GRAD_BLOCK: usize = 256;

/// A block length of at most `target` tiles that splits the batch into a number of blocks
/// divisible by the worker threads where that costs at most halving the blocks, so that no
/// thread waits on another's last block: the weight gradient of a 48×64 map has 768 tiles of
/// F(2, 3), three blocks of 256, and two threads would take two and one (67 % busy); four
/// blocks of 192 keep both busy.
fn balanced_block(g: &Geometry, plan: &Plan, target: usize) -> usize {
    let (tiles, threads) = (plan.tiles(), rayon::current_num_threads().max(1));
    let fewest = tiles.div_ceil(target);
    let per_image = (fewest..=2 * fewest)
        .find(|&k| (g.n * k).is_multiple_of(threads))
        .unwrap_or(fewest);
    tiles.div_ceil(per_image)
}

/// The blocks of `block` tiles of all images: (image, first tile, tiles).
fn blocks(g: &Geometry, plan: &Plan, block: usize) -> Vec<(usize, (usize, usize))> {
    let t = plan.tiles();
    (0..g.n)
        .flat_map(|b| {
            (0..t)
                .step_by(block)
                .map(move |t0| (b, (t0, block.min(t - t0))))
        })
        .collect()
}

/// `Y` (N, C_out, ho, wo) of input `x` (N, C_in, H, W) and weight `w` (C_out, C_in, kh, kw),
/// both contiguous.
///
/// Block by block of tiles, in parallel: transform the block's input tiles, one product per
/// transform position on this thread, transform back into the output; a block's transform
/// domain stays in cache throughout (whole-map transforms, written out and read back by the
/// products, spent as long moving memory as the products took).
pub(super) fn forward(x: &[f32], w: &[f32], g: &Geometry, use_: Use) -> Vec<f32> {
    let plan = Plan::new(g, use_).expect("checked by applies");
    let xi = plan.xi();
    let u = transform_weights(w, g, &plan);
    let split = split_images(x, g, &plan);
    let plane = {
        let (phases, ph, pq) = split_plane(&plan);
        phases * ph * pq
    };
    let mut y = vec![0f32; g.n * g.cout * g.ho * g.wo];
    let images: Vec<SharedImage> = y
        .chunks_exact_mut(g.cout * g.ho * g.wo)
        .map(SharedImage::new)
        .collect();
    let bl = FORWARD_BLOCK;
    blocks(g, &plan, bl).into_par_iter().for_each_init(
        || {
            (
                Scratch::new(xi * g.cin * bl),
                Scratch::new(xi * g.cout * bl),
                Lanebuf::new(&plan, bl),
            )
        },
        |(v, m, buf), (b, (t0, len))| {
            let image = &split[b * g.cin * plane..][..g.cin * plane];
            transform_input(image, g, &plan, (t0, len), v, buf);
            for e in 0..xi {
                matmul_into(
                    Threads::One,
                    (g.cout, len, g.cin),
                    m,
                    View::new(e * g.cout * bl, bl, 1),
                    false,
                    &u,
                    View::new(e * g.cin, xi * g.cin, 1),
                    v,
                    View::new(e * g.cin * bl, bl, 1),
                );
            }
            transform_output(m, g, &plan, (t0, len), &images[b], buf);
        },
    );
    drop(images);
    y
}

/// `dX` (N, C_in, H, W) of the output gradient `dy` (N, C_out, ho, wo): the forward of the
/// flipped, channel-swapped kernel (see [`transposed`]).
pub(super) fn input_grad(w: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let taps = g.kh * g.kw;
    let mut flipped = vec![0f32; g.cin * g.cout * taps];
    flipped
        .par_chunks_mut(g.cout * taps)
        .enumerate()
        .for_each(|(ci, dst)| {
            for co in 0..g.cout {
                let src = &w[(co * g.cin + ci) * taps..][..taps];
                for (i, d) in dst[co * taps..][..taps].iter_mut().enumerate() {
                    *d = src[taps - 1 - i];
                }
            }
        });
    forward(dy, &flipped, &transposed(g), Use::Training)
}

/// `dW` (C_out, C_in, kh, kw) of input `x` and output gradient `dy`, in the transform domain:
/// `dU_ξ = Σ_images dM_ξ · V_ξᵀ` (one product per ξ, the forward's reduced size) with
/// `dM = A_y dY A_xᵀ` per tile, then `dW = G_yᵀ dU G_x` (the forward's transforms transposed).
pub(super) fn weight_grad(x: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let plan = Plan::new(g, Use::Training).expect("checked by applies");
    let (xi, taps) = (plan.xi(), g.kh * g.kw);
    let split = split_images(x, g, &plan);
    let plane = {
        let (phases, ph, pq) = split_plane(&plan);
        phases * ph * pq
    };
    // The blocks are cut into one fixed run per pool thread; each run sums its blocks'
    // products into its own dU (laid out (C_out, ξ, C_in)) and the runs' sums are added in run
    // order, so the bits depend on the shape and the thread count, never on the scheduling.
    let bl = balanced_block(g, &plan, WEIGHT_GRAD_BLOCK);
    let all = blocks(g, &plan, bl);
    let per_run = crate::ops::threads::chunk_len(all.len());
    let partials: Vec<Vec<f32>> = all
        .par_chunks(per_run)
        .map(|run| {
            let mut v = Scratch::new(xi * g.cin * bl);
            let mut dm = Scratch::new(xi * g.cout * bl);
            let mut buf = Lanebuf::new(&plan, bl);
            let mut sum = vec![0f32; g.cout * xi * g.cin];
            for (i, &(b, (t0, len))) in run.iter().enumerate() {
                let image = &split[b * g.cin * plane..][..g.cin * plane];
                transform_input(image, g, &plan, (t0, len), &mut v, &mut buf);
                let dy_b = &dy[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
                transform_output_grad(dy_b, g, &plan, (t0, len), &mut dm, &mut buf);
                for e in 0..xi {
                    matmul_into(
                        Threads::One,
                        (g.cout, g.cin, len),
                        &mut sum,
                        View::new(e * g.cin, xi * g.cin, 1),
                        i > 0,
                        &dm,
                        View::new(e * g.cout * bl, bl, 1),
                        &v,
                        View::new(e * g.cin * bl, 1, bl),
                    );
                }
            }
            sum
        })
        .collect();
    let du = crate::ops::threads::sum_in_order(partials);
    // dW per output channel: the taps as lanes over input channels, each a weighted sum of
    // the ξ lanes of dU (the kernel transform's coefficients, transposed).
    let coef = plan.kernel_coefficients();
    let coef_t: Vec<f32> = (0..taps)
        .flat_map(|tap| coef.iter().skip(tap).step_by(taps).copied())
        .collect();
    let coef_t = Terms::new(&coef_t, xi);
    let mut dw = vec![0f32; g.cout * g.cin * taps];
    dw.par_chunks_mut(g.cin * taps)
        .zip(du.par_chunks(xi * g.cin))
        .for_each_init(
            || vec![0f32; taps * g.cin],
            |by_tap, (dwk, duk)| {
                let (src, dst) = (Lanes::new(0, g.cin, xi), Lanes::new(0, g.cin, taps));
                apply(&coef_t, duk, src, by_tap, dst, g.cin);
                for (c, kernel) in dwk.chunks_exact_mut(taps).enumerate() {
                    for (tap, value) in kernel.iter_mut().enumerate() {
                        *value = by_tap[tap * g.cin + c];
                    }
                }
            },
        );
    dw
}

/// `U = G_y g G_xᵀ` of every (C_out, C_in) kernel, laid out (C_out, ξ, C_in) so that `U_ξ` is
/// a strided C_out × C_in view and each output channel is one parallel chunk. Per output
/// channel: the kernel taps as lanes over input channels, each ξ one weighted sum of lanes.
fn transform_weights(w: &[f32], g: &Geometry, plan: &Plan) -> Scratch {
    let (xi, taps) = (plan.xi(), g.kh * g.kw);
    let coef = Terms::new(&plan.kernel_coefficients(), taps);
    let mut u = Scratch::new(g.cout * xi * g.cin);
    u.par_chunks_mut(xi * g.cin).enumerate().for_each_init(
        || vec![0f32; taps * g.cin],
        |by_tap, (k, uk)| {
            for (c, kernel) in w[k * g.cin * taps..][..g.cin * taps]
                .chunks_exact(taps)
                .enumerate()
            {
                for (tap, &value) in kernel.iter().enumerate() {
                    by_tap[tap * g.cin + c] = value;
                }
            }
            let (src, dst) = (Lanes::new(0, g.cin, taps), Lanes::new(0, g.cin, xi));
            apply(&coef, by_tap, src, uk, dst, g.cin);
        },
    );
    u
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stride-1 k×k convolution of `n` images `h`×`w` (padding k/2, 16 channels in and out).
    fn geometry(n: usize, h: usize, w: usize, k: usize) -> Geometry {
        Geometry {
            n,
            cin: 16,
            h,
            w,
            cout: 16,
            kh: k,
            kw: k,
            ho: h,
            wo: w,
            stride: [1, 1],
            pad: [k / 2, k / 2],
            dil: [1, 1],
        }
    }

    /// The weight gradient's block length: never above the target, and a block count divisible
    /// by the threads whenever at most twice the fewest blocks reach one.
    #[test]
    fn weight_gradient_blocks_split_evenly_over_the_threads() {
        // (threads, images, h, w, expected block length); 48×64 has 768 F(2, 3) tiles, 8×12 has 24
        let cases = [
            (2, 1, 48, 64, 192), // 3 blocks of 256 → 4 of 192
            (2, 2, 48, 64, 256), // 2 × 3 blocks: even already
            (3, 1, 48, 64, 256),
            (4, 1, 48, 64, 192),
            (4, 2, 48, 64, 192),
            (7, 1, 48, 64, 256), // 3..=6 blocks: none divisible by 7, keep the fewest
            (2, 1, 8, 12, 12),   // one block → two
        ];
        for (threads, n, h, w, expected) in cases {
            let g = geometry(n, h, w, 3);
            let plan = Plan::new(&g, Use::Training).unwrap();
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool");
            let bl = pool.install(|| balanced_block(&g, &plan, WEIGHT_GRAD_BLOCK));
            assert_eq!(bl, expected, "{threads} threads, {n} × {h}×{w}");
            let count = blocks(&g, &plan, bl).len();
            assert_eq!(count, n * plan.tiles().div_ceil(bl));
            assert!(bl <= WEIGHT_GRAD_BLOCK);
        }
    }

    /// The weight gradient's bits depend on the shape and the pool's thread count only: the
    /// same inputs give the same bits while other work competes for the pool's threads (rayon's
    /// adaptive splitting once made the partial sums, and so the bits, follow the load).
    #[test]
    fn weight_gradient_bits_do_not_depend_on_the_load() {
        // 24 blocks of tiles: more than rayon's splitter makes without stealing (8 with 4
        // threads), so a stolen job would split the sums differently.
        let g = geometry(4, 64, 96, 3);
        let x: Vec<f32> = (0..g.n * g.cin * g.h * g.w)
            .map(|i| ((i * 7919 % 1009) as f32 - 504.0) * 1e-3)
            .collect();
        let dy: Vec<f32> = (0..g.n * g.cout * g.ho * g.wo)
            .map(|i| ((i * 104_729 % 2003) as f32 - 1001.0) * 1e-2)
            .collect();
        let changed = crate::ops::threads::first_round_that_differs_under_load(4, 20, || {
            vec![weight_grad(&x, &dy, &g)]
        });
        assert_eq!(
            changed, None,
            "the weight gradient's bits changed under load in this round"
        );
    }

    /// Each axis transform computes the correlation it stands for, exactly on small integers.
    #[test]
    fn axis_transforms_compute_the_correlation() {
        for (r, use_) in [1, 3, 5]
            .into_iter()
            .flat_map(|r| [(r, Use::Inference), (r, Use::Training)])
        {
            let axis = Axis::for_extent(r, use_).unwrap();
            let (m, n) = (axis.m, axis.n);
            let d: Vec<f64> = (0..n)
                .map(|i| (i as f64 * 7.0 + 3.0) % 11.0 - 5.0)
                .collect();
            let k: Vec<f64> = (0..r).map(|i| (i as f64 * 5.0 + 1.0) % 7.0 - 3.0).collect();
            let gk: Vec<f64> = (0..n)
                .map(|i| (0..r).map(|l| axis.g[i * r + l] * k[l]).sum())
                .collect();
            let bd: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|l| f64::from(axis.bt[i * n + l]) * d[l]).sum())
                .collect();
            for o in 0..m {
                let ours: f64 = (0..n)
                    .map(|i| f64::from(axis.at[o * n + i]) * gk[i] * bd[i])
                    .sum();
                let direct: f64 = (0..r).map(|l| k[l] * d[o + l]).sum();
                assert!(
                    (ours - direct).abs() < 1e-9,
                    "F({m}, {r}) output {o}: {ours} vs {direct}"
                );
            }
        }
    }

    /// Every compiled copy of the lane transform this processor runs gives the portable copy's
    /// bits, for every transform matrix the plans use and lengths that leave every remainder.
    #[test]
    fn lane_transform_copies_agree_with_the_portable_one() {
        use tiles::{Lanes, Terms, apply_with};
        let mut tested = Vec::new();
        for set in crate::ops::simd::Isa::ALL
            .into_iter()
            .filter(|s| s.supported())
        {
            for r in [1, 3, 5] {
                for use_ in [Use::Inference, Use::Training] {
                    let axis = Axis::for_extent(r, use_).unwrap();
                    let n = axis.n;
                    let mut bt: Vec<f32> = axis.bt.to_vec();
                    // a dense row too, so no path is only ever fed sparse rows
                    bt[..n]
                        .iter_mut()
                        .enumerate()
                        .for_each(|(i, v)| *v += 0.25 * i as f32);
                    let terms = Terms::new(&bt, n);
                    for len in [1, 15, 16, 17, 40, 129] {
                        let src: Vec<f32> = (0..n * len)
                            .map(|i| ((i * 29) % 97) as f32 * 0.013 - 0.6)
                            .collect();
                        let (mut want, mut got) = (vec![0f32; n * len], vec![0f32; n * len]);
                        let (ls, ld) = (Lanes::new(0, len, n), Lanes::new(0, len, n));
                        apply_with(
                            crate::ops::simd::Isa::Portable,
                            &terms,
                            &src,
                            ls,
                            &mut want,
                            ld,
                            len,
                        );
                        apply_with(set, &terms, &src, ls, &mut got, ld, len);
                        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                        assert_eq!(
                            bits(&got),
                            bits(&want),
                            "{} copy, F(m, {r}), length {len}",
                            set.name()
                        );
                    }
                }
            }
            tested.push(set.name());
        }
        eprintln!("lane transform copies checked: {tested:?}");
    }
}
