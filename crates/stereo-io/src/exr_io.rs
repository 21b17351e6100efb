//! Float32 disparity EXR: channel `Y` holds disparity (so any viewer shows it as grey),
//! channel `valid` holds 1 for a measured pixel and 0 where no surface was hit.
//! Header attributes `stereogen.f_px`, `stereogen.baseline_m`, `stereogen.units`, `stereogen.view`.

use std::path::Path;

use exr::prelude::*;

use crate::disparity::{DisparityMap, DisparityMeta};
use crate::error::{Error, Result as IoResult};
use crate::limits::{MAX_ALLOC, check_image_size, read_file_capped};

const DISPARITY_CHANNEL: &str = "Y";
const VALID_CHANNEL: &str = "valid";
const ATTR_F_PX: &str = "stereogen.f_px";
const ATTR_BASELINE: &str = "stereogen.baseline_m";
const ATTR_UNITS: &str = "stereogen.units";
const ATTR_VIEW: &str = "stereogen.view";

fn exr_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes a disparity map as a ZIP-compressed float32 EXR, durably ([`crate::atomic`]). Output
/// bytes depend only on the inputs.
pub fn write_disparity_exr(path: &Path, map: &DisparityMap, meta: &DisparityMeta) -> IoResult<()> {
    let bytes = encode_disparity_exr(map, meta).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// The bytes of [`write_disparity_exr`]'s file.
pub fn encode_disparity_exr(
    map: &DisparityMap,
    meta: &DisparityMeta,
) -> std::result::Result<Vec<u8>, String> {
    if map.data.len() != map.width * map.height || map.valid.len() != map.data.len() {
        return Err("disparity map buffers do not match its size".into());
    }
    let mut attrs = LayerAttributes::named("disparity");
    if let Some(f) = meta.f_px {
        attrs
            .other
            .insert(Text::from(ATTR_F_PX), AttributeValue::F64(f));
    }
    if let Some(b) = meta.baseline_m {
        attrs
            .other
            .insert(Text::from(ATTR_BASELINE), AttributeValue::F64(b));
    }
    attrs.other.insert(
        Text::from(ATTR_UNITS),
        AttributeValue::Text(Text::from("pixels")),
    );
    if let Some(v) = &meta.view {
        attrs.other.insert(
            Text::from(ATTR_VIEW),
            AttributeValue::Text(Text::from(v.as_str())),
        );
    }
    let valid: Vec<f16> = map
        .valid
        .iter()
        .map(|&v| if v { f16::ONE } else { f16::ZERO })
        .collect();
    encode_layer(
        (map.width, map.height),
        attrs,
        vec![
            AnyChannel::new(DISPARITY_CHANNEL, FlatSamples::F32(map.data.clone())),
            AnyChannel::new(VALID_CHANNEL, FlatSamples::F16(valid)),
        ],
    )
}

/// One ZIP-compressed scan-line layer of `channels` as EXR bytes that depend only on the inputs:
/// the one encoder of every EXR this crate writes (disparity, depth, normals).
pub(crate) fn encode_layer(
    size: (usize, usize),
    attrs: LayerAttributes,
    channels: Vec<AnyChannel<FlatSamples>>,
) -> std::result::Result<Vec<u8>, String> {
    // Increasing line order: parallel compression must not decide the chunk order, or equal
    // maps would give different bytes.
    let encoding = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let channels = AnyChannels::sort(SmallVec::from_vec(channels));
    let layer = Layer::new(size, attrs, encoding, channels);
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut bytes)
        .map_err(|e| format!("cannot encode EXR: {e}"))?;
    let mut bytes = bytes.into_inner();
    sort_header_attributes(&mut bytes)?;
    Ok(bytes)
}

/// `exr` keeps custom attributes in a `HashMap`, so their order in the header changes from one
/// map instance to the next. Sorting them by name makes equal images give equal bytes. It is a
/// permutation inside the header, so the header length and every chunk offset stay the same.
fn sort_header_attributes(bytes: &mut [u8]) -> std::result::Result<(), String> {
    const MULTIPART: u32 = 0x1000;
    if bytes.len() < 8 || bytes[..4] != [0x76, 0x2f, 0x31, 0x01] {
        return Err("writer produced no EXR magic number".into());
    }
    if u32::from_le_bytes(bytes[4..8].try_into().unwrap()) & MULTIPART != 0 {
        return Ok(());
    }
    let cstr_end = |from: usize| {
        bytes[from..]
            .iter()
            .position(|&b| b == 0)
            .map(|p| from + p)
            .ok_or("unterminated header string")
    };
    let mut attributes: Vec<(Vec<u8>, std::ops::Range<usize>)> = Vec::new();
    let mut pos = 8;
    while bytes.get(pos).copied().ok_or("truncated header")? != 0 {
        let name_end = cstr_end(pos)?;
        let type_end = cstr_end(name_end + 1)?;
        let size_at = type_end + 1;
        let size = i32::from_le_bytes(
            bytes
                .get(size_at..size_at + 4)
                .ok_or("truncated header")?
                .try_into()
                .unwrap(),
        );
        let end = size_at + 4 + usize::try_from(size).map_err(|_| "negative attribute size")?;
        if end > bytes.len() {
            return Err("attribute runs past the end of the file".into());
        }
        attributes.push((bytes[pos..name_end].to_vec(), pos..end));
        pos = end;
    }
    let mut sorted = attributes.clone();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let reordered: Vec<u8> = sorted
        .iter()
        .flat_map(|(_, r)| bytes[r.clone()].to_vec())
        .collect();
    bytes[8..pos].copy_from_slice(&reordered);
    Ok(())
}

