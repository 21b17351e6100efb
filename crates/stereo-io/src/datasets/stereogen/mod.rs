//! Our own layout, as `stereogen generate` writes it and every reader reads it.
//!
//! ```text
//! <root>/dataset.json                   recipe, seed and version the dataset was made with
//! <root>/manifest.jsonl                 one line per finished sample (written last)
//! <root>/failures.jsonl                 samples that failed, with the reason ([`FailureRecord`])
//! <root>/skipped_assets.jsonl           asset files that could not be used ([`SkippedAssetRecord`])
//! <root>/curation.jsonl                 samples `stereogen curate` replaced ([`curation`])
//! <root>/.stereogen.lock                held by the one process writing the directory
//! <root>/<category>/<id>_left.png       and _right.png (8-bit sRGB)
//! <root>/<category>/<id>_left.disp.exr  and _right.disp.exr (float32 disparity + validity)
//! <root>/<category>/<id>_left.depth.exr     and the other maps a recipe's `outputs` asks for, both
//!                                       views: `.normals.exr`, `.instance.png`, `.semantic.png`
//!                                       ([`crate::maps`])
//! <root>/<category>/<id>.scene.json.gz  the SceneSpec that reproduces the sample (gzip'd JSON;
//!                                       datasets made before hold a plain `<id>.scene.json`)
//! ```
//!
//! A farm's output holds one such dataset per task under `<root>/shards/` and, once merged, a
//! manifest whose paths point into them ([`farm`]).
//!
//! The writer is the generator: it names files with [`DatasetLayout::sample_paths`], writes each
//! atomically, then appends the [`ManifestEntry`] through [`Manifest`].

pub mod curation;
pub mod difficulty;
pub mod farm;
mod json_lines;
mod manifest;
mod sidecar;

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

pub use curation::{
    CURATION_DIR, CURATION_FILE, CurationRecord, CurationRound, curation_round_dir,
};
pub use difficulty::Difficulty;
pub use farm::{
    ChecksumCheck, MergeInfo, SHARD_INFO_FILE, SHARDS_DIR, ShardDirs, ShardId, ShardInfo,
};
pub use manifest::{
    DisparitySummary, InstanceRecord, Manifest, ManifestContents, ManifestEntry, read_manifest,
    read_manifest_from,
};
pub use sidecar::{
    FailureRecord, SIDECAR_RECORD_VERSION, SidecarContents, SidecarRecord, SkippedAssetRecord,
    append_sidecar, read_failures, read_sidecar, read_sidecar_from, read_skipped_assets,
    retain_sidecar,
};

use super::{DispKind, SampleFiles, SampleMeta};
use crate::error::{Error, Result};
use crate::maps::MapKind;
use crate::pixel_coords::continuous_to_pixel_centres;

/// `dataset.json`: what the dataset was made with.
pub const DATASET_INFO_FILE: &str = "dataset.json";
/// `manifest.jsonl`: the finished samples.
pub const MANIFEST_FILE: &str = "manifest.jsonl";
/// `failures.jsonl`: samples that failed, with the reason.
pub const FAILURES_FILE: &str = "failures.jsonl";
/// `skipped_assets.jsonl`: asset files that could not be used, with the reason.
pub const SKIPPED_ASSETS_FILE: &str = "skipped_assets.jsonl";
/// The lock file of the process writing the directory.
pub const LOCK_FILE: &str = ".stereogen.lock";
/// How a sample's SceneSpec file ends: gzip'd JSON (see the generator's `dataset::scene_file`).
pub const SCENE_SUFFIX: &str = ".scene.json.gz";

/// Paths of one sample's files, relative to the dataset root. The maps beside the disparity
/// ([`MapKind`]) are there when the recipe's `outputs` asked for them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SamplePaths {
    pub left: PathBuf,
    pub right: PathBuf,
    pub disp_left: PathBuf,
    pub disp_right: PathBuf,
    pub scene: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_left: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_right: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normals_left: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normals_right: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance_left: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance_right: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub semantic_left: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub semantic_right: Option<PathBuf>,
}

/// The views of a pair, in file-key order.
pub const VIEWS: [&str; 2] = ["left", "right"];

impl SamplePaths {
    /// The files of sample `id` of `category`: `<category>/<id>_left.png`, `_right.png`,
    /// `_left.disp.exr`, `_right.disp.exr`, `<id>.scene.json.gz` ([`SCENE_SUFFIX`]).
    pub fn new(category: &str, id: &str) -> Self {
        let c = PathBuf::from(category);
        Self {
            left: c.join(format!("{id}_left.png")),
            right: c.join(format!("{id}_right.png")),
            disp_left: c.join(format!("{id}_left.disp.exr")),
            disp_right: c.join(format!("{id}_right.disp.exr")),
            scene: c.join(format!("{id}{SCENE_SUFFIX}")),
            depth_left: None,
            depth_right: None,
            normals_left: None,
            normals_right: None,
            instance_left: None,
            instance_right: None,
            semantic_left: None,
            semantic_right: None,
        }
    }

