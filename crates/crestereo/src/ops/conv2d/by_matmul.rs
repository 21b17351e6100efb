//! A convolution composed as one matrix product over the unfolded input, the unfolding made of
//! shifted (and, for strided convolutions, stepped) slices of the zero-padded input (Burn tensor
//! ops only, so autodiff gives a backward of matrix products and slice gradients). The product
//! is [`crate::ops::matmul::matmul`]: on CubeCL backends at the default precision one fixed
//! float32 kernel per shape class.
//!
//! Used on every CubeCL backend at the default float32 precision (on wgpu at any precision): Burn 0.21's wgpu convolution runs direct kernels, and its input gradient a
//! direct transposed convolution. On lavapipe (the CI's Vulkan device) one training step's
//! transposed convolutions took 96 s of the step's ~160 s of kernel time (28 calls, 3.4 s
//! each), the forward's direct convolutions another 33 s; as matrix products the same
//! convolutions take a fraction of that (crate README, "Backends and kernels").

use burn::prelude::*;
use burn::tensor::Slice;

/// `x` (N, C, H, W) with `ph` zero rows above and below and `pw` zero columns left and right,
/// in `x`'s dtype.
fn pad_zeros<B: Backend>(x: Tensor<B, 4>, [ph, pw]: [usize; 2]) -> Tensor<B, 4> {
    let [n, c, h, w] = x.dims();
    let (device, dtype) = (x.device(), x.dtype());
    let x = if pw > 0 {
        let col = Tensor::zeros([n, c, h, pw], (&device, dtype));
        crate::ops::channels::cat(vec![col.clone(), x, col], 3)
    } else {
        x
    };
    if ph > 0 {
        let row = Tensor::zeros([n, c, ph, w + 2 * pw], (&device, dtype));
        crate::ops::channels::cat(vec![row.clone(), x, row], 2)
    } else {
        x
    }
}

/// Groups-1 convolution of `x` (N, C_in, H, W) with `weight` (C_out, C_in, kh, kw), symmetric
/// zero `padding`, `stride` and `dilation`.
pub(crate) fn conv2d_by_matmul<B: Backend>(
    x: Tensor<B, 4>,
    weight: Tensor<B, 4>,
    bias: Option<Tensor<B, 1>>,
    padding: [usize; 2],
    stride: [usize; 2],
    dilation: [usize; 2],
) -> Tensor<B, 4> {
    let [n, cin, h, w] = x.dims();
    let [cout, _, kh, kw] = weight.dims();
    let ho = (h + 2 * padding[0] - dilation[0] * (kh - 1) - 1) / stride[0] + 1;
    let wo = (w + 2 * padding[1] - dilation[1] * (kw - 1) - 1) / stride[1] + 1;
    let cols = if kh * kw == 1 && padding == [0, 0] && stride == [1, 1] {
        x
    } else {
        let padded = pad_zeros(x, padding);
        // Rows oy, oy + s, …, oy + s·(ho − 1) of the padded input (columns alike).
        let rows = |o: usize, s: usize, len: usize| {
            Slice::new(
                o as isize,
                Some((o + s * (len - 1) + 1) as isize),
                s as isize,
            )
        };
        // Channel index of the unfolded input: tap-major (ky, kx), then input channel.
        let taps = (0..kh * kw)
            .map(|t| {
                let (oy, ox) = ((t / kw) * dilation[0], (t % kw) * dilation[1]);
                padded.clone().slice([
                    Slice::from(0..n),
                    Slice::from(0..cin),
                    rows(oy, stride[0], ho),
                    rows(ox, stride[1], wo),
                ])
            })
            .collect();
        crate::ops::channels::cat(taps, 1)
    };
    let k = cin * kh * kw;
    let weight = weight
        .permute([0, 2, 3, 1])
        .reshape([1, cout, k])
        .expand([n, cout, k]);
    let y = crate::ops::matmul::matmul(weight, cols.reshape([n, k, ho * wo]));
    let y = match bias {
        Some(b) => y + b.reshape([1, cout, 1]),
        None => y,
    };
    y.reshape([n, cout, ho, wo])
}
