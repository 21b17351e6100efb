//! Inference: padding, the reference two-pass test procedure and N stacked cascades.

use anyhow::{Result, bail};
use burn::prelude::*;
use burn::tensor::ops::PadMode;
use stereo_io::DisparityMap;

use crate::export::onnx::{Graph, Value};
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

    /// The image size of each stage for an input of `size` = [H, W], first to last: stage `s`
    /// runs at `size / 2^(stages−1−s)`, the last at `size`.
    pub fn stage_sizes(&self, size: [usize; 2]) -> Vec<[usize; 2]> {
        (0..self.stages)
            .map(|s| size.map(|v| v >> (self.stages - 1 - s)))
            .collect()
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
    let [_, _, h, w] = left.dims();
    let mut run = Run {
        model,
        iters: opts.iters,
    };
    run_stages(&mut run, left, right, [h, w], opts)
}

/// [`cascade`] as ONNX nodes: the same stages, resizes and hand-overs.
pub fn emit_cascade<B: Backend>(
    model: &CREStereo<B>,
    g: &mut Graph,
    left: &Value,
    right: &Value,
    opts: InferenceOptions,
) -> Value {
    let [_, _, h, w] = left.dims();
    let mut emit = Emit {
        model,
        g,
        iters: opts.iters,
    };
    run_stages(&mut emit, left.clone(), right.clone(), [h, w], opts)
}

/// What the stacked cascade does at each stage, on tensors ([`Run`]) or as graph nodes
/// ([`Emit`]): the procedure itself is written once, in [`run_stages`].
trait Stages {
    type Array: Clone;
    /// An image pair's member resized (bilinear, align_corners) to `size`.
    fn resize(&mut self, image: &Self::Array, size: [usize; 2]) -> Self::Array;
    /// One pass of the network: its last prediction (N, 2, h, w).
    fn pass(
        &mut self,
        left: Self::Array,
        right: Self::Array,
        init: Option<Self::Array>,
    ) -> Self::Array;
}

fn run_stages<S: Stages>(
    stages: &mut S,
    left: S::Array,
    right: S::Array,
    size: [usize; 2],
    opts: InferenceOptions,
) -> S::Array {
    assert!(opts.stages >= 1 && opts.iters >= 1);
    let mut flow = None;
    for stage_size in opts.stage_sizes(size) {
        let (l, r) = if stage_size == size {
            (left.clone(), right.clone())
        } else {
            (
                stages.resize(&left, stage_size),
                stages.resize(&right, stage_size),
            )
        };
        flow = Some(stages.pass(l, r, flow.take()));
    }
    flow.expect("at least one stage")
}

struct Run<'a, B: Backend> {
    model: &'a CREStereo<B>,
    iters: usize,
}

impl<B: Backend> Stages for Run<'_, B> {
    type Array = Tensor<B, 4>;
    fn resize(&mut self, image: &Tensor<B, 4>, size: [usize; 2]) -> Tensor<B, 4> {
        resize_bilinear_align_corners(image.clone(), size)
    }
    fn pass(
        &mut self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        init: Option<Tensor<B, 4>>,
    ) -> Tensor<B, 4> {
        let preds = self.model.forward(left, right, self.iters, init);
        preds.into_iter().last().expect("at least one prediction")
    }
}

struct Emit<'a, B: Backend> {
    model: &'a CREStereo<B>,
    g: &'a mut Graph,
    iters: usize,
}

impl<B: Backend> Stages for Emit<'_, B> {
    type Array = Value;
    fn resize(&mut self, image: &Value, size: [usize; 2]) -> Value {
        emit_resize_bilinear_align_corners(self.g, image, size)
    }
    fn pass(&mut self, left: Value, right: Value, init: Option<Value>) -> Value {
        self.model
            .emit_forward(self.g, &left, &right, self.iters, init.as_ref())
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::test_util::uniform;
    use crate::{CREStereoConfig, CpuBackend};

    #[test]
    fn stage_sizes_halve_from_the_last() {
        let opts = |stages| InferenceOptions { iters: 1, stages };
        assert_eq!(opts(1).stage_sizes([128, 192]), [[128, 192]]);
        assert_eq!(
            opts(3).stage_sizes([128, 192]),
            [[32, 48], [64, 96], [128, 192]]
        );
    }

    /// The stacked cascade as a graph against `cascade` for one, two and three stages (resizes
    /// of the pair, hand-over of each stage's prediction, the last prediction).
    #[test]
    fn emitted_cascade_matches_forward_for_one_two_and_three_stages() {
        let model = CREStereoConfig::new().init_seeded::<CpuBackend>(5, &Default::default());
        let (h, w) = (128, 128);
        let left = uniform([1, 3, h, w], 0.0, 255.0);
        let right = uniform([1, 3, h, w], 0.0, 255.0);
        for stages in 1..=3 {
            let opts = InferenceOptions { iters: 2, stages };
            opts.check_size([h, w])
                .expect("a size every stage count takes");
            let out = run_emitted(&[left.to_data(), right.to_data()], |g, x| {
                vec![emit_cascade(&model, g, &x[0], &x[1], opts)]
            });
            let forward = cascade(&model, left.clone(), right.clone(), opts);
            let label = format!("{stages} stage(s)");
            let diff = assert_emit_matches(&label, &out[0], forward.into_data(), 1e-4);
            println!("cascade, {label}: max |emit − forward| = {diff:.2e}");
        }
    }
}
