//! `crestereo infer`: the disparity of one rectified pair.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use crestereo::weights::load_weights;
use crestereo::{BgrImage, CREStereoConfig, infer_disparity};
use stereo_io::colormap::{DisparityRange, colourise_with_bar};
use stereo_io::{DisparityFormat, DisparityMap, DisparityMeta};

use crate::checkpoint::weights_file;

use super::network_args::NetworkArgs;

#[derive(Debug, clap::Args)]
pub struct InferArgs {
    /// Left image (PNG/JPEG; 16-bit files are read as 8-bit, like training and evaluation).
    pub left: PathBuf,
    /// Right image (PNG/JPEG).
    pub right: PathBuf,
    /// Output disparity, format by extension: .exr (float32, channel "Y"), .pfm, .npy, .png
    /// (16-bit ×256, KITTI) or .disp.png (16-bit ×32, CREStereo).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write a PFM copy here.
    #[arg(long)]
    pub pfm: Option<PathBuf>,
    /// Colourised disparity PNG with a colour bar.
    #[arg(long)]
    pub viz: Option<PathBuf>,
    #[command(flatten)]
    pub network: NetworkArgs,
}

pub fn infer<B: Backend>(a: &InferArgs, device: &B::Device) -> Result<()> {
    let (l, r) = read_inputs(a)?;
    let weights = a.network.weights()?;
    let model = CREStereoConfig::new().init::<B>(device);
    let model = load_weights(model, weights_file(weights)?, device)?;
    let t0 = Instant::now();
    let opts = a.network.options();
    let disp = infer_disparity(&model, &l, &r, opts, device)?;
    eprintln!(
        "inference {}x{} ({} stages, {} iters): {:.2}s",
        l.width,
        l.height,
        opts.stages,
        opts.iters,
        t0.elapsed().as_secs_f64()
    );
    write_outputs(a, &disp)
}

/// The two images, after refusing (before the slow part, and in the tests without the network)
/// an output whose format or folder will not do.
fn read_inputs(a: &InferArgs) -> Result<(BgrImage, BgrImage)> {
    // Refuse an unknown output format before the slow part.
    let output: &Path = &a.output;
    if DisparityFormat::from_path(output).is_none() {
        bail!(
            "cannot tell the disparity format of {} from its extension (.exr, .pfm, .npy, .png, .disp.png)",
            output.display()
        );
    }
    for path in std::iter::once(&a.output).chain(&a.pfm).chain(&a.viz) {
        check_writable(path)?;
    }
    let (l, r) = (read_image(&a.left)?, read_image(&a.right)?);
    if (l.width, l.height) != (r.width, r.height) {
        bail!(
            "left image {} is {}x{} but right image {} is {}x{}",
            a.left.display(),
            l.width,
            l.height,
            a.right.display(),
            r.width,
            r.height
        );
    }
    Ok((l, r))
}

/// Refuses, before the slow part, an output whose folder is missing or not writable: creates and
/// removes a temp file where the durable write will put its own.
pub(super) fn check_writable(path: &Path) -> Result<()> {
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
        .with_context(|| format!("cannot write {}", path.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// The one image path into the network: `stereo-io` decodes to 8-bit RGB, then planar BGR.
fn read_image(path: &Path) -> Result<BgrImage> {
    let rgb = stereo_io::read_rgb(path).context("cannot read image")?;
    Ok(BgrImage::from_rgb(&rgb))
}

fn write_outputs(a: &InferArgs, disp: &DisparityMap) -> Result<()> {
    let meta = DisparityMeta::default();
    stereo_io::write_disparity(&a.output, disp, &meta, None)?;
    if let Some(p) = &a.pfm {
        stereo_io::write_disparity(p, disp, &meta, Some(DisparityFormat::Pfm))?;
    }
    if let Some(v) = &a.viz {
        let image = colourise_with_bar(disp, DisparityRange::of(disp));
        stereo_io::write_png_rgb(v, &image)?; // durable: encoded in memory, then atomic
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(dir: &Path, output: &str) -> InferArgs {
        InferArgs {
            left: dir.join("missing_left.png"),
            right: dir.join("missing_right.png"),
            output: dir.join(output),
            pfm: Some(dir.join("copy.pfm")),
            viz: Some(dir.join("viz.png")),
            network: NetworkArgs {
                weights: None,
                iters: 1,
                stages: 1,
            },
        }
    }

    #[test]
    fn an_unknown_output_format_is_refused_before_anything_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let err = read_inputs(&args(dir.path(), "disp.tiff")).unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("disp.tiff") && msg.contains("extension"),
            "{msg}"
        );
    }

    #[test]
    fn a_missing_output_folder_is_refused_before_anything_is_read() {
        let dir = tempfile::tempdir().unwrap();
        for (output, viz) in [
            ("nowhere/disp.exr", "viz.png"),
            ("disp.exr", "nowhere/viz.png"),
        ] {
            let mut a = args(dir.path(), output);
            a.viz = Some(dir.path().join(viz));
            let msg = format!("{:#}", read_inputs(&a).unwrap_err());
            assert!(
                msg.contains("nowhere") && msg.contains("does not exist"),
                "{msg}"
            );
            assert!(
                !msg.contains("missing_left"),
                "checked after the images: {msg}"
            );
        }
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "the write probe left a file"
        );
    }

    #[test]
    fn outputs_follow_their_extensions() {
        let dir = tempfile::tempdir().unwrap();
        let disp = DisparityMap {
            width: 3,
            height: 2,
            data: vec![0.5, 1.0, 2.0, 4.0, 8.0, 16.0],
            valid: vec![true; 6],
        };
        for name in ["disp.exr", "disp.pfm", "disp.npy", "disp.disp.png"] {
            write_outputs(&args(dir.path(), name), &disp).unwrap();
            let (back, _) = stereo_io::read_disparity(&dir.path().join(name), None).unwrap();
            assert_eq!(back.data, disp.data, "{name}");
        }
        let (copy, _) = stereo_io::read_disparity(&dir.path().join("copy.pfm"), None).unwrap();
        assert_eq!(copy.data, disp.data);
        let viz = stereo_io::read_rgb(&dir.path().join("viz.png")).unwrap();
        assert_eq!((viz.width, viz.height), (3 + 72, 64));
        let at = |x: usize, y: usize| &viz.data[(y * viz.width + x) * 3..][..3];
        assert_eq!(at(2, 1), &[255, 0, 0]); // the largest disparity
        assert_eq!(at(0, 0), &stereo_io::colormap::ramp(0.5 / 16.0)); // the range starts at 0
    }
}
