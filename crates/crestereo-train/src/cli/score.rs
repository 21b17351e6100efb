//! `crestereo score`: weights × dataset → one line of scores per sample (`crate::score`).

use std::path::PathBuf;

use anyhow::Result;
use burn::prelude::*;

use crate::eval::EvalOptions;
use crate::score::{ScoreHeader, score, weights_fingerprint};

use super::eval::{ModelArgs, load_model, open_dataset, progress_bar, show_progress};

#[derive(Debug, clap::Args)]
pub struct ScoreArgs {
    /// Dataset root (any layout stereo-io reads): DIR, DIR:FORMAT, or a WebDataset export's
    /// splits as DIR:webdataset:SPLIT[,SPLIT].
    #[arg(value_name = "DIR[:FORMAT[:SPLITS]]")]
    pub data: String,
    /// Force the dataset layout instead of detecting it.
    #[arg(long)]
    pub format: Option<stereo_io::DatasetFormat>,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Score the first N samples only (0 = all); a later run with a larger N goes on.
    #[arg(long, default_value_t = 0)]
    pub limit: usize,
    /// The scores (JSON lines; an existing file of the same weights and options is continued).
    #[arg(long, default_value = "scores.jsonl")]
    pub out: PathBuf,
}

pub fn run<B: Backend>(a: &ScoreArgs, device: &B::Device) -> Result<()> {
    let dataset = open_dataset(&a.data, a.format)?;
    let model = load_model::<B>(&a.model, device)?;
    // The header's fingerprint: the file's CRC-32C, or "untrained (seed N)".
    let fingerprint = match &model.file {
        Some(file) => weights_fingerprint(file)?,
        None => model.weights.clone(),
    };
    let opts = EvalOptions {
        iters: a.model.network.iters,
        stages: a.model.network.stages,
        limit: a.limit,
        ..EvalOptions::default()
    };
    let header = ScoreHeader::new(dataset.as_ref(), &model.weights, fingerprint, &opts);
    let bar = progress_bar();
    let outcome = score(
        &model.model,
        dataset.as_ref(),
        &header,
        &opts,
        &a.out,
        device,
        show_progress(&bar, ""),
    )?;
    bar.finish_and_clear();
    eprintln!(
        "scored {} sample(s) at {:.3} samples/s ({} already in {}, {} unreadable)",
        outcome.scored,
        outcome.rate,
        outcome.resumed,
        a.out.display(),
        outcome.failed
    );
    Ok(())
}
