//! PFM (Portable Float Map): `PF` (3 channels) or `Pf` (1 channel), `W H`, then a scale whose
//! sign gives the byte order (negative = little-endian), then float32 rows **bottom row first**.
//!
//! As a disparity file (SceneFlow, Middlebury, ETH3D) `inf` marks a pixel without ground truth;
//! NaN is rejected, since no dataset uses it and it would poison any loss it reached.

use std::path::Path;

use crate::disparity::DisparityMap;
use crate::error::{Error, Result};

/// Interleaved float samples, row-major from the **top** row (the file's order is flipped on read).
#[derive(Debug, Clone, PartialEq)]
pub struct FloatImage {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

/// Largest side accepted by the readers: the limits policy's ([`crate::limits`]).
pub const MAX_SIDE: usize = crate::limits::MAX_IMAGE_SIDE as usize;

/// Byte order of a written PFM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endian {
    Little,
    Big,
}

pub fn read_pfm(path: &Path) -> Result<FloatImage> {
    let bytes = crate::limits::read_file_capped(path, crate::limits::MAX_ALLOC, "a PFM file")?;
    decode_pfm(&bytes, path)
}

/// Parses PFM bytes; `path` only names the source in errors.
pub fn decode_pfm(bytes: &[u8], path: &Path) -> Result<FloatImage> {
    let bad = |m: String| Error::format(path, format!("not a valid PFM file: {m}"));
    let mut pos = 0usize;
    // One whitespace-separated header token; PFM writers differ in the whitespace they use.
    let mut token = |what: &str| -> Result<String> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 64 {
            pos += 1;
        }
        if start == pos {
            return Err(bad(format!("truncated header: missing {what}")));
        }
        if pos >= bytes.len() {
            return Err(bad(format!("truncated header after {what}")));
        }
        String::from_utf8(bytes[start..pos].to_vec())
            .map_err(|_| bad(format!("{what} is not text")))
    };
    let channels = match token("the PF/Pf magic")?.as_str() {
        "PF" => 3,
        "Pf" => 1,
        other => {
            return Err(bad(format!(
                "magic is {other:?}, expected \"PF\" (3 channels) or \"Pf\" (1 channel)"
            )));
        }
    };
    let dim = |t: String, what: &str| -> Result<usize> {
        let v: usize = t
            .parse()
            .map_err(|_| bad(format!("{what} {t:?} is not a positive integer")))?;
        if v == 0 || v > MAX_SIDE {
            return Err(bad(format!("{what} {v} is outside 1..={MAX_SIDE}")));
        }
        Ok(v)
    };
    let width = dim(token("the width")?, "width")?;
    let height = dim(token("the height")?, "height")?;
    let scale_text = token("the scale")?;
    let scale: f64 = scale_text
        .parse()
        .map_err(|_| bad(format!("scale {scale_text:?} is not a number")))?;
    if !scale.is_finite() || scale == 0.0 {
        return Err(bad(format!(
            "scale {scale_text} must be finite and non-zero (its sign gives the byte order)"
        )));
    }
    let little = scale < 0.0;
    // Exactly one whitespace byte separates the header from the raster.
    pos += 1;
    crate::limits::check_image_size(path, width as u64, height as u64)?;
    let n = width * height * channels;
    let need = n * 4;
    crate::limits::check_alloc(path, "a PFM raster", need as u64)?;
    let have = bytes.len().saturating_sub(pos);
    if have < need {
        return Err(bad(format!(
            "truncated: {width}x{height}x{channels} floats need {need} bytes of pixels, the file has {have}"
        )));
    }
    let raster = &bytes[pos..pos + need];
    let row_len = width * channels;
    let mut data = vec![0f32; n];
    for (file_row, chunk) in raster.chunks_exact(row_len * 4).enumerate() {
        let out_row = height - 1 - file_row;
        let out = &mut data[out_row * row_len..(out_row + 1) * row_len];
        for (o, b) in out.iter_mut().zip(chunk.chunks_exact(4)) {
            let b: [u8; 4] = b.try_into().expect("chunks of 4");
            *o = if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(FloatImage {
        width,
        height,
        channels,
        data,
    })
}

/// Encodes a 1- or 3-channel float image as PFM (scale magnitude 1).
pub fn encode_pfm(img: &FloatImage, endian: Endian) -> std::result::Result<Vec<u8>, String> {
    let magic = match img.channels {
        1 => "Pf",
        3 => "PF",
        c => return Err(format!("PFM holds 1 or 3 channels, not {c}")),
    };
    if img.data.len() != img.width * img.height * img.channels {
        return Err("float image buffer does not match its size".into());
    }
    let scale = if endian == Endian::Little {
        "-1.0"
    } else {
        "1.0"
    };
    let mut out = format!("{magic}\n{} {}\n{scale}\n", img.width, img.height).into_bytes();
    out.reserve(img.data.len() * 4);
    let row_len = img.width * img.channels;
    for row in (0..img.height).rev() {
        for &v in &img.data[row * row_len..(row + 1) * row_len] {
            out.extend_from_slice(&if endian == Endian::Little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            });
        }
    }
    Ok(out)
}

