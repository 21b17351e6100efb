//! `crestereo eval`: weights × dataset → printed table, JSON report, per-image CSV.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use crestereo::{CREStereo, CREStereoConfig};
use indicatif::{ProgressBar, ProgressStyle};

use crate::checkpoint::weights_file;
use crate::disturb::{self, Disturbance};
use crate::eval::{EvalOptions, EvalReport, ImageResult, evaluate};

use super::network_args::NetworkArgs;

/// The network and how it runs, as `eval` and `score` take them.
#[derive(Debug, clap::Args)]
pub struct ModelArgs {
    #[command(flatten)]
    pub network: NetworkArgs,
    /// Use an untrained network initialised with this seed (a baseline) instead of weights.
    #[arg(long, conflicts_with = "weights")]
    pub untrained_seed: Option<u64>,
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Dataset root (any layout stereo-io reads): DIR, DIR:FORMAT, or a WebDataset export's
    /// splits as DIR:webdataset:SPLIT[,SPLIT] (default: its only split, else `val`, else `test`).
    #[arg(long, value_name = "DIR[:FORMAT[:SPLITS]]")]
    pub data: String,
    /// Force the dataset layout instead of detecting it.
    #[arg(long)]
    pub format: Option<stereo_io::DatasetFormat>,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Evaluate at most N samples (0 = all).
    #[arg(long, default_value_t = 0)]
    pub limit: usize,
    /// Foreground masks `<DIR>/<sample id>.png` for mxIoU / mxIoUbd.
    #[arg(long)]
    pub fg_masks: Option<PathBuf>,
    /// Boundary band p of mxIoUbd.
    #[arg(long, default_value_t = 4)]
    pub boundary: usize,
    /// The JSON report.
    #[arg(long, default_value = "eval.json")]
    pub json: PathBuf,
    /// The per-image CSV (default: beside the JSON, `<name>.per_image.csv`).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// The paper's robustness test: evaluate again with the right view disturbed, for each
    /// level of KIND: blur (Gaussian sigma, px), colour (gain/gamma strength s: per-channel gains
    /// in [1-s, 1+s]), noise (sigma of 255, per pixel and channel), perspective (corner
    /// displacement, px), vshift (px, down), distortion (radial, corner displacement, px), or
    /// `all`. LEVELS is a comma list (default 3 levels per kind, e.g. blur:1,2,4); level 0 is the
    /// undisturbed pair. The left view and the ground truth are never changed. Repeatable.
    /// Adds the rows to the JSON and writes `<name>.disturb.csv` and `<name>.disturb.png`.
    #[arg(long = "disturb", value_name = "KIND[:LEVELS]")]
    pub disturb: Vec<String>,
    /// Seed of the disturbances' random parts (colour gains, noise, corner directions); each
    /// sample draws its own from (seed, kind, sample id).
    #[arg(long, default_value_t = 0, requires = "disturb")]
    pub disturb_seed: u64,
}

/// The network to evaluate and how the report names its weights.
pub(super) struct Evaluated<B: Backend> {
    pub model: CREStereo<B>,
    pub weights: String,
    /// The weights file read (none for an untrained network).
    pub file: Option<PathBuf>,
}

/// The network of `--weights` (a file, checkpoint or run) or of `--untrained-seed`.
pub(super) fn load_model<B: Backend>(a: &ModelArgs, device: &B::Device) -> Result<Evaluated<B>> {
    Ok(match (&a.network.weights, a.untrained_seed) {
        (Some(w), _) => {
            let file = weights_file(w)?;
            let model = crestereo::weights::load_weights(
                CREStereoConfig::new().init::<B>(device),
                &file,
                device,
            )?;
            Evaluated {
                model,
                weights: file.display().to_string(),
                file: Some(file),
            }
        }
        (None, Some(seed)) => Evaluated {
            model: crate::train::seeded_model::<B>(seed, device),
            weights: format!("untrained (seed {seed})"),
            file: None,
        },
        (None, None) => bail!(
            "no weights: pass --weights FILE|CHECKPOINT|RUN (or --untrained-seed N for a baseline)"
        ),
    })
}

