//! CPU kernels of the fused AGCL ops on contiguous float32 slices (rayon over image rows).
//!
//! Layouts: feature maps channel-last (N, H, W, C) so the inner loops over channels are
//! contiguous; flow (N, 2, H, W), offsets (N, 2K, H, W) and upstream gradients as the tensors
//! come (NCHW). Outputs are written channel-last per row and permuted by the caller.

use rayon::prelude::*;

use super::CorrSpec;

/// Sizes of one feature map batch.
#[derive(Clone, Copy, Debug)]
pub struct Dims {
    pub n: usize,
    pub c: usize,
    pub h: usize,
    pub w: usize,
}

const NONE: usize = usize::MAX;

/// The four corners of a bilinear sample, zero outside the image (PyTorch's
/// `grid_sample(align_corners=True, padding_mode="zeros")` on pixel coordinates).
/// Corner order: (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bilinear {
    /// Flat pixel index `y·W + x` of each corner, or `NONE` outside.
    pub idx: [usize; 4],
    pub weight: [f32; 4],
    pub wx: [f32; 2],
    pub wy: [f32; 2],
}

impl Bilinear {
    #[inline]
    pub fn new(px: f32, py: f32, h: usize, w: usize) -> Self {
        let x0 = px.floor();
        let y0 = py.floor();
        let wx1 = px - x0;
        let wy1 = py - y0;
        let wx0 = 1.0 - wx1;
        let wy0 = 1.0 - wy1;
        let (wm, hm) = ((w - 1) as f32, (h - 1) as f32);
        let at = |xx: f32, yy: f32| {
            if xx >= 0.0 && yy >= 0.0 && xx <= wm && yy <= hm {
                yy as usize * w + xx as usize
            } else {
                NONE
            }
        };
        Bilinear {
            idx: [
                at(x0, y0),
                at(x0 + 1.0, y0),
                at(x0, y0 + 1.0),
                at(x0 + 1.0, y0 + 1.0),
            ],
            weight: [wx0 * wy0, wx1 * wy0, wx0 * wy1, wx1 * wy1],
            wx: [wx0, wx1],
            wy: [wy0, wy1],
        }
    }

    /// Channel vectors of the four corners in a channel-last image (zeros outside).
    #[inline]
    fn corners<'a>(&self, img: &'a [f32], zeros: &'a [f32], c: usize) -> [&'a [f32]; 4] {
        self.idx.map(|i| {
            if i == NONE {
                zeros
            } else {
                &img[i * c..(i + 1) * c]
            }
        })
    }
}

/// Splits `rows` parallel row tasks into about one chunk per thread (the gradient kernels keep
/// one scatter buffer per chunk).
fn rows_per_chunk(rows: usize) -> usize {
    crate::ops::threads::chunk_len(rows)
}

/// Where the offset correlation samples the right map: candidate k of pixel (x, y) at
/// `(x, y) + flow + window offset k + learned offset k`, summed in the reference's order.
struct OffsetSampling<'a> {
    spec: &'a CorrSpec,
    /// The learned offsets, (N, 2K, H, W).
    offset: &'a [f32],
    k_num: usize,
    h: usize,
    w: usize,
}

impl<'a> OffsetSampling<'a> {
    fn new(spec: &'a CorrSpec, offset: &'a [f32], d: Dims) -> Self {
        let (k_num, h, w) = (spec.candidates(), d.h, d.w);
        OffsetSampling {
            spec,
            offset,
            k_num,
            h,
            w,
        }
    }

    /// The bilinear footprint of candidate `k` of pixel (`x`, `y`) of image `n`, whose flow is
    /// (`fx`, `fy`).
    #[inline]
    fn at(&self, n: usize, k: usize, x: usize, y: usize, fx: f32, fy: f32) -> Bilinear {
        let (k_num, h, w) = (self.k_num, self.h, self.w);
        let (hw, p) = (h * w, y * w + x);
        let ox = self.offset[(n * 2 * k_num + 2 * k) * hw + p];
        let oy = self.offset[(n * 2 * k_num + 2 * k + 1) * hw + p];
        let (dx, dy) = self.spec.window_offset(k);
        let px = x as f32 + fx + dx as f32 + ox;
        let py = y as f32 + fy + dy as f32 + oy;
        Bilinear::new(px, py, h, w)
    }
}

