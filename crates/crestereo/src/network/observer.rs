//! A hook into the forward pass: the parity tests (and anyone debugging) see the intermediate
//! tensors at named points without the network storing them.

use burn::prelude::*;

use crate::network::level::Level;

/// Called by [`crate::CREStereo::forward_observed`] at named points of the forward pass, in
/// order. Every method does nothing by default; implement those whose tensors you want (clone
/// a tensor to keep it: clones share the data).
pub trait ForwardObserver<B: Backend> {
    /// The encoder's 1/4-resolution feature maps of the left and right image (N, 256, H/4, W/4).
    fn features(&mut self, _left: &Tensor<B, 4>, _right: &Tensor<B, 4>) {}

    /// The learned-offset convolution's output before the sigmoid (N, 18, h, w), at 1/8 and 1/16.
    fn offset_logits(&mut self, _level: Level, _logits: &Tensor<B, 4>) {}

    /// The positional encoding added to both 1/16 maps before self-attention (C, H/16, W/16).
    fn positional_encoding(&mut self, _table: &Tensor<B, 3>) {}

    /// The self-attention output tokens (N, H/16·W/16, C), row-major.
    fn self_attention(&mut self, _left: &Tensor<B, 3>, _right: &Tensor<B, 3>) {}

    /// The cross-attention output tokens inside the 1/16 correlation of iteration `iteration`.
    fn cross_attention(&mut self, _iteration: usize, _left: &Tensor<B, 3>, _right: &Tensor<B, 3>) {}

    /// One refinement iteration's correlation and update-block outputs.
    fn iteration(&mut self, _step: &IterationOutputs<'_, B>) {}
}

/// What one refinement iteration computed, for [`ForwardObserver::iteration`].
#[derive(Debug)]
pub struct IterationOutputs<'a, B: Backend> {
    pub level: Level,
    /// The iteration's index within its level.
    pub index: usize,
    /// The correlation volume (N, groups·9, h, w).
    pub corr: &'a Tensor<B, 4>,
    /// The flow update (N, 2, h, w).
    pub delta_flow: &'a Tensor<B, 4>,
    /// The convex-upsampling weights (N, 9·rate², h, w).
    pub up_mask: &'a Tensor<B, 4>,
    /// The new hidden state (N, hidden, h, w).
    pub net: &'a Tensor<B, 4>,
}

/// The observer of a plain [`crate::CREStereo::forward`]: sees nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoObserver;

impl<B: Backend> ForwardObserver<B> for NoObserver {}
