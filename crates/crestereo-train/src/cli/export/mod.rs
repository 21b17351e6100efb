//! `crestereo export`: a trained model out of the binary, as an ONNX graph (onnxruntime,
//! TensorRT) or as a state dict the reference PyTorch model loads.

mod onnx;
mod pytorch;

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use burn::prelude::Backend;
use crestereo::weights::load_weights;
use crestereo::{CREStereo, CREStereoConfig};

use crate::checkpoint::weights_file;
use crate::cli::infer::check_writable;

#[derive(Debug, clap::Subcommand)]
pub enum ExportCommand {
    /// A static-shape ONNX graph (opset 17, no custom ops, weights as initializers) of exactly
    /// what `crestereo infer` computes at one image size.
    Onnx(onnx::OnnxArgs),
    /// The weights as a PyTorch state dict under the reference's key names (`.pth`), which the
    /// reference model loads with `strict=True`.
    Pytorch(pytorch::PytorchArgs),
}

/// The command with the model on `B` (the binary exports from the CPU backend).
pub fn run<B: Backend>(command: &ExportCommand, device: &B::Device) -> Result<()> {
    match command {
        ExportCommand::Onnx(args) => onnx::run::<B>(args, device),
        ExportCommand::Pytorch(args) => pytorch::run::<B>(args, device),
    }
}

/// Refuses, before anything is read, an output that is a folder, one that exists (without
/// `force`), and one whose folder is missing or not writable.
fn check_output(path: &Path, force: bool) -> Result<()> {
    if path.is_dir() {
        bail!("cannot write {}: it is a folder", path.display());
    }
    if !force && path.symlink_metadata().is_ok() {
        bail!(
            "{} already exists: pass --force to replace it",
            path.display()
        );
    }
    check_writable(path)
}

/// The weights file that `weights` names (anything `crestereo infer` takes), refused in one line
/// where there is none: checked before the slow part, and in the tests without the network.
fn existing_weights_file(weights: &Path) -> Result<PathBuf> {
    let file = weights_file(weights)?;
    if !file.is_file() {
        bail!(
            "cannot read weights {}: the file does not exist",
            file.display()
        );
    }
    Ok(file)
}

/// The model with the weights `file` on `device`; a file that does not fit is named in one line
/// (the loaders explain a misfit over several: the first says what is wrong).
fn load_model<B: Backend>(file: &Path, device: &B::Device) -> Result<CREStereo<B>> {
    let model = CREStereoConfig::new().init::<B>(device);
    load_weights(model, file, device).map_err(|e| {
        let text = format!("{e:#}");
        let first = text
            .lines()
            .next()
            .unwrap_or_default()
            .trim_end_matches(':');
        let name = file.display().to_string();
        if first.contains(&name) {
            anyhow::anyhow!("not CREStereo weights: {first}")
        } else {
            anyhow::anyhow!("{name} is not CREStereo weights: {first}")
        }
    })
}
