//! Inference: padding, the reference two-pass test procedure and N stacked cascades.

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::ops::PadMode;

use crate::io::BgrImage;
use crate::model::CREStereo;
use crate::upsample::resize_bilinear_align_corners;

#[derive(Debug, Clone, Copy)]
pub struct InferenceOptions {
    /// Iterations per pass (the reference test procedure uses 20).
    pub iters: usize,
    /// Number of stacked cascades: 1 = one full-resolution pass without initialisation;
    /// 2 = the reference procedure (½ resolution pass, then full resolution with `flow_init`,
    /// only the 1/4 level); 3 = ¼, ½, full.
    pub stages: usize,
}

impl Default for InferenceOptions {
    fn default() -> Self {
        Self {
            iters: 20,
            stages: 2,
        }
    }
}

/// A float32 disparity map (positive values, row-major).
#[derive(Debug, Clone)]
pub struct Disparity {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

/// Image tensor (1, 3, H, W) from a BGR image.
pub fn image_tensor<B: Backend>(img: &BgrImage, device: &B::Device) -> Tensor<B, 4> {
    Tensor::from_data(
        TensorData::new(img.data.clone(), [1, 3, img.height, img.width]),
        device,
    )
}

/// The stacked-cascade procedure on (N, 3, H, W) BGR tensors whose size is a multiple of
/// `16 · 2^(stages−1)`. Stage `s` (of `stages`) runs on the pair resized (bilinear,
/// align_corners) to `H / 2^(stages−1−s)`; the first stage has no initialisation, each later one
/// is initialised with the previous prediction and runs only the 1/4 level.
/// Returns the final prediction (N, 2, H, W); channel 0 is the disparity.
pub fn cascade<B: Backend>(
    model: &CREStereo<B>,
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    opts: InferenceOptions,
) -> Tensor<B, 4> {
    assert!(opts.stages >= 1 && opts.iters >= 1);
    let [_, _, h, w] = left.dims();
    let mut flow: Option<Tensor<B, 4>> = None;
    for s in 0..opts.stages {
        let f = 1usize << (opts.stages - 1 - s);
        let (l, r) = if f == 1 {
            (left.clone(), right.clone())
        } else {
            (
                resize_bilinear_align_corners(left.clone(), [h / f, w / f]),
                resize_bilinear_align_corners(right.clone(), [h / f, w / f]),
            )
        };
        let preds = model.forward(l, r, opts.iters, flow.take());
        flow = preds.into_iter().last();
    }
    flow.expect("at least one prediction")
}

/// Runs the network on an image pair of any size: pads (edge replicate, bottom/right) to a
/// multiple of `16 · 2^(stages−1)` (32 for the reference two-stage procedure), runs
/// [`cascade`] and crops back.
pub fn infer_disparity<B: Backend>(
    model: &CREStereo<B>,
    left: &BgrImage,
    right: &BgrImage,
    opts: InferenceOptions,
    device: &B::Device,
) -> Result<Disparity> {
    if (left.width, left.height) != (right.width, right.height) {
        bail!(
            "left and right images differ in size: {}x{} vs {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
    }
    if opts.stages == 0 || opts.stages > 4 {
        bail!("stages must be 1..=4, got {}", opts.stages);
    }
    if opts.iters == 0 {
        bail!("iters must be at least 1");
    }
    let m = 16usize << (opts.stages - 1);
    let (w, h) = (left.width, left.height);
    let (pw, ph) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
    let pad = |t: Tensor<B, 4>| {
        if (pw, ph) == (w, h) {
            t
        } else {
            t.pad((0, pw - w, 0, ph - h), PadMode::Edge)
        }
    };
    let l = pad(image_tensor::<B>(left, device));
    let r = pad(image_tensor::<B>(right, device));
    let pred = cascade(model, l, r, opts);
    let disp = pred.slice([0..1, 0..1, 0..h, 0..w]).reshape([h * w]);
    let data: Vec<f32> = disp
        .into_data()
        .convert::<f32>()
        .into_vec()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    Ok(Disparity {
        width: w,
        height: h,
        data,
    })
}
