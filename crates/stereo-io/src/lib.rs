//! Formats shared by the generator and the trainer: float32 disparity EXR and 8-bit images.
//!
//! Every reader names the file and the problem in its error; nothing here panics on bad input.

pub mod atomic;
pub mod disparity;
pub mod error;
pub mod exr_io;
pub mod image_io;

pub use atomic::{temp_sibling, write_atomically, write_bytes_atomically};
pub use disparity::{DisparityMap, DisparityMeta, DisparityStats};
pub use error::{Error, Result};
pub use exr_io::{read_depth_channel, read_disparity_exr, write_disparity_exr};
pub use image_io::{RgbImage, read_rgb, write_png_rgb};