fn read_flat(path: &Path) -> IoResult<Layer<AnyChannels<FlatSamples>>> {
    let bytes = read_file_capped(path, MAX_ALLOC, "an EXR file")?;
    decode_flat(&bytes, path)
}

/// Refuses headers whose pixels the limits policy ([`crate::limits`]) does not allow, or that
/// would need far more memory than the file could hold: ZIP, the best-compressing EXR codec,
/// stays near 1:1000, so a small file claiming gigapixels is corrupt and must not make the
/// decoder allocate (and abort the process).
fn check_decoded_size(bytes: &[u8], path: &Path) -> IoResult<()> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| exr_err(path, e))?;
    let budget = (bytes.len() as u128 * 4096 + (1 << 20)).min(u128::from(MAX_ALLOC));
    for header in &meta.headers {
        let (width, height) = (header.layer_size.x(), header.layer_size.y());
        check_image_size(path, width as u64, height as u64)?;
        let per_pixel: u128 = header
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample() as u128)
            .sum();
        let need = width as u128 * height as u128 * per_pixel;
        if need > budget {
            return Err(exr_err(
                path,
                format!(
                    "header claims {width}x{height} pixels ({need} bytes decoded) from a {}-byte file: corrupt or truncated",
                    bytes.len()
                ),
            ));
        }
    }
    Ok(())
}

pub(crate) fn decode_flat(bytes: &[u8], path: &Path) -> IoResult<Layer<AnyChannels<FlatSamples>>> {
    check_decoded_size(bytes, path)?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| exr_err(path, e))?;
    Ok(image.layer_data)
}

pub(crate) fn samples_f32(samples: &FlatSamples) -> Vec<f32> {
    match samples {
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
    }
}

fn attr_f64(layer: &Layer<AnyChannels<FlatSamples>>, name: &str) -> Option<f64> {
    match layer.attributes.other.get(&Text::from(name))? {
        AttributeValue::F64(v) => Some(*v),
        AttributeValue::F32(v) => Some(f64::from(*v)),
        _ => None,
    }
}

/// Reads a disparity EXR written by [`write_disparity_exr`], or any single-channel float EXR
/// (then every finite positive pixel counts as valid).
pub fn read_disparity_exr(path: &Path) -> IoResult<(DisparityMap, DisparityMeta)> {
    let bytes = read_file_capped(path, MAX_ALLOC, "an EXR file")?;
    decode_disparity_exr(&bytes, path)
}

/// [`read_disparity_exr`] from bytes already in memory; `path` names them in errors.
pub fn decode_disparity_exr(bytes: &[u8], path: &Path) -> IoResult<(DisparityMap, DisparityMeta)> {
    let mut layer = decode_flat(bytes, path)?;
    let (width, height) = (layer.size.width(), layer.size.height());
    let channels = &mut layer.channel_data.list;
    let position = |name: &str| channels.iter().position(|c| c.name.to_string() == name);
    let (disp_at, valid_at) = (
        position(DISPARITY_CHANNEL).or(if channels.len() == 1 { Some(0) } else { None }),
        position(VALID_CHANNEL),
    );
    let disp_at = disp_at.ok_or_else(|| {
        Error::format(
            path,
            format!(
                "no disparity channel `{DISPARITY_CHANNEL}` (channels: {})",
                channel_names(channels)
            ),
        )
    })?;
    // Move the decoded samples out instead of copying them (8 MB for a 1080p map).
    let data = match std::mem::replace(
        &mut channels[disp_at].sample_data,
        FlatSamples::F32(Vec::new()),
    ) {
        FlatSamples::F32(v) => v,
        other => samples_f32(&other),
    };
    crate::disparity::refuse_nan(path, &data, width, "")?;
    let valid = match valid_at.map(|i| &channels[i].sample_data) {
        Some(FlatSamples::F16(v)) => v.iter().map(|x| x.to_f32() > 0.5).collect(),
        Some(other) => samples_f32(other).iter().map(|&v| v > 0.5).collect(),
        None => data.iter().map(|&d| d.is_finite() && d > 0.0).collect(),
    };
    let view = match layer.attributes.other.get(&Text::from(ATTR_VIEW)) {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        _ => None,
    };
    let meta = DisparityMeta {
        f_px: attr_f64(&layer, ATTR_F_PX),
        baseline_m: attr_f64(&layer, ATTR_BASELINE),
        view,
    };
    Ok((
        DisparityMap {
            width,
            height,
            data,
            valid,
        },
        meta,
    ))
}

