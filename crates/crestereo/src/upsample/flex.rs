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
/// composed path in `super::convex_upsample` defines it.
pub(super) fn convex_upsample(flow: &FlexTensor, mask: &FlexTensor, rate: usize) -> FlexTensor {
    let [n, c, h, w] = flow.shape().dims();
    let (flow, mask) = (flow.to_contiguous(), mask.to_contiguous());
    let (flow, mask): (&[f32], &[f32]) = (flow.storage(), mask.storage());
    let (r2, plane) = (rate * rate, h * w);
    // Softmax over the 9 neighbours, laid out (N, H, W, rate², 9): one pixel's weights together.
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
            let mut neighbours = [0f32; 9];
            for (k, v) in neighbours.iter_mut().enumerate() {
                let (yy, xx) = ((y + k / 3).wrapping_sub(1), (x + k % 3).wrapping_sub(1));
                if yy < h && xx < w {
                    *v = scale * f[yy * w + xx];
                }
            }
            for bb in 0..rate {
                let wk = &wrow[(x * r2 + a * rate + bb) * 9..][..9];
                dst[rate * x + bb] = wk.iter().zip(&neighbours).map(|(p, v)| p * v).sum();
            }
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, c, rh, rw]))
}
