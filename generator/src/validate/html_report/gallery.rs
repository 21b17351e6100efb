//! The gallery: which samples (deterministic, spread over the categories and the index range)
//! and their pictures as data: URIs (JPEG for the photographs, PNG for the colourised disparity
//! and maps),
//! scaled down to [`THUMB_WIDTH`] so the page stays small.

use std::collections::BTreeMap;

use base64::Engine;
use image::imageops::FilterType;

use crate::dataset::ManifestEntry;
use crate::validate::dataset_files::DatasetFiles;
use stereo_io::colormap::{DisparityRange, colourise};

/// Widest thumbnail (px); smaller images keep their size.
pub const THUMB_WIDTH: u32 = 256;
/// JPEG quality of the image thumbnails.
pub const JPEG_QUALITY: u8 = 80;

/// One sample on the page.
pub struct Tile {
    pub id: String,
    pub category: String,
    pub index: u64,
    /// Why it is shown (outliers) or a short description.
    pub caption: String,
    pub left: Option<String>,
    pub disparity: Option<String>,
    pub right: Option<String>,
    /// Top of the colour scale (px).
    pub scale_max: String,
    /// The left view's maps beside the disparity (name, picture), where the sample has them.
    pub maps: Vec<(String, String)>,
    /// Files that could not be shown, one line each.
    pub problems: Vec<String>,
}

/// `n` positions in `entries` (sorted by index): categories take turns, each contributing
/// samples evenly spaced over its own index range.
pub fn choose(entries: &[ManifestEntry], n: usize) -> Vec<usize> {
    let mut by: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, e) in entries.iter().enumerate() {
        by.entry(&e.category).or_default().push(i);
    }
    let groups: Vec<Vec<usize>> = by.into_values().collect();
    let n = n.min(entries.len());
    let mut share = vec![0usize; groups.len()];
    let mut given = 0;
    while given < n {
        for (k, g) in groups.iter().enumerate() {
            if given < n && share[k] < g.len() {
                share[k] += 1;
                given += 1;
            }
        }
    }
    let mut out: Vec<usize> = groups
        .iter()
        .zip(&share)
        .flat_map(|(g, &m)| (0..m).map(move |j| g[j * g.len() / m.max(1)]))
        .collect();
    out.sort_unstable();
    out
}

fn data_uri(mime: &str, bytes: &[u8]) -> String {
    format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

fn thumb_size(w: u32, h: u32) -> (u32, u32) {
    if w <= THUMB_WIDTH {
        (w, h)
    } else {
        (
            THUMB_WIDTH,
            ((h as f64 * THUMB_WIDTH as f64 / w as f64).round() as u32).max(1),
        )
    }
}

/// A file of the sample: its bytes (from its folder or its export's shard) and its name for
/// messages.
fn read(files: &DatasetFiles, e: &ManifestEntry, key: &str) -> Result<Vec<u8>, String> {
    files.read(e, key).map_err(|err| err.to_string())
}

fn photo(files: &DatasetFiles, e: &ManifestEntry, key: &str) -> Result<String, String> {
    let path = files.path(e, key);
    let img = image::load_from_memory(&read(files, e, key)?)
        .map_err(|err| format!("{}: {err}", path.display()))?
        .to_rgb8();
    let (w, h) = thumb_size(img.width(), img.height());
    let small = if (w, h) == img.dimensions() {
        img
    } else {
        image::imageops::resize(&img, w, h, FilterType::Triangle)
    };
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY)
        .encode_image(&small)
        .map_err(|err| format!("{}: {err}", path.display()))?;
    Ok(data_uri("image/jpeg", &out))
}

/// The colourised left map and the top of its scale.
fn disparity(files: &DatasetFiles, e: &ManifestEntry) -> Result<(String, f32), String> {
    let path = files.path(e, "disp_left");
    let (map, _) = stereo_io::decode_disparity_exr(&read(files, e, "disp_left")?, &path)
        .map_err(|err| err.to_string())?;
    let max = map.stats().map_or(1.0, |s| s.max).max(1e-3);
    let rgb = colourise(&map, DisparityRange::new(0.0, max));
    Ok((png_thumbnail(rgb, &path)?, max))
}

/// A colourised map as a PNG data: URI, scaled down (nearest neighbour) to the thumbnail size;
/// `path` names it in messages.
pub fn png_thumbnail(rgb: stereo_io::RgbImage, path: &std::path::Path) -> Result<String, String> {
    let img = image::RgbImage::from_raw(rgb.width as u32, rgb.height as u32, rgb.data)
        .ok_or_else(|| format!("{}: bad size", path.display()))?;
    let (w, h) = thumb_size(img.width(), img.height());
    let small = if (w, h) == img.dimensions() {
        img
    } else {
        image::imageops::resize(&img, w, h, FilterType::Nearest)
    };
    let mut out = std::io::Cursor::new(Vec::new());
    small
        .write_to(&mut out, image::ImageFormat::Png)
        .map_err(|err| format!("{}: {err}", path.display()))?;
    Ok(data_uri("image/png", out.get_ref()))
}

/// The tile of one sample; files that cannot be read become problems of the tile.
pub fn tile(files: &DatasetFiles, e: &ManifestEntry, caption: String) -> Tile {
    let mut problems = Vec::new();
    let mut keep = |r: Result<String, String>| r.map_err(|p| problems.push(p)).ok();
    let left = keep(photo(files, e, "left"));
    let right = keep(photo(files, e, "right"));
    let (disparity, scale_max) = match disparity(files, e) {
        Ok((uri, max)) => (Some(uri), format!("{max:.1}")),
        Err(p) => {
            problems.push(p);
            (None, "-".into())
        }
    };
    let maps = super::maps::thumbnails(files, e, &mut problems);
    Tile {
        id: e.id.clone(),
        category: e.category.clone(),
        index: e.index,
        caption,
        left,
        disparity,
        right,
        scale_max,
        maps,
        problems,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thumbnails_keep_the_aspect_and_never_grow() {
        assert_eq!(thumb_size(960, 540), (256, 144));
        assert_eq!(thumb_size(64, 48), (64, 48));
    }
}
