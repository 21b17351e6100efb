//! Inference: padding, the reference two-pass test procedure and N stacked cascades.

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::ops::PadMode;
use stereo_io::DisparityMap;

use crate::input::BgrImage;
use crate::network::model::CREStereo;
use crate::ops::upsample::{emit_resize_bilinear_align_corners, resize_bilinear_align_corners};

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

impl InferenceOptions {
    /// The stacked cascades the network runs: 1 to 4.
    pub const STAGES: std::ops::RangeInclusive<usize> = 1..=4;

    /// One clear line when the stages or iterations are out of range.
    pub fn check(&self) -> Result<()> {
        if !Self::STAGES.contains(&self.stages) {
            bail!(
                "stages must be {}..={}, got {}",
                Self::STAGES.start(),
                Self::STAGES.end(),
                self.stages
            );
        }
        if self.iters == 0 {
            bail!("iters must be at least 1");
        }
        Ok(())
    }

    /// (multiple, minimum) of the image height and width these options take: every stage's 1/16
    /// level must have whole pixels, two or more per axis (the sampling grid is normalised by
    /// `size − 1`). `crestereo infer` pads to the multiple; a fixed-size graph must be one.
    pub fn size_rule(&self) -> (usize, usize) {
        let multiple = 16usize << (self.stages.max(1) - 1);
        (multiple, 2 * multiple)
    }

    /// One clear line when a fixed input size `[h, w]` (an ONNX graph's) does not suit these
    /// options.
    pub fn check_size(&self, size: [usize; 2]) -> Result<()> {
        self.check()?;
        let (multiple, minimum) = self.size_rule();
        let [h, w] = size;
        // The network's input limit; the graph's constant tables (pixel grids, resize matrices)
        // grow with the size, so it is refused here, before any is built.
        if h > MAX_INPUT_SIDE || w > MAX_INPUT_SIDE || h * w > MAX_INPUT_PIXELS {
            bail!(
                "size {h}x{w} is over the network's limit ({MAX_INPUT_SIDE} px a side, {MAX_INPUT_PIXELS} pixels)"
            );
        }
        if h % multiple != 0 || w % multiple != 0 {
            let up = |v: usize| v.div_ceil(multiple) * multiple;
            bail!(
                "size {h}x{w} is not a multiple of {multiple} in both axes ({} stage(s) need it); the nearest sizes that are: {}x{}, {}x{} (pad the images to it, as `crestereo infer` does)",
                self.stages,
                up(h),
                up(w),
                (h / multiple).max(1) * multiple,
                (w / multiple).max(1) * multiple
            );
        }
        if h < minimum || w < minimum {
            bail!(
                "size {h}x{w} is too small: {} stage(s) need at least {minimum}x{minimum}",
                self.stages
            );
        }
        Ok(())
    }
}

/// The longest side of an image the network takes (after padding to its multiple).
pub const MAX_INPUT_SIDE: usize = 8192;
/// The most pixels of an image the network takes (after padding): 2^24, e.g. 4096×4096 or
/// 5472×3072. The network's memory grows with the pixels: `crestereo infer` (two stages, CPU
/// backend) peaked at 186 MB for 512×256 and 470 MB for 1024×512, about 0.72 KB a pixel, so this
/// bounds one inference to about 12 GiB. The ONNX graph grows by about 11 bytes a pixel (23.7 MB
/// at 256×512, 45.3 MB at 1024×2048), so at this limit it is about 0.2 GB, far inside protobuf's
/// 2 GiB.
pub const MAX_INPUT_PIXELS: usize = 1 << 24;

/// Refuses, before anything is allocated for it, an image of `width` × `height` (padded) that
/// the network does not take.
pub fn check_input_size(width: usize, height: usize) -> Result<()> {
    if width > MAX_INPUT_SIDE || height > MAX_INPUT_SIDE || width * height > MAX_INPUT_PIXELS {
        bail!(
            "an image of {width}x{height} pixels is over the network's limit ({MAX_INPUT_SIDE} px a side, {MAX_INPUT_PIXELS} pixels after padding): scale it down or crop it"
        );
    }
    Ok(())
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

/// [`cascade`] as ONNX nodes: the same stages, resizes and hand-overs.
pub fn emit_cascade<B: Backend>(
    model: &CREStereo<B>,
    g: &mut crate::export::onnx::Graph,
    left: &crate::export::onnx::Value,
    right: &crate::export::onnx::Value,
    opts: InferenceOptions,
) -> crate::export::onnx::Value {
    assert!(opts.stages >= 1 && opts.iters >= 1);
    let [_, _, h, w] = left.dims();
    let mut flow: Option<crate::export::onnx::Value> = None;
    for s in 0..opts.stages {
        let f = 1usize << (opts.stages - 1 - s);
        let (l, r) = if f == 1 {
            (left.clone(), right.clone())
        } else {
            (
                emit_resize_bilinear_align_corners(g, left, [h / f, w / f]),
                emit_resize_bilinear_align_corners(g, right, [h / f, w / f]),
            )
        };
        flow = Some(model.emit_forward(g, &l, &r, opts.iters, flow.as_ref()));
    }
    flow.expect("at least one stage")
}

/// Runs the network on an image pair of any size: pads (edge replicate, bottom/right) to a
/// multiple of `16 · 2^(stages−1)` (32 for the reference two-stage procedure), runs
/// [`cascade`] and crops back. Channel 0 of the prediction is the left view's disparity.
pub fn infer_disparity<B: Backend>(
    model: &CREStereo<B>,
    left: &BgrImage,
    right: &BgrImage,
    opts: InferenceOptions,
    device: &B::Device,
) -> Result<DisparityMap> {
    if (left.width, left.height) != (right.width, right.height) {
        bail!(
            "left and right images differ in size: {}x{} vs {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
    }
    opts.check()?;
    let (m, _) = opts.size_rule();
    let (w, h) = (left.width, left.height);
    let (pw, ph) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
    check_input_size(pw, ph)?;
    let pad = |t: Tensor<B, 4>| {
        if (pw, ph) == (w, h) {
            t
        } else {
            t.pad((0, pw - w, 0, ph - h), PadMode::Edge)
        }
    };
    let l = pad(left.to_tensor::<B>(device));
    let r = pad(right.to_tensor::<B>(device));
    let pred = cascade(model, l, r, opts);
    let disp = pred.slice([0..1, 0..1, 0..h, 0..w]).reshape([h * w]);
    let data: Vec<f32> = disp
        .into_data()
        .convert::<f32>()
        .into_vec()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    Ok(prediction_map(w, h, data))
}

/// A prediction as a disparity map: the network gives every pixel a value, so every pixel is
/// valid. Values are kept as they are (a diverged network's NaN stays visible in metrics).
fn prediction_map(width: usize, height: usize, data: Vec<f32>) -> DisparityMap {
    DisparityMap {
        width,
        height,
        valid: vec![true; data.len()],
        data,
    }
}
