//! Convex upsampling composed from Burn tensor ops: the fallback where no kernel exists.

use burn::prelude::*;
use burn::tensor::activation::softmax;

/// `x` (N, C, H, W) with one row and column of zeros on every side, in `x`'s dtype (Burn's
/// constant `pad` makes its border in the default float dtype: Flex then fails on float64).
fn pad_zeros<B: Backend>(x: Tensor<B, 4>) -> Tensor<B, 4> {
    let [n, c, h, w] = x.dims();
    let zeros = |shape: [usize; 4]| Tensor::zeros(shape, (&x.device(), x.dtype()));
    let (col, row) = (zeros([n, c, h, 1]), zeros([n, c, 1, w + 2]));
    let x = crate::ops::channels::cat(vec![col.clone(), x, col], 3);
    crate::ops::channels::cat(vec![row.clone(), x, row], 2)
}

/// [`super::convex_upsample`] composed from tensor ops (any backend, and the reference its
/// kernels are tested against).
pub fn convex_upsample<B: Backend>(
    flow: Tensor<B, 4>,
    mask: Tensor<B, 4>,
    rate: usize,
) -> Tensor<B, 4> {
    // Ranks stay at 5 or below: with the 7-D softmax and 6-D permutation this had before, the
    // gradients came out wrong on wgpu (Burn 0.21 fusion; found by the Vulkan tests).
    let [n, c, h, w] = flow.dims();
    let (rr, hw) = (rate * rate, h * w);
    // mask channel k·rate² + ry·rate + rx: weight of neighbour k for sub-pixel (ry, rx)
    let mask = softmax(mask.reshape([n, 9, rr, hw]), 1);
    let padded = pad_zeros(flow.mul_scalar(rate as f64));
    let neighbours = (0..9)
        .map(|k| {
            let (ky, kx) = (k / 3, k % 3);
            padded
                .clone()
                .slice([0..n, 0..c, ky..ky + h, kx..kx + w])
                .reshape([n, c, 1, hw])
        })
        .collect();
    let unfolded = crate::ops::channels::cat(neighbours, 2); // (n, c, 9, h·w)
    let up = (mask.reshape([n, 1, 9, rr, hw]) * unfolded.reshape([n, c, 9, 1, hw])).sum_dim(2);
    // (n·c, ry, rx, y, x) → (n·c, y, ry, x, rx): sub-pixels interleaved into the full grid
    up.reshape([n * c, rate, rate, h, w])
        .permute([0, 3, 1, 4, 2])
        .reshape([n, c, h * rate, w * rate])
}
