//! 3×3 stride-1 convolutions by Winograd's minimal filtering F(2×2, 3×3).
//!
//! Every 2×2 block of outputs is computed from the 4×4 input tile under it: the tile and the
//! kernel are mapped into a 4×4 "transform domain" (`V = Bᵀ d B`, `U = G g Gᵀ`), multiplied
//! there element by element and summed over input channels, and mapped back (`Y = Aᵀ M A`).
//! Summed over channels, each of the 16 transform positions ξ is one matrix product
//!
//! ```text
//! M_ξ (C_out × tiles) = U_ξ (C_out × C_in) · V_ξ (C_in × tiles)
//! ```
//!
//! so a 3×3 convolution costs 16 multiplications per 4 outputs instead of 36: 2.25× fewer
//! floating-point operations in the products, for two cheap transforms that only add and halve.
//! The matrices hold 0, ±1 and ½ (exact in binary), so the rounding error stays at the level of
//! a direct convolution (the unit tests compare with Burn's to 1e-5).
//!
//! The input gradient of such a convolution is itself one (the kernel flipped and its channel
//! axes swapped, padding `2 − p`), so the backward reuses the forward; the weight gradient stays
//! with the shifted-view products.

use rayon::prelude::*;

use super::Geometry;
use super::views::{View, matmul_into};

/// Below these sizes the products are too thin or too few for the transforms to pay.
const MIN_CIN: usize = 16;
const MIN_COUT: usize = 16;
const MIN_TILES: usize = 64;

/// Transform positions per tile (4 × 4).
const XI: usize = 16;

/// The grid of 2×2 output tiles of one image.
struct Tiles {
    rows: usize,
    cols: usize,
}

impl Tiles {
    fn new(g: &Geometry) -> Self {
        Tiles {
            rows: g.ho.div_ceil(2),
            cols: g.wo.div_ceil(2),
        }
    }

    fn count(&self) -> usize {
        self.rows * self.cols
    }
}

/// Whether the forward of `g` takes this path: a 3×3 kernel, stride 1, no dilation, and
/// enough channels and tiles.
pub(super) fn applies(g: &Geometry) -> bool {
    g.kh == 3
        && g.kw == 3
        && g.stride == [1, 1]
        && g.dil == [1, 1]
        && g.cin >= MIN_CIN
        && g.cout >= MIN_COUT
        && g.ho > 0
        && g.wo > 0
        && Tiles::new(g).count() >= MIN_TILES
}

/// Whether the input gradient of `g` takes this path (as the forward of [`transposed`]).
pub(super) fn applies_to_input_grad(g: &Geometry) -> bool {
    applies(g) && g.pad[0] <= 2 && g.pad[1] <= 2 && applies(&transposed(g))
}

/// The convolution whose forward is the input gradient of `g`: output gradient in, input
/// gradient out, padding `2 − p` (only for `applies(g)` and p ≤ 2).
fn transposed(g: &Geometry) -> Geometry {
    Geometry {
        n: g.n,
        cin: g.cout,
        h: g.ho,
        w: g.wo,
        cout: g.cin,
        kh: 3,
        kw: 3,
        ho: g.h,
        wo: g.w,
        stride: [1, 1],
        pad: [2 - g.pad[0], 2 - g.pad[1]],
        dil: [1, 1],
    }
}

