//! `crestereo export pytorch`.

use std::path::PathBuf;

use anyhow::{Result, bail};
use crestereo::weights::named_parameters;
use stereo_io::pth::write_state_dict;

use super::{check_output, existing_weights_file, load_model};
use crate::cli::network_args::required_weights;

#[derive(Debug, clap::Args)]
pub struct PytorchArgs {
    /// Weights: a reference PyTorch state dict, a Burn record (.mpk), a checkpoint directory or
    /// a training run (its newest checkpoint).
    #[arg(long, env = "CRESTEREO_WEIGHTS")]
    pub weights: Option<PathBuf>,
    /// Output state dict (.pth).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Replace an existing output file.
    #[arg(long)]
    pub force: bool,
}

pub fn run<B: burn::prelude::Backend>(args: &PytorchArgs, device: &B::Device) -> Result<()> {
    let file = refuse_early(args)?;
    let model = load_model::<B>(&file, device)?;
    let output = &args.output;
    let tensors = named_parameters(&model);
    // The output may have appeared while the weights were read.
    if !args.force && output.exists() {
        bail!(
            "{} already exists: pass --force to replace it",
            output.display()
        );
    }
    let bytes = write_state_dict(&tensors, output)?;
    eprintln!(
        "wrote {}: {} tensors, {:.1} MB (PyTorch state dict, reference key names)",
        output.display(),
        tensors.len(),
        bytes as f64 / 1e6
    );
    Ok(())
}

/// Everything that can be refused without reading the weights, refused first; the weights file.
fn refuse_early(args: &PytorchArgs) -> Result<PathBuf> {
    let weights = required_weights(args.weights.as_deref())?;
    let output = &args.output;
    if !matches!(
        output.extension().and_then(|e| e.to_str()),
        Some("pth" | "pt")
    ) {
        bail!(
            "cannot write {}: the output must end in .pth or .pt (weights are read by their extension)",
            output.display()
        );
    }
    check_output(output, args.force)?;
    existing_weights_file(weights)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_checked_before_anything_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let existing = dir.path().join("old.pth");
        std::fs::write(&existing, b"keep").unwrap();
        let err = |output: PathBuf, force: bool| {
            let args = PytorchArgs {
                weights: Some(dir.path().join("missing.pt")),
                output,
                force,
            };
            format!("{:#}", refuse_early(&args).unwrap_err())
        };
        let msg = err(existing.clone(), false);
        assert!(
            msg.contains("already exists") && msg.contains("--force"),
            "{msg}"
        );
        // with --force the output passes and the weights are the problem
        let msg = err(existing.clone(), true);
        assert!(
            msg.contains("missing.pt") && msg.contains("does not exist"),
            "{msg}"
        );
        let msg = err(dir.path().join("nowhere/model.pth"), false);
        assert!(
            msg.contains("nowhere") && msg.contains("does not exist"),
            "{msg}"
        );
        let msg = err(dir.path().join("model.mpk"), false);
        assert!(msg.contains(".pth or .pt"), "{msg}");
        assert_eq!(std::fs::read(&existing).unwrap(), b"keep");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "the write probe left a file"
        );
    }
}
