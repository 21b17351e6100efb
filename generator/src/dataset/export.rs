//! `stereogen export`: a dataset of ours rewritten in another trainer's layout.
//!
//! | format | layout | disparity |
//! | --- | --- | --- |
//! | `crestereo` | `<category>/<id>_left.jpg`, `_right.jpg`, `_left.disp.png`, `_right.disp.png` | 16-bit PNG, d·32, 0 = invalid |
//! | `kitti` | `training/image_2/NNNNNN_10.png`, `image_3/`, `disp_occ_0/`, `disp_occ_1/` | 16-bit PNG, d·256, 0 = invalid |
//! | `middlebury` | `<category>_<id>/im0.png`, `im1.png`, `disp0.pfm`, `disp1.pfm`, `calib.txt` | float32 PFM, inf = invalid |
//!
//! Images are hard links to ours where the format matches (PNG), copies where the filesystem
//! refuses links. CREStereo's loader wants `*_left.jpg` names but decodes by content (OpenCV,
//! Pillow), so by default its "jpg" files are links to our lossless PNGs; `jpeg_quality` makes
//! real JPEGs instead. Every file appears atomically (temp name + rename), so an interrupted
//! export can be re-run.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use super::layout::DatasetLayout;
use super::manifest::{Manifest, ManifestEntry};

/// A layout `stereogen export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Crestereo,
    Kitti,
    Middlebury,
}

#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub dataset: PathBuf,
    pub format: ExportFormat,
    pub out: PathBuf,
    /// CREStereo only: write real JPEGs with this quality instead of linking our PNGs.
    pub jpeg_quality: Option<u8>,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExportSummary {
    pub samples: usize,
    /// Image files that are hard links to ours.
    pub linked: usize,
    /// Files written (disparities, calibrations, copied or re-encoded images).
    pub written: usize,
    /// Valid pixels the format cannot hold (KITTI: disparity ≥ 256 px), stored as invalid.
    pub dropped_pixels: usize,
}

/// Places `src` at `dst`: a hard link (or a copy across filesystems), atomically.
fn link_or_copy(src: &Path, dst: &Path, summary: &mut ExportSummary) -> anyhow::Result<()> {
    let tmp = stereo_io::temp_sibling(dst);
    let _ = std::fs::remove_file(&tmp);
    if std::fs::hard_link(src, &tmp).is_ok() {
        summary.linked += 1;
    } else {
        std::fs::copy(src, &tmp).with_context(|| format!("cannot copy {} to {}", src.display(), tmp.display()))?;
        summary.written += 1;
    }
    std::fs::rename(&tmp, dst).with_context(|| format!("cannot rename {} to {}", tmp.display(), dst.display()))
}

fn read_disp(layout: &DatasetLayout, rel: &Path) -> anyhow::Result<stereo_io::DisparityMap> {
    let path = layout.abs(rel);
    Ok(stereo_io::read_disparity_exr(&path)?.0)
}

/// Marks valid pixels at or above `max` invalid; returns how many.
fn drop_unrepresentable(map: &mut stereo_io::DisparityMap, max: f32) -> usize {
    let mut n = 0;
    for (d, v) in map.data.iter_mut().zip(map.valid.iter_mut()) {
        if *v && *d >= max {
            *v = false;
            *d = 0.0;
            n += 1;
        }
    }
    n
}

fn mkdir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))
}

fn export_crestereo(layout: &DatasetLayout, e: &ManifestEntry, opts: &ExportOptions, s: &mut ExportSummary) -> anyhow::Result<()> {
    let dir = opts.out.join(&e.category);
    mkdir(&dir)?;
    for (view, img, disp) in [("left", &e.files.left, &e.files.disp_left), ("right", &e.files.right, &e.files.disp_right)] {
        let jpg = dir.join(format!("{}_{view}.jpg", e.id));
        match opts.jpeg_quality {
            Some(q) => {
                stereo_io::write_jpeg_rgb(&jpg, &stereo_io::read_rgb(&layout.abs(img))?, q)?;
                s.written += 1;
            }
            None => link_or_copy(&layout.abs(img), &jpg, s)?,
        }
        let map = read_disp(layout, disp)?;
        stereo_io::write_disparity_png16(&dir.join(format!("{}_{view}.disp.png", e.id)), &map, stereo_io::CRESTEREO_SCALE)?;
        s.written += 1;
    }
    Ok(())
}

