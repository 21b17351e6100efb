//! [`MatmulOps`] for `Autodiff<B>`: the inner backend's product, recorded as one graph node
//! whose backward is two more fixed float32 products, `dL = dY · Rᵀ` and `dR = Lᵀ · dY`.

use burn::backend::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::tensor::TensorMetadata;
use burn::tensor::ops::FloatTensor;

use super::MatmulOps;

/// The inner tensor with its last two dimensions swapped.
fn transposed<B: MatmulOps>(t: FloatTensor<B>) -> FloatTensor<B> {
    let rank = TensorMetadata::shape(&t).num_dims();
    B::float_swap_dims(t, rank - 2, rank - 1)
}

#[derive(Debug)]
struct MatmulBackward;

impl<B: MatmulOps> Backward<B, 2> for MatmulBackward {
    type State = [FloatTensor<B>; 2];

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let [lhs, rhs] = ops.state;
        let [lhs_node, rhs_node] = ops.parents;
        if let Some(node) = lhs_node {
            grads.register::<B>(node.id, B::f32_matmul(grad.clone(), transposed::<B>(rhs)));
        }
        if let Some(node) = rhs_node {
            grads.register::<B>(node.id, B::f32_matmul(transposed::<B>(lhs), grad));
        }
    }
}

impl<B: MatmulOps, C: CheckpointStrategy> MatmulOps for Autodiff<B, C> {
    fn f32_matmul(lhs: FloatTensor<Self>, rhs: FloatTensor<Self>) -> FloatTensor<Self> {
        let nodes = [&lhs, &rhs].map(|t| t.node.clone());
        let inner = [lhs.primitive, rhs.primitive];
        match MatmulBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let [l, r] = inner.clone();
                prep.finish(inner, B::f32_matmul(l, r))
            }
            OpsKind::UnTracked(prep) => {
                let [l, r] = inner;
                prep.finish(B::f32_matmul(l, r))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::backend::Flex;

    /// Burn's own product on Flex, so the recorded node's backward can be checked on the CPU.
    impl MatmulOps for Flex {
        fn f32_matmul(l: FloatTensor<Self>, r: FloatTensor<Self>) -> FloatTensor<Self> {
            <Flex as burn::tensor::ops::FloatTensorOps<Flex>>::float_matmul(l, r)
        }
    }

    /// The gradients of the recorded product equal Burn's matmul gradients (exercised on Flex
    /// through the same `Backward`: the fixed kernel itself runs on CubeCL backends only, and
    /// is checked on lavapipe in `crestereo-train/tests/vulkan.rs`).
    #[test]
    fn backward_matches_burns_matmul() {
        use burn::prelude::*;
        use burn::tensor::TensorPrimitive;
        type A = Autodiff<Flex>;
        let d = Default::default();
        let l = Tensor::<A, 3>::random([2, 3, 4], burn::tensor::Distribution::Default, &d)
            .require_grad();
        let r = Tensor::<A, 3>::random([2, 4, 5], burn::tensor::Distribution::Default, &d)
            .require_grad();
        let ours: Tensor<A, 3> =
            Tensor::from_primitive(TensorPrimitive::Float(<A as MatmulOps>::f32_matmul(
                l.clone().into_primitive().tensor(),
                r.clone().into_primitive().tensor(),
            )));
        let g = ours.clone().sin().sum().backward();
        let (gl, gr) = (l.grad(&g).unwrap(), r.grad(&g).unwrap());
        let (l2, r2) = (l.detach().require_grad(), r.detach().require_grad());
        let burns = l2.clone().matmul(r2.clone());
        let g2 = burns.clone().sin().sum().backward();
        ours.into_data()
            .assert_approx_eq::<f32>(&burns.into_data(), burn::tensor::Tolerance::default());
        gl.into_data().assert_approx_eq::<f32>(
            &l2.grad(&g2).unwrap().into_data(),
            burn::tensor::Tolerance::default(),
        );
        gr.into_data().assert_approx_eq::<f32>(
            &r2.grad(&g2).unwrap().into_data(),
            burn::tensor::Tolerance::default(),
        );
    }
}
