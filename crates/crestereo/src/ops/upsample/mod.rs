//! Convex upsampling and align-corners bilinear resizing.
//!
//! On the Flex backend the convex upsampling runs as two parallel kernels (`flex`), under
//! autodiff on Flex (training) as the same kernels recorded with their own backward
//! (`autodiff`); elsewhere it is composed from tensor ops ([`composed::convex_upsample`]).

use burn::prelude::*;

use crate::ops::dispatch::{
    Kernels, from_autodiff_flex, from_flex, kernels_f32, to_autodiff_flex, to_flex,
};

mod autodiff;
pub mod composed;
mod flex;

/// Interpolation matrix (out × in) of 1-D linear resizing with `align_corners = true`, with the
/// weights computed in float32 exactly as PyTorch's CPU kernel does (`scale = (in−1)/(out−1)`,
/// `src = scale · dst`, `λ1 = src − ⌊src⌋`, `λ0 = 1 − λ1`).
fn linear_weights(n_in: usize, n_out: usize) -> Vec<f32> {
    let mut m = vec![0f32; n_out * n_in];
    let scale: f32 = if n_out > 1 {
        (n_in - 1) as f32 / (n_out - 1) as f32
    } else {
        0.0
    };
    for o in 0..n_out {
        let src = scale * o as f32;
        let i0 = (src as usize).min(n_in - 1);
        let i1 = if i0 < n_in - 1 { i0 + 1 } else { i0 };
        let l1 = src - i0 as f32;
        let l0 = 1.0 - l1;
        m[o * n_in + i0] += l0;
        m[o * n_in + i1] += l1;
    }
    m
}

/// Bilinear resize with `align_corners = true` (set explicitly; the reference uses it everywhere),
/// as two interpolation-matrix products whose weights match PyTorch's float32 arithmetic.
/// Differentiable.
pub fn resize_bilinear_align_corners<B: Backend>(
    x: Tensor<B, 4>,
    size: [usize; 2],
) -> Tensor<B, 4> {
    let [n, c, h, w] = x.dims();
    let [ho, wo] = size;
    if [h, w] == size {
        return x;
    }
    let device = x.device();
    // width: (N·C·H, W) @ (W, Wo)
    let dtype = x.dtype();
    let matrix = |n_in, n_out| {
        let m = Tensor::<B, 2>::from_data(
            TensorData::new(linear_weights(n_in, n_out), [n_out, n_in]),
            &device,
        );
        crate::ops::float_like(m, dtype).transpose()
    };
    let rw = matrix(w, wo);
    let y = crate::ops::matmul::matmul(x.reshape([n * c * h, w]), rw).reshape([n * c, h, wo]);
    // height: (N·C·Wo, H) @ (H, Ho)
    let rh = matrix(h, ho);
    crate::ops::matmul::matmul(y.swap_dims(1, 2).reshape([n * c * wo, h]), rh)
        .reshape([n, c, wo, ho])
        .swap_dims(2, 3)
}

/// Convex upsampling of `flow` (N, 2, H, W) by `rate` with `mask` (N, 9·rate², H, W):
/// softmax over the 9 neighbours of a zero-padded 3×3 window of `rate · flow`.
/// Returns (N, 2, rate·H, rate·W).
pub fn convex_upsample<B: Backend>(
    flow: Tensor<B, 4>,
    mask: Tensor<B, 4>,
    rate: usize,
) -> Tensor<B, 4> {
    let [n, _, h, w] = flow.dims();
    assert_eq!(
        mask.dims(),
        [n, 9 * rate * rate, h, w],
        "convex_upsample: mask shape"
    );
    match kernels_f32(&[&flow, &mask]) {
        Kernels::Flex => {
            let (flow, mask) = (to_flex(flow), to_flex(mask));
            from_flex(flex::convex_upsample(&flow, &mask, rate))
        }
        Kernels::AutodiffFlex => {
            let (flow, mask) = (to_autodiff_flex(flow), to_autodiff_flex(mask));
            from_autodiff_flex(autodiff::convex_upsample(flow, mask, rate))
        }
        _ => composed::convex_upsample(flow, mask, rate),
    }
}

/// [`resize_bilinear_align_corners`] as ONNX nodes: the same two interpolation-matrix
/// products, the matrices as constants of the graph.
pub fn emit_resize_bilinear_align_corners(
    g: &mut crate::export::onnx::Graph,
    x: &crate::export::onnx::Value,
    size: [usize; 2],
) -> crate::export::onnx::Value {
    let [n, c, h, w] = x.dims();
    let [ho, wo] = size;
    if [h, w] == size {
        return x.clone();
    }
    // (in × out): the transpose of `linear_weights`' (out × in).
    let mut matrix = |n_in: usize, n_out: usize| {
        g.shared_constant("resize", &[n_in, n_out], || {
            let m = linear_weights(n_in, n_out);
            (0..n_in * n_out)
                .map(|k| m[(k % n_out) * n_in + k / n_out])
                .collect()
        })
    };
    let rw = matrix(w, wo);
    let rh = matrix(h, ho);
    let y = g.reshape(x, &[n * c * h, w]);
    let y = g.matmul(&y, &rw);
    let y = g.reshape(&y, &[n * c, h, wo]);
    let y = g.transpose(&y, &[0, 2, 1]);
    let y = g.reshape(&y, &[n * c * wo, h]);
    let y = g.matmul(&y, &rh);
    let y = g.reshape(&y, &[n, c, wo, ho]);
    g.transpose(&y, &[0, 1, 3, 2])
}

