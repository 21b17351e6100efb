//! The decoded image types every reader and writer shares ([`crate::image_io`] for PNG and the
//! format dispatch, [`crate::jpeg`] for JPEG).

use std::path::Path;

use crate::error::Error;

/// An 8-bit RGB image, row-major from the top-left pixel, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

/// Samples of an [`Image`], interleaved.
#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
}

/// An image at its native bit depth: 1 (grey), 2 (grey+alpha), 3 (RGB) or 4 (RGBA) channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub samples: Samples,
}

impl Image {
    /// An 8-bit RGB image from its interleaved samples (row-major, three per pixel).
    pub fn rgb8(width: usize, height: usize, samples: Vec<u8>) -> Self {
        Image {
            width,
            height,
            channels: 3,
            samples: Samples::U8(samples),
        }
    }
}

pub(crate) fn image_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}
