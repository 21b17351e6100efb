//! `crestereo export onnx`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use crestereo::export::export_onnx;

use super::{check_output, existing_weights_file, load_model};
use crate::cli::network_args::NetworkArgs;

#[derive(Debug, clap::Args)]
pub struct OnnxArgs {
    #[command(flatten)]
    pub network: NetworkArgs,
    /// Image size HxW the graph takes (static shapes); both must be multiples of
    /// 16·2^(stages−1), 32 for the reference two-stage procedure.
    #[arg(long)]
    pub size: String,
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

pub fn run<B: burn::prelude::Backend>(a: &OnnxArgs, device: &B::Device) -> Result<()> {
    let size = parse_size(&a.size)?;
    let opts = a.network.options();
    opts.check_size(size)?;
    let weights = a.network.weights()?;
    check_output(&a.output, a.force)?;
    let model = load_model::<B>(&existing_weights_file(weights)?, device)?;
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
        crestereo::export::onnx::OPSET,
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