/// Group-wise correlation of one candidate: the mean product of `l` and `r` over each group of
/// `cg` channels, group `g` written to `out[g * stride]`.
#[inline]
fn group_correlation(l: &[f32], r: &[f32], cg: usize, out: &mut [f32], stride: usize) {
    for (g, (lg, rg)) in l.chunks_exact(cg).zip(r.chunks_exact(cg)).enumerate() {
        let dot: f32 = lg.iter().zip(rg).map(|(a, b)| a * b).sum();
        out[g * stride] = dot / cg as f32;
    }
}

/// Offset correlation forward. `left`, `right`: (N, H, W, C); `flow`: (N, 2, H, W);
/// `offset`: (N, 2K, H, W). Returns (N, H, W, G·K).
pub fn offset_corr_forward(
    left: &[f32],
    right: &[f32],
    flow: &[f32],
    offset: &[f32],
    d: Dims,
    spec: CorrSpec,
) -> Vec<f32> {
    let Dims { n: _, c, h, w } = d;
    let k_num = spec.candidates();
    let g_num = spec.groups;
    let cg = c / g_num;
    let gk = g_num * k_num;
    let hw = h * w;
    let mut out = vec![0f32; d.n * hw * gk];
    let zeros = vec![0f32; c];
    let sampling = OffsetSampling::new(&spec, offset, d);
    out.par_chunks_mut(w * gk)
        .enumerate()
        .for_each(|(row, out_row)| {
            let (n, y) = (row / h, row % h);
            let mut sample = vec![0f32; c];
            let img = &right[n * hw * c..(n + 1) * hw * c];
            for x in 0..w {
                let p = y * w + x;
                let l = &left[(n * hw + p) * c..(n * hw + p + 1) * c];
                let fx = flow[(n * 2) * hw + p];
                let fy = flow[(n * 2 + 1) * hw + p];
                for k in 0..k_num {
                    let b = sampling.at(n, k, x, y, fx, fy);
                    let [r0, r1, r2, r3] = b.corners(img, &zeros, c);
                    let [w0, w1, w2, w3] = b.weight;
                    for i in 0..c {
                        sample[i] = w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i];
                    }
                    group_correlation(l, &sample, cg, &mut out_row[x * gk + k..], k_num);
                }
            }
        });
    out
}

/// Gradients of [`offset_corr_forward`].
#[derive(Debug, Default)]
pub struct OffsetCorrGrads {
    /// (N, H, W, C)
    pub left: Vec<f32>,
    /// (N, H, W, C)
    pub right: Vec<f32>,
    /// (N, H, W, 2)
    pub flow: Vec<f32>,
    /// (N, H, W, 2K)
    pub offset: Vec<f32>,
}

