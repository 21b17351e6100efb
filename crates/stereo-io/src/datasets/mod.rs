//! Stereo datasets on disk: one [`StereoDataset`] trait, one [`StereoSample`], and a module per
//! layout that holds its file names, its reader and (where the layout makes sense as an output)
//! its writer ([`write`]). [`open_dataset`] recognises a layout from its root folder;
//! [`export::export_dataset`] converts between layouts.
//!
//! Every reader lists its samples when opened (sorted by path, so indices are stable; ours in
//! manifest order) and decodes files only in [`StereoDataset::sample`].

pub mod crestereo;
mod detect;
pub mod export;
pub mod falling_things;
pub mod instereo2k;
pub mod kitti;
pub mod middlebury;
mod sample_maps;
mod scan;
pub mod sceneflow;
pub mod sintel;
pub mod stereogen;
pub mod webdataset;
pub mod write;

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::disparity::DisparityMap;
use crate::error::{Error, Result};
use crate::image_io::{RgbImage, read_rgb};

pub use detect::detect_format;
pub use sample_maps::{MapData, MapFile, SampleMaps, ViewMaps, map_member};
pub use stereogen::InstanceRecord;

/// A dataset layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DatasetFormat {
    /// stereogen's own: `manifest.jsonl` + PNG images + float32 EXR disparity.
    Stereogen,
    /// CREStereo's release: `*_left.jpg`, `*_right.jpg`, `*_{left,right}.disp.png` (÷32).
    Crestereo,
    /// SceneFlow (FlyingThings3D, Driving, Monkaa): `frames_cleanpass|frames_finalpass`, `disparity/*.pfm`.
    SceneFlow,
    /// Middlebury 2014 / MiddEval3: `<scene>/im0.png, im1.png, disp0.pfm, calib.txt`.
    Middlebury,
    /// ETH3D two-view: `<scene>/im0.png, im1.png, disp0GT.pfm, mask0nocc.png`, the ground truth
    /// beside the images or in the official `_gt` tree.
    Eth3d,
    /// KITTI 2012: `training/colored_0|colored_1|disp_occ` (÷256).
    Kitti2012,
    /// KITTI 2015: `training/image_2|image_3|disp_occ_0` (÷256); no right-view disparity.
    Kitti2015,
    /// MPI Sintel stereo: `training/clean_left|clean_right|disparities` (RGB-packed).
    Sintel,
    /// NVIDIA Falling Things: `*.left.jpg`, `*.left.depth.png` (1e-4 m) + `_camera_settings.json`.
    FallingThings,
    /// InStereo2K: `<pair>/left.png, right.png, left_disp.png, right_disp.png` (÷100).
    InStereo2k,
    /// WebDataset tar shards with a `<split>.index.json` each (what `export --format
    /// webdataset` writes, see [`webdataset`]).
    WebDataset,
}

impl DatasetFormat {
    pub const ALL: [DatasetFormat; 11] = [
        Self::Stereogen,
        Self::Crestereo,
        Self::SceneFlow,
        Self::Middlebury,
        Self::Eth3d,
        Self::Kitti2012,
        Self::Kitti2015,
        Self::Sintel,
        Self::FallingThings,
        Self::InStereo2k,
        Self::WebDataset,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Stereogen => "stereogen",
            Self::Crestereo => "crestereo",
            Self::SceneFlow => "sceneflow",
            Self::Middlebury => "middlebury",
            Self::Eth3d => "eth3d",
            Self::Kitti2012 => "kitti2012",
            Self::Kitti2015 => "kitti2015",
            Self::Sintel => "sintel",
            Self::FallingThings => "fallingthings",
            Self::InStereo2k => "instereo2k",
            Self::WebDataset => "webdataset",
        }
    }
}

impl fmt::Display for DatasetFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for DatasetFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let norm: String = s
            .to_ascii_lowercase()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .collect();
        let alias = match norm.as_str() {
            "ours" => "stereogen",
            "flyingthings3d" | "flyingthings" | "driving" | "monkaa" => "sceneflow",
            "middlebury2014" | "middeval3" => "middlebury",
            "fat" => "fallingthings",
            other => other,
        };
        Self::ALL
            .into_iter()
            .find(|f| f.name() == alias)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|f| f.name()).collect();
                format!(
                    "unknown dataset format {s:?} (one of: {})",
                    names.join(", ")
                )
            })
    }
}

