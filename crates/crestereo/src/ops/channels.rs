//! Concatenation: [`cat`], Burn's with its inputs kept alive until its output is in the autodiff
//! graph, and [`cat_channels`], two maps along channels on Flex, copied in parallel, with its own
//! backward.
//!
//! Flex concatenates on the calling thread, and Burn's backward of a concatenation hands each
//! part a strided view of the gradient, which the next gradient sum then walks element by
//! element on one thread. The GRU input `[h, x]` and the update block's `[context, motion]`
//! are concatenated every iteration; the other threads waited through both.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

use crate::ops::dispatch::{Kernels, from_autodiff_flex, from_flex, kernels_f32, same};

/// `Tensor::cat(tensors, dim)`, safe beside a `backward()` on another thread: the network's and
/// the trainer's one way to concatenate (`Tensor::cat` and `Tensor::stack` are disallowed by the
/// workspace's `clippy.toml`).
///
/// Burn 0.21's autodiff concatenation lets go of its inputs (their reference counts, which tell
/// Burn a node is still wanted) before it registers its output (tracel-ai/burn#5573). Every
/// `backward()` ends by sweeping all the graphs of the process and frees the steps of any graph in
/// which no tensor is referenced: a backward finishing on another thread inside that window (a
/// replica on another device, another test) freed the convolutions of the flow branch before the
/// motion encoder's concatenation joined it to the loss, and their parameters silently lost part
/// of their gradient. Clones of the inputs, held until the output is registered, close the window;
/// they share the inputs' storage, so nothing is copied.
pub fn cat<B: Backend, const D: usize>(tensors: Vec<Tensor<B, D>>, dim: usize) -> Tensor<B, D> {
    let kept = tensors.clone();
    #[allow(clippy::disallowed_methods)] // the one call, with its inputs held
    let out = Tensor::cat(tensors, dim);
    drop(kept);
    out
}

/// `Tensor::cat([a, b], 1)` for (N, C, H, W) maps: the same values (and gradients), copied in
/// parallel on Flex with float32 maps, Burn's concatenation elsewhere.
pub(crate) fn cat_channels<B: Backend>(a: Tensor<B, 4>, b: Tensor<B, 4>) -> Tensor<B, 4> {
    match kernels_f32(&[&a, &b]) {
        Kernels::Flex => {
            let (a, b): (FlexTensor, FlexTensor) = (
                same(a.into_primitive().tensor()),
                same(b.into_primitive().tensor()),
            );
            from_flex(cat_flex(&[a, b]))
        }
        Kernels::AutodiffFlex => from_autodiff_flex(tracked_cat(
            same(a.into_primitive().tensor()),
            same(b.into_primitive().tensor()),
        )),
        _ => cat(vec![a, b], 1),
    }
}

type Tracked = burn::tensor::ops::FloatTensor<Autodiff<Flex>>;

#[derive(Debug)]
struct CatBackward;

impl Backward<Flex, 2> for CatBackward {
    /// The channels of the first part.
    type State = usize;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let d = grads.consume::<Flex>(&ops.node).to_contiguous();
        let [n, c, h, w] = d.shape().dims();
        let first = ops.state;
        let ranges = [(0, first), (first, c - first)];
        for (parent, (start, channels)) in ops.parents.into_iter().zip(ranges) {
            if let Some(node) = parent {
                let part = channel_range(d.storage(), [n, c, h, w], start, channels);
                grads.register::<Flex>(node.id, part);
            }
        }
    }
}

fn tracked_cat(a: Tracked, b: Tracked) -> Tracked {
    let nodes = [a.node.clone(), b.node.clone()];
    let first = a.primitive.shape().dims::<4>()[1];
    let parts = [a.primitive, b.primitive];
    match CatBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => prep.finish(first, cat_flex(&parts)),
        OpsKind::UnTracked(prep) => prep.finish(cat_flex(&parts)),
    }
}

/// Channels `start..start + channels` of a contiguous (N, C, H, W) map, as a contiguous map.
fn channel_range(
    src: &[f32],
    [n, c, h, w]: [usize; 4],
    start: usize,
    channels: usize,
) -> FlexTensor {
    let plane = h * w;
    let mut out = vec![0f32; n * channels * plane];
    out.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(j, dst)| {
            let (b, k) = (j / channels, j % channels);
            dst.copy_from_slice(&src[(b * c + start + k) * plane..][..plane]);
        });
    FlexTensor::from_data(TensorData::new(out, [n, channels, h, w]))
}