    /// [`SamplePaths::new`] with the files of `maps` for both views:
    /// `<category>/<id>_<view>.<suffix>` ([`MapKind::suffix`]).
    pub fn with_maps(category: &str, id: &str, maps: &[MapKind]) -> Self {
        let mut paths = Self::new(category, id);
        for &kind in maps {
            for view in VIEWS {
                *paths.map_slot(kind, view) =
                    Some(PathBuf::from(category).join(format!("{id}_{view}.{}", kind.suffix())));
            }
        }
        paths
    }

    fn map_slot(&mut self, kind: MapKind, view: &str) -> &mut Option<PathBuf> {
        let left = view == "left";
        match (kind, left) {
            (MapKind::Depth, true) => &mut self.depth_left,
            (MapKind::Depth, false) => &mut self.depth_right,
            (MapKind::Normals, true) => &mut self.normals_left,
            (MapKind::Normals, false) => &mut self.normals_right,
            (MapKind::Instance, true) => &mut self.instance_left,
            (MapKind::Instance, false) => &mut self.instance_right,
            (MapKind::Semantic, true) => &mut self.semantic_left,
            (MapKind::Semantic, false) => &mut self.semantic_right,
        }
    }

    /// The file of map `kind` of `view` ("left" or "right"), where the sample has it.
    pub fn map(&self, kind: MapKind, view: &str) -> Option<&Path> {
        let left = view == "left";
        match (kind, left) {
            (MapKind::Depth, true) => &self.depth_left,
            (MapKind::Depth, false) => &self.depth_right,
            (MapKind::Normals, true) => &self.normals_left,
            (MapKind::Normals, false) => &self.normals_right,
            (MapKind::Instance, true) => &self.instance_left,
            (MapKind::Instance, false) => &self.instance_right,
            (MapKind::Semantic, true) => &self.semantic_left,
            (MapKind::Semantic, false) => &self.semantic_right,
        }
        .as_deref()
    }

    /// The maps the sample has (both views of each), in [`MapKind::ALL`]'s order.
    pub fn maps(&self) -> Vec<MapKind> {
        MapKind::ALL
            .into_iter()
            .filter(|&k| VIEWS.iter().any(|v| self.map(k, v).is_some()))
            .collect()
    }

    /// Every file with its key (the keys of the manifest's `files` and `sha256`): the five every
    /// sample has, then its maps (`depth_left`, `depth_right`, `normals_left`, ...).
    pub fn all(&self) -> Vec<(&'static str, &Path)> {
        let mut all: Vec<(&'static str, &Path)> = vec![
            ("left", &self.left),
            ("right", &self.right),
            ("disp_left", &self.disp_left),
            ("disp_right", &self.disp_right),
            ("scene", &self.scene),
        ];
        let maps: [(&'static str, &Option<PathBuf>); 8] = [
            ("depth_left", &self.depth_left),
            ("depth_right", &self.depth_right),
            ("normals_left", &self.normals_left),
            ("normals_right", &self.normals_right),
            ("instance_left", &self.instance_left),
            ("instance_right", &self.instance_right),
            ("semantic_left", &self.semantic_left),
            ("semantic_right", &self.semantic_right),
        ];
        all.extend(
            maps.into_iter()
                .filter_map(|(k, p)| Some((k, p.as_deref()?))),
        );
        all
    }

    /// Every path, to rewrite in place (a farm merge puts them under a shard's folder).
    pub fn all_mut(&mut self) -> Vec<&mut PathBuf> {
        let mut all = vec![
            &mut self.left,
            &mut self.right,
            &mut self.disp_left,
            &mut self.disp_right,
            &mut self.scene,
        ];
        for p in [
            &mut self.depth_left,
            &mut self.depth_right,
            &mut self.normals_left,
            &mut self.normals_right,
            &mut self.instance_left,
            &mut self.instance_right,
            &mut self.semantic_left,
            &mut self.semantic_right,
        ] {
            all.extend(p.as_mut());
        }
        all
    }
}

/// `dataset.json`. `R` is the recipe: `serde_json::Value` for readers that do not interpret it,
/// the generator's `Recipe` for the generator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetInfo<R = serde_json::Value> {
    pub stereogen_version: String,
    pub seed: u64,
    pub recipe_fingerprint: String,
    pub recipe: R,
    /// Fingerprint of the asset index the samples were planned with (the content pack, the asset
    /// folders); absent for datasets that draw no assets or were made before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assets_fingerprint: Option<String>,
    /// The rounds of `stereogen curate --replace`, in order; absent before the first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub curation: Vec<CurationRound>,
    /// The classes of the `semantic` maps, where the dataset has them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub semantic_classes: Vec<SemanticClass>,
}

