//! The per-pixel maps a dataset may hold beside disparity, on the disparity's pixel grid:
//!
//! | map | file | pixel | no surface |
//! |---|---|---|---|
//! | depth | `<id>_<view>.depth.exr` | float32 channel `Y`: metres along the optical axis | 0 |
//! | normals | `<id>_<view>.normals.exr` | float32 `R`,`G`,`B` = x, y, z of the unit surface normal in the camera's frame (x right, y down, z forward: OpenCV's) | 0, 0, 0 |
//! | instance | `<id>_<view>.instance.png` | 16-bit grey: the object's instance id (the sample's `instances` table) | 0 |
//! | semantic | `<id>_<view>.semantic.png` | 16-bit grey: the object's class id (the dataset's `semantic_classes`) | 0 |
//!
//! A normal is the surface's shading normal on the side the camera sees: the face's normal turned
//! towards the camera, or on smooth-shaded faces the corner normals interpolated on that side, which
//! near a silhouette may lean past the viewing ray (a few pixels then have z > 0). Every map records
//! the same first surface as the disparity at each pixel: where the disparity is valid, depth is
//! positive, both ids are non-zero, the normal has unit length (or is 0, 0, 0 on the rare pixel
//! where the surface has no shading normal: Cycles writes none where a mesh's folded faces leave a
//! vertex normal undefined), and
//! `disparity == (f_px · baseline / depth) as f32` (computed in f64).
//!
//! Writers give bytes that depend only on the map (EXR: ZIP, increasing line order, sorted
//! header; PNG: one encoder), durably ([`crate::atomic`]); readers refuse a map of the wrong kind
//! or size and NaN with an error naming the file.

use std::path::Path;

use exr::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::exr_io::{channel_names, decode_flat, encode_layer, samples_f32};
use crate::image_io::{Samples, decode, decode_bytes, encode_png};
use crate::limits::{MAX_ALLOC, read_file_capped};

/// A map beside the disparity, as a recipe's `outputs` and a manifest's `files` name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapKind {
    Depth,
    Normals,
    Instance,
    Semantic,
}

impl MapKind {
    pub const ALL: [MapKind; 4] = [Self::Depth, Self::Normals, Self::Instance, Self::Semantic];

    pub fn name(self) -> &'static str {
        match self {
            Self::Depth => "depth",
            Self::Normals => "normals",
            Self::Instance => "instance",
            Self::Semantic => "semantic",
        }
    }

    /// What a view's file name ends with after `<id>_<view>.`.
    pub fn suffix(self) -> &'static str {
        match self {
            Self::Depth => "depth.exr",
            Self::Normals => "normals.exr",
            Self::Instance => "instance.png",
            Self::Semantic => "semantic.png",
        }
    }

    /// The map's key in a manifest's `files` and `sha256` for `view` ("left" or "right"):
    /// `depth_left`, `normals_right`, ...
    pub fn file_key(self, view: &str) -> String {
        format!("{}_{view}", self.name())
    }

    /// The map named `name` ([`MapKind::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

impl std::fmt::Display for MapKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Metric depth along the optical axis (metres), row-major from the top row; 0 = no surface.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

/// Unit surface normals in the camera's frame (x right, y down, z forward), row-major from the
/// top row; `[0, 0, 0]` = no surface.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalMap {
    pub width: usize,
    pub height: usize,
    pub data: Vec<[f32; 3]>,
}

/// Instance or class ids, row-major from the top row; 0 = no surface.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdMap {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u16>,
}

const DEPTH_CHANNEL: &str = "Y";
const NORMAL_CHANNELS: [&str; 3] = ["R", "G", "B"];
const ATTR_UNITS: &str = "stereogen.units";
const ATTR_FRAME: &str = "stereogen.frame";
const ATTR_VIEW: &str = "stereogen.view";
/// What a normals EXR says about its frame.
pub const NORMALS_FRAME: &str = "camera: x right, y down, z forward";

/// Float32 channels as one ZIP-compressed scan-line EXR layer with text attributes.
fn encode_float_exr(
    width: usize,
    height: usize,
    layer: &str,
    channels: Vec<(&str, Vec<f32>)>,
    text: &[(&str, &str)],
) -> std::result::Result<Vec<u8>, String> {
    if channels.iter().any(|(_, c)| c.len() != width * height) {
        return Err(format!(
            "map buffers do not match its size {width}x{height}"
        ));
    }
    let mut attrs = LayerAttributes::named(layer);
    for (name, value) in text {
        attrs
            .other
            .insert(Text::from(*name), AttributeValue::Text(Text::from(*value)));
    }
    let list = channels
        .into_iter()
        .map(|(name, data)| AnyChannel::new(name, FlatSamples::F32(data)))
        .collect();
    encode_layer((width, height), attrs, list)
}

