//! ONNX export of inference: the graph of exactly what [`crate::infer::cascade`] computes at one
//! image size, built by the modules' `emit` methods into an [`crate::export::onnx::Graph`].

pub mod onnx;

use std::collections::BTreeSet;

use anyhow::Result;
use burn::prelude::*;
use onnx_protobuf::Message;

use crate::export::onnx::Graph;
use crate::infer::{InferenceOptions, emit_cascade};
use crate::network::model::CREStereo;

/// A serialised graph and what it is made of.
pub struct OnnxExport {
    /// The `ModelProto`, serialised.
    pub bytes: Vec<u8>,
    /// The op types the graph uses, sorted.
    pub op_types: BTreeSet<String>,
    pub nodes: usize,
}

/// The graph of `model`'s inference at `size` = [H, W]: inputs `left` and `right` (1, 3, H, W)
/// float32, BGR in 0..255 (what the reference model takes), output `disparity` (1, 1, H, W).
pub fn export_onnx<B: Backend>(
    model: &CREStereo<B>,
    size: [usize; 2],
    opts: InferenceOptions,
) -> Result<OnnxExport> {
    opts.check_size(size)?;
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
