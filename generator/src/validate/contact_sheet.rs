//! A contact sheet: each sample's left image beside its colourised left disparity, in a grid.
//! The quickest way for a person to see what a dataset looks like and whether the ground truth
//! lines up with the pictures.
//!
//! A dataset with maps beside the disparity (a recipe's `[render] outputs`) gets one more row per
//! map under each sample's pair, in [`MapKind::ALL`]'s order, each the left view's map beside the
//! right view's: depth as inverse depth on the disparity ramp over the sample's range (near red,
//! far blue), normals as `(n + 1) / 2` in RGB, instance and semantic ids in a fixed categorical
//! palette (`stereo_io::colormap`); black is no surface. Without maps the sheet is as it was.

use std::path::Path;

use anyhow::bail;
use stereo_io::colormap::{
    DisparityRange, colourise, colourise_depth, colourise_ids, colourise_normals,
    inverse_depth_range,
};
use stereo_io::{MapKind, RgbImage};

use crate::dataset::{DatasetLayout, Manifest, ManifestEntry};

/// Gap between tiles, in pixels.
const GAP: usize = 6;

fn blit(dst: &mut RgbImage, src: &RgbImage, x0: usize, y0: usize) {
    for y in 0..src.height {
        let d = ((y0 + y) * dst.width + x0) * 3;
        let s = y * src.width * 3;
        dst.data[d..d + src.width * 3].copy_from_slice(&src.data[s..s + src.width * 3]);
    }
}

/// The maps any of `entries` has, in [`MapKind::ALL`]'s order: the sheet's extra rows.
pub fn sheet_maps(entries: &[ManifestEntry]) -> Vec<MapKind> {
    MapKind::ALL
        .into_iter()
        .filter(|&k| entries.iter().any(|e| e.files.maps().contains(&k)))
        .collect()
}

/// Sample `e`'s map `kind` of both views, colourised; `None` where the sample lacks it. Depth
/// shares one range over both views.
fn map_pair(
    layout: &DatasetLayout,
    e: &ManifestEntry,
    kind: MapKind,
) -> anyhow::Result<Option<[RgbImage; 2]>> {
    let (Some(l), Some(r)) = (e.files.map(kind, "left"), e.files.map(kind, "right")) else {
        return Ok(None);
    };
    let (l, r) = (layout.abs(l), layout.abs(r));
    Ok(Some(match kind {
        MapKind::Depth => {
            let maps = [
                stereo_io::read_depth_exr(&l)?,
                stereo_io::read_depth_exr(&r)?,
            ];
            let range = inverse_depth_range(&maps);
            maps.map(|m| colourise_depth(&m, range))
        }
        MapKind::Normals => [
            colourise_normals(&stereo_io::read_normals_exr(&l)?),
            colourise_normals(&stereo_io::read_normals_exr(&r)?),
        ],
        MapKind::Instance | MapKind::Semantic => [
            colourise_ids(&stereo_io::read_id_png(&l)?),
            colourise_ids(&stereo_io::read_id_png(&r)?),
        ],
    }))
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
    let maps = sheet_maps(&entries);
    // A tile: the image and disparity, then a row per map, GAP apart.
    let tile_h = h + maps.len() * (h + GAP);
    let cols = cols.clamp(1, entries.len());
    let rows = entries.len().div_ceil(cols);
    let tile_w = 2 * w + GAP;
    let mut sheet = RgbImage {
        width: cols * tile_w + (cols + 1) * GAP * 2,
        height: rows * tile_h + (rows + 1) * GAP,
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
        let y0 = GAP + r * (tile_h + GAP);
        blit(&mut sheet, &image, x0, y0);
        // Zero to the sample's largest disparity, the shared colour map (`stereo_io::colormap`).
        blit(
            &mut sheet,
            &colourise(&disp, DisparityRange::new(0.0, max)),
            x0 + w + GAP,
            y0,
        );
        for (k, &kind) in maps.iter().enumerate() {
            let y = y0 + (k + 1) * (h + GAP);
            if let Some([left, right]) = map_pair(&layout, e, kind)? {
                for (x, img) in [(x0, &left), (x0 + w + GAP, &right)] {
                    if (img.width, img.height) != (w, h) {
                        bail!("sample {}'s {kind} map is not {w}x{h}", e.id);
                    }
                    blit(&mut sheet, img, x, y);
                }
            }
        }
    }
    stereo_io::write_png_rgb(out, &sheet)?;
    Ok(entries.len())
}
