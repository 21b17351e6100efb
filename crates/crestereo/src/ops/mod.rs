//! The operations the network is built from, each with its CPU (Flex) and GPU (CubeCL) kernels
//! and the composed Burn ops it falls back to: which one runs is decided in [`dispatch`].
//! Concatenation, instance norm, 2-D convolution, matrix products (full float32 on CubeCL
//! backends), the AGCL correlation and convex upsampling;
//! [`simd`] and [`threads`] say how the CPU kernels use the processor.

pub mod agcl;
pub(crate) mod channels;
mod compiled;
pub mod conv2d;
pub mod dispatch;
pub mod matmul;
pub(crate) mod norm;
pub mod simd;
pub mod threads;
pub mod upsample;

/// `t` in float dtype `dtype` (constants made in float32 join a float64 network this way).
pub(crate) fn float_like<B: burn::prelude::Backend, const D: usize>(
    t: burn::prelude::Tensor<B, D>,
    dtype: burn::tensor::DType,
) -> burn::prelude::Tensor<B, D> {
    if t.dtype() == dtype { t } else { t.cast(dtype) }
}
