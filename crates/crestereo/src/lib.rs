//! CREStereo (Li et al., CVPR 2022) on Burn 0.21.
//!
//! The network is a faithful port of the reference implementation: the same parameter names
//! (a reference PyTorch state dict loads directly, see [`weights`]), the same cascade
//! hand-over and sign conventions, and explicit PyTorch defaults where Burn's differ
//! (instance norm without affine, `align_corners = true` everywhere with PyTorch's float32
//! interpolation weights, zero padding in the bilinear sampler, LayerNorm eps 1e-5, bias-free
//! attention projections, LoFTR's positional-encoding quirk).
//!
//! Tensors are NCHW float32. Images enter as [`BgrImage`]: **BGR** values in 0..255, made from
//! 8-bit RGB decoded by `stereo-io` (the one image path, see [`input`]). This crate holds the
//! network only; files are read and written by `stereo-io`.
//!
//! ```no_run
//! use std::path::Path;
//! use crestereo::{BgrImage, CREStereoConfig, CpuBackend, InferenceOptions, infer_disparity};
//! # fn main() -> anyhow::Result<()> {
//! let device = Default::default();
//! let mut model = CREStereoConfig::new().init::<CpuBackend>(&device);
//! let report = crestereo::weights::load_pytorch(&mut model, "weights.pt", false)?; // applied/missing/unused
//! let read = |p: &str| stereo_io::read_rgb(Path::new(p)).map(|rgb| BgrImage::from_rgb(&rgb));
//! let (left, right) = (read("left.png")?, read("right.png")?);
//! let disp = infer_disparity(&model, &left, &right, InferenceOptions { iters: 20, stages: 2 }, &device)?;
//! stereo_io::write_disparity(Path::new("disp.exr"), &disp, &Default::default(), None)?;
//! # Ok(()) }
//! ```
//!
//! Training: `model.forward(left, right, iters, None)` returns the `2·iters` full-resolution
//! predictions (N, 2, H, W), channel 0 = disparity; [`sequence_loss`] is the reference loss.
//! [`CREStereo::forward_observed`] shows the intermediates to a [`ForwardObserver`].

// The crate in floors: `ops` (the kernels, their dispatch and composed fallbacks) at the bottom,
// `network` (the modules, read top-down like the reference: encoder, attention, correlation,
// update, refinement, model) on it, `export` (the ONNX graph builder and the exporter) and
// `weights` above, `infer` (the cascade driver) on top.
pub mod export;
pub mod infer;
pub mod input;
pub mod loss;
pub mod network;
pub mod ops;
pub mod weights;

pub use infer::{InferenceOptions, infer_disparity};
pub use input::BgrImage;
pub use loss::sequence_loss;
pub use network::attention::{
    LinearAttention, LinearAttentionConfig, LoFTREncoderLayer, LoFTREncoderLayerConfig,
};
pub use network::corr::{AdaptiveGroupCorrelation, AdaptiveGroupCorrelationConfig, SearchWindow};
pub use network::encoder::{BasicEncoder, BasicEncoderConfig, ResidualBlock, ResidualBlockConfig};
pub use network::gru::{SepConvGru, SepConvGruConfig};
pub use network::model::{CREStereo, CREStereoConfig};
pub use network::motion_encoder::{BasicMotionEncoder, BasicMotionEncoderConfig};
pub use network::observer::{ForwardObserver, IterationOutputs, NoObserver};
pub use network::position_encoding::{PositionEncodingSine, PositionEncodingSineConfig};
pub use network::refine::Level;
pub use network::update::{UpdateBlock, UpdateBlockConfig};
pub use ops::channels::cat;
pub use ops::upsample::{convex_upsample, resize_bilinear_align_corners};

