//! NumPy `.npy` (format versions 1-3). Reads bool, integer and float arrays of either byte order
//! and either memory order, converting to float32 in C order; writes little-endian float32.
//! As disparity: shape (H, W) or (H, W, 1); `inf` = no ground truth, NaN = error.

use std::path::Path;

use crate::disparity::DisparityMap;
use crate::error::{Error, Result};
use crate::limits::{MAX_ALLOC, bytes_text, read_file_capped, read_to_end_capped};

const MAGIC: &[u8] = b"\x93NUMPY";

/// A float32 array in C (row-major) order.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Reads every array of a NumPy `.npz` archive (stored or deflated), names without `.npy`,
/// in archive order.
pub fn read_npz(path: &Path) -> Result<Vec<(String, NpyArray)>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let bad = |m: String| Error::format(path, format!("not a valid .npz archive: {m}"));
    let mut archive =
        zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| bad(e.to_string()))?;
    let mut out = Vec::new();
    // Every array of the archive is held at once: they share one buffer's limit, so a zip bomb
    // (gigabytes of zeros deflated to a few megabytes) is refused before it is decompressed.
    let mut left = MAX_ALLOC;
    for i in 0..archive.len() {
        let entry = archive.by_index(i).map_err(|e| bad(e.to_string()))?;
        let name = entry.name().trim_end_matches(".npy").to_string();
        let bytes = read_to_end_capped(entry, &path.join(&name), left, "the arrays of the archive")
            .map_err(|e| bad(format!("{name}: {e}")))?;
        let array =
            decode_npy(&bytes, &path.join(&name)).map_err(|e| bad(format!("{name}: {e}")))?;
        left = left.saturating_sub((array.data.len() * 4).max(bytes.len()) as u64);
        out.push((name, array));
    }
    Ok(out)
}

pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = read_file_capped(path, MAX_ALLOC, "an .npy file")?;
    decode_npy(&bytes, path)
}

/// Value of `'key':` in the header dict, as the raw text up to the next top-level comma.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let at = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = header[at + key.len() + 2..]
        .trim_start()
        .strip_prefix(':')?
        .trim_start();
    let end = if rest.starts_with('(') {
        rest.find(')')? + 1
    } else {
        rest.find([',', '}']).unwrap_or(rest.len())
    };
    Some(rest[..end].trim())
}

pub fn decode_npy(bytes: &[u8], path: &Path) -> Result<NpyArray> {
    let bad = |m: String| Error::format(path, format!("not a valid .npy file: {m}"));
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad(
            "missing the \\x93NUMPY magic (truncated or another format)".into(),
        ));
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            12,
        ),
        v => return Err(bad(format!("unsupported format version {v}"))),
    };
    let header = bytes
        .get(start..start.saturating_add(header_len))
        .ok_or_else(|| bad("truncated header".into()))?;
    let header = std::str::from_utf8(header).map_err(|_| bad("header is not text".into()))?;
    let descr = dict_value(header, "descr")
        .ok_or_else(|| bad("header has no 'descr'".into()))?
        .trim_matches(['\'', '"']);
    let fortran = match dict_value(header, "fortran_order") {
        Some("True") => true,
        Some("False") => false,
        other => return Err(bad(format!("header 'fortran_order' is {other:?}"))),
    };
    let shape_text =
        dict_value(header, "shape").ok_or_else(|| bad("header has no 'shape'".into()))?;
    let shape: Vec<usize> = shape_text
        .trim_matches(['(', ')'])
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse()
                .map_err(|_| bad(format!("shape {shape_text} is not a tuple of sizes")))
        })
        .collect::<Result<_>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n as u64 <= MAX_ALLOC / 4)
        .ok_or_else(|| {
            bad(format!(
                "shape {shape_text} is over the readers' limit of {} for one array",
                bytes_text(MAX_ALLOC)
            ))
        })?;
    let (order, kind, size) = {
        let mut c = descr.chars();
        let order = c.next().ok_or_else(|| bad("empty 'descr'".into()))?;
        let kind = c
            .next()
            .ok_or_else(|| bad(format!("dtype {descr:?} is not understood")))?;
        let size: usize = c
            .as_str()
            .parse()
            .map_err(|_| bad(format!("dtype {descr:?} is not understood")))?;
        (order, kind, size)
    };
    let big = match order {
        '<' | '|' | '=' => false,
        '>' => true,
        _ => return Err(bad(format!("dtype {descr:?} has no byte order"))),
    };
    let raw = &bytes[start + header_len..];
    let need = count
        .checked_mul(size)
        .ok_or_else(|| bad("size overflow".into()))?;
    if raw.len() < need {
        return Err(bad(format!(
            "truncated: shape {shape_text} of {descr} needs {need} bytes of data, the file has {}",
            raw.len()
        )));
    }
    macro_rules! conv {
        ($t:ty, $n:expr) => {
            raw[..need]
                .chunks_exact($n)
                .map(|b| {
                    let b: [u8; $n] = b.try_into().unwrap();
                    (if big {
                        <$t>::from_be_bytes(b)
                    } else {
                        <$t>::from_le_bytes(b)
                    }) as f32
                })
                .collect::<Vec<f32>>()
        };
    }
    let data = match (kind, size) {
        ('f', 4) => conv!(f32, 4),
        ('f', 8) => conv!(f64, 8),
        ('f', 2) => raw[..need]
            .chunks_exact(2)
            .map(|b| {
                half::f16::from_bits(if big {
                    u16::from_be_bytes([b[0], b[1]])
                } else {
                    u16::from_le_bytes([b[0], b[1]])
                })
                .to_f32()
            })
            .collect(),
        ('u', 1) | ('b', 1) => raw[..need].iter().map(|&b| f32::from(b)).collect(),
        ('i', 1) => raw[..need].iter().map(|&b| f32::from(b as i8)).collect(),
        ('u', 2) => conv!(u16, 2),
        ('i', 2) => conv!(i16, 2),
        ('u', 4) => conv!(u32, 4),
        ('i', 4) => conv!(i32, 4),
        ('u', 8) => conv!(u64, 8),
        ('i', 8) => conv!(i64, 8),
        _ => {
            return Err(bad(format!(
                "dtype {descr:?} is not supported (bool, integers, float16/32/64)"
            )));
        }
    };
    let data = if fortran && shape.len() > 1 {
        fortran_to_c(&shape, &data)
    } else {
        data
    };
    Ok(NpyArray { shape, data })
}