/// Offset correlation backward; `grad`: (N, G·K, H, W). The right map's gradient is a scatter:
/// each row chunk accumulates into its own buffer, summed at the end.
#[allow(clippy::too_many_arguments)]
pub fn offset_corr_backward(
    left: &[f32],
    right: &[f32],
    flow: &[f32],
    offset: &[f32],
    grad: &[f32],
    d: Dims,
    spec: CorrSpec,
    need_right: bool,
) -> OffsetCorrGrads {
    let Dims { n: nb, c, h, w } = d;
    let k_num = spec.candidates();
    let g_num = spec.groups;
    let cg = c / g_num;
    let hw = h * w;
    let rows = nb * h;
    let mut grads = OffsetCorrGrads {
        left: vec![0f32; nb * hw * c],
        right: Vec::new(),
        flow: vec![0f32; nb * hw * 2],
        offset: vec![0f32; nb * hw * 2 * k_num],
    };
    let zeros = vec![0f32; c];
    let sampling = OffsetSampling::new(&spec, offset, d);
    let chunk = rows_per_chunk(rows);
    let right_size = if need_right { nb * hw * c } else { 0 };
    // One scatter buffer per fixed chunk of rows, the buffers added in chunk order: the bits
    // depend on the shape and the pool's thread count, never on which thread stole what.
    let partials: Vec<Vec<f32>> = grads
        .left
        .par_chunks_mut(chunk * w * c)
        .zip(grads.offset.par_chunks_mut(chunk * w * 2 * k_num))
        .zip(grads.flow.par_chunks_mut(chunk * w * 2))
        .enumerate()
        .map(|(ci, ((dl_rows, doff_rows), dflow_rows))| {
            let mut dright = vec![0f32; right_size];
            let rows = dl_rows
                .chunks_mut(w * c)
                .zip(doff_rows.chunks_mut(w * 2 * k_num))
                .zip(dflow_rows.chunks_mut(w * 2));
            for (j, ((dl_row, doff_row), dflow_row)) in rows.enumerate() {
                let row = ci * chunk + j;
                let (n, y) = (row / h, row % h);
                let img = &right[n * hw * c..(n + 1) * hw * c];
                for x in 0..w {
                    let p = y * w + x;
                    let l = &left[(n * hw + p) * c..(n * hw + p + 1) * c];
                    let dl = &mut dl_row[x * c..(x + 1) * c];
                    let fx = flow[(n * 2) * hw + p];
                    let fy = flow[(n * 2 + 1) * hw + p];
                    let (mut dfx, mut dfy) = (0f32, 0f32);
                    for k in 0..k_num {
                        let b = sampling.at(n, k, x, y, fx, fy);
                        let [r0, r1, r2, r3] = b.corners(img, &zeros, c);
                        let [w0, w1, w2, w3] = b.weight;
                        let ([wx0, wx1], [wy0, wy1]) = (b.wx, b.wy);
                        let (mut dpx, mut dpy) = (0f32, 0f32);
                        for g in 0..g_num {
                            let ga = grad[((n * g_num + g) * k_num + k) * hw + p] / cg as f32;
                            for i in g * cg..(g + 1) * cg {
                                let s = w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i];
                                dl[i] += ga * s;
                                let lc = ga * l[i];
                                dpx += lc * (wy0 * (r1[i] - r0[i]) + wy1 * (r3[i] - r2[i]));
                                dpy += lc * (wx0 * (r2[i] - r0[i]) + wx1 * (r3[i] - r1[i]));
                            }
                            if need_right {
                                for (corner, &idx) in b.idx.iter().enumerate() {
                                    if idx == NONE {
                                        continue;
                                    }
                                    let wgt = b.weight[corner] * ga;
                                    let base = (n * hw + idx) * c;
                                    for i in g * cg..(g + 1) * cg {
                                        dright[base + i] += wgt * l[i];
                                    }
                                }
                            }
                        }
                        doff_row[x * 2 * k_num + 2 * k] = dpx;
                        doff_row[x * 2 * k_num + 2 * k + 1] = dpy;
                        dfx += dpx;
                        dfy += dpy;
                    }
                    dflow_row[x * 2] = dfx;
                    dflow_row[x * 2 + 1] = dfy;
                }
            }
            dright
        })
        .collect();
    grads.right = crate::ops::threads::sum_in_order(partials);
    grads
}

/// Per-pixel bilinear corners of the warp `x + flow_x, y + flow_y` for one image.
fn warp_corners(flow: &[f32], n: usize, h: usize, w: usize) -> Vec<Bilinear> {
    let hw = h * w;
    (0..hw)
        .into_par_iter()
        .map(|p| {
            let (y, x) = (p / w, p % w);
            let fx = flow[(n * 2) * hw + p];
            let fy = flow[(n * 2 + 1) * hw + p];
            Bilinear::new(x as f32 + fx, y as f32 + fy, h, w)
        })
        .collect()
}