// The backends the network's kernels are written for, named here once for every crate that picks
// one: a type spelt out elsewhere that drifted from these would run the composed ops silently.
/// The CPU backend used by the tests, the CLI and the bench.
pub type CpuBackend = burn::backend::Flex;
/// The CPU backend with autodiff (training).
pub type CpuAutodiffBackend = burn::backend::Autodiff<burn::backend::Flex>;
#[cfg(feature = "cuda")]
pub use ops::dispatch::CudaBackend;
/// The CUDA backend with autodiff (training).
#[cfg(feature = "cuda")]
pub type CudaAutodiffBackend = burn::backend::Autodiff<CudaBackend>;
#[cfg(feature = "wgpu")]
pub use ops::dispatch::WgpuBackend;
/// The wgpu backend with autodiff (training).
#[cfg(feature = "wgpu")]
pub type WgpuAutodiffBackend = burn::backend::Autodiff<WgpuBackend>;

/// Helpers of the unit tests that compare a kernel with the composed ops it replaces.
#[cfg(test)]
mod test_util {
    use burn::prelude::*;

    use crate::weights::NamedArray;
    use crate::{CREStereo, CpuAutodiffBackend, sequence_loss};

    /// The named gradients of one training step of `model` (two iterations, loss with γ 0.9)
    /// on a fixed 32×64 pair and disparity.
    pub(crate) fn fixed_step_gradients(model: &CREStereo<CpuAutodiffBackend>) -> Vec<NamedArray> {
        type A = CpuAutodiffBackend;
        let device = Default::default();
        let (n, h, w) = (1, 32, 64);
        let image = |salt: usize| {
            let v: Vec<f32> = (0..n * 3 * h * w)
                .map(|i| (((i * 7919 + salt * 104_729) % 2003) as f32) * 0.1)
                .collect();
            Tensor::<A, 1>::from_floats(v.as_slice(), &device).reshape([n, 3, h, w])
        };
        let d: Vec<f32> = (0..n * h * w).map(|i| (i % 37) as f32 * 0.5).collect();
        let disp = Tensor::<A, 1>::from_floats(d.as_slice(), &device).reshape([n, h, w]);
        let valid = Tensor::<A, 3>::ones([n, h, w], &device);
        let preds = model.forward(image(1), image(2), 2, None);
        let grads = sequence_loss(&preds, disp, valid, 0.9).backward();
        crate::weights::named_gradients(model, &grads)
    }

    /// The parameters whose gradients differ in any bit between `a` and `b`.
    pub(crate) fn differing_gradients(a: &[NamedArray], b: &[NamedArray]) -> Vec<String> {
        assert_eq!(a.len(), b.len(), "gradient lists of different lengths");
        a.iter()
            .zip(b)
            .filter(|(x, y)| {
                x.data.len() != y.data.len()
                    || x.data
                        .iter()
                        .zip(&y.data)
                        .any(|(p, q)| p.to_bits() != q.to_bits())
            })
            .map(|(x, _)| x.name.clone())
            .collect()
    }

    /// A Flex tensor of values drawn uniformly from `lo..hi`.
    pub(crate) fn uniform<const D: usize>(
        shape: [usize; D],
        lo: f64,
        hi: f64,
    ) -> Tensor<crate::CpuBackend, D> {
        Tensor::random(
            shape,
            burn::tensor::Distribution::Uniform(lo, hi),
            &Default::default(),
        )
    }

    /// The largest absolute difference of two tensors.
    pub(crate) fn max_abs<B: Backend>(a: Tensor<B, 4>, b: Tensor<B, 4>) -> f32 {
        (a - b).abs().max().into_scalar().elem()
    }

    /// A kernel's output and named gradients against the composed ops': output within 1e-5, each
    /// gradient within 1e-5 of its largest magnitude (at least 1).
    pub(crate) fn assert_output_and_grads_close<B: Backend, const K: usize>(
        label: &str,
        names: [&str; K],
        (out_k, grads_k): (Tensor<B, 4>, [Tensor<B, 4>; K]),
        (out_c, grads_c): (Tensor<B, 4>, [Tensor<B, 4>; K]),
    ) {
        let diff = max_abs(out_k, out_c);
        assert!(diff < 1e-5, "{label} output: max difference {diff}");
        for ((name, k), c) in names.iter().zip(grads_k).zip(grads_c) {
            let scale: f32 = c.clone().abs().max().into_scalar().elem();
            let diff = max_abs(k, c);
            assert!(
                diff <= 1e-5 * scale.max(1.0),
                "{label} d {name}: max difference {diff} (scale {scale})"
            );
        }
    }
}