/// What is known about a sample besides its pixels.
///
/// `cx`, `cy` use **0-based pixel centres** (pixel `i`'s centre is at `x = i`; the convention of
/// OpenCV `K` matrices, see [`crate::pixel_coords`]): our manifest's continuous `cx = W/2` reads
/// as `(W − 1)/2`, and so does a Middlebury/ETH3D `calib.txt`'s corner-origin `cx = W/2`. Falling Things' values are passed on
/// as its `_camera_settings.json` gives them.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SampleMeta {
    /// The dataset layout it came from.
    pub format: Option<DatasetFormat>,
    /// A stable name: the path of the left image relative to the root, or our sample id.
    pub id: String,
    pub left_path: PathBuf,
    pub right_path: PathBuf,
    pub disp_left_path: PathBuf,
    /// The right-view disparity file, where the sample has one.
    pub disp_right_path: Option<PathBuf>,
    /// Focal length in pixels, where the dataset gives it.
    pub f_px: Option<f64>,
    /// Baseline in metres, where the dataset gives it.
    pub baseline_m: Option<f64>,
    /// Principal point, 0-based pixel centres.
    pub cx: Option<f64>,
    pub cy: Option<f64>,
    /// Middlebury/ETH3D `ndisp`: an upper bound of the disparity range.
    pub ndisp: Option<u32>,
    /// Anything else, as text (e.g. our `category`, Middlebury's `doffs`).
    pub extra: BTreeMap<String, String>,
    /// The files of the maps beside the disparity (depth, normals, instance and semantic ids:
    /// [`crate::maps`]) where the layout keeps them as files (ours); empty otherwise. A
    /// WebDataset export holds them as members: [`StereoDataset::maps`] reads them either way.
    pub maps: Vec<MapFile>,
    /// The objects the sample's instance maps name (ours: the manifest line's `instances`);
    /// empty where it has none.
    pub instances: Vec<InstanceRecord>,
}

/// One stereo pair with its ground truth, decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoSample {
    pub left: RgbImage,
    pub right: RgbImage,
    /// Left-view disparity; `disp_left.valid` says where it has ground truth.
    pub disp_left: DisparityMap,
    pub disp_right: Option<DisparityMap>,
    /// A stricter validity mask where the dataset ships one (ETH3D/Middlebury `mask0nocc`, KITTI
    /// `disp_noc`, Sintel occlusions and out-of-frame), already combined with `disp_left.valid`.
    pub valid_left: Option<Vec<bool>>,
    pub meta: SampleMeta,
}

impl StereoSample {
    /// `valid_left` where the dataset has it, else the disparity's own validity.
    pub fn valid_mask(&self) -> &[bool] {
        self.valid_left.as_deref().unwrap_or(&self.disp_left.valid)
    }
}

/// A readable stereo dataset. Implementations are `Send + Sync`: samples may be decoded from
/// several threads at once.
pub trait StereoDataset: Send + Sync {
    fn format(&self) -> DatasetFormat;
    fn root(&self) -> &Path;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The stable name of sample `index` (without decoding it).
    fn id(&self, index: usize) -> Option<&str>;
    /// Decodes sample `index`; an index out of range is an error.
    fn sample(&self, index: usize) -> Result<StereoSample>;
    /// Decodes the maps sample `index` has beside its disparity ([`SampleMaps`]: depth, normals,
    /// instance and semantic ids of each view, on the disparity's pixel grid); none for a layout
    /// or sample without them. An index out of range is an error.
    fn maps(&self, index: usize) -> Result<SampleMaps> {
        if index >= self.len() {
            return Err(range_error(self.root(), self.format(), self.len(), index));
        }
        Ok(SampleMaps::default())
    }
}

/// How a disparity file is decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum DispKind {
    Exr,
    Pfm,
    Png16(f32),
    Sintel,
    /// Falling Things: 16-bit depth in 1e-4 m, 0 = none; `d = fx · baseline / Z`.
    FatDepth {
        fx: f64,
        baseline_m: f64,
    },
}

