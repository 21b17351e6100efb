//! Instance normalisation (optionally followed by ReLU) as one parallel pass per plane on Flex,
//! with its own backward.
//!
//! Composed, an instance norm is a mean, a broadcast subtraction, a square, a second mean, an
//! addition, a square root and a broadcast division: each its own pass over the map, the
//! broadcast ones through Flex's strided iterator on one thread, and twice as many in the
//! backward. The encoder normalises 11 maps per image at ½ and ¼ resolution.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

use crate::ops::dispatch::{
    Kernels, from_autodiff_flex, from_flex, kernels_f32, to_autodiff_flex, to_flex,
};

/// `(x − mean) / sqrt(var + eps)` per (image, channel) plane, biased variance as PyTorch's
/// `instance_norm`, then ReLU when `relu_after`.
pub fn instance_norm_act<B: Backend>(x: Tensor<B, 4>, eps: f64, relu_after: bool) -> Tensor<B, 4> {
    match kernels_f32(&[&x]) {
        Kernels::Flex => from_flex(forward(&to_flex(x), eps, relu_after, false).0),
        Kernels::AutodiffFlex => from_autodiff_flex(tracked(to_autodiff_flex(x), eps, relu_after)),
        _ => {
            let y = composed::instance_norm(x, eps);
            if relu_after { relu(y) } else { y }
        }
    }
}

/// The norm composed from tensor ops: the fallback where no kernel exists.
pub mod composed {
    use burn::prelude::*;

    /// The norm from tensor ops, for any backend (and the reference the kernel is tested
    /// against).
    pub fn instance_norm<B: Backend>(x: Tensor<B, 4>, eps: f64) -> Tensor<B, 4> {
        let [n, c, h, w] = x.dims();
        let flat = x.reshape([n, c, h * w]);
        let mean = flat.clone().mean_dim(2);
        let centered = flat - mean;
        let var = centered.clone().square().mean_dim(2);
        (centered / (var.add_scalar(eps)).sqrt()).reshape([n, c, h, w])
    }
}

/// The output, the normalised map before ReLU when `keep` (the backward needs it; without
/// ReLU it is the output itself, shared) and `1 / sqrt(var + eps)` per plane. Sums in float64,
/// so the statistics do not depend on the plane's size.
fn forward(
    x: &FlexTensor,
    eps: f64,
    relu_after: bool,
    keep: bool,
) -> (FlexTensor, Option<FlexTensor>, Vec<f32>) {
    let [n, c, h, w] = x.shape().dims();
    let plane = h * w;
    let x = x.to_contiguous();
    let src: &[f32] = x.storage();
    let mut normed = vec![0f32; src.len()];
    let mut inv = vec![0f32; n * c];
    // ReLU in the same pass unless the map before it is kept.
    let relu_in_place = relu_after && !keep;
    normed
        .par_chunks_mut(plane.max(1))
        .zip(inv.par_iter_mut())
        .zip(src.par_chunks(plane.max(1)))
        .for_each(|((out, inv), x)| {
            let mean = (x.iter().map(|&v| f64::from(v)).sum::<f64>() / plane as f64) as f32;
            let var = x
                .iter()
                .map(|&v| f64::from(v - mean) * f64::from(v - mean))
                .sum::<f64>()
                / plane as f64;
            let scale = ((var + eps) as f32).sqrt();
            *inv = 1.0 / scale;
            for (o, &v) in out.iter_mut().zip(x) {
                let m = (v - mean) / scale;
                *o = if relu_in_place { m.max(0.0) } else { m };
            }
        });
    let shape = [n, c, h, w];
    let normed = FlexTensor::from_data(TensorData::new(normed, shape));
    if !relu_after || !keep {
        let kept = keep.then(|| normed.clone());
        return (normed, kept, inv);
    }
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(plane.max(1))
        .zip(normed.storage::<f32>().par_chunks(plane.max(1)))
        .for_each(|(o, m)| o.iter_mut().zip(m).for_each(|(o, &m)| *o = m.max(0.0)));
    (
        FlexTensor::from_data(TensorData::new(out, shape)),
        Some(normed),
        inv,
    )
}

