//! Convex upsampling on the Flex CPU backend: the softmax of the mask, then each output pixel's
//! weighted sum of its 3×3 neighbourhood, each one parallel pass.
//!
//! Composed, the same work is a softmax over a middle axis of a 7-D view, nine shifted slices
//! stacked, a broadcast product, a sum and a six-axis permutation, each a full pass over
//! mask-sized tensors, most of them on one thread.

use burn::backend::flex::FlexTensor;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

/// `flow` (N, C, H, W) upsampled by `rate` with `mask` (N, 9·rate², H, W; channel
/// `k·rate² + a·rate + b` weighs neighbour k = 3·ky + kx for output offset (a, b)), as the
/// composed path in `super::composed::convex_upsample` defines it.
pub(super) fn convex_upsample(flow: &FlexTensor, mask: &FlexTensor, rate: usize) -> FlexTensor {
    let weights = softmax_weights(mask, rate);
    let [n, c, h, w] = flow.shape().dims();
    let flow = flow.to_contiguous();
    let flow: &[f32] = flow.storage();
    let (r2, plane) = (rate * rate, h * w);
    // Output rows (N, C, rate·H, rate·W) in parallel: out(r·y + a, r·x + b) = Σ_k weight_k ·
    // rate · flow(y + ky − 1, x + kx − 1), zero outside the map.
    let (rh, rw) = (rate * h, rate * w);
    let scale = rate as f32;
    let mut out = vec![0f32; n * c * rh * rw];
    out.par_chunks_mut(rw).enumerate().for_each(|(row, dst)| {
        let (bc, oy) = (row / rh, row % rh);
        let (b, (y, a)) = (bc / c, (oy / rate, oy % rate));
        let f = &flow[bc * plane..][..plane];
        let wrow = &weights[(b * h + y) * w * r2 * 9..][..w * r2 * 9];
        for x in 0..w {
            let neighbours = neighbourhood(f, (h, w), (y, x), scale);
            for bb in 0..rate {
                let wk = &wrow[(x * r2 + a * rate + bb) * 9..][..9];
                dst[rate * x + bb] = wk.iter().zip(&neighbours).map(|(p, v)| p * v).sum();
            }
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, c, rh, rw]))
}

/// `scale ·` the zero-padded 3×3 neighbourhood of (y, x) in one flow plane, neighbour
/// k = 3·ky + kx at (y + ky − 1, x + kx − 1).
fn neighbourhood(
    f: &[f32],
    (h, w): (usize, usize),
    (y, x): (usize, usize),
    scale: f32,
) -> [f32; 9] {
    let mut neighbours = [0f32; 9];
    for (k, v) in neighbours.iter_mut().enumerate() {
        let (yy, xx) = ((y + k / 3).wrapping_sub(1), (x + k % 3).wrapping_sub(1));
        if yy < h && xx < w {
            *v = scale * f[yy * w + xx];
        }
    }
    neighbours
}

/// The softmax of `mask` (N, 9·rate², H, W) over its 9 neighbours, laid out
/// (N, H, W, rate², 9): one pixel's weights together.
fn softmax_weights(mask: &FlexTensor, rate: usize) -> Vec<f32> {
    let [n, _, h, w] = mask.shape().dims();
    let mask = mask.to_contiguous();
    let mask: &[f32] = mask.storage();
    let (r2, plane) = (rate * rate, h * w);
    let mut weights = vec![0f32; n * plane * r2 * 9];
    weights
        .par_chunks_mut(w * r2 * 9)
        .enumerate()
        .for_each(|(row, dst)| {
            let (b, y) = (row / h, row % h);
            let m = &mask[b * 9 * r2 * plane..][..9 * r2 * plane];
            for (x, px) in dst.chunks_exact_mut(r2 * 9).enumerate() {
                for (s, wk) in px.chunks_exact_mut(9).enumerate() {
                    let logit = |k: usize| m[(k * r2 + s) * plane + y * w + x];
                    let max = (0..9).map(logit).fold(f32::NEG_INFINITY, f32::max);
                    let mut sum = 0.0;
                    for (k, e) in wk.iter_mut().enumerate() {
                        *e = (logit(k) - max).exp();
                        sum += *e;
                    }
                    wk.iter_mut().for_each(|e| *e /= sum);
                }
            }
        });
    weights
}