/// How a mask file is turned into "keep this pixel".
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum MaskKind {
    /// Middlebury/ETH3D non-occlusion masks: 255 = non-occluded, 128 occluded, 0 unknown.
    Is255,
    /// Sintel occlusion / out-of-frame masks: 0 = keep, 255 = occluded / out of frame.
    IsZero,
    /// KITTI `disp_noc`: a non-zero 16-bit value = non-occluded ground truth.
    Png16NonZero,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SampleFiles {
    pub id: String,
    pub left: PathBuf,
    pub right: PathBuf,
    pub disp_left: (PathBuf, DispKind),
    pub disp_right: Option<(PathBuf, DispKind)>,
    pub masks: Vec<(PathBuf, MaskKind)>,
    pub meta: SampleMeta,
}

/// A dataset as a list of sample files: every layout is read through this.
pub struct FileListDataset {
    format: DatasetFormat,
    root: PathBuf,
    samples: Vec<SampleFiles>,
}

impl FileListDataset {
    pub(crate) fn new(format: DatasetFormat, root: &Path, samples: Vec<SampleFiles>) -> Self {
        Self {
            format,
            root: root.to_path_buf(),
            samples,
        }
    }
}

pub(crate) fn read_disp(path: &Path, kind: DispKind) -> Result<DisparityMap> {
    match kind {
        DispKind::Exr => Ok(crate::exr_io::read_disparity_exr(path)?.0),
        DispKind::Pfm => crate::pfm::read_disparity_pfm(path),
        DispKind::Png16(scale) => crate::png_disp::read_disparity_png16(path, scale),
        DispKind::Sintel => crate::png_disp::read_disparity_sintel(path),
        DispKind::FatDepth { fx, baseline_m } => {
            let img = crate::image_io::read_image(path)?;
            let crate::image_io::Samples::U16(depth) = img.samples else {
                return Err(Error::format(
                    path,
                    "a Falling Things depth PNG must be 16-bit",
                ));
            };
            if img.channels != 1 {
                return Err(Error::format(
                    path,
                    format!(
                        "a Falling Things depth PNG must be grey, this one has {} channels",
                        img.channels
                    ),
                ));
            }
            let depth_m: Vec<f32> = depth.iter().map(|&v| v as f32 * 1e-4).collect();
            Ok(DisparityMap::from_depth(
                img.width,
                img.height,
                &depth_m,
                fx,
                baseline_m,
                f32::INFINITY,
            ))
        }
    }
}

fn read_mask(path: &Path, kind: MaskKind) -> Result<(usize, usize, Vec<bool>)> {
    let img = crate::image_io::read_image(path)?;
    let c = img.channels;
    let keep: Vec<bool> = match (&img.samples, kind) {
        (crate::image_io::Samples::U8(v), MaskKind::Is255) => {
            v.iter().step_by(c).map(|&p| p == 255).collect()
        }
        (crate::image_io::Samples::U8(v), MaskKind::IsZero) => {
            v.iter().step_by(c).map(|&p| p == 0).collect()
        }
        (crate::image_io::Samples::U16(v), MaskKind::Png16NonZero) => {
            v.iter().step_by(c).map(|&p| p != 0).collect()
        }
        (crate::image_io::Samples::U16(v), MaskKind::Is255) => {
            v.iter().step_by(c).map(|&p| p == u16::MAX).collect()
        }
        (crate::image_io::Samples::U16(v), MaskKind::IsZero) => {
            v.iter().step_by(c).map(|&p| p == 0).collect()
        }
        (crate::image_io::Samples::U8(_), MaskKind::Png16NonZero) => {
            return Err(Error::format(
                path,
                "expected a 16-bit disparity PNG as mask",
            ));
        }
    };
    Ok((img.width, img.height, keep))
}

/// Joins a decoding thread; a panic there (a decoder bug) continues on this thread.
fn join<T>(h: std::thread::ScopedJoinHandle<'_, T>) -> T {
    h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
}

fn same_size(path: &Path, what: &str, got: (usize, usize), want: (usize, usize)) -> Result<()> {
    if got != want {
        return Err(Error::format(
            path,
            format!(
                "{what} is {}x{} but the left image is {}x{}",
                got.0, got.1, want.0, want.1
            ),
        ));
    }
    Ok(())
}

/// The error for a sample index past the end of `dataset`.
pub(crate) fn out_of_range(dataset: &dyn StereoDataset, index: usize) -> Error {
    range_error(dataset.root(), dataset.format(), dataset.len(), index)
}

fn range_error(root: &Path, format: DatasetFormat, len: usize, index: usize) -> Error {
    Error::format(
        root,
        format!("sample index {index} is out of range: the {format} dataset has {len} samples"),
    )
}

impl StereoDataset for FileListDataset {
    fn format(&self) -> DatasetFormat {
        self.format
    }
    fn root(&self) -> &Path {
        &self.root
    }
    fn len(&self) -> usize {
        self.samples.len()
    }
    fn id(&self, index: usize) -> Option<&str> {
        self.samples.get(index).map(|s| s.id.as_str())
    }
    fn sample(&self, index: usize) -> Result<StereoSample> {
        let f = self
            .samples
            .get(index)
            .ok_or_else(|| out_of_range(self, index))?;
        // The files are independent: decode them on parallel threads (a sample is 4+ files of
        // which each decoder uses about one core).
        let (left, right, disp_left, disp_right, masks) = std::thread::scope(|sc| {
            let right = sc.spawn(|| read_rgb(&f.right));
            let disp_left = sc.spawn(|| read_disp(&f.disp_left.0, f.disp_left.1));
            let disp_right = f
                .disp_right
                .as_ref()
                .map(|(p, k)| sc.spawn(move || read_disp(p, *k)));
            let masks: Vec<_> = f
                .masks
                .iter()
                .map(|(p, kind)| sc.spawn(move || read_mask(p, *kind)))
                .collect();
            let left = read_rgb(&f.left);
            (
                left,
                join(right),
                join(disp_left),
                disp_right.map(join),
                masks.into_iter().map(join).collect::<Vec<_>>(),
            )
        });
        let left = left?;
        let size = (left.width, left.height);
        let right = right?;
        same_size(
            &f.right,
            "the right image",
            (right.width, right.height),
            size,
        )?;
        let disp_left = disp_left?;
        same_size(
            &f.disp_left.0,
            "the disparity",
            (disp_left.width, disp_left.height),
            size,
        )?;
        let disp_right = match (&f.disp_right, disp_right) {
            (Some((p, _)), Some(d)) => {
                let d = d?;
                same_size(p, "the disparity", (d.width, d.height), size)?;
                Some(d)
            }
            _ => None,
        };
        let valid_left = if f.masks.is_empty() {
            None
        } else {
            let mut keep = disp_left.valid.clone();
            for ((p, _), mask) in f.masks.iter().zip(masks) {
                let (w, h, m) = mask?;
                same_size(p, "the mask", (w, h), size)?;
                keep.iter_mut().zip(m).for_each(|(k, m)| *k &= m);
            }
            Some(keep)
        };
        Ok(StereoSample {
            left,
            right,
            disp_left,
            disp_right,
            valid_left,
            meta: f.meta.clone(),
        })
    }
    fn maps(&self, index: usize) -> Result<SampleMaps> {
        let f = self
            .samples
            .get(index)
            .ok_or_else(|| out_of_range(self, index))?;
        sample_maps::read_map_files(&f.meta.maps, sample_maps::size_in_extra(&f.meta.extra))
    }
}

/// Choices a layout leaves to the reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReadOptions {
    /// Which rectification of Middlebury 2014's scenes is read.
    pub middlebury_variant: middlebury::MiddleburyVariant,
}

