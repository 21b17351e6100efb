//! Float32 disparity EXR: channel `Y` holds disparity (so any viewer shows it as grey),
//! channel `valid` holds 1 for a measured pixel and 0 where no surface was hit.
//! Header attributes `stereogen.f_px`, `stereogen.baseline_m`, `stereogen.units`, `stereogen.view`.

use std::path::Path;

use exr::prelude::*;

use crate::disparity::{DisparityMap, DisparityMeta};
use crate::error::{Error, Result as IoResult};

const DISPARITY_CHANNEL: &str = "Y";
const VALID_CHANNEL: &str = "valid";
const ATTR_F_PX: &str = "stereogen.f_px";
const ATTR_BASELINE: &str = "stereogen.baseline_m";
const ATTR_UNITS: &str = "stereogen.units";
const ATTR_VIEW: &str = "stereogen.view";

fn exr_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Exr { path: path.to_path_buf(), message: e.to_string() }
}

/// Writes a disparity map as a ZIP-compressed float32 EXR. Output bytes depend only on the inputs.
pub fn write_disparity_exr(path: &Path, map: &DisparityMap, meta: &DisparityMeta) -> IoResult<()> {
    if map.data.len() != map.width * map.height || map.valid.len() != map.data.len() {
        return Err(Error::format(path, "disparity map buffers do not match its size"));
    }
    let mut attrs = LayerAttributes::named("disparity");
    if let Some(f) = meta.f_px {
        attrs.other.insert(Text::from(ATTR_F_PX), AttributeValue::F64(f));
    }
    if let Some(b) = meta.baseline_m {
        attrs.other.insert(Text::from(ATTR_BASELINE), AttributeValue::F64(b));
    }
    attrs.other.insert(Text::from(ATTR_UNITS), AttributeValue::Text(Text::from("pixels")));
    if let Some(v) = &meta.view {
        attrs.other.insert(Text::from(ATTR_VIEW), AttributeValue::Text(Text::from(v.as_str())));
    }
    let valid: Vec<f16> = map.valid.iter().map(|&v| if v { f16::ONE } else { f16::ZERO }).collect();
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new(DISPARITY_CHANNEL, FlatSamples::F32(map.data.clone())),
        AnyChannel::new(VALID_CHANNEL, FlatSamples::F16(valid)),
    ]));
    let layer = Layer::new((map.width, map.height), attrs, Encoding::SMALL_LOSSLESS, channels);
    Image::from_layer(layer).write().to_file(path).map_err(|e| exr_err(path, e))
}

fn read_flat(path: &Path) -> IoResult<Layer<AnyChannels<FlatSamples>>> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_err(path, e))?;
    Ok(image.layer_data)
}

fn samples_f32(samples: &FlatSamples) -> Vec<f32> {
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
    let layer = read_flat(path)?;
    let (width, height) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let find = |name: &str| channels.iter().find(|c| c.name.to_string() == name);
    let disp = find(DISPARITY_CHANNEL).or(if channels.len() == 1 { channels.first() } else { None }).ok_or_else(|| {
        let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
        Error::format(path, format!("no disparity channel `{DISPARITY_CHANNEL}` (channels: {})", names.join(", ")))
    })?;
    let data = samples_f32(&disp.sample_data);
    if data.iter().any(|d| d.is_nan()) {
        return Err(Error::format(path, "disparity contains NaN"));
    }
    let valid = match find(VALID_CHANNEL) {
        Some(c) => samples_f32(&c.sample_data).iter().map(|&v| v > 0.5).collect(),
        None => data.iter().map(|&d| d.is_finite() && d > 0.0).collect(),
    };
    let view = match layer.attributes.other.get(&Text::from(ATTR_VIEW)) {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        _ => None,
    };
    let meta = DisparityMeta { f_px: attr_f64(&layer, ATTR_F_PX), baseline_m: attr_f64(&layer, ATTR_BASELINE), view };
    Ok((DisparityMap { width, height, data, valid }, meta))
}

/// Reads the planar depth channel from a render-pass EXR (Blender multilayer: `*.Depth.Z`,
/// or a plain `Z`/`depth` channel). Returns (width, height, row-major depth from the top row).
pub fn read_depth_channel(path: &Path) -> IoResult<(usize, usize, Vec<f32>)> {
    let layer = read_flat(path)?;
    let channels = &layer.channel_data.list;
    let depth = channels
        .iter()
        .find(|c| {
            let n = c.name.to_string();
            n.ends_with(".Depth.Z") || n == "Z" || n == "Depth.Z" || n == "depth"
        })
        .ok_or_else(|| {
            let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
            Error::format(path, format!("no depth channel (channels: {})", names.join(", ")))
        })?;
    Ok((layer.size.width(), layer.size.height(), samples_f32(&depth.sample_data)))
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
        let meta = DisparityMeta { f_px: Some(1050.0), baseline_m: Some(0.12), view: Some("left".into()) };
        write_disparity_exr(&path, &map, &meta).unwrap();
        let (back, back_meta) = read_disparity_exr(&path).unwrap();
        assert_eq!(back, map);
        assert_eq!(back_meta, meta);
    }

    #[test]
    fn writing_is_deterministic() {
        let dir = tempfile::tempdir().unwrap();
        let mut map = DisparityMap::new(16, 9);
        for (i, d) in map.data.iter_mut().enumerate() {
            *d = i as f32 * 0.37;
        }
        map.valid.iter_mut().for_each(|v| *v = true);
        let meta = DisparityMeta::default();
        let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
        write_disparity_exr(&a, &map, &meta).unwrap();
        write_disparity_exr(&b, &map, &meta).unwrap();
        assert_eq!(std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
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
        assert!(read_disparity_exr(&cut).unwrap_err().to_string().contains("cut.exr"));
    }
}
