//! ONNX export of inference: a static-shape graph (opset 17, default domain only, weights as
//! initializers) of exactly what [`crate::infer::cascade`] computes at one image size.
//!
//! Each module emits its own nodes beside its `forward` (`emit` methods), in the same order of
//! operations, so a changed module and its export change together; [`Graph`] keeps every
//! value's static shape so the emitters read shapes as `forward` reads `dims()`. The graph uses
//! no `Einsum` (matrix products only), bilinear sampling is `GridSample` and bilinear resizing
//! is two matrix products, as in the model: nothing TensorRT 10 rejects.

mod graph;
mod ops;

use std::collections::BTreeSet;

use anyhow::{Result, bail};
use burn::prelude::*;
use onnx_protobuf::Message;

pub use graph::{Attr, Graph, IR_VERSION, OPSET, Value};

use crate::infer::{InferenceOptions, emit_cascade};
use crate::model::CREStereo;

/// A serialised graph and what it is made of.
pub struct OnnxExport {
    /// The `ModelProto`, serialised.
    pub bytes: Vec<u8>,
    /// The op types the graph uses, sorted.
    pub op_types: BTreeSet<String>,
    pub nodes: usize,
}

/// (multiple, minimum) of the image height and width a graph of `stages` stacked cascades
/// takes: every stage's 1/16 level must have whole pixels, two or more per axis (the sampling
/// grid is normalised by `size − 1`).
pub fn size_rule(stages: usize) -> (usize, usize) {
    let multiple = 16usize << (stages - 1);
    (multiple, 2 * multiple)
}

/// One clear line when `[h, w]` does not suit `opts`.
pub fn check_size(size: [usize; 2], opts: InferenceOptions) -> Result<()> {
    if opts.stages == 0 || opts.stages > 4 {
        bail!("stages must be 1..=4, got {}", opts.stages);
    }
    if opts.iters == 0 {
        bail!("iters must be at least 1");
    }
    let (multiple, minimum) = size_rule(opts.stages);
    let [h, w] = size;
    // The network's input limit; the graph's constant tables (pixel grids, resize matrices)
    // grow with the size, so it is refused here, before any is built.
    use crate::infer::{MAX_INPUT_PIXELS, MAX_INPUT_SIDE};
    if h > MAX_INPUT_SIDE || w > MAX_INPUT_SIDE || h * w > MAX_INPUT_PIXELS {
        bail!(
            "size {h}x{w} is over the network's limit ({MAX_INPUT_SIDE} px a side, {MAX_INPUT_PIXELS} pixels)"
        );
    }
    if h % multiple != 0 || w % multiple != 0 {
        let up = |v: usize| v.div_ceil(multiple) * multiple;
        bail!(
            "size {h}x{w} is not a multiple of {multiple} in both axes ({} stage(s) need it); the nearest sizes that are: {}x{}, {}x{} (pad the images to it, as `crestereo infer` does)",
            opts.stages,
            up(h),
            up(w),
            (h / multiple).max(1) * multiple,
            (w / multiple).max(1) * multiple
        );
    }
    if h < minimum || w < minimum {
        bail!(
            "size {h}x{w} is too small: {} stage(s) need at least {minimum}x{minimum}",
            opts.stages
        );
    }
    Ok(())
}

/// The graph of `model`'s inference at `size` = [H, W]: inputs `left` and `right` (1, 3, H, W)
/// float32, BGR in 0..255 (what the reference model takes), output `disparity` (1, 1, H, W).
pub fn export_onnx<B: Backend>(
    model: &CREStereo<B>,
    size: [usize; 2],
    opts: InferenceOptions,
) -> Result<OnnxExport> {
    check_size(size, opts)?;
    let [h, w] = size;
    let mut g = Graph::default();
    let left = g.input("left", &[1, 3, h, w]);
    let right = g.input("right", &[1, 3, h, w]);
    let prediction = emit_cascade(model, &mut g, &left, &right, opts);
    let disparity = g.narrow(&prediction, 1, 0, 1);
    g.output(&disparity, "disparity");
    let op_types = g.op_types();
    let nodes = g.node_count();
    let doc = format!(
        "CREStereo inference at {h}x{w}: {} stacked cascade(s) of {} iterations. Inputs left/right: 1x3x{h}x{w} float32, BGR, 0..255. Output disparity: 1x1x{h}x{w}, pixels, positive, of the left view.",
        opts.stages, opts.iters
    );
    let model = g.into_model("crestereo", &doc);
    let bytes = model.write_to_bytes()?;
    Ok(OnnxExport {
        bytes,
        op_types,
        nodes,
    })
}
