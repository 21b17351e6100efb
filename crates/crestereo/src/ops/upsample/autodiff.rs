//! Convex upsampling under autodiff on Flex (training): the Flex kernel recorded as one graph
//! node with its own backward (`flex::convex_upsample_grad`), in place of the composed path's
//! softmax, stacked slices, product, sum and permutation nodes.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::tensor::ops::FloatTensor;

use super::flex;

#[derive(Debug)]
struct ConvexUpsampleBackward;

impl Backward<Flex, 2> for ConvexUpsampleBackward {
    /// The flow, the mask and the rate.
    type State = (FlexTensor, FlexTensor, usize);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let d = grads.consume::<Flex>(&ops.node);
        let (flow, mask, rate) = ops.state;
        let (dflow, dmask) = flex::convex_upsample_grad(&flow, &mask, rate, &d);
        let [node_flow, node_mask] = ops.parents;
        if let Some(node) = node_flow {
            grads.register::<Flex>(node.id, dflow);
        }
        if let Some(node) = node_mask {
            grads.register::<Flex>(node.id, dmask);
        }
    }
}

/// [`flex::convex_upsample`] as one tracked operation.
pub(super) fn convex_upsample(
    flow: FloatTensor<Autodiff<Flex>>,
    mask: FloatTensor<Autodiff<Flex>>,
    rate: usize,
) -> FloatTensor<Autodiff<Flex>> {
    let nodes = [flow.node.clone(), mask.node.clone()];
    let (flow, mask) = (flow.primitive, mask.primitive);
    match ConvexUpsampleBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let out = flex::convex_upsample(&flow, &mask, rate);
            prep.finish((flow, mask, rate), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(flex::convex_upsample(&flow, &mask, rate)),
    }
}