/// `[a, b]` along channels: output channel k of image i is channel k of `a`, or k − C_a of `b`.
fn cat_flex([a, b]: &[FlexTensor; 2]) -> FlexTensor {
    let [n, ca, h, w] = a.shape().dims();
    let cb = b.shape().dims::<4>()[1];
    let (c, plane) = (ca + cb, h * w);
    let (a, b) = (a.to_contiguous(), b.to_contiguous());
    let (a, b): (&[f32], &[f32]) = (a.storage(), b.storage());
    let mut out = vec![0f32; n * c * plane];
    out.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(j, dst)| {
            let (i, k) = (j / c, j % c);
            let src = if k < ca {
                &a[(i * ca + k) * plane..]
            } else {
                &b[(i * cb + k - ca) * plane..]
            };
            dst.copy_from_slice(&src[..plane]);
        });
    FlexTensor::from_data(TensorData::new(out, [n, c, h, w]))
}

#[cfg(test)]
mod tests {
    use burn::prelude::*;

    use crate::CpuBackend;

    fn map<B: Backend>(c: usize, s: f32, device: &B::Device) -> Tensor<B, 4> {
        let v: Vec<f32> = (0..2 * c * 3 * 4).map(|i| (i as f32 * s).sin()).collect();
        Tensor::<B, 1>::from_floats(v.as_slice(), device).reshape([2, c, 3, 4])
    }

    /// The parallel copy gives exactly Burn's concatenation, a strided view as input included.
    #[test]
    fn cat_channels_matches_burn_cat() {
        let device = Default::default();
        let a = map::<CpuBackend>(3, 1.0, &device);
        let b = map::<CpuBackend>(6, -0.5, &device)
            .swap_dims(2, 3)
            .swap_dims(2, 3)
            .narrow(1, 1, 4);
        let want = super::cat(vec![a.clone(), b.clone()], 1);
        let got = super::cat_channels(a, b);
        assert_eq!(got.dims(), want.dims());
        assert_eq!(got.into_data(), want.into_data());
    }

    /// Under autodiff the values and both parts' gradients are exactly Burn's.
    #[test]
    fn cat_channels_gradients_match_burn_cat() {
        type A = crate::CpuAutodiffBackend;
        let device = Default::default();
        let weights = map::<A>(7, 0.37, &device);
        let run = |ours: bool| {
            let a = map::<A>(3, 1.0, &device).require_grad();
            let b = map::<A>(4, -0.5, &device).require_grad();
            let y = if ours {
                super::cat_channels(a.clone(), b.clone())
            } else {
                super::cat(vec![a.clone(), b.clone()], 1)
            };
            // b also reaches the loss directly, so its two gradients are summed
            let loss = (y.clone() * weights.clone()).sum() + (b.clone() * b.clone()).sum();
            let grads = loss.backward();
            let ga = a.grad(&grads).expect("a gradient").into_data();
            let gb = b.grad(&grads).expect("a gradient").into_data();
            (y.inner().into_data(), ga, gb)
        };
        assert_eq!(run(true), run(false));
    }

    /// A `backward()` finishing on another thread while a training step builds its graph leaves
    /// the step's gradients bit-identical. Threads that train in one process (the replicas of a
    /// data-parallel run, tests) do this all the time; with Burn's concatenation unguarded, the
    /// flow branch of the motion encoder lost its gradient in every one of 10 runs of this test.
    #[test]
    fn a_concurrent_backward_leaves_a_step_unchanged() {
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

        use crate::test_util::{differing_gradients, fixed_step_gradients};
        use crate::{CREStereoConfig, CpuAutodiffBackend};
        type A = CpuAutodiffBackend;
        let device = Default::default();
        let model = CREStereoConfig::new().init::<A>(&device);
        // The model's parameters have been through a backward once: as in the second
        // micro-batch of an accumulated step, their first use starts a graph of its own.
        let quiet = fixed_step_gradients(&model);
        let (stop, passes) = (AtomicBool::new(false), AtomicUsize::new(0));
        let (differ, during) = std::thread::scope(|s| {
            s.spawn(|| {
                let x = Tensor::<A, 1>::from_floats([1.0, 2.0, 3.0], &device).require_grad();
                while !stop.load(Ordering::Relaxed) {
                    let _ = (x.clone() * 2.0).sum().backward();
                    passes.fetch_add(1, Ordering::Relaxed);
                }
            });
            let mut differ = Vec::new();
            let before = passes.load(Ordering::Relaxed);
            for _ in 0..3 {
                for name in differing_gradients(&quiet, &fixed_step_gradients(&model)) {
                    if !differ.contains(&name) {
                        differ.push(name);
                    }
                }
            }
            let during = passes.load(Ordering::Relaxed) - before;
            stop.store(true, Ordering::Relaxed);
            (differ, during)
        });
        // Without backward passes beside the steps the test would prove nothing.
        assert!(
            during > 0,
            "no backward ran on the other thread during the steps"
        );
        assert!(
            differ.is_empty(),
            "gradients changed by a backward on another thread ({during} of them during the steps): {differ:?}"
        );
    }
}