/// `dx = inv · (g − mean(g) − x̂ · mean(g · x̂))` per plane, with `g` the output gradient masked
/// by ReLU where it follows.
fn backward(normed: &FlexTensor, inv: &[f32], dy: &FlexTensor, relu_after: bool) -> FlexTensor {
    let [n, c, h, w] = normed.shape().dims();
    let plane = h * w;
    let dy = dy.to_contiguous();
    let (xh, dy): (&[f32], &[f32]) = (normed.storage(), dy.storage());
    let mut dx = vec![0f32; xh.len()];
    dx.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(i, dx)| {
            let (xh, dy) = (&xh[i * plane..][..plane], &dy[i * plane..][..plane]);
            let g = |x: f32, d: f32| if relu_after && x <= 0.0 { 0.0 } else { d };
            let (mut sum_g, mut sum_gx) = (0f64, 0f64);
            for (&x, &d) in xh.iter().zip(dy) {
                sum_g += f64::from(g(x, d));
                sum_gx += f64::from(g(x, d)) * f64::from(x);
            }
            let (mean_g, mean_gx) = (
                (sum_g / plane as f64) as f32,
                (sum_gx / plane as f64) as f32,
            );
            for ((out, &x), &d) in dx.iter_mut().zip(xh).zip(dy) {
                *out = inv[i] * (g(x, d) - mean_g - x * mean_gx);
            }
        });
    FlexTensor::from_data(TensorData::new(dx, [n, c, h, w]))
}

type Tracked = burn::tensor::ops::FloatTensor<Autodiff<Flex>>;

#[derive(Debug)]
struct NormBackward;

impl Backward<Flex, 1> for NormBackward {
    /// The normalised map before ReLU, `1 / sqrt(var + eps)` per plane, whether ReLU follows.
    type State = (FlexTensor, Vec<f32>, bool);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (normed, inv, relu_after) = ops.state;
        if let [Some(node)] = ops.parents {
            grads.register::<Flex>(node.id, backward(&normed, &inv, &dy, relu_after));
        }
    }
}

fn tracked(x: Tracked, eps: f64, relu_after: bool) -> Tracked {
    match NormBackward
        .prepare::<NoCheckpointing>([x.node.clone()])
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let (out, normed, inv) = forward(&x.primitive, eps, relu_after, true);
            let normed = normed.expect("kept for the backward");
            prep.finish((normed, inv, relu_after), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(forward(&x.primitive, eps, relu_after, false).0),
    }
}

#[cfg(test)]
mod tests {
    use burn::prelude::*;
    use burn::tensor::activation::relu;

    fn map<B: Backend>(device: &B::Device) -> Tensor<B, 4> {
        let (n, c, h, w) = (2, 3, 5, 7);
        let v: Vec<f32> = (0..n * c * h * w)
            .map(|i| (i as f32 * 0.71).sin() * 3.0 + (i / 35) as f32)
            .collect();
        Tensor::<B, 1>::from_floats(v.as_slice(), device).reshape([n, c, h, w])
    }

    fn max_diff<B: Backend>(a: Tensor<B, 4>, b: Tensor<B, 4>) -> f32 {
        (a - b).abs().max().into_scalar().elem()
    }

    /// The kernel's output and input gradient against the composed ops, with and without ReLU.
    #[test]
    fn fused_norm_matches_composed_ops() {
        type A = crate::CpuAutodiffBackend;
        let device = Default::default();
        for relu_after in [false, true] {
            let plain =
                super::instance_norm_act(map::<crate::CpuBackend>(&device), 1e-5, relu_after);
            let want = super::composed::instance_norm(map::<crate::CpuBackend>(&device), 1e-5);
            let want = if relu_after { relu(want) } else { want };
            assert!(max_diff(plain, want) < 2e-6, "forward, relu {relu_after}");

            let weights = map::<A>(&device).cos();
            let grad = |ours: bool| {
                let x = map::<A>(&device).require_grad();
                let y = if ours {
                    super::instance_norm_act(x.clone(), 1e-5, relu_after)
                } else {
                    let y = super::composed::instance_norm(x.clone(), 1e-5);
                    if relu_after { relu(y) } else { y }
                };
                let grads = (y * weights.clone()).sum().backward();
                x.grad(&grads).expect("a gradient")
            };
            let (got, want) = (grad(true), grad(false));
            let scale: f32 = want.clone().abs().max().into_scalar().elem();
            let err = max_diff(got, want) / scale;
            assert!(err < 1e-5, "gradient, relu {relu_after}: {err}");
        }
    }
}
