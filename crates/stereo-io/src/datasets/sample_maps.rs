//! The per-pixel maps a sample may have beside its disparity (depth, normals, instance and
//! semantic ids: [`crate::maps`]), as the dataset readers give them: [`StereoDataset::maps`]
//! decodes them, [`SampleMeta::maps`] names the files of a layout that keeps them as files (ours)
//! and [`SampleMeta::instances`] carries the sample's instance table.
//!
//! What [`StereoDataset::sample`] returns is the same whether a sample has maps or not: a caller
//! that never asks for them reads every dataset as before.
//!
//! [`StereoDataset::maps`]: super::StereoDataset::maps
//! [`StereoDataset::sample`]: super::StereoDataset::sample
//! [`SampleMeta::maps`]: super::SampleMeta::maps
//! [`SampleMeta::instances`]: super::SampleMeta::instances

use std::path::{Path, PathBuf};

use super::stereogen::{SamplePaths, VIEWS};
use crate::error::{Error, Result};
use crate::maps::{
    DepthMap, IdMap, MapKind, NormalMap, decode_depth_exr, decode_id_png, decode_normals_exr,
    encode_depth_exr, encode_id_png, encode_normals_exr,
};

/// One map file of a sample: which map, which view (`"left"` or `"right"`), where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MapFile {
    pub kind: MapKind,
    pub view: &'static str,
    pub path: PathBuf,
}

impl MapFile {
    /// The map files a manifest's `files` names, each joined to `root`, in [`MapKind::ALL`]'s
    /// order, left before right.
    pub fn of_sample(files: &SamplePaths, root: &Path) -> Vec<MapFile> {
        MapKind::ALL
            .into_iter()
            .flat_map(|kind| VIEWS.into_iter().map(move |view| (kind, view)))
            .filter_map(|(kind, view)| {
                Some(MapFile {
                    kind,
                    view,
                    path: root.join(files.map(kind, view)?),
                })
            })
            .collect()
    }
}

/// The member name of map `kind` of `view` in a WebDataset shard, after `<key>.`: its manifest
/// file key and its file's extension (`depth_left.exr`, `normals_right.exr`,
/// `instance_left.png`, `semantic_right.png`).
pub fn map_member(kind: MapKind, view: &str) -> String {
    let ext = kind.suffix().rsplit('.').next().unwrap_or("");
    format!("{}.{ext}", kind.file_key(view))
}

/// One decoded map.
#[derive(Debug, Clone, PartialEq)]
pub enum MapData {
    Depth(DepthMap),
    Normals(NormalMap),
    /// Instance or semantic ids (which, the [`MapKind`] beside it says).
    Ids(IdMap),
}

impl MapData {
    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        match self {
            Self::Depth(m) => (m.width, m.height),
            Self::Normals(m) => (m.width, m.height),
            Self::Ids(m) => (m.width, m.height),
        }
    }

    /// The map of `kind` from a file's bytes (`path` names them in errors).
    pub fn decode(kind: MapKind, bytes: &[u8], path: &Path) -> Result<Self> {
        Ok(match kind {
            MapKind::Depth => Self::Depth(decode_depth_exr(bytes, path)?),
            MapKind::Normals => Self::Normals(decode_normals_exr(bytes, path)?),
            MapKind::Instance | MapKind::Semantic => Self::Ids(decode_id_png(bytes, path)?),
        })
    }

    /// The bytes of its file, as the generator writes it for `view`.
    pub fn encode(&self, view: &str) -> std::result::Result<Vec<u8>, String> {
        match self {
            Self::Depth(m) => encode_depth_exr(m, view),
            Self::Normals(m) => encode_normals_exr(m, view),
            Self::Ids(m) => encode_id_png(m),
        }
    }
}

/// The maps of one sample, decoded; `None` where the sample has no such map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SampleMaps {
    pub depth_left: Option<DepthMap>,
    pub depth_right: Option<DepthMap>,
    pub normals_left: Option<NormalMap>,
    pub normals_right: Option<NormalMap>,
    pub instance_left: Option<IdMap>,
    pub instance_right: Option<IdMap>,
    pub semantic_left: Option<IdMap>,
    pub semantic_right: Option<IdMap>,
}