/// `Y` (N, C_out, ho, wo) of input `x` (N, C_in, H, W) and weight `w` (C_out, C_in, 3, 3),
/// both contiguous.
pub(super) fn forward(x: &[f32], w: &[f32], g: &Geometry) -> Vec<f32> {
    let tiles = Tiles::new(g);
    let t = tiles.count();
    let u = transform_weights(w, g.cout, g.cin);
    let mut v = vec![0f32; g.cin * XI * t];
    let mut m = vec![0f32; g.cout * XI * t];
    let mut y = vec![0f32; g.n * g.cout * g.ho * g.wo];
    for b in 0..g.n {
        let image = &x[b * g.cin * g.h * g.w..][..g.cin * g.h * g.w];
        transform_input(image, g, &tiles, &mut v);
        for xi in 0..XI {
            matmul_into(
                (g.cout, t, g.cin),
                &mut m,
                View::new(xi * t, XI * t, 1),
                false,
                &u,
                View::new(xi * g.cin, XI * g.cin, 1),
                &v,
                View::new(xi * t, XI * t, 1),
            );
        }
        let out = &mut y[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
        transform_output(&m, g, &tiles, out);
    }
    y
}

/// `dX` (N, C_in, H, W) of the output gradient `dy` (N, C_out, ho, wo): the forward of the
/// flipped, channel-swapped kernel (see [`transposed`]).
pub(super) fn input_grad(w: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let mut flipped = vec![0f32; g.cin * g.cout * 9];
    flipped
        .par_chunks_mut(g.cout * 9)
        .enumerate()
        .for_each(|(ci, dst)| {
            for co in 0..g.cout {
                let src = &w[(co * g.cin + ci) * 9..][..9];
                for (i, d) in dst[co * 9..][..9].iter_mut().enumerate() {
                    *d = src[8 - i];
                }
            }
        });
    forward(dy, &flipped, &transposed(g))
}

/// `U = G g Gᵀ` of every (C_out, C_in) kernel, laid out (C_out, 16, C_in) so that `U_ξ` is a
/// strided C_out × C_in view and each output channel is one parallel chunk.
fn transform_weights(w: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    let mut u = vec![0f32; cout * XI * cin];
    u.par_chunks_mut(XI * cin).enumerate().for_each(|(k, uk)| {
        for c in 0..cin {
            let g = &w[(k * cin + c) * 9..][..9];
            // G g (4×3): along the kernel's rows.
            let mut a = [[0f32; 3]; 4];
            for s in 0..3 {
                let (g0, g1, g2) = (g[s], g[3 + s], g[6 + s]);
                a[0][s] = g0;
                a[1][s] = 0.5 * (g0 + g1 + g2);
                a[2][s] = 0.5 * (g0 - g1 + g2);
                a[3][s] = g2;
            }
            // (G g) Gᵀ (4×4): along its columns.
            for (r, &[t0, t1, t2]) in a.iter().enumerate() {
                let row = [t0, 0.5 * (t0 + t1 + t2), 0.5 * (t0 - t1 + t2), t2];
                for (s, value) in row.into_iter().enumerate() {
                    uk[(4 * r + s) * cin + c] = value;
                }
            }
        }
    });
    u
}

/// `V = Bᵀ d B` of every 4×4 input tile (stride 2, zero outside the image) of one image
/// (C_in, H, W) into `v`, laid out (C_in, 16, tiles).
///
/// One row of tiles at a time, each of the 16 tile positions as a vector over the row's tiles,
/// so that every step is an element-wise loop over contiguous arrays (vectorised) and every
/// write a contiguous run of `v`.
fn transform_input(x: &[f32], g: &Geometry, tiles: &Tiles, v: &mut [f32]) {
    let (t, cols) = (tiles.count(), tiles.cols);
    // The padded plane every tile reads from: 2 more rows and columns than the tiles cover.
    let (ph, pw) = (2 * tiles.rows + 2, 2 * tiles.cols + 2);
    debug_assert!(g.h + g.pad[0] <= ph && g.w + g.pad[1] <= pw);
    v.par_chunks_mut(XI * t).enumerate().for_each_init(
        || (vec![0f32; ph * pw], vec![0f32; 2 * XI * cols]),
        |(padded, scratch), (c, vc)| {
            padded.fill(0.0);
            let plane = &x[c * g.h * g.w..][..g.h * g.w];
            for (iy, row) in plane.chunks_exact(g.w).enumerate() {
                padded[(iy + g.pad[0]) * pw + g.pad[1]..][..g.w].copy_from_slice(row);
            }
            let (d, e) = scratch.split_at_mut(XI * cols);
            for i in 0..tiles.rows {
                // d[4r + s][j] = element (r, s) of tile (i, j).
                for r in 0..4 {
                    let row = &padded[(2 * i + r) * pw..][..pw];
                    for s in 0..4 {
                        let lane = &mut d[(4 * r + s) * cols..][..cols];
                        for (j, value) in lane.iter_mut().enumerate() {
                            *value = row[2 * j + s];
                        }
                    }
                }
                // Bᵀ d along the tile's rows: e[4s + r'] (column s of row r').
                for s in 0..4 {
                    let lane = |r: usize| &d[(4 * r + s) * cols..][..cols];
                    let out = quad(&mut e[4 * s * cols..][..4 * cols], cols);
                    input_rows([lane(0), lane(1), lane(2), lane(3)], out);
                }
                // (Bᵀ d) B along its columns, straight into v's rows of this tile row.
                for r in 0..4 {
                    let lane = |s: usize| &e[(4 * s + r) * cols..][..cols];
                    let mut out = quad(&mut vc[4 * r * t..][..4 * t], t);
                    for o in out.iter_mut() {
                        *o = &mut std::mem::take(o)[i * cols..][..cols];
                    }
                    input_rows([lane(0), lane(1), lane(2), lane(3)], out);
                }
            }
        },
    );
}

/// The four consecutive `len`-long slices at the start of `buf`.
fn quad(buf: &mut [f32], len: usize) -> [&mut [f32]; 4] {
    let (a, rest) = buf.split_at_mut(len);
    let (b, rest) = rest.split_at_mut(len);
    let (c, rest) = rest.split_at_mut(len);
    [a, b, c, &mut rest[..len]]
}

/// One application of `Bᵀ` to four rows of values, element-wise:
/// `(d0 − d2, d1 + d2, d2 − d1, d1 − d3)`.
fn input_rows([d0, d1, d2, d3]: [&[f32]; 4], [o0, o1, o2, o3]: [&mut [f32]; 4]) {
    let n = o0.len();
    let (d0, d1, d2, d3) = (&d0[..n], &d1[..n], &d2[..n], &d3[..n]);
    let (o1, o2, o3) = (&mut o1[..n], &mut o2[..n], &mut o3[..n]);
    for j in 0..n {
        o0[j] = d0[j] - d2[j];
        o1[j] = d1[j] + d2[j];
        o2[j] = d2[j] - d1[j];
        o3[j] = d1[j] - d3[j];
    }
}

/// `Y = Aᵀ M A` of every tile of `m` (C_out, 16, tiles) into one image's output
/// (C_out, ho, wo), the odd last row or column of tiles cut back. Vectorised over each row of
/// tiles like [`transform_input`].
fn transform_output(m: &[f32], g: &Geometry, tiles: &Tiles, y: &mut [f32]) {
    let (t, cols) = (tiles.count(), tiles.cols);
    y.par_chunks_mut(g.ho * g.wo).enumerate().for_each_init(
        || vec![0f32; 12 * cols],
        |scratch, (k, plane)| {
            let mk = &m[k * XI * t..][..XI * t];
            let (a, out) = scratch.split_at_mut(8 * cols);
            for i in 0..tiles.rows {
                let lane = |r: usize, s: usize| &mk[(4 * r + s) * t + i * cols..][..cols];
                // Aᵀ M along the rows: a[2s + r'].
                for s in 0..4 {
                    let (a0, a1) = a[2 * s * cols..][..2 * cols].split_at_mut(cols);
                    output_rows([lane(0, s), lane(1, s), lane(2, s), lane(3, s)], [a0, a1]);
                }
                for r in 0..2 {
                    let oy = 2 * i + r;
                    if oy >= g.ho {
                        break;
                    }
                    // (Aᵀ M) A along the columns, then interleaved into the output row.
                    let a_lane = |s: usize| &a[(2 * s + r) * cols..][..cols];
                    let (y0, y1) = out[..2 * cols].split_at_mut(cols);
                    output_rows([a_lane(0), a_lane(1), a_lane(2), a_lane(3)], [y0, y1]);
                    let row = &mut plane[oy * g.wo..][..g.wo];
                    for (ox, value) in row.iter_mut().enumerate() {
                        *value = out[(ox % 2) * cols + ox / 2];
                    }
                }
            }
        },
    );
}

/// One application of `Aᵀ` to four rows of values, element-wise: `(m0 + m1 + m2, m1 − m2 − m3)`.
fn output_rows([m0, m1, m2, m3]: [&[f32]; 4], [o0, o1]: [&mut [f32]; 2]) {
    let n = o0.len();
    let (m0, m1, m2, m3) = (&m0[..n], &m1[..n], &m2[..n], &m3[..n]);
    let o1 = &mut o1[..n];
    for j in 0..n {
        o0[j] = m0[j] + m1[j] + m2[j];
        o1[j] = m1[j] - m2[j] - m3[j];
    }
}
