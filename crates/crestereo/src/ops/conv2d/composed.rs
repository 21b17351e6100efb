//! The convolution by Burn's own op: the fallback where no kernel applies (other backends,
//! float64, grouped convolutions) and the reference the kernels are tested
//! against.

use burn::prelude::*;
use burn::tensor::ops::ConvOptions;

use super::Conv2d;

/// Burn's convolution with `conv`'s parameters (any backend and dtype; parameters cast to the
/// input's float dtype, so a float64 input runs in float64).
pub fn conv2d<B: Backend>(conv: &Conv2d<B>, x: Tensor<B, 4>) -> Tensor<B, 4> {
    let dtype = x.dtype();
    let cast = |t: Tensor<B, 4>| match dtype == t.dtype() {
        true => t,
        false => t.cast(dtype),
    };
    let weight = cast(conv.weight.val());
    let bias = conv.bias.as_ref().map(|b| {
        let b = b.val();
        if b.dtype() == dtype { b } else { b.cast(dtype) }
    });
    let padding = conv.symmetric_padding().unwrap_or_else(|| {
        panic!(
            "convolution padding {:?} is not symmetric explicit or valid",
            conv.padding
        )
    });
    burn::tensor::module::conv2d(
        x,
        weight,
        bias,
        ConvOptions::new(conv.stride, padding, conv.dilation, conv.groups),
    )
}