/// [`composed::convex_upsample`] as ONNX nodes (ranks ≤ 5, a softmax over one axis, nine
/// slices of the zero-padded flow).
pub fn emit_convex_upsample(
    g: &mut crate::export::onnx::Graph,
    flow: &crate::export::onnx::Value,
    mask: &crate::export::onnx::Value,
    rate: usize,
) -> crate::export::onnx::Value {
    let [n, c, h, w] = flow.dims();
    assert_eq!(
        mask.dims(),
        [n, 9 * rate * rate, h, w],
        "convex_upsample: mask shape"
    );
    let (rr, hw) = (rate * rate, h * w);
    let mask = g.reshape(mask, &[n, 9, rr, hw]);
    let mask = g.softmax(&mask, 1);
    let scaled = g.mul_scalar(flow, rate as f32);
    let col = g.zeros(&[n, c, h, 1]);
    let row = g.zeros(&[n, c, 1, w + 2]);
    let padded = g.concat(&[&col, &scaled, &col], 3);
    let padded = g.concat(&[&row, &padded, &row], 2);
    let neighbours: Vec<crate::export::onnx::Value> = (0..9)
        .map(|k| {
            let (ky, kx) = (k / 3, k % 3);
            let crop = g.crop(&padded, ky..ky + h, kx..kx + w);
            g.reshape(&crop, &[n, c, 1, hw])
        })
        .collect();
    let unfolded = g.concat(&neighbours.iter().collect::<Vec<_>>(), 2);
    let mask = g.reshape(&mask, &[n, 1, 9, rr, hw]);
    let unfolded = g.reshape(&unfolded, &[n, c, 9, 1, hw]);
    let up = g.mul(&mask, &unfolded);
    let up = g.sum_dim(&up, 2);
    let up = g.reshape(&up, &[n * c, rate, rate, h, w]);
    let up = g.transpose(&up, &[0, 3, 1, 4, 2]);
    g.reshape(&up, &[n, c, h * rate, w * rate])
}

#[cfg(test)]
mod tests {
    use burn::tensor::Distribution;

    use super::*;
    use crate::test_util::{assert_output_and_grads_close, max_abs};
    use crate::{CpuAutodiffBackend, CpuBackend};

    const CASES: [(usize, usize, usize, usize); 3] = [(1, 6, 9, 4), (2, 5, 4, 2), (1, 1, 3, 4)];

    fn inputs((n, h, w, rate): (usize, usize, usize, usize)) -> [Tensor<CpuBackend, 4>; 3] {
        let device = Default::default();
        let random = |shape, std| Tensor::random(shape, Distribution::Normal(0.0, std), &device);
        [
            random([n, 2, h, w], 3.0),
            random([n, 9 * rate * rate, h, w], 2.0),
            random([n, 2, rate * h, rate * w], 1.0),
        ]
    }

    /// The Flex kernel against the composed ops, same inputs.
    #[test]
    fn flex_convex_upsampling_matches_the_composed_ops() {
        for case @ (n, h, w, rate) in CASES {
            let [flow, mask, _] = inputs(case);
            let kernel = convex_upsample(flow.clone(), mask.clone(), rate);
            assert_eq!(kernel.dims(), [n, 2, rate * h, rate * w]);
            let diff = max_abs(kernel, composed::convex_upsample(flow, mask, rate));
            assert!(diff < 1e-5, "{case:?}: max difference {diff}");
        }
    }

    /// Under autodiff on Flex: the kernel's output and the gradients its backward gives (flow
    /// and mask) against autodiff of the composed ops.
    #[test]
    fn autodiff_convex_upsampling_matches_the_composed_ops_and_their_gradients() {
        type A = CpuAutodiffBackend;
        for case @ (_, _, _, rate) in CASES {
            let [flow, mask, weights] = inputs(case);
            let run = |kernel: bool| {
                let flow = Tensor::<A, 4>::from_inner(flow.clone()).require_grad();
                let mask = Tensor::<A, 4>::from_inner(mask.clone()).require_grad();
                let out = if kernel {
                    convex_upsample(flow.clone(), mask.clone(), rate)
                } else {
                    composed::convex_upsample(flow.clone(), mask.clone(), rate)
                };
                let grads = (out.clone() * Tensor::from_inner(weights.clone()))
                    .sum()
                    .backward();
                let g = |t: &Tensor<A, 4>| t.grad(&grads).expect("a gradient");
                (out.inner(), [g(&flow), g(&mask)])
            };
            let label = format!("{case:?}");
            assert_output_and_grads_close(&label, ["flow", "mask"], run(true), run(false));
        }
    }

    /// Convex upsampling and the bilinear resize as graph nodes against `forward`'s kernels.
    #[test]
    fn emitted_upsampling_and_resize_match_forward() {
        use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
        for case @ (_, h, w, rate) in CASES {
            let [flow, mask, _] = inputs(case);
            let sizes = [[2 * h + 1, 3 * w], [h.max(2), 2]];
            let out = run_emitted(&[flow.to_data(), mask.to_data()], |g, x| {
                let mut out = vec![emit_convex_upsample(g, &x[0], &x[1], rate)];
                out.extend(sizes.map(|s| emit_resize_bilinear_align_corners(g, &x[0], s)));
                out
            });
            let label = format!("convex upsampling {case:?}");
            let forward = convex_upsample(flow.clone(), mask, rate);
            assert_emit_matches(&label, &out[0], forward.into_data(), 1e-5);
            for (size, emitted) in sizes.iter().zip(&out[1..]) {
                let forward = resize_bilinear_align_corners(flow.clone(), *size);
                let label = format!("resize {case:?} to {size:?}");
                assert_emit_matches(&label, emitted, forward.into_data(), 1e-5);
            }
        }
    }
}
