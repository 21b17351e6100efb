//! The operations the network is built from, each with its CPU (Flex) and GPU (CubeCL) kernels
//! and the composed Burn ops it falls back to: which one runs is decided in [`dispatch`].
//! Concatenation, instance norm, 2-D convolution, the AGCL correlation and convex upsampling;
//! [`simd`] and [`threads`] say how the CPU kernels use the processor.

pub mod agcl;
pub(crate) mod channels;
pub mod conv2d;
pub mod dispatch;
pub(crate) mod norm;
pub mod simd;
pub mod threads;
pub mod upsample;
