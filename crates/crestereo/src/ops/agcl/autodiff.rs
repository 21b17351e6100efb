//! [`AgclOps`] for `Autodiff<B>`: the inner backend's forward kernel, recorded as one graph
//! node whose backward calls the inner backend's gradient kernel (only for the inputs that
//! require a gradient).

use burn::backend::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::tensor::ops::FloatTensor;

use super::{AgclOps, CorrSpec};

#[derive(Debug)]
struct OffsetCorrBackward;

impl<B: AgclOps> Backward<B, 4> for OffsetCorrBackward {
    /// The four inputs (kept alive for the backward; they are the level's feature maps, the
    /// detached flow and the offsets, all alive anyway) and the static parameters.
    type State = ([FloatTensor<B>; 4], CorrSpec);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let ([left, right, flow, offset], spec) = ops.state;
        let need = ops.parents.each_ref().map(|p| p.is_some());
        let computed = B::agcl_offset_corr_backward(left, right, flow, offset, grad, spec, need);
        for (parent, g) in ops.parents.into_iter().zip(computed) {
            if let (Some(node), Some(g)) = (parent, g) {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

#[derive(Debug)]
struct WarpBackward;

impl<B: AgclOps> Backward<B, 2> for WarpBackward {
    type State = [FloatTensor<B>; 2];

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let [right, flow] = ops.state;
        let need = ops.parents.each_ref().map(|p| p.is_some());
        let computed = B::agcl_warp_backward(right, flow, grad, need);
        for (parent, g) in ops.parents.into_iter().zip(computed) {
            if let (Some(node), Some(g)) = (parent, g) {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: AgclOps, C: CheckpointStrategy> AgclOps for Autodiff<B, C> {
    fn agcl_offset_corr(
        left: FloatTensor<Self>,
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        offset: FloatTensor<Self>,
        spec: CorrSpec,
    ) -> FloatTensor<Self> {
        let nodes = [&left, &right, &flow, &offset].map(|t| t.node.clone());
        let inner = [left, right, flow, offset].map(|t| t.primitive);
        match OffsetCorrBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let [l, r, f, o] = inner.clone();
                let out = B::agcl_offset_corr(l, r, f, o, spec);
                prep.finish((inner, spec), out)
            }
            OpsKind::UnTracked(prep) => {
                let [l, r, f, o] = inner;
                prep.finish(B::agcl_offset_corr(l, r, f, o, spec))
            }
        }
    }

    fn agcl_offset_corr_backward(
        left: FloatTensor<Self>,
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        offset: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: CorrSpec,
        need: [bool; 4],
    ) -> [Option<FloatTensor<Self>>; 4] {
        // Not differentiated twice: run on the inner values, results enter as constants.
        B::agcl_offset_corr_backward(
            left.primitive,
            right.primitive,
            flow.primitive,
            offset.primitive,
            grad.primitive,
            spec,
            need,
        )
        .map(|g| g.map(<Self as burn::tensor::backend::AutodiffBackend>::from_inner))
    }

    fn agcl_warp(right: FloatTensor<Self>, flow: FloatTensor<Self>) -> FloatTensor<Self> {
        let nodes = [&right, &flow].map(|t| t.node.clone());
        let inner = [right, flow].map(|t| t.primitive);
        match WarpBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let [r, f] = inner.clone();
                let out = B::agcl_warp(r, f);
                prep.finish(inner, out)
            }
            OpsKind::UnTracked(prep) => {
                let [r, f] = inner;
                prep.finish(B::agcl_warp(r, f))
            }
        }
    }

    fn agcl_warp_backward(
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        need: [bool; 2],
    ) -> [Option<FloatTensor<Self>>; 2] {
        B::agcl_warp_backward(right.primitive, flow.primitive, grad.primitive, need)
            .map(|g| g.map(<Self as burn::tensor::backend::AutodiffBackend>::from_inner))
    }
}
