//! `crestereo export pytorch`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use crestereo::weights::{load_weights, named_parameters};
use crestereo::weights_pth::write_state_dict;
use crestereo::{CREStereoConfig, CpuBackend};

use crate::checkpoint::weights_file;

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

pub fn run(args: &PytorchArgs) -> Result<()> {
    // Everything that can be refused without reading the weights is refused first.
    let weights = args
        .weights
        .as_deref()
        .context("no weights given: pass --weights FILE or set CRESTEREO_WEIGHTS")?;
    let output = &args.output;
    check_output(output, args.force)?;
    let file = weights_file(weights)?;
    if !file.is_file() {
        bail!(
            "cannot read weights {}: the file does not exist",
            file.display()
        );
    }

    let device = Default::default();
    let model = CREStereoConfig::new().init::<CpuBackend>(&device);
    let model = load_weights(model, &file, &device).map_err(|e| {
        // The loaders explain a misfit over several lines (each missing parameter, each shape):
        // the first says what is wrong.
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
    })?;

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

/// Refuses an output that would not be read back as PyTorch weights, one that exists (without
/// `force`), and one whose folder is missing or not writable: creates and removes a temporary
/// file where the durable write will put its own.
fn check_output(path: &Path, force: bool) -> Result<()> {
    if !matches!(
        path.extension().and_then(|e| e.to_str()),
        Some("pth" | "pt")
    ) {
        bail!(
            "cannot write {}: the output must end in .pth or .pt (weights are read by their extension)",
            path.display()
        );
    }
    if path.is_dir() {
        bail!("cannot write {}: it is a folder", path.display());
    }
    if !force && path.symlink_metadata().is_ok() {
        bail!(
            "{} already exists: pass --force to replace it",
            path.display()
        );
    }
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !folder.is_dir() {
        bail!(
            "cannot write {}: the folder {} does not exist",
            path.display(),
            folder.display()
        );
    }
    let probe = stereo_io::temp_sibling(path);
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
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
            format!("{:#}", run(&args).unwrap_err())
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