fn options(a: &EvalArgs) -> Result<EvalOptions> {
    if let Some(dir) = &a.fg_masks
        && !dir.is_dir()
    {
        bail!("--fg-masks {}: not a directory", dir.display());
    }
    Ok(EvalOptions {
        iters: a.model.network.iters,
        stages: a.model.network.stages,
        limit: a.limit,
        fg_masks: a.fg_masks.clone(),
        boundary_px: a.boundary,
        ..EvalOptions::default()
    })
}

/// The dataset of `--data DIR[:FORMAT[:SPLITS]]` and `--format`, as evaluation reads it.
pub(super) fn open_dataset(
    data: &str,
    format: Option<stereo_io::DatasetFormat>,
) -> Result<Box<dyn stereo_io::StereoDataset>> {
    let at = super::train::parse_location(data, "--data")?;
    let format = match (at.format, format) {
        (Some(x), Some(y)) if x != y => {
            bail!("--data {data} says {x}, --format says {y}")
        }
        (x, y) => x.or(y),
    };
    crate::data::open_data(
        &at.path,
        format,
        at.splits.as_deref(),
        crate::data::SplitUse::Eval,
        "--data",
    )
}

/// The progress callback of a pass: position, and the last sample's EPE after `label`.
pub(super) fn show_progress<'a>(
    bar: &'a ProgressBar,
    label: &'a str,
) -> impl FnMut(usize, usize, &ImageResult) + 'a {
    move |i, n, r| {
        bar.set_length(n as u64);
        bar.set_position(i as u64);
        if let Some(m) = r.all {
            bar.set_message(format!("{label}{}: EPE {:.3}", r.id, m.epe));
        }
    }
}

/// The progress bar of a pass over a dataset.
pub(super) fn progress_bar() -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}] {per_sec} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

pub fn run<B: Backend>(a: &EvalArgs, device: &B::Device) -> Result<()> {
    // A wrong --disturb fails before any image is read.
    let disturb = disturb::parse_specs(&a.disturb).map_err(anyhow::Error::msg)?;
    let dataset = open_dataset(&a.data, a.format)?;
    let evaluated = load_model::<B>(&a.model, device)?;
    let opts = options(a)?;
    let bar = progress_bar();
    let pass = |opts: &EvalOptions, label: &str| -> Result<EvalReport> {
        bar.reset();
        let report = evaluate(
            &evaluated.model,
            dataset.as_ref(),
            &evaluated.weights,
            opts,
            device,
            show_progress(&bar, label),
        )?;
        Ok(report)
    };
    let mut report = pass(&opts, "")?;
    for (kind, levels) in &disturb {
        for &level in levels {
            let d = Disturbance {
                kind: *kind,
                level,
                seed: a.disturb_seed,
            };
            let disturbed = pass(
                &EvalOptions {
                    disturbance: Some(d),
                    ..opts.clone()
                },
                &format!("{} {level}: ", kind.name()),
            )?;
            report.disturbed.extend(disturbed.disturbed_row());
        }
    }
    bar.finish_and_clear();
    let csv = a
        .csv
        .clone()
        .unwrap_or_else(|| a.json.with_extension("per_image.csv"));
    report.write(&a.json, &csv)?;
    print!("{}", report.table());
    eprintln!("wrote {} and {}", a.json.display(), csv.display());
    if !report.disturbed.is_empty() {
        let rows = &report.disturbed;
        let table = a.json.with_extension("disturb.csv");
        stereo_io::write_bytes_atomically(&table, disturb::disturbance_csv(rows).as_bytes())
            .with_context(|| format!("cannot write {}", table.display()))?;
        let plot = a.json.with_extension("disturb.png");
        let baseline = disturb::headline(report.mean_nonocc, report.mean_all).map(|h| h.1.epe);
        crate::plot::plot_disturbance(rows, baseline, &plot)?;
        print!("{}", disturb::disturbance_table(rows));
        eprintln!("wrote {} and {}", table.display(), plot.display());
    }
    if report.images == 0 {
        bail!(
            "no image could be evaluated ({} failed)",
            report.failed.len()
        );
    }
    Ok(())
}
