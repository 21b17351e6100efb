//! A contact sheet: each sample's left image beside its colourised left disparity, in a grid.
//! The quickest way for a person to see what a dataset looks like and whether the ground truth
//! lines up with the pictures.

use std::path::Path;

use anyhow::bail;
use stereo_io::RgbImage;
use stereo_io::colormap::{DisparityRange, colourise};

use crate::dataset::{DatasetLayout, Manifest};

/// Gap between tiles, in pixels.
const GAP: usize = 6;

fn blit(dst: &mut RgbImage, src: &RgbImage, x0: usize, y0: usize) {
    for y in 0..src.height {
        let d = ((y0 + y) * dst.width + x0) * 3;
        let s = y * src.width * 3;
        dst.data[d..d + src.width * 3].copy_from_slice(&src.data[s..s + src.width * 3]);
    }
}

/// Writes a sheet of the first `count` samples (by index), `cols` samples per row.
pub fn write_contact_sheet(
    dataset: &Path,
    count: usize,
    cols: usize,
    out: &Path,
) -> anyhow::Result<usize> {
    let layout = DatasetLayout::new(dataset);
    let mut entries = Manifest::read(&layout.manifest())?;
    entries.sort_by_key(|e| e.index);
    entries.truncate(count);
    if entries.is_empty() {
        bail!("{} has no finished samples", dataset.display());
    }
    let (w, h) = (entries[0].width as usize, entries[0].height as usize);
    let cols = cols.clamp(1, entries.len());
    let rows = entries.len().div_ceil(cols);
    let tile_w = 2 * w + GAP;
    let mut sheet = RgbImage {
        width: cols * tile_w + (cols + 1) * GAP * 2,
        height: rows * h + (rows + 1) * GAP,
        data: Vec::new(),
    };
    sheet.data = vec![255; sheet.width * sheet.height * 3];
    for (i, e) in entries.iter().enumerate() {
        if (e.width as usize, e.height as usize) != (w, h) {
            bail!(
                "sample {} is {}x{}, the sheet is {w}x{h}",
                e.id,
                e.width,
                e.height
            );
        }
        let image = stereo_io::read_rgb(&layout.abs(&e.files.left))?;
        let (disp, _) = stereo_io::read_disparity_exr(&layout.abs(&e.files.disp_left))?;
        let max = disp.stats().map_or(1.0, |s| s.max);
        let (r, c) = (i / cols, i % cols);
        let x0 = GAP * 2 + c * (tile_w + GAP * 2);
        let y0 = GAP + r * (h + GAP);
        blit(&mut sheet, &image, x0, y0);
        // Zero to the sample's largest disparity, the shared colour map (`stereo_io::colormap`).
        blit(
            &mut sheet,
            &colourise(&disp, DisparityRange::new(0.0, max)),
            x0 + w + GAP,
            y0,
        );
    }
    stereo_io::write_png_rgb(out, &sheet)?;
    Ok(entries.len())
}