/// Reorders a column-major array to row-major.
fn fortran_to_c(shape: &[usize], data: &[f32]) -> Vec<f32> {
    let n = data.len();
    let mut out = vec![0f32; n];
    let mut idx = vec![0usize; shape.len()];
    for (c_pos, o) in out.iter_mut().enumerate() {
        // Fortran offset of the C-order multi-index.
        let mut rem = c_pos;
        for d in (0..shape.len()).rev() {
            idx[d] = rem % shape[d];
            rem /= shape[d];
        }
        let mut f = 0usize;
        for d in (0..shape.len()).rev() {
            f = f * shape[d] + idx[d];
        }
        *o = data[f];
    }
    out
}

/// Encodes a little-endian float32 C-order array (format version 1.0).
pub fn encode_npy(arr: &NpyArray) -> std::result::Result<Vec<u8>, String> {
    if arr.shape.iter().product::<usize>() != arr.data.len() {
        return Err("array data does not match its shape".into());
    }
    let dims: Vec<String> = arr.shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    // Pad with spaces so the data starts on a 64-byte boundary, ending with a newline.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + arr.data.len() * 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in &arr.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

pub fn write_npy(path: &Path, arr: &NpyArray) -> Result<()> {
    let bytes = encode_npy(arr).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Reads an (H, W) or (H, W, 1) array as disparity: `inf` = invalid, NaN = error.
pub fn read_disparity_npy(path: &Path) -> Result<DisparityMap> {
    let arr = read_npy(path)?;
    let (h, w) = match arr.shape.as_slice() {
        [h, w] | [h, w, 1] => (*h, *w),
        s => {
            return Err(Error::format(
                path,
                format!(
                    "a disparity array must have shape (H, W) or (H, W, 1), this one has {s:?}"
                ),
            ));
        }
    };
    crate::limits::check_image_size(path, w as u64, h as u64)?;
    crate::pfm::floats_to_disparity(path, w, h, arr.data)
}

/// Writes a map as float32 (H, W) with `inf` where invalid.
pub fn write_disparity_npy(path: &Path, map: &DisparityMap) -> Result<()> {
    let data = crate::pfm::disparity_to_floats(path, map)?;
    write_npy(
        path,
        &NpyArray {
            shape: vec![map.height, map.width],
            data,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
        let header = format!(
            "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}\n",
            if fortran { "True" } else { "False" }
        );
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&[1, 0]);
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    #[test]
    fn reads_other_dtypes_orders_and_byte_orders() {
        let p = Path::new("a.npy");
        let f64s: Vec<u8> = [1.5f64, -2.0, 3.25, 4.0, 5.0, 6.0]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let a = decode_npy(&npy(">f8", false, "(2, 3)", &f64s), p).unwrap();
        assert_eq!(
            (a.shape.clone(), a.data.clone()),
            (vec![2, 3], vec![1.5, -2.0, 3.25, 4.0, 5.0, 6.0])
        );
        // Fortran order: the bytes list column by column.
        let u16s: Vec<u8> = [1u16, 4, 2, 5, 3, 6]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let b = decode_npy(&npy("<u2", true, "(2, 3)", &u16s), p).unwrap();
        assert_eq!(b.data, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let e = decode_npy(&npy("<c8", false, "(1,)", &[0; 8]), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.npy") && e.contains("<c8"), "{e}");
        let t = decode_npy(&npy("<f4", false, "(4, 4)", &[0; 10]), p)
            .unwrap_err()
            .to_string();
        assert!(t.contains("truncated"), "{t}");
    }
}
