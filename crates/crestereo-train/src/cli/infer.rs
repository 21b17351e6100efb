//! `crestereo infer`: the disparity of one rectified pair.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use crestereo::io::{read_bgr, write_exr, write_pfm, write_visualisation};
use crestereo::weights::load_weights;
use crestereo::{CREStereoConfig, InferenceOptions, infer_disparity};

use crate::checkpoint::weights_file;

#[derive(Debug, clap::Args)]
pub struct InferArgs {
    /// Left image (PNG/JPEG).
    pub left: PathBuf,
    /// Right image (PNG/JPEG).
    pub right: PathBuf,
    /// Output disparity: float32 EXR (channel "Y"), or PFM if the name ends in .pfm.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write a PFM copy here.
    #[arg(long)]
    pub pfm: Option<PathBuf>,
    /// Colourised disparity PNG with a colour bar.
    #[arg(long)]
    pub viz: Option<PathBuf>,
    /// Weights: a reference PyTorch state dict (.pt/.pth), a Burn record (.mpk), a checkpoint
    /// directory or a training run (its newest checkpoint).
    #[arg(long, env = "CRESTEREO_WEIGHTS")]
    pub weights: Option<PathBuf>,
    /// Refinement iterations per pass.
    #[arg(long, default_value_t = 20)]
    pub iters: usize,
    /// Stacked cascades: 1, 2 (reference test procedure) or 3.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub stages: u8,
}

pub fn infer<B: Backend>(a: &InferArgs, device: &B::Device) -> Result<()> {
    let (left, right): (&Path, &Path) = (&a.left, &a.right);
    let l = read_bgr(left)?;
    let r = read_bgr(right)?;
    if (l.width, l.height) != (r.width, r.height) {
        bail!(
            "left image {} is {}x{} but right image {} is {}x{}",
            left.display(),
            l.width,
            l.height,
            right.display(),
            r.width,
            r.height
        );
    }
    let weights = a
        .weights
        .as_deref()
        .context("no weights given: pass --weights FILE or set CRESTEREO_WEIGHTS")?;
    let model = CREStereoConfig::new().init::<B>(device);
    let model = load_weights(model, weights_file(weights)?, device)?;
    let t0 = Instant::now();
    let disp = infer_disparity(
        &model,
        &l,
        &r,
        InferenceOptions {
            iters: a.iters,
            stages: usize::from(a.stages),
        },
        device,
    )?;
    eprintln!(
        "inference {}x{} ({} stages, {} iters): {:.2}s",
        l.width,
        l.height,
        usize::from(a.stages),
        a.iters,
        t0.elapsed().as_secs_f64()
    );
    let output: &Path = &a.output;
    if output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pfm"))
    {
        write_pfm(output, disp.width, disp.height, &disp.data)?;
    } else {
        write_exr(output, disp.width, disp.height, &disp.data)?;
    }
    if let Some(p) = &a.pfm {
        write_pfm(p, disp.width, disp.height, &disp.data)?;
    }
    if let Some(v) = &a.viz {
        write_visualisation(v, disp.width, disp.height, &disp.data)?;
    }
    Ok(())
}