/// The named float channels of an EXR, in `names`' order, NaN refused.
fn decode_float_exr(
    bytes: &[u8],
    path: &Path,
    what: &str,
    names: &[&str],
) -> Result<(usize, usize, Vec<Vec<f32>>)> {
    let layer = decode_flat(bytes, path)?;
    let (width, height) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let mut out = Vec::with_capacity(names.len());
    for name in names {
        let channel = channels
            .iter()
            .find(|c| c.name.to_string() == *name)
            .ok_or_else(|| {
                Error::format(
                    path,
                    format!(
                        "a {what} EXR has channel `{name}`; this one has {}",
                        channel_names(channels)
                    ),
                )
            })?;
        let data = samples_f32(&channel.sample_data);
        if let Some(i) = data.iter().position(|v| v.is_nan()) {
            return Err(Error::format(
                path,
                format!(
                    "{what} is NaN at pixel ({}, {})",
                    i % width.max(1),
                    i / width.max(1)
                ),
            ));
        }
        out.push(data);
    }
    Ok((width, height, out))
}

/// The bytes of a depth EXR for `view`.
pub fn encode_depth_exr(map: &DepthMap, view: &str) -> std::result::Result<Vec<u8>, String> {
    encode_float_exr(
        map.width,
        map.height,
        "depth",
        vec![(DEPTH_CHANNEL, map.data.clone())],
        &[(ATTR_UNITS, "metres"), (ATTR_VIEW, view)],
    )
}