/// Opens the dataset at `root`: with `format` given, as that layout; otherwise the layout is
/// recognised from the folder (see [`detect_format`]). Layout choices take their defaults.
pub fn open_dataset(root: &Path, format: Option<DatasetFormat>) -> Result<Box<dyn StereoDataset>> {
    open_dataset_with(root, format, &ReadOptions::default())
}

/// [`open_dataset`] with the layout choices of `opts`.
pub fn open_dataset_with(
    root: &Path,
    format: Option<DatasetFormat>,
    opts: &ReadOptions,
) -> Result<Box<dyn StereoDataset>> {
    if !root.is_dir() {
        return Err(Error::format(root, "is not a directory"));
    }
    let format = match format {
        Some(f) => f,
        None => detect_format(root)?,
    };
    if format == DatasetFormat::WebDataset {
        let shards = webdataset::WebDataset::open(root)?;
        if shards.is_empty() {
            return Err(Error::format(root, "no samples in its WebDataset shards"));
        }
        return Ok(Box::new(shards));
    }
    let samples = scan_files(format, root, opts)?;
    if samples.is_empty() {
        return Err(Error::format(root, format!("no {format} samples found")));
    }
    Ok(Box::new(FileListDataset::new(format, root, samples)))
}

/// The sample files of `format` under `root`: the dispatch to each layout's reader.
fn scan_files(format: DatasetFormat, root: &Path, opts: &ReadOptions) -> Result<Vec<SampleFiles>> {
    let mut samples = match format {
        DatasetFormat::Stereogen => stereogen::scan(root)?,
        DatasetFormat::Crestereo => crestereo::scan(root)?,
        DatasetFormat::SceneFlow => sceneflow::scan(root)?,
        DatasetFormat::Middlebury | DatasetFormat::Eth3d => {
            middlebury::scan(root, format, opts.middlebury_variant)?
        }
        DatasetFormat::Kitti2012 => kitti::scan(root, &kitti::KITTI_2012)?,
        DatasetFormat::Kitti2015 => kitti::scan(root, &kitti::KITTI_2015)?,
        DatasetFormat::Sintel => sintel::scan(root)?,
        DatasetFormat::FallingThings => falling_things::scan(root)?,
        DatasetFormat::InStereo2k => instereo2k::scan(root)?,
        DatasetFormat::WebDataset => {
            return Err(Error::format(
                root,
                "WebDataset shards are not a list of files",
            ));
        }
    };
    // Ours keep manifest order; the others are sorted so indices are stable.
    if format != DatasetFormat::Stereogen {
        samples.sort_by(|a, b| a.left.cmp(&b.left));
    }
    for s in &mut samples {
        s.meta.format = Some(format);
        s.meta.id = s.id.clone();
        s.meta.left_path = s.left.clone();
        s.meta.right_path = s.right.clone();
        s.meta.disp_left_path = s.disp_left.0.clone();
        s.meta.disp_right_path = s.disp_right.as_ref().map(|(p, _)| p.clone());
    }
    Ok(samples)
}