/// Writes a PFM atomically.
pub fn write_pfm(path: &Path, img: &FloatImage, endian: Endian) -> Result<()> {
    let bytes = encode_pfm(img, endian).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Turns disparity floats into a map: `±inf` = no ground truth, NaN = error.
pub(crate) fn floats_to_disparity(
    path: &Path,
    width: usize,
    height: usize,
    data: Vec<f32>,
) -> Result<DisparityMap> {
    crate::disparity::refuse_nan(path, &data, width, " (use inf for no ground truth)")?;
    let readings = data.into_iter().map(|d| d.is_finite().then_some(d));
    Ok(DisparityMap::from_readings(width, height, readings))
}

/// Reads a disparity PFM. `inf` marks pixels without ground truth (Middlebury, ETH3D). A
/// 3-channel `PF` file (some datasets and tools write disparity so) is read from its first
/// channel.
pub fn read_disparity_pfm(path: &Path) -> Result<DisparityMap> {
    let img = read_pfm(path)?;
    let data = if img.channels == 1 {
        img.data
    } else {
        img.data.iter().step_by(img.channels).copied().collect()
    };
    floats_to_disparity(path, img.width, img.height, data)
}

/// A map's values with `inf` where it is invalid (the Middlebury convention of PFM and NPY
/// disparities; [`floats_to_disparity`] is the inverse).
pub(crate) fn disparity_to_floats(path: &Path, map: &DisparityMap) -> Result<Vec<f32>> {
    if map.data.len() != map.width * map.height || map.valid.len() != map.data.len() {
        return Err(Error::format(
            path,
            "disparity map buffers do not match its size",
        ));
    }
    Ok(map
        .data
        .iter()
        .zip(&map.valid)
        .map(|(&d, &v)| if v { d } else { f32::INFINITY })
        .collect())
}

/// Writes a little-endian 1-channel disparity PFM with `inf` where the map is invalid
/// (the Middlebury convention), atomically.
pub fn write_disparity_pfm(path: &Path, map: &DisparityMap) -> Result<()> {
    let data = disparity_to_floats(path, map)?;
    write_pfm(
        path,
        &FloatImage {
            width: map.width,
            height: map.height,
            channels: 1,
            data,
        },
        Endian::Little,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_stored_bottom_up_in_both_byte_orders() {
        let img = FloatImage {
            width: 2,
            height: 2,
            channels: 1,
            data: vec![1.0, 2.0, 3.0, 4.0],
        };
        let le = encode_pfm(&img, Endian::Little).unwrap();
        let header = b"Pf\n2 2\n-1.0\n";
        assert_eq!(&le[..header.len()], header);
        // The first stored row is the bottom one: 3, 4.
        assert_eq!(&le[header.len()..header.len() + 4], &3f32.to_le_bytes());
        let be = encode_pfm(&img, Endian::Big).unwrap();
        assert_eq!(&be[b"Pf\n2 2\n1.0\n".len()..][..4], &3f32.to_be_bytes());
        let p = Path::new("x.pfm");
        assert_eq!(decode_pfm(&le, p).unwrap(), img);
        assert_eq!(decode_pfm(&be, p).unwrap(), img);
    }
}