pub fn write_depth_exr(path: &Path, map: &DepthMap, view: &str) -> Result<()> {
    let bytes = encode_depth_exr(map, view).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Reads a depth EXR from bytes in memory; `path` names them in errors. A negative or infinite
/// depth is refused (no surface is 0).
pub fn decode_depth_exr(bytes: &[u8], path: &Path) -> Result<DepthMap> {
    let (width, height, mut channels) = decode_float_exr(bytes, path, "depth", &[DEPTH_CHANNEL])?;
    let data = channels.remove(0);
    if let Some(i) = data.iter().position(|d| !(d.is_finite() && *d >= 0.0)) {
        return Err(Error::format(
            path,
            format!(
                "depth {} at pixel ({}, {}): depth is finite and not negative (0 = no surface)",
                data[i],
                i % width.max(1),
                i / width.max(1)
            ),
        ));
    }
    Ok(DepthMap {
        width,
        height,
        data,
    })
}

pub fn read_depth_exr(path: &Path) -> Result<DepthMap> {
    decode_depth_exr(&read_file_capped(path, MAX_ALLOC, "an EXR file")?, path)
}

/// The bytes of a normals EXR for `view`.
pub fn encode_normals_exr(map: &NormalMap, view: &str) -> std::result::Result<Vec<u8>, String> {
    let channels = (0..3)
        .map(|c| {
            (
                NORMAL_CHANNELS[c],
                map.data.iter().map(|n| n[c]).collect::<Vec<f32>>(),
            )
        })
        .collect();
    encode_float_exr(
        map.width,
        map.height,
        "normals",
        channels,
        &[(ATTR_FRAME, NORMALS_FRAME), (ATTR_VIEW, view)],
    )
}

pub fn write_normals_exr(path: &Path, map: &NormalMap, view: &str) -> Result<()> {
    let bytes = encode_normals_exr(map, view).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// Reads a normals EXR from bytes in memory; `path` names them in errors.
pub fn decode_normals_exr(bytes: &[u8], path: &Path) -> Result<NormalMap> {
    let (width, height, c) = decode_float_exr(bytes, path, "normals", &NORMAL_CHANNELS)?;
    let data = (0..width * height)
        .map(|i| [c[0][i], c[1][i], c[2][i]])
        .collect();
    Ok(NormalMap {
        width,
        height,
        data,
    })
}

pub fn read_normals_exr(path: &Path) -> Result<NormalMap> {
    decode_normals_exr(&read_file_capped(path, MAX_ALLOC, "an EXR file")?, path)
}

/// The bytes of a 16-bit grey PNG of ids.
pub fn encode_id_png(map: &IdMap) -> std::result::Result<Vec<u8>, String> {
    if map.data.len() != map.width * map.height {
        return Err(format!(
            "id map buffer does not match its size {}x{}",
            map.width, map.height
        ));
    }
    encode_png(&crate::image_io::Image {
        width: map.width,
        height: map.height,
        channels: 1,
        samples: Samples::U16(map.data.clone()),
    })
}

pub fn write_id_png(path: &Path, map: &IdMap) -> Result<()> {
    let bytes = encode_id_png(map).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

fn id_map_from(path: &Path, img: image::DynamicImage) -> Result<IdMap> {
    let (width, height) = (img.width() as usize, img.height() as usize);
    let raw = img.as_luma16().ok_or_else(|| {
        Error::format(
            path,
            format!(
                "an id map is a 16-bit grey PNG, this one is {:?}",
                img.color()
            ),
        )
    })?;
    Ok(IdMap {
        width,
        height,
        data: raw.as_raw().clone(),
    })
}

/// Reads an instance or semantic PNG from bytes in memory; `path` names them in errors.
pub fn decode_id_png(bytes: &[u8], path: &Path) -> Result<IdMap> {
    id_map_from(path, decode_bytes(bytes, path)?)
}

pub fn read_id_png(path: &Path) -> Result<IdMap> {
    id_map_from(path, decode(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth() -> DepthMap {
        DepthMap {
            width: 3,
            height: 2,
            data: vec![0.0, 1.5, 1e-3, 123.456, 0.0, 7.25],
        }
    }

    #[test]
    fn maps_round_trip_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let d = depth();
        let p = dir.path().join("a.depth.exr");
        write_depth_exr(&p, &d, "left").unwrap();
        assert_eq!(read_depth_exr(&p).unwrap(), d);

        let n = NormalMap {
            width: 2,
            height: 2,
            data: vec![
                [0.0, 0.0, 0.0],
                [0.0, 0.0, -1.0],
                [0.6, -0.8, 0.0],
                [-0.267_261_24, 0.534_522_5, -0.801_783_7],
            ],
        };
        let p = dir.path().join("a.normals.exr");
        write_normals_exr(&p, &n, "right").unwrap();
        assert_eq!(read_normals_exr(&p).unwrap(), n);

        let ids = IdMap {
            width: 3,
            height: 1,
            data: vec![0, 1, 65535],
        };
        let p = dir.path().join("a.instance.png");
        write_id_png(&p, &ids).unwrap();
        assert_eq!(read_id_png(&p).unwrap(), ids);
    }

    #[test]
    fn equal_maps_give_equal_bytes() {
        let mut big = DepthMap {
            width: 320,
            height: 200,
            data: vec![0.0; 64000],
        };
        for (i, v) in big.data.iter_mut().enumerate() {
            *v = 1.0 + (i as f32 * 0.37).sin().abs();
        }
        let first = encode_depth_exr(&big, "left").unwrap();
        for _ in 0..4 {
            assert!(encode_depth_exr(&big, "left").unwrap() == first);
        }
    }

    #[test]
    fn wrong_files_are_refused_with_the_file_named() {
        let dir = tempfile::tempdir().unwrap();
        // A disparity EXR is not a normals EXR.
        let p = dir.path().join("disp.exr");
        crate::write_disparity_exr(&p, &crate::DisparityMap::new(4, 4), &Default::default())
            .unwrap();
        let err = read_normals_exr(&p).unwrap_err().to_string();
        assert!(err.contains("disp.exr") && err.contains("`R`"), "{err}");
        // A negative depth is no depth.
        let mut d = depth();
        d.data[2] = -1.0;
        let bytes = encode_depth_exr(&d, "left").unwrap();
        let err = decode_depth_exr(&bytes, Path::new("neg.exr"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("neg.exr") && err.contains("(2, 0)"), "{err}");
        // An 8-bit PNG is no id map.
        let p = dir.path().join("rgb.png");
        crate::write_png_rgb(
            &p,
            &crate::RgbImage {
                width: 2,
                height: 2,
                data: vec![0; 12],
            },
        )
        .unwrap();
        let err = read_id_png(&p).unwrap_err().to_string();
        assert!(err.contains("rgb.png") && err.contains("16-bit"), "{err}");
        // Garbage.
        let p = dir.path().join("junk.exr");
        std::fs::write(&p, b"not an exr").unwrap();
        assert!(
            read_depth_exr(&p)
                .unwrap_err()
                .to_string()
                .contains("junk.exr")
        );
    }

    #[test]
    fn kinds_name_their_files_and_keys() {
        for k in MapKind::ALL {
            assert_eq!(MapKind::from_name(k.name()), Some(k));
            let json = serde_json::to_string(&k).unwrap();
            assert_eq!(json, format!("\"{}\"", k.name()));
        }
        assert_eq!(MapKind::Normals.file_key("right"), "normals_right");
        assert_eq!(MapKind::Instance.suffix(), "instance.png");
    }
}
