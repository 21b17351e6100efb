//! Convex upsampling and align-corners bilinear resizing.

use burn::prelude::*;
use burn::tensor::activation::softmax;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions, PadMode};

/// Bilinear resize with `align_corners = true` (set explicitly; the reference uses it everywhere).
pub fn resize_bilinear_align_corners<B: Backend>(x: Tensor<B, 4>, size: [usize; 2]) -> Tensor<B, 4> {
    let [_, _, h, w] = x.dims();
    if [h, w] == size {
        return x;
    }
    interpolate(x, size, InterpolateOptions::new(InterpolateMode::Bilinear).with_align_corners(true))
}

/// Convex upsampling of `flow` (N, 2, H, W) by `rate` with `mask` (N, 9·rate², H, W):
/// softmax over the 9 neighbours of a zero-padded 3×3 window of `rate · flow`.
/// Returns (N, 2, rate·H, rate·W).
pub fn convex_upsample<B: Backend>(flow: Tensor<B, 4>, mask: Tensor<B, 4>, rate: usize) -> Tensor<B, 4> {
    let [n, c, h, w] = flow.dims();
    assert_eq!(mask.dims(), [n, 9 * rate * rate, h, w], "convex_upsample: mask shape");
    let mask = softmax(mask.reshape([n, 1, 9, rate, rate, h, w]), 2);
    let padded = flow.mul_scalar(rate as f64).pad((1, 1, 1, 1), PadMode::Constant(0.0));
    let mut neigh = Vec::with_capacity(9);
    for ky in 0..3 {
        for kx in 0..3 {
            neigh.push(padded.clone().slice([0..n, 0..c, ky..ky + h, kx..kx + w]));
        }
    }
    let unfolded = Tensor::stack::<5>(neigh, 2).reshape([n, c, 9, 1, 1, h, w]);
    let up = (mask * unfolded).sum_dim(2).reshape([n, c, rate, rate, h, w]);
    up.permute([0, 1, 4, 2, 5, 3]).reshape([n, c, rate * h, rate * w])
}