/// One class of the `semantic` maps: pixels of value `id` show a `name`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SemanticClass {
    pub id: u16,
    pub name: String,
}

/// Where each file of one of our dataset directories lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DatasetLayout {
    pub root: PathBuf,
}

impl DatasetLayout {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    pub fn info(&self) -> PathBuf {
        self.root.join(DATASET_INFO_FILE)
    }

    pub fn manifest(&self) -> PathBuf {
        self.root.join(MANIFEST_FILE)
    }

    pub fn failures(&self) -> PathBuf {
        self.root.join(FAILURES_FILE)
    }

    pub fn skipped_assets(&self) -> PathBuf {
        self.root.join(SKIPPED_ASSETS_FILE)
    }

    /// `curation.jsonl` ([`CurationRecord`]).
    pub fn curation_log(&self) -> PathBuf {
        self.root.join(CURATION_FILE)
    }

    pub fn lock(&self) -> PathBuf {
        self.root.join(LOCK_FILE)
    }

    /// The files of sample `id` of `category`, relative to the root ([`SamplePaths::new`]).
    pub fn sample_paths(&self, category: &str, id: &str) -> SamplePaths {
        SamplePaths::new(category, id)
    }

    pub fn abs(&self, rel: &Path) -> PathBuf {
        self.root.join(rel)
    }

    /// Reads `dataset.json`, with the recipe as `R`.
    pub fn read_info<R: DeserializeOwned>(&self) -> Result<DatasetInfo<R>> {
        let path = self.info();
        let text =
            crate::limits::read_document(&path, "a dataset description").map_err(|e| {
                match e.io_kind() {
                    Some(_) => self.unmerged_error(&path).unwrap_or(e),
                    None => e,
                }
            })?;
        serde_json::from_str(&text)
            .map_err(|e| Error::format(&path, format!("not a stereogen dataset description: {e}")))
    }

    /// Writes `dataset.json` atomically.
    pub fn write_info<R: Serialize>(&self, info: &DatasetInfo<R>) -> Result<()> {
        let path = self.info();
        let json = serde_json::to_string_pretty(info).map_err(|e| {
            Error::format(&path, format!("cannot encode the dataset description: {e}"))
        })?;
        crate::atomic::write_bytes_atomically(&path, json.as_bytes())
    }

    /// Removes the temporary files ([`crate::temp_sibling`]) a run killed mid-write left in the
    /// root and its category folders; returns how many.
    pub fn remove_partial_files(&self) -> usize {
        let mut removed = 0;
        let Ok(dirs) = std::fs::read_dir(&self.root) else {
            return 0;
        };
        for dir in dirs
            .flatten()
            .map(|e| e.path())
            .chain(std::iter::once(self.root.clone()))
        {
            let Ok(entries) = std::fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.flatten() {
                if crate::atomic::is_temp_name(&e.file_name().to_string_lossy())
                    && std::fs::remove_file(e.path()).is_ok()
                {
                    removed += 1;
                }
            }
        }
        removed
    }
}

/// What the dataset readers see of a manifest entry. `cx`, `cy` go over into the pixel-centre
/// convention of [`SampleMeta`].
fn sample_meta(e: &ManifestEntry) -> SampleMeta {
    let mut meta = SampleMeta {
        id: e.id.clone(),
        f_px: Some(e.f_px),
        baseline_m: Some(e.baseline_m),
        cx: Some(continuous_to_pixel_centres(e.cx)),
        cy: Some(continuous_to_pixel_centres(e.cy)),
        ..Default::default()
    };
    meta.extra.insert("category".into(), e.category.clone());
    for (k, v) in [
        ("index", e.index),
        ("seed", e.seed),
        ("width", u64::from(e.width)),
        ("height", u64::from(e.height)),
    ] {
        meta.extra.insert(k.into(), v.to_string());
    }
    meta
}

/// Our samples in manifest order.
pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    let layout = DatasetLayout::new(root);
    let contents = read_manifest(&layout.manifest())?;
    Ok(contents
        .entries
        .iter()
        .map(|e| SampleFiles {
            id: e.id.clone(),
            left: layout.abs(&e.files.left),
            right: layout.abs(&e.files.right),
            disp_left: (layout.abs(&e.files.disp_left), DispKind::Exr),
            disp_right: Some((layout.abs(&e.files.disp_right), DispKind::Exr)),
            masks: vec![],
            meta: SampleMeta {
                maps: super::MapFile::of_sample(&e.files, &layout.root),
                instances: e.instances.clone(),
                ..sample_meta(e)
            },
        })
        .collect())
}
