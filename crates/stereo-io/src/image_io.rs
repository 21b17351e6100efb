//! 8-bit RGB images through the `image` crate.

use std::path::Path;

use crate::error::{Error, Result};

/// An 8-bit RGB image, row-major from the top-left pixel, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

/// Reads any format `image` decodes (PNG, JPEG) and converts it to RGB8.
pub fn read_rgb(path: &Path) -> Result<RgbImage> {
    let img = image::open(path).map_err(|e| Error::Image { path: path.to_path_buf(), message: e.to_string() })?;
    let rgb = img.to_rgb8();
    Ok(RgbImage { width: rgb.width() as usize, height: rgb.height() as usize, data: rgb.into_raw() })
}

/// Writes an RGB8 PNG.
pub fn write_png_rgb(path: &Path, img: &RgbImage) -> Result<()> {
    if img.data.len() != img.width * img.height * 3 {
        return Err(Error::format(path, "image buffer does not match its size"));
    }
    image::save_buffer_with_format(
        path,
        &img.data,
        img.width as u32,
        img.height as u32,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| Error::Image { path: path.to_path_buf(), message: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let img = RgbImage { width: 2, height: 2, data: (0..12).map(|i| i * 20).collect() };
        write_png_rgb(&path, &img).unwrap();
        assert_eq!(read_rgb(&path).unwrap(), img);
        std::fs::write(&path, b"\x89PNG broken").unwrap();
        assert!(read_rgb(&path).unwrap_err().to_string().contains("x.png"));
    }
}
