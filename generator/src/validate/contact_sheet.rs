//! A contact sheet: each sample's left image beside its colourised left disparity, in a grid.
//! The quickest way for a person to see what a dataset looks like and whether the ground truth
//! lines up with the pictures.

use std::path::Path;

use anyhow::bail;
use stereo_io::{DisparityMap, RgbImage};

use crate::dataset::{DatasetLayout, Manifest};

/// Gap between tiles, in pixels.
const GAP: usize = 6;

/// Disparity to colour: far (small) is blue, near (large) is red, through cyan, green and yellow.
/// Invalid pixels are black.
pub fn colourise(map: &DisparityMap, max: f32) -> RgbImage {
    let mut data = Vec::with_capacity(map.data.len() * 3);
    for (&d, &v) in map.data.iter().zip(&map.valid) {
        if !v {
            data.extend([0, 0, 0]);
            continue;
        }
        let t = f64::from((d / max.max(1e-6)).clamp(0.0, 1.0));
        // Hue from 240° (blue) down to 0° (red), full saturation and value.
        let h = (1.0 - t) * 4.0;
        let x = 1.0 - (h % 2.0 - 1.0).abs();
        let (r, g, b) = match h as u32 {
            0 => (1.0, x, 0.0),
            1 => (x, 1.0, 0.0),
            2 => (0.0, 1.0, x),
            _ => (0.0, x, 1.0),
        };
        data.extend([r, g, b].map(|c: f64| (c * 255.0).round() as u8));
    }
    RgbImage { width: map.width, height: map.height, data }
}

fn blit(dst: &mut RgbImage, src: &RgbImage, x0: usize, y0: usize) {
    for y in 0..src.height {
        let d = ((y0 + y) * dst.width + x0) * 3;
        let s = y * src.width * 3;
        dst.data[d..d + src.width * 3].copy_from_slice(&src.data[s..s + src.width * 3]);
    }
}

/// Writes a sheet of the first `count` samples (by index), `cols` samples per row.
pub fn write_contact_sheet(dataset: &Path, count: usize, cols: usize, out: &Path) -> anyhow::Result<usize> {
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
    let mut sheet = RgbImage { width: cols * tile_w + (cols + 1) * GAP * 2, height: rows * h + (rows + 1) * GAP, data: Vec::new() };
    sheet.data = vec![255; sheet.width * sheet.height * 3];
    for (i, e) in entries.iter().enumerate() {
        if (e.width as usize, e.height as usize) != (w, h) {
            bail!("sample {} is {}x{}, the sheet is {w}x{h}", e.id, e.width, e.height);
        }
        let image = stereo_io::read_rgb(&layout.abs(&e.files.left))?;
        let (disp, _) = stereo_io::read_disparity_exr(&layout.abs(&e.files.disp_left))?;
        let max = disp.stats().map_or(1.0, |s| s.max);
        let (r, c) = (i / cols, i % cols);
        let x0 = GAP * 2 + c * (tile_w + GAP * 2);
        let y0 = GAP + r * (h + GAP);
        blit(&mut sheet, &image, x0, y0);
        blit(&mut sheet, &colourise(&disp, max), x0 + w + GAP, y0);
    }
    stereo_io::write_png_rgb(out, &sheet)?;
    Ok(entries.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_run_from_blue_to_red_and_invalid_is_black() {
        let map = DisparityMap { width: 4, height: 1, data: vec![0.0, 5.0, 10.0, 3.0], valid: vec![true, true, true, false] };
        let img = colourise(&map, 10.0);
        assert_eq!(&img.data[0..3], &[0, 0, 255]);
        assert_eq!(&img.data[6..9], &[255, 0, 0]);
        assert_eq!(&img.data[3..6], &[0, 255, 0]);
        assert_eq!(&img.data[9..12], &[0, 0, 0]);
    }
}
