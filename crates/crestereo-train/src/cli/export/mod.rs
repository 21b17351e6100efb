//! `crestereo export`: a trained model out of the binary, as an ONNX graph (onnxruntime,
//! TensorRT) or as a state dict the reference PyTorch model loads.

mod onnx;
mod pytorch;

use anyhow::Result;

#[derive(Debug, clap::Subcommand)]
pub enum ExportCommand {
    /// A static-shape ONNX graph (opset 17, no custom ops, weights as initializers) of exactly
    /// what `crestereo infer` computes at one image size.
    Onnx(onnx::OnnxArgs),
    /// The weights as a PyTorch state dict under the reference's key names (`.pth`), which the
    /// reference model loads with `strict=True`.
    Pytorch(pytorch::PytorchArgs),
}

pub fn run(command: &ExportCommand) -> Result<()> {
    match command {
        ExportCommand::Onnx(args) => onnx::run(args),
        ExportCommand::Pytorch(args) => pytorch::run(args),
    }
}
