//! Images: 8- and 16-bit, grey and colour, PNG and JPEG (the format is recognised from the file's
//! bytes, not its name). PNG goes through the `image` crate, JPEG through libjpeg-turbo's decoder
//! ([`crate::jpeg`]).

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageFormat, ImageReader};

use crate::error::{Error, Result};

use crate::images::image_err;
pub use crate::images::{Image, RgbImage, Samples};

/// The bytes of an image file, refusing one larger than any image within the limits could
/// need ([`crate::limits::MAX_ALLOC`]) before reading it.
pub(crate) fn read_image_file(path: &Path) -> Result<Vec<u8>> {
    crate::limits::read_file_capped(path, crate::limits::MAX_ALLOC, "an image file")
}

/// Decodes an image file, recognising the format from its content.
pub(crate) fn decode(path: &Path) -> Result<DynamicImage> {
    let bytes = read_image_file(path)?;
    decode_bytes(&bytes, path)
}

/// Decodes PNG or JPEG bytes within the limits policy ([`crate::limits`]): the size the header
/// states is checked before any pixel is decoded.
pub(crate) fn decode_bytes(bytes: &[u8], path: &Path) -> Result<DynamicImage> {
    if crate::jpeg::is_jpeg(bytes) {
        return jpeg_to_dynamic(crate::jpeg::decode_jpeg(bytes, path)?, path);
    }
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| image_err(path, e))?;
    if reader.format() != Some(ImageFormat::Png) {
        return Err(image_err(path, "unknown image format (not PNG or JPEG)"));
    }
    reader.limits(crate::limits::image_limits());
    let (width, height) = reader.into_dimensions().map_err(|e| image_err(path, e))?;
    crate::limits::check_image_size(path, width.into(), height.into())?;
    let mut reader = ImageReader::with_format(Cursor::new(bytes), ImageFormat::Png);
    reader.limits(crate::limits::image_limits());
    reader.decode().map_err(|e| image_err(path, e))
}

/// A decoded JPEG (8-bit grey or RGB) as the `image` crate's type.
fn jpeg_to_dynamic(img: Image, path: &Path) -> Result<DynamicImage> {
    let (w, h) = (img.width as u32, img.height as u32);
    let Samples::U8(data) = img.samples else {
        return Err(image_err(path, "JPEG decoded to 16-bit samples"));
    };
    let built = match img.channels {
        1 => image::GrayImage::from_raw(w, h, data).map(DynamicImage::ImageLuma8),
        _ => image::RgbImage::from_raw(w, h, data).map(DynamicImage::ImageRgb8),
    };
    built.ok_or_else(|| image_err(path, "JPEG decoder returned a buffer of the wrong size"))
}

/// Reads PNG or JPEG (JPEG through libjpeg-turbo's decoder, see [`crate::jpeg`]) and converts it
/// to RGB8.
pub fn read_rgb(path: &Path) -> Result<RgbImage> {
    Ok(to_rgb(decode(path)?))
}

pub(crate) fn to_rgb(img: DynamicImage) -> RgbImage {
    let rgb = match img {
        DynamicImage::ImageRgb8(b) => b,
        other => other.to_rgb8(),
    };
    RgbImage {
        width: rgb.width() as usize,
        height: rgb.height() as usize,
        data: rgb.into_raw(),
    }
}

/// Reads an image keeping its bit depth (8 or 16; float images are rejected) and channel count.
pub fn read_image(path: &Path) -> Result<Image> {
    let img = decode(path)?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let (channels, samples) = match img {
        DynamicImage::ImageLuma8(b) => (1, Samples::U8(b.into_raw())),
        DynamicImage::ImageLumaA8(b) => (2, Samples::U8(b.into_raw())),
        DynamicImage::ImageRgb8(b) => (3, Samples::U8(b.into_raw())),
        DynamicImage::ImageRgba8(b) => (4, Samples::U8(b.into_raw())),
        DynamicImage::ImageLuma16(b) => (1, Samples::U16(b.into_raw())),
        DynamicImage::ImageLumaA16(b) => (2, Samples::U16(b.into_raw())),
        DynamicImage::ImageRgb16(b) => (3, Samples::U16(b.into_raw())),
        DynamicImage::ImageRgba16(b) => (4, Samples::U16(b.into_raw())),
        other => {
            return Err(image_err(
                path,
                format!(
                    "unsupported pixel type {:?} (expected 8- or 16-bit integers)",
                    other.color()
                ),
            ));
        }
    };
    Ok(Image {
        width,
        height,
        channels,
        samples,
    })
}

/// Encodes an 8- or 16-bit image with 1-4 channels as PNG.
pub fn encode_png(img: &Image) -> std::result::Result<Vec<u8>, String> {
    use image::ExtendedColorType as C;
    let n = img.width * img.height * img.channels;
    let (ty, bytes): (C, Vec<u8>) = match (&img.samples, img.channels) {
        (Samples::U8(v), c) if v.len() == n => (
            [C::L8, C::La8, C::Rgb8, C::Rgba8]
                .get(c.wrapping_sub(1))
                .copied()
                .ok_or("1-4 channels")?,
            v.clone(),
        ),
        // The encoder takes 16-bit samples in native byte order.
        (Samples::U16(v), c) if v.len() == n => (
            [C::L16, C::La16, C::Rgb16, C::Rgba16]
                .get(c.wrapping_sub(1))
                .copied()
                .ok_or("1-4 channels")?,
            v.iter().flat_map(|s| s.to_ne_bytes()).collect(),
        ),
        _ => return Err("image buffer does not match its size".into()),
    };
    let mut out = Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &bytes,
        img.width as u32,
        img.height as u32,
        ty,
        ImageFormat::Png,
    )
    .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Writes an 8- or 16-bit PNG durably ([`crate::atomic`]).
pub fn write_png(path: &Path, img: &Image) -> Result<()> {
    let bytes =
        encode_png(img).map_err(|m| Error::format(path, format!("cannot encode PNG: {m}")))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Writes an RGB8 PNG durably: encoded in memory, then written, synced and renamed into place,
/// so a disk that fills up can never leave a short PNG under `path`.
pub fn write_png_rgb(path: &Path, img: &RgbImage) -> Result<()> {
    if img.data.len() != img.width * img.height * 3 {
        return Err(Error::format(path, "image buffer does not match its size"));
    }
    write_png(
        path,
        &Image {
            width: img.width,
            height: img.height,
            channels: 3,
            samples: Samples::U8(img.data.clone()),
        },
    )
}

/// Writes an RGB8 JPEG with `quality` 1..=100 (clamped), 4:4:4, durably: the one JPEG encoder
/// ([`crate::jpeg`], libjpeg-turbo's codec), so every JPEG we write decodes like OpenCV's.
pub fn write_jpeg_rgb(path: &Path, img: &RgbImage, quality: u8) -> Result<()> {
    if img.data.len() != img.width * img.height * 3 {
        return Err(Error::format(path, "image buffer does not match its size"));
    }
    let opts = crate::jpeg::JpegOptions {
        quality: quality.clamp(1, 100),
        ..Default::default()
    };
    crate::jpeg::write_jpeg(path, img, opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let img = RgbImage {
            width: 2,
            height: 2,
            data: (0..12).map(|i| i * 20).collect(),
        };
        write_png_rgb(&path, &img).unwrap();
        assert_eq!(read_rgb(&path).unwrap(), img);
        std::fs::write(&path, b"\x89PNG broken").unwrap();
        assert!(read_rgb(&path).unwrap_err().to_string().contains("x.png"));
    }
}
