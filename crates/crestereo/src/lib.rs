//! CREStereo (Li et al., CVPR 2022) on Burn 0.21.
//!
//! The network is a faithful port of the reference implementation: the same parameter names
//! (a reference PyTorch state dict loads directly, see [`weights`]), the same cascade
//! hand-over and sign conventions, and explicit PyTorch defaults where Burn's differ
//! (instance norm without affine, `align_corners = true` everywhere with PyTorch's float32
//! interpolation weights, zero padding in the bilinear sampler, LayerNorm eps 1e-5, bias-free
//! attention projections, LoFTR's positional-encoding quirk).
//!
//! Tensors are NCHW float32. Images enter as **BGR** values in 0..255.
//!
//! ```no_run
//! use crestereo::{CREStereoConfig, CpuBackend, InferenceOptions, infer_disparity};
//! use crestereo::io::read_bgr;
//! # fn main() -> anyhow::Result<()> {
//! let device = Default::default();
//! let mut model = CREStereoConfig::new().init::<CpuBackend>(&device);
//! let report = crestereo::weights::load_pytorch(&mut model, "weights.pt", false)?; // applied/missing/unused
//! let (left, right) = (read_bgr("left.png")?, read_bgr("right.png")?);
//! let disp = infer_disparity(&model, &left, &right, InferenceOptions { iters: 20, stages: 2 }, &device)?;
//! crestereo::io::write_exr("disp.exr", disp.width, disp.height, &disp.data)?;
//! # Ok(()) }
//! ```
//!
//! Training: `model.forward(left, right, iters, None)` returns the `2·iters` full-resolution
//! predictions (N, 2, H, W), channel 0 = disparity; [`sequence_loss`] is the reference loss.

pub mod agcl;
pub mod attention;
pub mod conv2d;
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

pub use attention::{
    LinearAttention, LinearAttentionConfig, LoFTREncoderLayer, LoFTREncoderLayerConfig,
};
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
