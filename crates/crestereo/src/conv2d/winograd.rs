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
//! of two; the kernel transform runs in float64. Used: F(2, 3) per axis for 3×3 kernels
//! (2.25× fewer products) and F(4, 5) for the GRU's 1×5 and 5×1 (2.5× fewer); the unit tests
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
use super::views::{View, matmul_into};

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
    fn for_extent(r: usize) -> Option<Self> {
        match r {
            1 => Some(Axis::new(1, 1, &[])),
            3 => Some(Axis::new(2, 3, &[0.0, 1.0, -1.0])),
            5 => Some(Axis::new(4, 5, &[0.0, 1.0, -1.0, 2.0, -2.0, 0.5, -0.5])),
            _ => None,
        }
    }
}

/// The two axes of a convolution's transform and its grid of output tiles per image.
struct Plan {
    y: Axis,
    x: Axis,
    rows: usize,
    cols: usize,
}

impl Plan {
    fn new(g: &Geometry) -> Option<Self> {
        let (y, x) = (Axis::for_extent(g.kh)?, Axis::for_extent(g.kw)?);
        Some(Plan {
            rows: g.ho.div_ceil(y.m),
            cols: g.wo.div_ceil(x.m),
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
        && Plan::new(g).is_some()
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

/// `Y` (N, C_out, ho, wo) of input `x` (N, C_in, H, W) and weight `w` (C_out, C_in, kh, kw),
/// both contiguous.
pub(super) fn forward(x: &[f32], w: &[f32], g: &Geometry) -> Vec<f32> {
    let plan = Plan::new(g).expect("checked by applies");
    let (t, xi) = (plan.tiles(), plan.xi());
    let u = transform_weights(w, g, &plan);
    let mut v = vec![0f32; g.cin * xi * t];
    let mut m = vec![0f32; g.cout * xi * t];
    let mut y = vec![0f32; g.n * g.cout * g.ho * g.wo];
    for b in 0..g.n {
        let image = &x[b * g.cin * g.h * g.w..][..g.cin * g.h * g.w];
        transform_input(image, g, &plan, &mut v);
        for e in 0..xi {
            matmul_into(
                (g.cout, t, g.cin),
                &mut m,
                View::new(e * t, xi * t, 1),
                false,
                &u,
                View::new(e * g.cin, xi * g.cin, 1),
                &v,
                View::new(e * t, xi * t, 1),
            );
        }
        let out = &mut y[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
        transform_output(&m, g, &plan, out);
    }
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
    forward(dy, &flipped, &transposed(g))
}

/// `dW` (C_out, C_in, kh, kw) of input `x` and output gradient `dy`, in the transform domain:
/// `dU_ξ = Σ_images dM_ξ · V_ξᵀ` (one product per ξ, the forward's reduced size) with
/// `dM = A_y dY A_xᵀ` per tile, then `dW = G_yᵀ dU G_x` (the forward's transforms transposed).
pub(super) fn weight_grad(x: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let plan = Plan::new(g).expect("checked by applies");
    let (t, xi, taps) = (plan.tiles(), plan.xi(), g.kh * g.kw);
    let mut v = vec![0f32; g.cin * xi * t];
    let mut dm = vec![0f32; g.cout * xi * t];
    let mut du = vec![0f32; g.cout * xi * g.cin];
    for b in 0..g.n {
        transform_input(
            &x[b * g.cin * g.h * g.w..][..g.cin * g.h * g.w],
            g,
            &plan,
            &mut v,
        );
        let dy_b = &dy[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
        transform_output_grad(dy_b, g, &plan, &mut dm);
        for e in 0..xi {
            matmul_into(
                (g.cout, g.cin, t),
                &mut du,
                View::new(e * g.cin, xi * g.cin, 1),
                b > 0,
                &dm,
                View::new(e * t, xi * t, 1),
                &v,
                View::new(e * t, 1, xi * t),
            );
        }
    }
    let coef = plan.kernel_coefficients();
    let mut dw = vec![0f32; g.cout * g.cin * taps];
    dw.par_chunks_mut(g.cin * taps)
        .zip(du.par_chunks(xi * g.cin))
        .for_each_init(
            || vec![0f32; taps * g.cin],
            |by_tap, (dwk, duk)| {
                let src: Vec<&[f32]> = duk.chunks_exact(g.cin).collect();
                for (tap, dst) in by_tap.chunks_exact_mut(g.cin).enumerate() {
                    let column: Vec<f32> = (0..xi).map(|e| coef[e * taps + tap]).collect();
                    combine(dst, &column, &src);
                }
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
fn transform_weights(w: &[f32], g: &Geometry, plan: &Plan) -> Vec<f32> {
    let (xi, taps) = (plan.xi(), g.kh * g.kw);
    let coef = plan.kernel_coefficients();
    let mut u = vec![0f32; g.cout * xi * g.cin];
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
            let src: Vec<&[f32]> = by_tap.chunks_exact(g.cin).collect();
            for (e, dst) in uk.chunks_exact_mut(g.cin).enumerate() {
                combine(dst, &coef[e * taps..][..taps], &src);
            }
        },
    );
    u
}

/// The most points an axis transform has (F(4, 5)).
const MAX_N: usize = 8;

/// The first `n` (≤ [`MAX_N`]) lanes `lane(0..n)`, without allocating.
fn lanes<'a>(n: usize, lane: impl Fn(usize) -> &'a [f32]) -> [&'a [f32]; MAX_N] {
    std::array::from_fn(|k| if k < n { lane(k) } else { &[] })
}

/// `dst = Σ_k coef[k] · src[k]`, element-wise over equal-length lanes, zero terms skipped.
fn combine(dst: &mut [f32], coef: &[f32], src: &[&[f32]]) {
    dst.fill(0.0);
    for (&c, s) in coef.iter().zip(src) {
        if c == 0.0 {
            continue;
        }
        let s = &s[..dst.len()];
        for (d, &v) in dst.iter_mut().zip(s) {
            *d += c * v;
        }
    }
}

/// Tiles transformed together: long enough lanes for vectorised loops, short enough for the
/// scratch lanes (ξ of them, twice) to stay in cache.
const BLOCK: usize = 256;

/// Offset of each tile's top-left input in the padded plane (row stride `pw`), for the block
/// of tiles starting at `t0`.
fn tile_origins(plan: &Plan, pw: usize, t0: usize, origins: &mut [usize]) {
    for (q, o) in origins.iter_mut().enumerate() {
        let (i, j) = ((t0 + q) / plan.cols, (t0 + q) % plan.cols);
        *o = plan.y.m * i * pw + plan.x.m * j;
    }
}

/// `V = B_yᵀ d B_x` of every input tile (stride m, zero outside the image) of one image
/// (C_in, H, W) into `v`, laid out (C_in, ξ, tiles).
///
/// Tiles go in blocks, each tile position as a lane over the block's tiles, so that every
/// transform step is an element-wise loop over contiguous lanes (vectorised) and every write
/// a contiguous run of `v`.
fn transform_input(x: &[f32], g: &Geometry, plan: &Plan, v: &mut [f32]) {
    let (ay, ax) = (&plan.y, &plan.x);
    let (t, xi) = (plan.tiles(), plan.xi());
    // The padded plane every tile reads from.
    let (ph, pw) = (ay.m * plan.rows + ay.r - 1, ax.m * plan.cols + ax.r - 1);
    debug_assert!(g.h + g.pad[0] <= ph && g.w + g.pad[1] <= pw);
    v.par_chunks_mut(xi * t).enumerate().for_each_init(
        || {
            (
                vec![0f32; ph * pw],
                vec![0f32; 2 * xi * BLOCK],
                vec![0usize; BLOCK],
            )
        },
        |(padded, scratch, origins), (c, vc)| {
            padded.fill(0.0);
            let plane = &x[c * g.h * g.w..][..g.h * g.w];
            for (iy, row) in plane.chunks_exact(g.w).enumerate() {
                padded[(iy + g.pad[0]) * pw + g.pad[1]..][..g.w].copy_from_slice(row);
            }
            let (d, e) = scratch.split_at_mut(xi * BLOCK);
            for t0 in (0..t).step_by(BLOCK) {
                let len = BLOCK.min(t - t0);
                let origins = &mut origins[..len];
                tile_origins(plan, pw, t0, origins);
                // d[r·n_x + s][q] = element (r, s) of tile t0 + q.
                for r in 0..ay.n {
                    for s in 0..ax.n {
                        let lane = &mut d[(r * ax.n + s) * BLOCK..][..len];
                        let at = r * pw + s;
                        for (value, &o) in lane.iter_mut().zip(origins.iter()) {
                            *value = padded[o + at];
                        }
                    }
                }
                // B_yᵀ d along the tiles' rows: e[r'·n_x + s].
                for r2 in 0..ay.n {
                    for s in 0..ax.n {
                        let src = lanes(ay.n, |r| &d[(r * ax.n + s) * BLOCK..][..len]);
                        let dst = &mut e[(r2 * ax.n + s) * BLOCK..][..len];
                        combine(dst, &ay.bt[r2 * ay.n..][..ay.n], &src[..ay.n]);
                    }
                }
                // (B_yᵀ d) B_x along their columns, straight into v.
                for r2 in 0..ay.n {
                    let src = lanes(ax.n, |s| &e[(r2 * ax.n + s) * BLOCK..][..len]);
                    for s2 in 0..ax.n {
                        let dst = &mut vc[(r2 * ax.n + s2) * t + t0..][..len];
                        combine(dst, &ax.bt[s2 * ax.n..][..ax.n], &src[..ax.n]);
                    }
                }
            }
        },
    );
}

/// `Y = A_yᵀ M A_x` of every tile of `m` (C_out, ξ, tiles) into one image's output
/// (C_out, ho, wo), tiles reaching past the map cut back. In blocks of tiles like
/// [`transform_input`].
fn transform_output(m: &[f32], g: &Geometry, plan: &Plan, y: &mut [f32]) {
    let (ay, ax) = (&plan.y, &plan.x);
    let (t, xi) = (plan.tiles(), plan.xi());
    y.par_chunks_mut(g.ho * g.wo).enumerate().for_each_init(
        || vec![0f32; (ay.m * ax.n + ax.m) * BLOCK],
        |scratch, (k, plane)| {
            let mk = &m[k * xi * t..][..xi * t];
            let (a, out) = scratch.split_at_mut(ay.m * ax.n * BLOCK);
            for t0 in (0..t).step_by(BLOCK) {
                let len = BLOCK.min(t - t0);
                // A_yᵀ M along the rows: a[a'·n_x + s].
                for a2 in 0..ay.m {
                    for s in 0..ax.n {
                        let src = lanes(ay.n, |r| &mk[(r * ax.n + s) * t + t0..][..len]);
                        let dst = &mut a[(a2 * ax.n + s) * BLOCK..][..len];
                        combine(dst, &ay.at[a2 * ay.n..][..ay.n], &src[..ay.n]);
                    }
                }
                for a2 in 0..ay.m {
                    // (A_yᵀ M) A_x along the columns: out[b'][q], then into the map.
                    let src = lanes(ax.n, |s| &a[(a2 * ax.n + s) * BLOCK..][..len]);
                    for b2 in 0..ax.m {
                        let dst = &mut out[b2 * BLOCK..][..len];
                        combine(dst, &ax.at[b2 * ax.n..][..ax.n], &src[..ax.n]);
                    }
                    for q in 0..len {
                        let (i, j) = ((t0 + q) / plan.cols, (t0 + q) % plan.cols);
                        let oy = ay.m * i + a2;
                        if oy >= g.ho {
                            continue;
                        }
                        let row = &mut plane[oy * g.wo..][..g.wo];
                        for b2 in 0..ax.m.min(g.wo - ax.m * j) {
                            row[ax.m * j + b2] = out[b2 * BLOCK + q];
                        }
                    }
                }
            }
        },
    );
}

/// `dM = A_y dY A_xᵀ` of every output tile of one image's output gradient (C_out, ho, wo)
/// into `dm`, laid out (C_out, ξ, tiles): the transpose of [`transform_output`] (outputs past
/// the map count as zero).
fn transform_output_grad(dy: &[f32], g: &Geometry, plan: &Plan, dm: &mut [f32]) {
    let (ay, ax) = (&plan.y, &plan.x);
    let (t, xi) = (plan.tiles(), plan.xi());
    // Columns of Aᵀ: how each output of a tile weighs transform point r (or s).
    let column = |axis: &Axis, r: usize| -> Vec<f32> {
        (0..axis.m).map(|a| axis.at[a * axis.n + r]).collect()
    };
    let (cy, cx): (Vec<Vec<f32>>, Vec<Vec<f32>>) = (
        (0..ay.n).map(|r| column(ay, r)).collect(),
        (0..ax.n).map(|s| column(ax, s)).collect(),
    );
    dm.par_chunks_mut(xi * t).enumerate().for_each_init(
        || vec![0f32; (ay.m * ax.m + ay.n * ax.m) * BLOCK],
        |scratch, (k, dmk)| {
            let plane = &dy[k * g.ho * g.wo..][..g.ho * g.wo];
            let (d, a) = scratch.split_at_mut(ay.m * ax.m * BLOCK);
            for t0 in (0..t).step_by(BLOCK) {
                let len = BLOCK.min(t - t0);
                // d[a·m_x + b][q] = output (a, b) of tile t0 + q, zero past the map.
                for a2 in 0..ay.m {
                    for b2 in 0..ax.m {
                        let lane = &mut d[(a2 * ax.m + b2) * BLOCK..][..len];
                        for (q, value) in lane.iter_mut().enumerate() {
                            let (i, j) = ((t0 + q) / plan.cols, (t0 + q) % plan.cols);
                            let (oy, ox) = (ay.m * i + a2, ax.m * j + b2);
                            *value = if oy < g.ho && ox < g.wo {
                                plane[oy * g.wo + ox]
                            } else {
                                0.0
                            };
                        }
                    }
                }
                // A_y dY along the rows: a[r·m_x + b].
                for (r, coef) in cy.iter().enumerate() {
                    for b2 in 0..ax.m {
                        let src = lanes(ay.m, |a2| &d[(a2 * ax.m + b2) * BLOCK..][..len]);
                        let dst = &mut a[(r * ax.m + b2) * BLOCK..][..len];
                        combine(dst, coef, &src[..ay.m]);
                    }
                }
                // (A_y dY) A_xᵀ along the columns, straight into dm.
                for r in 0..ay.n {
                    let src = lanes(ax.m, |b2| &a[(r * ax.m + b2) * BLOCK..][..len]);
                    for (s, coef) in cx.iter().enumerate() {
                        let dst = &mut dmk[(r * ax.n + s) * t + t0..][..len];
                        combine(dst, coef, &src[..ax.m]);
                    }
                }
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each axis transform computes the correlation it stands for, exactly on small integers.
    #[test]
    fn axis_transforms_compute_the_correlation() {
        for r in [1, 3, 5] {
            let axis = Axis::for_extent(r).unwrap();
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
}
