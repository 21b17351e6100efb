//! `crestereo export onnx`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use crestereo::InferenceOptions;
use crestereo::onnx::{check_size, export_onnx};

use super::{check_output, load_model, weights_arg};

#[derive(Debug, clap::Args)]
pub struct OnnxArgs {
    /// Weights: a reference PyTorch state dict (.pt/.pth), a Burn record (.mpk), a checkpoint
    /// directory or a training run (its newest checkpoint).
    #[arg(long, env = "CRESTEREO_WEIGHTS")]
    pub weights: Option<PathBuf>,
    /// Image size HxW the graph takes (static shapes); both must be multiples of
    /// 16·2^(stages−1), 32 for the reference two-stage procedure.
    #[arg(long)]
    pub size: String,
    /// Refinement iterations per pass.
    #[arg(long, default_value_t = 20)]
    pub iters: usize,
    /// Stacked cascades: 1, 2 (reference test procedure) or 3.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub stages: u8,
    /// Output graph (.onnx).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Replace an existing output file.
    #[arg(long)]
    pub force: bool,
}

/// `HxW`, e.g. `480x640`.
fn parse_size(s: &str) -> Result<[usize; 2]> {
    let parse = |v: &str| v.trim().parse::<usize>().ok().filter(|&v| v > 0);
    match s.split_once(['x', 'X']).map(|(h, w)| (parse(h), parse(w))) {
        Some((Some(h), Some(w))) => Ok([h, w]),
        _ => bail!("--size {s}: expected HEIGHTxWIDTH, e.g. 480x640"),
    }
}

pub fn run(a: &OnnxArgs) -> Result<()> {
    let size = parse_size(&a.size)?;
    let opts = InferenceOptions {
        iters: a.iters,
        stages: usize::from(a.stages),
    };
    check_size(size, opts)?;
    let weights = weights_arg(a.weights.as_deref())?;
    check_output(&a.output, a.force)?;
    let model = load_model(weights)?;
    let t0 = Instant::now();
    let export = export_onnx(&model, size, opts)?;
    stereo_io::write_bytes_atomically(&a.output, &export.bytes)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    let [h, w] = size;
    eprintln!(
        "wrote {} ({:.1} MB, {} nodes, opset {}): {h}x{w}, {} stage(s) of {} iterations, in {:.1}s",
        a.output.display(),
        export.bytes.len() as f64 / 1e6,
        export.nodes,
        crestereo::onnx::OPSET,
        opts.stages,
        opts.iters,
        t0.elapsed().as_secs_f64()
    );
    eprintln!(
        "op types: {}",
        export
            .op_types
            .iter()
            .cloned()
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}