fn export_kitti(layout: &DatasetLayout, e: &ManifestEntry, n: usize, opts: &ExportOptions, s: &mut ExportSummary) -> anyhow::Result<()> {
    let base = opts.out.join("training");
    let name = format!("{n:06}_10.png");
    for (img_dir, disp_dir, img, disp) in [("image_2", "disp_occ_0", &e.files.left, &e.files.disp_left), ("image_3", "disp_occ_1", &e.files.right, &e.files.disp_right)] {
        mkdir(&base.join(img_dir))?;
        mkdir(&base.join(disp_dir))?;
        link_or_copy(&layout.abs(img), &base.join(img_dir).join(&name), s)?;
        let mut map = read_disp(layout, disp)?;
        // The largest value a 16-bit PNG at ×256 holds is 65535/256 ≈ 255.996 px.
        s.dropped_pixels += drop_unrepresentable(&mut map, 65535.5 / stereo_io::KITTI_SCALE);
        stereo_io::write_disparity_png16(&base.join(disp_dir).join(&name), &map, stereo_io::KITTI_SCALE)?;
        s.written += 1;
    }
    Ok(())
}

fn export_middlebury(layout: &DatasetLayout, e: &ManifestEntry, opts: &ExportOptions, s: &mut ExportSummary) -> anyhow::Result<()> {
    let dir = opts.out.join(format!("{}_{}", e.category, e.id));
    mkdir(&dir)?;
    link_or_copy(&layout.abs(&e.files.left), &dir.join("im0.png"), s)?;
    link_or_copy(&layout.abs(&e.files.right), &dir.join("im1.png"), s)?;
    let left = read_disp(layout, &e.files.disp_left)?;
    stereo_io::write_disparity_pfm(&dir.join("disp0.pfm"), &left)?;
    stereo_io::write_disparity_pfm(&dir.join("disp1.pfm"), &read_disp(layout, &e.files.disp_right)?)?;
    let (vmin, vmax) = left.stats().map_or((0.0, 0.0), |st| (st.min.floor(), st.max.ceil()));
    // Our rig: square pixels, both cameras share the intrinsics; no disparity offset.
    let cam = format!("[{} 0 {}; 0 {} {}; 0 0 1]", e.f_px, e.cx, e.f_px, e.cy);
    let calib = format!(
        "cam0={cam}\ncam1={cam}\ndoffs=0\nbaseline={}\nwidth={}\nheight={}\nndisp={}\nisint=0\nvmin={vmin}\nvmax={vmax}\n",
        e.baseline_m * 1000.0,
        e.width,
        e.height,
        (vmax as u32 + 1).max(1)
    );
    stereo_io::write_bytes_atomically(&dir.join("calib.txt"), calib.as_bytes())?;
    s.written += 3;
    Ok(())
}

/// Writes every sample of the manifest of `opts.dataset` into `opts.out` in `opts.format`.
pub fn export(opts: &ExportOptions) -> anyhow::Result<ExportSummary> {
    let layout = DatasetLayout::new(&opts.dataset);
    let manifest = layout.manifest();
    if !manifest.is_file() {
        bail!("{} is not a stereogen dataset (no manifest.jsonl)", opts.dataset.display());
    }
    let entries = Manifest::read(&manifest)?;
    if entries.is_empty() {
        bail!("{} has no finished samples", opts.dataset.display());
    }
    if opts.out.canonicalize().ok().is_some_and(|o| opts.dataset.canonicalize().ok().is_some_and(|d| o == d)) {
        bail!("--out must differ from the dataset directory");
    }
    mkdir(&opts.out)?;
    let mut s = ExportSummary::default();
    let mut index = String::new();
    for (n, e) in entries.iter().enumerate() {
        match opts.format {
            ExportFormat::Crestereo => export_crestereo(&layout, e, opts, &mut s),
            ExportFormat::Kitti => export_kitti(&layout, e, n, opts, &mut s),
            ExportFormat::Middlebury => export_middlebury(&layout, e, opts, &mut s),
        }
        .with_context(|| format!("exporting sample {} ({})", e.id, e.category))?;
        index.push_str(&format!("{n:06}\t{}\t{}\n", e.category, e.id));
        s.samples += 1;
    }
    // Which of our samples each exported one is (KITTI renumbers them).
    stereo_io::write_bytes_atomically(&opts.out.join("stereogen_samples.tsv"), index.as_bytes())?;
    Ok(s)
}
