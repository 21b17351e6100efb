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

    /// The map of `kind` in the file at `path`.
    pub fn read(kind: MapKind, path: &Path) -> Result<Self> {
        let bytes = crate::limits::read_file_capped(path, crate::limits::MAX_ALLOC, "a map file")?;
        Self::decode(kind, &bytes, path)
    }
}

/// One view's maps; `None` where the sample has no such map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewMaps {
    pub depth: Option<DepthMap>,
    pub normals: Option<NormalMap>,
    pub instance: Option<IdMap>,
    pub semantic: Option<IdMap>,
}

impl ViewMaps {
    /// Whether the view has map `kind`.
    pub fn has(&self, kind: MapKind) -> bool {
        match kind {
            MapKind::Depth => self.depth.is_some(),
            MapKind::Normals => self.normals.is_some(),
            MapKind::Instance => self.instance.is_some(),
            MapKind::Semantic => self.semantic.is_some(),
        }
    }

    /// Puts `map` in the place of `kind`; a map of another kind than `kind` is an error naming
    /// `path`.
    pub fn set(&mut self, kind: MapKind, map: MapData, path: &Path) -> Result<()> {
        match (kind, map) {
            (MapKind::Depth, MapData::Depth(m)) => self.depth = Some(m),
            (MapKind::Normals, MapData::Normals(m)) => self.normals = Some(m),
            (MapKind::Instance, MapData::Ids(m)) => self.instance = Some(m),
            (MapKind::Semantic, MapData::Ids(m)) => self.semantic = Some(m),
            (kind, _) => return Err(Error::format(path, format!("is not a {kind} map"))),
        }
        Ok(())
    }

    /// The bytes of map `kind`'s file, as the generator writes it for `view`; `None` where the
    /// view has no such map.
    pub fn encode(
        &self,
        kind: MapKind,
        view: &str,
    ) -> Option<std::result::Result<Vec<u8>, String>> {
        Some(match kind {
            MapKind::Depth => encode_depth_exr(self.depth.as_ref()?, view),
            MapKind::Normals => encode_normals_exr(self.normals.as_ref()?, view),
            MapKind::Instance => encode_id_png(self.instance.as_ref()?),
            MapKind::Semantic => encode_id_png(self.semantic.as_ref()?),
        })
    }

    /// Whether `map` is this view's map `kind`, bit for bit (a float's sign of zero included).
    pub fn holds(&self, kind: MapKind, map: &MapData) -> bool {
        let bits = |a: &[f32], b: &[f32]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        match (kind, map) {
            (MapKind::Depth, MapData::Depth(m)) => self.depth.as_ref().is_some_and(|d| {
                (d.width, d.height) == (m.width, m.height) && bits(&d.data, &m.data)
            }),
            (MapKind::Normals, MapData::Normals(m)) => self.normals.as_ref().is_some_and(|n| {
                (n.width, n.height) == (m.width, m.height)
                    && bits(n.data.as_flattened(), m.data.as_flattened())
            }),
            (MapKind::Instance, MapData::Ids(m)) => self.instance.as_ref() == Some(m),
            (MapKind::Semantic, MapData::Ids(m)) => self.semantic.as_ref() == Some(m),
            _ => false,
        }
    }
}

/// The maps of one sample, decoded, per view.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SampleMaps {
    pub left: ViewMaps,
    pub right: ViewMaps,
}

impl SampleMaps {
    /// The maps of `view` ("left" or "right").
    pub fn view(&self, view: &str) -> &ViewMaps {
        if view == "left" {
            &self.left
        } else {
            &self.right
        }
    }

    pub fn view_mut(&mut self, view: &str) -> &mut ViewMaps {
        if view == "left" {
            &mut self.left
        } else {
            &mut self.right
        }
    }

    /// Whether either view has map `kind`.
    pub fn has(&self, kind: MapKind) -> bool {
        self.left.has(kind) || self.right.has(kind)
    }

    /// Whether the sample has no map.
    pub fn is_empty(&self) -> bool {
        self.kinds().is_empty()
    }

    /// The maps the sample has (in either view), in [`MapKind::ALL`]'s order.
    pub fn kinds(&self) -> Vec<MapKind> {
        MapKind::ALL.into_iter().filter(|&k| self.has(k)).collect()
    }

    /// Puts `map` in the place of `kind` and `view` ([`ViewMaps::set`]).
    pub fn set(&mut self, kind: MapKind, view: &str, map: MapData, path: &Path) -> Result<()> {
        self.view_mut(view).set(kind, map, path)
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
            .map(|f| sc.spawn(move || MapData::read(f.kind, &f.path)))
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
        assert_eq!(maps.right.depth.as_ref(), Some(&depth));
        assert_eq!(maps.left.semantic.as_ref(), Some(&ids));
        assert!(maps.left.depth.is_none() && maps.left.instance.is_none());
        assert_eq!(maps.kinds(), vec![MapKind::Depth, MapKind::Semantic]);
        // Encoding what was read gives the file's bytes again, and holds what was read.
        for (kind, view, path) in [
            (MapKind::Depth, "right", &d),
            (MapKind::Semantic, "left", &s),
        ] {
            let bytes = maps.view(view).encode(kind, view).unwrap().unwrap();
            assert_eq!(bytes, std::fs::read(path).unwrap());
            let back = MapData::decode(kind, &bytes, path).unwrap();
            assert!(maps.view(view).holds(kind, &back));
            assert!(!maps.view(view).holds(MapKind::Instance, &back));
        }
        assert!(maps.left.encode(MapKind::Depth, "left").is_none());
        // One bit off is not held (a normal's -0.0 against 0.0 included).
        let normals = ViewMaps {
            normals: Some(NormalMap {
                width: 1,
                height: 1,
                data: vec![[-0.0, 0.0, -1.0]],
            }),
            ..ViewMaps::default()
        };
        let flipped = MapData::Normals(NormalMap {
            width: 1,
            height: 1,
            data: vec![[0.0, 0.0, -1.0]],
        });
        assert!(!normals.holds(MapKind::Normals, &flipped));
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
