//! Disparity in PNG files.
//!
//! - 16-bit grey with a scale: `d = value / scale`, value 0 = no ground truth. CREStereo uses
//!   ×32 (`*.disp.png`), KITTI ×256.
//! - Sintel's RGB packing (8-bit RGB): `d = R·4 + G/2^6 + B/2^14`.

use std::path::Path;

use image::DynamicImage;

use crate::disparity::DisparityMap;
use crate::error::{Error, Result};
use crate::image_io::{Image, Samples, decode, decode_bytes, encode_png};

/// CREStereo's release: value = round(d · 32).
pub const CRESTEREO_SCALE: f32 = 32.0;
/// KITTI 2012/2015: value = round(d · 256).
pub const KITTI_SCALE: f32 = 256.0;

fn check_scale(path: &Path, scale: f32) -> Result<()> {
    if !(scale.is_finite() && scale > 0.0) {
        return Err(Error::format(
            path,
            format!("disparity scale {scale} must be finite and positive"),
        ));
    }
    Ok(())
}

/// The error for a disparity PNG of another colour type: `rule` says what it must be.
fn wrong_colour(path: &Path, rule: &str, img: &DynamicImage) -> Error {
    Error::format(path, format!("{rule}, this one is {:?}", img.color()))
}

fn png16_from_image(path: &Path, img: DynamicImage, scale: f32) -> Result<DisparityMap> {
    check_scale(path, scale)?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let raw = img
        .as_luma16()
        .ok_or_else(|| wrong_colour(path, "a scaled disparity PNG must be 16-bit grey", &img))?;
    let readings = raw
        .iter()
        .map(|&v| (v != 0).then(|| (f64::from(v) / f64::from(scale)) as f32));
    Ok(DisparityMap::from_readings(width, height, readings))
}

/// Reads a 16-bit disparity PNG: `d = value / scale`, 0 = invalid.
pub fn read_disparity_png16(path: &Path, scale: f32) -> Result<DisparityMap> {
    png16_from_image(path, decode(path)?, scale)
}

/// [`read_disparity_png16`] from bytes already in memory; `path` names them in errors.
pub fn decode_disparity_png16(bytes: &[u8], path: &Path, scale: f32) -> Result<DisparityMap> {
    png16_from_image(path, decode_bytes(bytes, path)?, scale)
}

/// Quantises a map to 16-bit values `round(d · scale)`, 0 where invalid.
///
/// A valid disparity that would round to 0 is stored as 1 (the smallest valid value, an error of
/// at most 1/scale) so it stays valid; a negative, non-finite or too large valid disparity
/// (above 65535/scale) is an error.
pub fn quantize_png16(map: &DisparityMap, scale: f32) -> std::result::Result<Vec<u16>, String> {
    if !(scale.is_finite() && scale > 0.0) {
        return Err(format!(
            "disparity scale {scale} must be finite and positive"
        ));
    }
    if map.data.len() != map.width * map.height || map.valid.len() != map.data.len() {
        return Err("disparity map buffers do not match its size".into());
    }
    let mut out = Vec::with_capacity(map.data.len());
    for (i, (&d, &v)) in map.data.iter().zip(&map.valid).enumerate() {
        if !v {
            out.push(0);
            continue;
        }
        let q = (f64::from(d) * f64::from(scale)).round();
        if !(q.is_finite() && (0.0..=65535.0).contains(&q)) || d < 0.0 {
            let (x, y) = (i % map.width, i / map.width);
            return Err(format!(
                "disparity {d} at pixel ({x}, {y}) does not fit a 16-bit PNG with scale {scale} (0..={})",
                65535.0 / scale
            ));
        }
        out.push((q as u16).max(1));
    }
    Ok(out)
}

/// Encodes a map as a 16-bit grey PNG with `scale`.
pub fn encode_disparity_png16(
    map: &DisparityMap,
    scale: f32,
) -> std::result::Result<Vec<u8>, String> {
    let q = quantize_png16(map, scale)?;
    encode_png(&Image {
        width: map.width,
        height: map.height,
        channels: 1,
        samples: Samples::U16(q),
    })
}

/// Writes a 16-bit disparity PNG atomically (see [`quantize_png16`]).
pub fn write_disparity_png16(path: &Path, map: &DisparityMap, scale: f32) -> Result<()> {
    let bytes = encode_disparity_png16(map, scale).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Reads Sintel's RGB-packed disparity: `d = R·4 + G/2^6 + B/2^14`. Sintel's maps are dense;
/// every pixel is valid (its occlusion and out-of-frame masks are separate files).
pub fn read_disparity_sintel(path: &Path) -> Result<DisparityMap> {
    let img = decode(path)?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let rgb = img
        .as_rgb8()
        .ok_or_else(|| wrong_colour(path, "a Sintel disparity PNG must be 8-bit RGB", &img))?;
    let data: Vec<f32> = rgb
        .chunks_exact(3)
        .map(|p| {
            (f64::from(p[0]) * 4.0 + f64::from(p[1]) / 64.0 + f64::from(p[2]) / 16384.0) as f32
        })
        .collect();
    Ok(DisparityMap {
        width,
        height,
        valid: vec![true; data.len()],
        data,
    })
}

/// Writes Sintel's packing (resolution 2^-14 px, range 0..1024 px); invalid pixels are stored as 0.
pub fn write_disparity_sintel(path: &Path, map: &DisparityMap) -> Result<()> {
    if map.data.len() != map.width * map.height || map.valid.len() != map.data.len() {
        return Err(Error::format(
            path,
            "disparity map buffers do not match its size",
        ));
    }
    let mut rgb = Vec::with_capacity(map.data.len() * 3);
    for (i, (&d, &v)) in map.data.iter().zip(&map.valid).enumerate() {
        let d = if v { f64::from(d) } else { 0.0 };
        let q = (d * 16384.0).round();
        if !(q.is_finite() && (0.0..16_777_216.0).contains(&q)) {
            return Err(Error::format(
                path,
                format!(
                    "disparity {d} at pixel ({}, {}) does not fit Sintel's packing (0..1024)",
                    i % map.width,
                    i / map.width
                ),
            ));
        }
        let q = q as u32;
        rgb.extend_from_slice(&[(q >> 16) as u8, (q >> 8) as u8, q as u8]);
    }
    let bytes = encode_png(&Image {
        width: map.width,
        height: map.height,
        channels: 3,
        samples: Samples::U8(rgb),
    })
    .map_err(|m| Error::format(path, format!("cannot encode PNG: {m}")))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sintel_packing_matches_the_formula() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.png");
        // R=3, G=128, B=64 -> 12 + 2 + 1/256.
        let img = Image {
            width: 1,
            height: 1,
            channels: 3,
            samples: Samples::U8(vec![3, 128, 64]),
        };
        crate::image_io::write_png(&p, &img).unwrap();
        let m = read_disparity_sintel(&p).unwrap();
        assert_eq!(m.data, vec![14.0 + 1.0 / 256.0]);
    }
}
