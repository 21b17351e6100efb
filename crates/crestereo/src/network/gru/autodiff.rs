//! The GRU gates under autodiff on Flex (training): the two gate kernels of `flex` recorded as
//! two graph nodes with their own backward (`flex::reset_input_grad`, `flex::blend_grad`), in
//! place of the ~10 element-wise nodes of the composed gates whose backward runs each product,
//! slice and concatenation as its own one-thread pass.

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::tensor::ops::FloatTensor;

use super::flex::{self, GateMath};

type Tracked = FloatTensor<Autodiff<Flex>>;

/// Registers each gradient whose parent requires one.
fn register<const K: usize>(
    grads: &mut Gradients,
    parents: [Option<NodeId>; K],
    computed: [FlexTensor; K],
) {
    for (parent, g) in parents.into_iter().zip(computed) {
        if let Some(id) = parent {
            grads.register::<Flex>(id, g);
        }
    }
}

#[derive(Debug)]
struct ResetInputBackward;

impl Backward<Flex, 3> for ResetInputBackward {
    /// The stacked gate logits and the hidden state.
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let d = grads.consume::<Flex>(&ops.node);
        let (zr, h) = ops.state;
        let (dzr, dh, dx) = flex::reset_input_grad(&zr, &h, &d);
        register(grads, ops.parents.map(|n| n.map(|n| n.id)), [dzr, dh, dx]);
    }
}

#[derive(Debug)]
struct BlendBackward;

impl Backward<Flex, 3> for BlendBackward {
    /// The stacked gate logits, the hidden state and the candidate `tanh(q)` (kept instead of
    /// the logits `q`: the backward needs only it).
    type State = (FlexTensor, FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let d = grads.consume::<Flex>(&ops.node);
        let (zr, h, t) = ops.state;
        let (dzr, dh, dq) = flex::blend_grad(&zr, &h, &t, &d);
        register(grads, ops.parents.map(|n| n.map(|n| n.id)), [dzr, dh, dq]);
    }
}

/// [`flex::reset_input`] as one tracked operation.
pub(super) fn reset_input(zr: Tracked, h: Tracked, x: Tracked) -> Tracked {
    let nodes = [zr.node.clone(), h.node.clone(), x.node.clone()];
    let (zr, h, x) = (zr.primitive, h.primitive, x.primitive);
    match ResetInputBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let out = flex::reset_input(&zr, &h, &x, GateMath::Std);
            prep.finish((zr, h), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(flex::reset_input(&zr, &h, &x, GateMath::Std)),
    }
}

/// [`flex::blend`] as one tracked operation.
pub(super) fn blend(zr: Tracked, h: Tracked, q: Tracked) -> Tracked {
    let nodes = [zr.node.clone(), h.node.clone(), q.node.clone()];
    let (zr, h, q) = (zr.primitive, h.primitive, q.primitive);
    match BlendBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let t = flex::tanh(&q);
            let out = flex::blend_tanh(&zr, &h, &t);
            prep.finish((zr, h, t), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(flex::blend(&zr, &h, &q, GateMath::Std)),
    }
}
