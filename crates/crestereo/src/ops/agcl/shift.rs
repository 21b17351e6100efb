//! The 1/4 level's shifted correlation: `left` against the warped right map read at the
//! integer window offsets, replicate border. One kernel with its own backward on Flex and
//! `Autodiff<Flex>`; other backends run the composed version (`composed::shift_corr`: edge
//! pad, one crop per candidate, products and group means), which is what it replaced on the CPU.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::TensorMetadata;
use burn::tensor::ops::FloatTensor;

use super::kernels::{self, Dims};
use super::layout::{channel_last, from_channel_last};
use super::{CorrSpec, composed};
use crate::ops::dispatch::{
    Kernels, from_autodiff_flex, from_flex, kernels_f32, to_autodiff_flex, to_flex,
};

/// Shifted group correlation (N, G·K, H, W) of `left` and `warped` (N, C, H, W).
pub fn shift_corr<B: Backend>(
    left: Tensor<B, 4>,
    warped: Tensor<B, 4>,
    spec: CorrSpec,
) -> Tensor<B, 4> {
    assert_eq!(
        left.dims(),
        warped.dims(),
        "AGCL: left/warped shapes differ"
    );
    match kernels_f32(&[&left, &warped]) {
        Kernels::Flex => from_flex(flex_forward(&to_flex(left), &to_flex(warped), spec)),
        Kernels::AutodiffFlex => {
            let (l, r) = (to_autodiff_flex(left), to_autodiff_flex(warped));
            from_autodiff_flex(autodiff_forward(l, r, spec))
        }
        _ => composed::shift_corr(left, warped, spec),
    }
}

fn dims(t: &FlexTensor) -> Dims {
    let [n, c, h, w] = t.shape().dims();
    Dims { n, c, h, w }
}

fn flex_forward(left: &FlexTensor, warped: &FlexTensor, spec: CorrSpec) -> FlexTensor {
    let d = dims(left);
    let (l, r) = (channel_last(left), channel_last(warped));
    let out = kernels::shift_corr_forward(l.storage(), r.storage(), d, spec);
    from_channel_last(out, d, spec.groups * spec.candidates())
}

#[derive(Debug)]
struct ShiftCorrBackward;

impl Backward<Flex, 2> for ShiftCorrBackward {
    type State = (FlexTensor, FlexTensor, CorrSpec);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<Flex>(&ops.node).to_contiguous();
        let (left, warped, spec) = ops.state;
        let d = dims(&left);
        let (l, r) = (channel_last(&left), channel_last(&warped));
        let (dl, dr) =
            kernels::shift_corr_backward(l.storage(), r.storage(), grad.storage(), d, spec);
        let [node_l, node_r] = ops.parents;
        if let Some(node) = node_l {
            grads.register::<Flex>(node.id, from_channel_last(dl, d, d.c));
        }
        if let Some(node) = node_r {
            grads.register::<Flex>(node.id, from_channel_last(dr, d, d.c));
        }
    }
}

fn autodiff_forward(
    left: FloatTensor<Autodiff<Flex>>,
    warped: FloatTensor<Autodiff<Flex>>,
    spec: CorrSpec,
) -> FloatTensor<Autodiff<Flex>> {
    let nodes = [left.node.clone(), warped.node.clone()];
    let (l, r) = (left.primitive, warped.primitive);
    match ShiftCorrBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let out = flex_forward(&l, &r, spec);
            prep.finish((l, r, spec), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(flex_forward(&l, &r, spec)),
    }
}