/// Bilinear warp of `right` (N, C, H, W) by `flow` (N, 2, H, W), zero outside.
/// Returns (N, C, H, W).
pub fn warp_forward(right: &[f32], flow: &[f32], d: Dims) -> Vec<f32> {
    let Dims { n: nb, c, h, w } = d;
    let hw = h * w;
    let mut out = vec![0f32; nb * c * hw];
    for n in 0..nb {
        let corners = warp_corners(flow, n, h, w);
        out[n * c * hw..(n + 1) * c * hw]
            .par_chunks_mut(hw)
            .enumerate()
            .for_each(|(ch, plane)| {
                let src = &right[(n * c + ch) * hw..(n * c + ch + 1) * hw];
                for (o, b) in plane.iter_mut().zip(&corners) {
                    let mut v = 0f32;
                    for (&i, &wt) in b.idx.iter().zip(&b.weight) {
                        if i != NONE {
                            v += wt * src[i];
                        }
                    }
                    *o = v;
                }
            });
    }
    out
}

/// Gradients of [`warp_forward`]: (d right (N, C, H, W), d flow (N, 2, H, W)), each only if
/// asked for.
pub fn warp_backward(
    right: &[f32],
    flow: &[f32],
    grad: &[f32],
    d: Dims,
    need: [bool; 2],
) -> (Vec<f32>, Vec<f32>) {
    let Dims { n: nb, c, h, w } = d;
    let hw = h * w;
    let mut dright = vec![0f32; if need[0] { nb * c * hw } else { 0 }];
    let mut dflow = vec![0f32; if need[1] { nb * 2 * hw } else { 0 }];
    for n in 0..nb {
        let corners = warp_corners(flow, n, h, w);
        if need[0] {
            dright[n * c * hw..(n + 1) * c * hw]
                .par_chunks_mut(hw)
                .enumerate()
                .for_each(|(ch, plane)| {
                    let g = &grad[(n * c + ch) * hw..(n * c + ch + 1) * hw];
                    for (&gv, b) in g.iter().zip(&corners) {
                        for (&i, &wt) in b.idx.iter().zip(&b.weight) {
                            if i != NONE {
                                plane[i] += wt * gv;
                            }
                        }
                    }
                });
        }
        if need[1] {
            // d flow: reduce over channels; each task owns a block of pixels
            let (dfx, dfy) = dflow[n * 2 * hw..(n + 1) * 2 * hw].split_at_mut(hw);
            let block = 256;
            dfx.par_chunks_mut(block)
                .zip(dfy.par_chunks_mut(block))
                .enumerate()
                .for_each(|(bi, (dx_blk, dy_blk))| {
                    let p0 = bi * block;
                    for ch in 0..c {
                        let src = &right[(n * c + ch) * hw..(n * c + ch + 1) * hw];
                        let g = &grad[(n * c + ch) * hw..(n * c + ch + 1) * hw];
                        for j in 0..dx_blk.len() {
                            let p = p0 + j;
                            let b = &corners[p];
                            let r = b.idx.map(|i| if i == NONE { 0.0 } else { src[i] });
                            let ([wx0, wx1], [wy0, wy1]) = (b.wx, b.wy);
                            dx_blk[j] += g[p] * (wy0 * (r[1] - r[0]) + wy1 * (r[3] - r[2]));
                            dy_blk[j] += g[p] * (wx0 * (r[2] - r[0]) + wx1 * (r[3] - r[1]));
                        }
                    }
                });
        }
    }
    (dright, dflow)
}

/// Clamped (replicate-border) source pixel of candidate `k` at (x, y): the 1/4 level's shifted
/// correlation reads the warped map at `clamp(y + dy)`, `clamp(x + dx)`.
#[inline]
fn shifted_pixel(spec: &CorrSpec, k: usize, x: usize, y: usize, h: usize, w: usize) -> usize {
    let (dx, dy) = spec.window_offset(k);
    let cx = (x as i64 + dx).clamp(0, w as i64 - 1) as usize;
    let cy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
    cy * w + cx
}