/// Gradients of [`convex_upsample`] from the gradient `d` (N, C, rate·H, rate·W) of its output:
/// (d flow, d mask). With weights p_k (the softmax), neighbour values v_k and output o = Σ p_k v_k
/// per output pixel and channel: d v_k = p_k · d o (scattered back to the flow pixels, times
/// rate), d mask_k = p_k · Σ_channels d o · (v_k − o).
pub(super) fn convex_upsample_grad(
    flow: &FlexTensor,
    mask: &FlexTensor,
    rate: usize,
    d: &FlexTensor,
) -> (FlexTensor, FlexTensor) {
    let weights = softmax_weights(mask, rate);
    let [n, c, h, w] = flow.shape().dims();
    let (flow, d) = (flow.to_contiguous(), d.to_contiguous());
    let (flow, d): (&[f32], &[f32]) = (flow.storage(), d.storage());
    let (r2, plane, scale) = (rate * rate, h * w, rate as f32);
    let (rh, rw) = (rate * h, rate * w);
    let dout = |bc: usize, y: usize, x: usize, s: usize| {
        d[(bc * rh + rate * y + s / rate) * rw + rate * x + s % rate]
    };
    // d mask per input row of every image, laid out like the weights (N, H, W, rate², 9) ...
    let mut dm = vec![0f32; n * plane * r2 * 9];
    dm.par_chunks_mut(w * r2 * 9)
        .enumerate()
        .for_each(|(row, dst)| {
            let (b, y) = (row / h, row % h);
            let mut neighbours = vec![[0f32; 9]; c];
            for (x, px) in dst.chunks_exact_mut(r2 * 9).enumerate() {
                for (ch, v) in neighbours.iter_mut().enumerate() {
                    let f = &flow[(b * c + ch) * plane..][..plane];
                    *v = neighbourhood(f, (h, w), (y, x), scale);
                }
                for (s, dk) in px.chunks_exact_mut(9).enumerate() {
                    let p = &weights[((b * h + y) * w + x) * r2 * 9 + s * 9..][..9];
                    let mut g = [0f32; 9];
                    for (ch, v) in neighbours.iter().enumerate() {
                        let go = dout(b * c + ch, y, x, s);
                        let o: f32 = p.iter().zip(v).map(|(p, v)| p * v).sum();
                        for (gk, vk) in g.iter_mut().zip(v) {
                            *gk += go * (vk - o);
                        }
                    }
                    for ((dk, pk), gk) in dk.iter_mut().zip(p).zip(g) {
                        *dk = pk * gk;
                    }
                }
            }
        });
    // ... then into the mask's layout (N, 9·rate², H, W), plane by plane.
    let mut dmask = vec![0f32; n * 9 * r2 * plane];
    dmask
        .par_chunks_mut(plane)
        .enumerate()
        .for_each(|(i, dst)| {
            let (b, (k, s)) = (i / (9 * r2), ((i % (9 * r2)) / r2, i % r2));
            for (px, value) in dst.iter_mut().enumerate() {
                *value = dm[(b * plane + px) * r2 * 9 + s * 9 + k];
            }
        });
    // d flow, gathered per flow pixel from the outputs whose neighbourhoods hold it: flow pixel
    // (yy, xx) is neighbour k of pixel (yy − ky + 1, xx − kx + 1).
    let mut dflow = vec![0f32; n * c * plane];
    dflow.par_chunks_mut(w).enumerate().for_each(|(row, dst)| {
        let (bc, yy) = (row / h, row % h);
        let b = bc / c;
        for (xx, value) in dst.iter_mut().enumerate() {
            let mut sum = 0f32;
            for k in 0..9 {
                let (y, x) = ((yy + 1).wrapping_sub(k / 3), (xx + 1).wrapping_sub(k % 3));
                if y >= h || x >= w {
                    continue;
                }
                let p = &weights[((b * h + y) * w + x) * r2 * 9..][..r2 * 9];
                for s in 0..r2 {
                    sum += p[s * 9 + k] * dout(bc, y, x, s);
                }
            }
            *value = scale * sum;
        }
    });
    (
        FlexTensor::from_data(TensorData::new(dflow, [n, c, h, w])),
        FlexTensor::from_data(TensorData::new(dmask, [n, 9 * r2, h, w])),
    )
}
