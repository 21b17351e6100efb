//! CREStereo (Li et al., CVPR 2022) on Burn.
//!
//! The network is a faithful port of the reference implementation: the same parameter names
//! (so a reference PyTorch state dict loads directly, see [`weights`]), the same cascade
//! hand-over and sign conventions, and explicit PyTorch defaults where Burn's differ
//! (instance norm without affine, `align_corners = true` everywhere, zero padding in the
//! bilinear sampler, LayerNorm eps 1e-5, bias-free attention projections).
//!
//! Tensors are NCHW, float32. Images enter as BGR values in 0..255.

pub mod attention;
pub mod corr;
pub mod encoder;
pub mod gru;
pub mod infer;
pub mod io;
pub mod loss;
pub mod model;
pub mod motion_encoder;
pub mod npy;
pub mod position_encoding;
pub mod update;
pub mod upsample;
pub mod weights;

pub use attention::{LinearAttention, LinearAttentionConfig, LoFTREncoderLayer, LoFTREncoderLayerConfig};
pub use corr::{AdaptiveGroupCorrelation, AdaptiveGroupCorrelationConfig, SearchWindow};
pub use encoder::{BasicEncoder, BasicEncoderConfig, ResidualBlock, ResidualBlockConfig};
pub use gru::{SepConvGru, SepConvGruConfig};
pub use infer::{InferenceOptions, infer_disparity};
pub use loss::sequence_loss;
pub use model::{CREStereo, CREStereoConfig, Trace};
pub use motion_encoder::{BasicMotionEncoder, BasicMotionEncoderConfig};
pub use position_encoding::{PositionEncodingSine, PositionEncodingSineConfig};
pub use update::{UpdateBlock, UpdateBlockConfig};
pub use upsample::{convex_upsample, resize_bilinear_align_corners};

/// The CPU backend used by the tests, the CLI and the bench.
pub type CpuBackend = burn::backend::Flex;
/// The CPU backend with autodiff (training).
pub type CpuAutodiffBackend = burn::backend::Autodiff<burn::backend::Flex>;