/// Shifted group correlation (replicate border). `left`, `right`: (N, H, W, C).
/// Returns (N, H, W, G·K).
pub fn shift_corr_forward(left: &[f32], right: &[f32], d: Dims, spec: CorrSpec) -> Vec<f32> {
    let Dims { n: nb, c, h, w } = d;
    let (k_num, g_num) = (spec.candidates(), spec.groups);
    let (cg, gk, hw) = (c / g_num, g_num * k_num, h * w);
    let mut out = vec![0f32; nb * hw * gk];
    out.par_chunks_mut(w * gk)
        .enumerate()
        .for_each(|(row, out_row)| {
            let (n, y) = (row / h, row % h);
            for x in 0..w {
                let l = &left[(n * hw + y * w + x) * c..][..c];
                for k in 0..k_num {
                    let q = shifted_pixel(&spec, k, x, y, h, w);
                    let r = &right[(n * hw + q) * c..][..c];
                    group_correlation(l, r, cg, &mut out_row[x * gk + k..], k_num);
                }
            }
        });
    out
}

/// Gradients of [`shift_corr_forward`] w.r.t. (left, right), both (N, H, W, C); `grad`:
/// (N, G·K, H, W). The right map's gradient is a scatter (one buffer per row chunk).
pub fn shift_corr_backward(
    left: &[f32],
    right: &[f32],
    grad: &[f32],
    d: Dims,
    spec: CorrSpec,
) -> (Vec<f32>, Vec<f32>) {
    let Dims { n: nb, c, h, w } = d;
    let (k_num, g_num) = (spec.candidates(), spec.groups);
    let (cg, hw) = (c / g_num, h * w);
    let mut dleft = vec![0f32; nb * hw * c];
    let size = nb * hw * c;
    let chunk = rows_per_chunk(nb * h);
    // As in `offset_corr_backward`: a scatter buffer per fixed row chunk, added in chunk order.
    let partials: Vec<Vec<f32>> = dleft
        .par_chunks_mut(chunk * w * c)
        .enumerate()
        .map(|(ci, dl_rows)| {
            let mut dright = vec![0f32; size];
            for (j, dl_row) in dl_rows.chunks_mut(w * c).enumerate() {
                let row = ci * chunk + j;
                let (n, y) = (row / h, row % h);
                for x in 0..w {
                    let p = y * w + x;
                    let l = &left[(n * hw + p) * c..][..c];
                    let dl = &mut dl_row[x * c..(x + 1) * c];
                    for k in 0..k_num {
                        let q = n * hw + shifted_pixel(&spec, k, x, y, h, w);
                        let r = &right[q * c..][..c];
                        for g in 0..g_num {
                            let ga = grad[((n * g_num + g) * k_num + k) * hw + p] / cg as f32;
                            for i in g * cg..(g + 1) * cg {
                                dl[i] += ga * r[i];
                                dright[q * c + i] += ga * l[i];
                            }
                        }
                    }
                }
            }
            dright
        })
        .collect();
    let dright = crate::ops::threads::sum_in_order(partials);
    (dleft, dright)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ops::agcl::SearchWindow;

    /// The scatter kernels' bits depend on the shape and the pool's thread count only, whatever
    /// else runs on the pool (see `crate::ops::threads::sum_in_order`).
    #[test]
    fn gradient_bits_do_not_depend_on_the_load() {
        let d = Dims {
            n: 2,
            c: 16,
            h: 12,
            w: 20,
        };
        let values = |len: usize, salt: usize| -> Vec<f32> {
            (0..len)
                .map(|i| (((i * 7919 + salt * 104_729) % 2003) as f32 - 1001.0) * 1e-3)
                .collect()
        };
        let hw = d.h * d.w;
        let spec = CorrSpec::new(SearchWindow::Square3x3, 4);
        let k = spec.candidates();
        let (left, right) = (values(d.n * hw * d.c, 1), values(d.n * hw * d.c, 2));
        let flow: Vec<f32> = values(d.n * 2 * hw, 3).iter().map(|v| v * 3.0).collect();
        let offset = values(d.n * 2 * k * hw, 4);
        let grad = values(d.n * spec.groups * k * hw, 5);
        let changed = crate::ops::threads::first_round_that_differs_under_load(4, 12, || {
            let a = offset_corr_backward(&left, &right, &flow, &offset, &grad, d, spec, true);
            let (sl, sr) = shift_corr_backward(&left, &right, &grad, d, spec);
            vec![a.left, a.right, a.flow, a.offset, sl, sr]
        });
        assert_eq!(
            changed, None,
            "a gradient's bits changed under load in this round"
        );
    }
}