impl SampleMaps {
    /// Whether the sample has no map.
    pub fn is_empty(&self) -> bool {
        self.iter().next().is_none()
    }

    /// The maps the sample has (in either view), in [`MapKind::ALL`]'s order.
    pub fn kinds(&self) -> Vec<MapKind> {
        let mut kinds: Vec<MapKind> = self.iter().map(|(k, _, _)| k).collect();
        kinds.dedup();
        kinds
    }

    /// Every map with its kind and view, in [`MapKind::ALL`]'s order, left before right.
    pub fn iter(&self) -> impl Iterator<Item = (MapKind, &'static str, MapData)> + '_ {
        let depth = |m: &Option<DepthMap>| m.clone().map(MapData::Depth);
        let normals = |m: &Option<NormalMap>| m.clone().map(MapData::Normals);
        let ids = |m: &Option<IdMap>| m.clone().map(MapData::Ids);
        [
            (MapKind::Depth, "left", depth(&self.depth_left)),
            (MapKind::Depth, "right", depth(&self.depth_right)),
            (MapKind::Normals, "left", normals(&self.normals_left)),
            (MapKind::Normals, "right", normals(&self.normals_right)),
            (MapKind::Instance, "left", ids(&self.instance_left)),
            (MapKind::Instance, "right", ids(&self.instance_right)),
            (MapKind::Semantic, "left", ids(&self.semantic_left)),
            (MapKind::Semantic, "right", ids(&self.semantic_right)),
        ]
        .into_iter()
        .filter_map(|(k, v, m)| Some((k, v, m?)))
    }

    /// Puts `map` in the place of `kind` and `view`; a map of another kind than `kind` is an
    /// error naming `path`.
    pub fn set(&mut self, kind: MapKind, view: &str, map: MapData, path: &Path) -> Result<()> {
        let left = view == "left";
        match (kind, map) {
            (MapKind::Depth, MapData::Depth(m)) => {
                *if left {
                    &mut self.depth_left
                } else {
                    &mut self.depth_right
                } = Some(m)
            }
            (MapKind::Normals, MapData::Normals(m)) => {
                *if left {
                    &mut self.normals_left
                } else {
                    &mut self.normals_right
                } = Some(m)
            }
            (MapKind::Instance, MapData::Ids(m)) => {
                *if left {
                    &mut self.instance_left
                } else {
                    &mut self.instance_right
                } = Some(m)
            }
            (MapKind::Semantic, MapData::Ids(m)) => {
                *if left {
                    &mut self.semantic_left
                } else {
                    &mut self.semantic_right
                } = Some(m)
            }
            (kind, _) => {
                return Err(Error::format(path, format!("is not a {kind} map")));
            }
        }
        Ok(())
    }
}

/// A sample's width and height as its facts give them (`width`, `height` in
/// [`SampleMeta::extra`](super::SampleMeta::extra): ours and their exports have them).
pub(crate) fn size_in_extra(
    extra: &std::collections::BTreeMap<String, String>,
) -> Option<(usize, usize)> {
    Some((
        extra.get("width")?.parse().ok()?,
        extra.get("height")?.parse().ok()?,
    ))
}

/// `map`, read from `path`, has the sample's size `want` (where known).
pub(crate) fn check_size(path: &Path, map: &MapData, want: Option<(usize, usize)>) -> Result<()> {
    match want {
        Some(want) if map.size() != want => Err(Error::format(
            path,
            format!(
                "the map is {}x{} but the sample is {}x{}",
                map.size().0,
                map.size().1,
                want.0,
                want.1
            ),
        )),
        _ => Ok(()),
    }
}

/// Reads `files` (on parallel threads: each decoder uses about one core), each checked to be of
/// size `want` where known.
pub(crate) fn read_map_files(
    files: &[MapFile],
    want: Option<(usize, usize)>,
) -> Result<SampleMaps> {
    let mut out = SampleMaps::default();
    if files.is_empty() {
        return Ok(out);
    }
    let decoded: Vec<Result<MapData>> = std::thread::scope(|sc| {
        let handles: Vec<_> = files
            .iter()
            .map(|f| {
                sc.spawn(move || {
                    let bytes = crate::limits::read_file_capped(
                        &f.path,
                        crate::limits::MAX_ALLOC,
                        "a map file",
                    )?;
                    MapData::decode(f.kind, &bytes, &f.path)
                })
            })
            .collect();
        handles.into_iter().map(super::join).collect()
    });
    for (f, map) in files.iter().zip(decoded) {
        let map = map?;
        check_size(&f.path, &map, want)?;
        out.set(f.kind, f.view, map, &f.path)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn members_are_named_by_file_key_and_extension() {
        assert_eq!(map_member(MapKind::Depth, "left"), "depth_left.exr");
        assert_eq!(map_member(MapKind::Normals, "right"), "normals_right.exr");
        assert_eq!(map_member(MapKind::Instance, "left"), "instance_left.png");
        assert_eq!(map_member(MapKind::Semantic, "right"), "semantic_right.png");
    }

    #[test]
    fn map_files_of_a_sample_follow_its_manifest_paths() {
        let none = SamplePaths::new("tree", "0000003");
        assert!(MapFile::of_sample(&none, Path::new("/d")).is_empty());
        let paths = SamplePaths::with_maps("tree", "0000003", &[MapKind::Semantic, MapKind::Depth]);
        let files = MapFile::of_sample(&paths, Path::new("/d"));
        let got: Vec<(MapKind, &str, PathBuf)> = files
            .into_iter()
            .map(|f| (f.kind, f.view, f.path))
            .collect();
        assert_eq!(
            got,
            vec![
                (
                    MapKind::Depth,
                    "left",
                    "/d/tree/0000003_left.depth.exr".into()
                ),
                (
                    MapKind::Depth,
                    "right",
                    "/d/tree/0000003_right.depth.exr".into()
                ),
                (
                    MapKind::Semantic,
                    "left",
                    "/d/tree/0000003_left.semantic.png".into()
                ),
                (
                    MapKind::Semantic,
                    "right",
                    "/d/tree/0000003_right.semantic.png".into()
                ),
            ]
        );
    }

    #[test]
    fn maps_read_from_files_keep_their_kind_view_and_size() {
        let dir = tempfile::tempdir().unwrap();
        let depth = DepthMap {
            width: 3,
            height: 2,
            data: vec![0.0, 1.5, 2.0, 3.0, 0.0, 7.25],
        };
        let ids = IdMap {
            width: 3,
            height: 2,
            data: vec![0, 1, 2, 3, 0, 65535],
        };
        let (d, s) = (dir.path().join("d.exr"), dir.path().join("s.png"));
        crate::maps::write_depth_exr(&d, &depth, "right").unwrap();
        crate::maps::write_id_png(&s, &ids).unwrap();
        let files = [
            MapFile {
                kind: MapKind::Depth,
                view: "right",
                path: d.clone(),
            },
            MapFile {
                kind: MapKind::Semantic,
                view: "left",
                path: s.clone(),
            },
        ];
        let maps = read_map_files(&files, Some((3, 2))).unwrap();
        assert_eq!(maps.depth_right.as_ref(), Some(&depth));
        assert_eq!(maps.semantic_left.as_ref(), Some(&ids));
        assert!(maps.depth_left.is_none() && maps.instance_left.is_none());
        assert_eq!(maps.kinds(), vec![MapKind::Depth, MapKind::Semantic]);
        // Encoding what was read gives the file's bytes again.
        for (kind, view, map) in maps.iter() {
            let path = if kind == MapKind::Depth { &d } else { &s };
            assert_eq!(map.encode(view).unwrap(), std::fs::read(path).unwrap());
        }
        // A map of another size than the sample's is refused, naming its file.
        let e = read_map_files(&files, Some((4, 2)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.exr") && e.contains("3x2"), "{e}");
        // A depth file where an id map is expected is refused.
        let wrong = [MapFile {
            kind: MapKind::Instance,
            view: "left",
            path: d,
        }];
        assert!(read_map_files(&wrong, None).is_err());
        assert!(read_map_files(&[], Some((1, 1))).unwrap().is_empty());
    }
}
