//! The ONNX graph builder every module's `emit` writes into: a static-shape graph (opset 17,
//! default domain only, weights as initializers); [`crate::export::export_onnx`] builds the
//! graph of [`crate::infer::cascade`] at one image size with it.
//!
//! Each module emits its own nodes beside its `forward` (`emit` methods), in the same order of
//! operations, so a changed module and its export change together; [`Graph`] keeps every
//! value's static shape so the emitters read shapes as `forward` reads `dims()`. The graph uses
//! no `Einsum` (matrix products only), bilinear sampling is `GridSample` and bilinear resizing
//! is two matrix products, as in the model: nothing TensorRT 10 rejects.

mod graph;
mod ops;

#[cfg(test)]
pub(crate) mod eval;

pub use graph::{Attr, Graph, IR_VERSION, OPSET, Value};