/// A file's channel names for an error message: quoted and escaped, so a hostile name (a
/// newline, a control character) cannot break the message's one line.
pub(crate) fn channel_names<S>(channels: &[exr::image::AnyChannel<S>]) -> String {
    channels
        .iter()
        .map(|c| format!("{:?}", c.name.to_string()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Reads the planar depth channel from a render-pass EXR (Blender multilayer: `*.Depth.Z`,
/// or a plain `Z`/`depth` channel). Returns (width, height, row-major depth from the top row).
pub fn read_depth_channel(path: &Path) -> IoResult<(usize, usize, Vec<f32>)> {
    let p = read_render_passes(path)?;
    Ok((p.width, p.height, p.depth))
}

/// The passes of a render-pass EXR the generator reads: depth, and Cycles' material index
/// (`*.IndexMA.X`: each pixel's first-surface material's `pass_index`) where it was rendered.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderPasses {
    pub width: usize,
    pub height: usize,
    /// Row-major from the top row.
    pub depth: Vec<f32>,
    pub material_index: Option<Vec<f32>>,
    /// Cycles' normal pass (`*.Normal.X/Y/Z`: the first surface's shading normal, world space),
    /// where it was rendered.
    pub normal: Option<[Vec<f32>; 3]>,
    /// Cycles' object index (`*.IndexOB.X`: the first surface's object's `pass_index`), where it
    /// was rendered.
    pub object_index: Option<Vec<f32>>,
}

/// Reads [`RenderPasses`] (see [`read_depth_channel`] for the depth channel's names).
pub fn read_render_passes(path: &Path) -> IoResult<RenderPasses> {
    let layer = read_flat(path)?;
    let channels = &layer.channel_data.list;
    let named = |test: &dyn Fn(&str) -> bool| {
        channels
            .iter()
            .find(|c| test(&c.name.to_string()))
            .map(|c| samples_f32(&c.sample_data))
    };
    let depth = named(&|n| n.ends_with(".Depth.Z") || n == "Z" || n == "Depth.Z" || n == "depth")
        .ok_or_else(|| {
        Error::format(
            path,
            format!("no depth channel (channels: {})", channel_names(channels)),
        )
    })?;
    let pass = |name: &str| {
        let dotted = format!(".{name}");
        named(&|n| n.ends_with(&dotted) || n == name)
    };
    let normal = match (pass("Normal.X"), pass("Normal.Y"), pass("Normal.Z")) {
        (Some(x), Some(y), Some(z)) => Some([x, y, z]),
        _ => None,
    };
    Ok(RenderPasses {
        width: layer.size.width(),
        height: layer.size.height(),
        depth,
        material_index: pass("IndexMA.X"),
        normal,
        object_index: pass("IndexOB.X"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_mask_and_meta() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.exr");
        let mut map = DisparityMap::new(3, 2);
        map.data = vec![0.0, 1.5, 1e-7, 123.456, 0.0, 7.0];
        map.valid = vec![false, true, true, true, false, true];
        let meta = DisparityMeta {
            f_px: Some(1050.0),
            baseline_m: Some(0.12),
            view: Some("left".into()),
        };
        write_disparity_exr(&path, &map, &meta).unwrap();
        let (back, back_meta) = read_disparity_exr(&path).unwrap();
        assert_eq!(back, map);
        assert_eq!(back_meta, meta);
    }

    #[test]
    fn writing_is_deterministic() {
        let dir = tempfile::tempdir().unwrap();
        // Large enough for many compressed chunks, which a parallel writer may finish out of order.
        let mut map = DisparityMap::new(640, 480);
        for (i, d) in map.data.iter_mut().enumerate() {
            *d = (i as f32 * 0.37).sin() * 50.0;
        }
        map.valid.iter_mut().for_each(|v| *v = true);
        // Several custom attributes: their order must not depend on the writer's hash map.
        let meta = DisparityMeta {
            f_px: Some(500.0),
            baseline_m: Some(0.2),
            view: Some("right".into()),
        };
        let first = dir.path().join("first.exr");
        write_disparity_exr(&first, &map, &meta).unwrap();
        let reference = std::fs::read(&first).unwrap();
        for i in 0..8 {
            let again = dir.path().join(format!("again{i}.exr"));
            write_disparity_exr(&again, &map, &meta).unwrap();
            assert!(
                std::fs::read(&again).unwrap() == reference,
                "write {i} gave different bytes"
            );
            assert_eq!(
                read_disparity_exr(&again).unwrap(),
                (map.clone(), meta.clone())
            );
        }
    }

    #[test]
    fn garbage_and_truncated_files_give_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let junk = dir.path().join("junk.exr");
        std::fs::write(&junk, b"definitely not an exr").unwrap();
        let err = read_disparity_exr(&junk).unwrap_err().to_string();
        assert!(err.contains("junk.exr"), "{err}");

        let good = dir.path().join("good.exr");
        let map = DisparityMap::new(8, 8);
        write_disparity_exr(&good, &map, &DisparityMeta::default()).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let cut = dir.path().join("cut.exr");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        assert!(
            read_disparity_exr(&cut)
                .unwrap_err()
                .to_string()
                .contains("cut.exr")
        );
    }
}
