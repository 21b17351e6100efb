//! Middlebury 2014 / MiddEval3 (`<scene>/im0.png`, `im1.png`, `disp0.pfm`, `disp1.pfm`,
//! `calib.txt`) and ETH3D two-view (the same with `disp0GT.pfm`, `mask0nocc.png`). PFM
//! disparity, `inf` = unknown.
//!
//! Middlebury 2014 ships every scene twice, `<Scene>-perfect` and `<Scene>-imperfect` (exact and
//! realistic rectification; the common layout is `Middlebury2014/<split>/<Scene>-perfect/`).
//! Which is read is a [`MiddleburyVariant`]; by default the imperfect one, as the MiddEval3
//! benchmark uses (a scene present in one variant only is read in that one).
//!
//! ETH3D's official archives put the ground truth in a separate tree:
//! `two_view_training/<scene>/im0.png, im1.png, calib.txt` and
//! `two_view_training_gt/<scene>/disp0GT.pfm, mask0nocc.png`; both that and everything in one
//! folder are read. The mask follows ETH3D's evaluator: a pixel counts where the mask is 255
//! (non-occluded); 128 (occluded) and 0 (unknown) do not.
//!
//! `calib.txt` (vision.middlebury.edu/stereo/data/scenes2014): `cam0`/`cam1` = `[f 0 cx; 0 f cy;
//! 0 0 1]` of the rectified views, `doffs = cx1 − cx0`, `baseline` in mm, `width`, `height`,
//! `ndisp` (a bound: disparities lie in `0 .. ndisp−1`), `isint`, `vmin`/`vmax` (a tight range).
//! The page does not say where pixel centres lie. Middlebury's own tool, cvkit (by an author of
//! the 2014 datasets), loads `calib.txt` with its default corner origin: pixel `i` covers
//! `[i, i + 1)`, its centre at `i + 0.5`. ETH3D's `calib.txt` comes from COLMAP, whose image
//! coordinates have the same origin. So `cx`, `cy` in `calib.txt` are read as corner-origin and
//! converted to [`SampleMeta`](super::SampleMeta)'s 0-based pixel centres (`− 0.5`), and written
//! back the other way: an exactly centred principal point is `width/2` in the file.

use std::path::{Path, PathBuf};

use super::scan::{file_name, rel_id, require, walk};
use super::write::{
    DatasetWriter, WriteSummary, mkdir, place_png_pair, under, write_right_disparity,
};
use super::{DatasetFormat, DispKind, MaskKind, SampleFiles, SampleMeta, StereoSample};
use crate::error::{Error, Result};
use crate::pixel_coords::{continuous_to_pixel_centres, pixel_centres_to_continuous};

pub const LEFT_IMAGE: &str = "im0.png";
pub const RIGHT_IMAGE: &str = "im1.png";
pub const LEFT_DISPARITY: &str = "disp0.pfm";
pub const RIGHT_DISPARITY: &str = "disp1.pfm";
pub const CALIBRATION: &str = "calib.txt";
/// ETH3D's left disparity.
pub const ETH3D_LEFT_DISPARITY: &str = "disp0GT.pfm";
/// Non-occlusion mask: 255 = non-occluded, 128 = occluded, 0 = unknown.
pub const NONOCCLUDED_MASK: &str = "mask0nocc.png";
/// The suffix ETH3D's ground-truth tree adds to the image tree's folder name.
pub const ETH3D_GT_FOLDER_SUFFIX: &str = "_gt";
/// Middlebury 2014's scene folder suffixes.
pub const PERFECT_SUFFIX: &str = "-perfect";
pub const IMPERFECT_SUFFIX: &str = "-imperfect";
/// Where the writer puts its scene folders, as the common layout has them.
pub const WRITTEN_SCENES_DIR: &str = "Middlebury2014/train";

/// Which rectification of a Middlebury 2014 scene is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MiddleburyVariant {
    /// `<Scene>-perfect`, where the scene has it.
    Perfect,
    /// `<Scene>-imperfect`, where the scene has it: what MiddEval3 uses.
    #[default]
    Imperfect,
    /// Both, each a sample of its own.
    Both,
}

impl MiddleburyVariant {
    pub fn name(self) -> &'static str {
        match self {
            Self::Perfect => "perfect",
            Self::Imperfect => "imperfect",
            Self::Both => "both",
        }
    }
}

impl std::fmt::Display for MiddleburyVariant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for MiddleburyVariant {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        [Self::Perfect, Self::Imperfect, Self::Both]
            .into_iter()
            .find(|v| v.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown Middlebury variant {s:?} (perfect, imperfect or both)"))
    }
}

/// A scene folder's name without its variant suffix, and the variant it names.
fn split_variant(dir_name: &str) -> (&str, Option<MiddleburyVariant>) {
    if let Some(base) = dir_name.strip_suffix(PERFECT_SUFFIX) {
        (base, Some(MiddleburyVariant::Perfect))
    } else if let Some(base) = dir_name.strip_suffix(IMPERFECT_SUFFIX) {
        (base, Some(MiddleburyVariant::Imperfect))
    } else {
        (dir_name, None)
    }
}

/// Whether the scene folder `dir` is read under `want`: folders without a variant always; a
/// variant folder when it is the one wanted, or when its scene has no folder of that one.
fn variant_wanted(dir: &Path, want: MiddleburyVariant) -> bool {
    let name = file_name(dir);
    let (base, variant) = split_variant(&name);
    match (variant, want) {
        (None, _) | (_, MiddleburyVariant::Both) => true,
        (Some(v), w) if v == w => true,
        (Some(_), w) => {
            let wanted_suffix = if w == MiddleburyVariant::Perfect {
                PERFECT_SUFFIX
            } else {
                IMPERFECT_SUFFIX
            };
            !dir.with_file_name(format!("{base}{wanted_suffix}"))
                .join(LEFT_DISPARITY)
                .is_file()
        }
    }
}

/// Parses a `calib.txt` into `meta`: `cam0` gives `f_px`, `cx`, `cy`; `baseline` (mm) gives
/// `baseline_m`; `ndisp`; every other key goes to `meta.extra` as text.
pub(crate) fn parse_calib(path: &Path, meta: &mut SampleMeta) -> Result<()> {
    let text = crate::limits::read_document(path, "a calib.txt")?;
    for line in text.lines() {
        let Some((k, v)) = line.split_once('=') else {
            continue;
        };
        let (k, v) = (k.trim(), v.trim());
        let num = |s: &str| {
            s.parse::<f64>()
                .map_err(|_| Error::format(path, format!("`{k}` value {s:?} is not a number")))
        };
        match k {
            "cam0" => {
                let nums: Vec<f64> = v
                    .trim_matches(['[', ']'])
                    .split([' ', ';'])
                    .filter(|s| !s.is_empty())
                    .map(num)
                    .collect::<Result<_>>()?;
                if nums.len() != 9 {
                    return Err(Error::format(
                        path,
                        format!("cam0 has {} numbers, expected a 3x3 matrix", nums.len()),
                    ));
                }
                meta.f_px = Some(nums[0]);
                meta.cx = Some(continuous_to_pixel_centres(nums[2]));
                meta.cy = Some(continuous_to_pixel_centres(nums[5]));
            }
            "baseline" => meta.baseline_m = Some(num(v)? / 1000.0),
            "ndisp" => meta.ndisp = Some(num(v)? as u32),
            _ => {
                meta.extra.insert(k.to_string(), v.to_string());
            }
        }
    }
    Ok(())
}

/// What a written `calib.txt` holds. Principal point in 0-based pixel centres (written in the
/// file's corner-origin convention, see the module).
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub f_px: f64,
    pub cx: f64,
    pub cy: f64,
    /// `cx1 − cx0`: 0 for a rig whose views share their intrinsics.
    pub doffs: f64,
    pub baseline_m: f64,
    pub width: usize,
    pub height: usize,
    pub ndisp: u32,
    pub vmin: f64,
    pub vmax: f64,
}

impl Calibration {
    /// The calibration of `s` as Middlebury states it; an error naming what the sample lacks.
    fn of_sample(s: &StereoSample) -> std::result::Result<Self, String> {
        let m = &s.meta;
        let missing: Vec<&str> = [
            ("f_px", m.f_px),
            ("baseline_m", m.baseline_m),
            ("cx", m.cx),
            ("cy", m.cy),
        ]
        .into_iter()
        .filter(|(_, v)| v.is_none())
        .map(|(k, _)| k)
        .collect();
        if !missing.is_empty() {
            return Err(format!(
                "calib.txt needs the focal length, baseline and principal point; the source gives no {}",
                missing.join(", ")
            ));
        }
        let doffs = match m.extra.get("doffs") {
            Some(t) => t
                .parse::<f64>()
                .map_err(|_| format!("doffs {t:?} is not a number"))?,
            None => 0.0,
        };
        let (vmin, vmax) = s.disp_left.stats().map_or((0.0, 0.0), |st| {
            (f64::from(st.min).floor(), f64::from(st.max).ceil())
        });
        let ndisp = (vmax as u32 + 1).max(m.ndisp.unwrap_or(1));
        Ok(Self {
            f_px: m.f_px.unwrap(),
            cx: m.cx.unwrap(),
            cy: m.cy.unwrap(),
            doffs,
            baseline_m: m.baseline_m.unwrap(),
            width: s.left.width,
            height: s.left.height,
            ndisp,
            vmin,
            vmax,
        })
    }

    pub fn to_text(&self) -> String {
        let cam = |cx: f64| {
            format!(
                "[{} 0 {}; 0 {} {}; 0 0 1]",
                self.f_px,
                pixel_centres_to_continuous(cx),
                self.f_px,
                pixel_centres_to_continuous(self.cy)
            )
        };
        format!(
            "cam0={}\ncam1={}\ndoffs={}\nbaseline={}\nwidth={}\nheight={}\nndisp={}\nisint=0\nvmin={}\nvmax={}\n",
            cam(self.cx),
            cam(self.cx + self.doffs),
            self.doffs,
            self.baseline_m * 1000.0,
            self.width,
            self.height,
            self.ndisp,
            self.vmin,
            self.vmax
        )
    }
}

/// The folder of ETH3D images that goes with the ground-truth folder `gt_dir`: the same folder
/// when it holds `im0.png`, else `<tree>/<scene>` for `gt_dir` = `<tree>_gt/<scene>`.
fn eth3d_image_dir(gt_dir: &Path) -> Option<PathBuf> {
    if gt_dir.join(LEFT_IMAGE).is_file() {
        return Some(gt_dir.to_path_buf());
    }
    let scene = gt_dir.file_name()?;
    let tree = gt_dir.parent()?;
    let image_tree = file_name(tree)
        .strip_suffix(ETH3D_GT_FOLDER_SUFFIX)?
        .to_string();
    Some(tree.with_file_name(image_tree).join(scene))
}

/// Middlebury (`disp0.pfm`, optional `disp1.pfm`, `calib.txt` required; scene folders chosen by
/// `variant`) or ETH3D (`disp0GT.pfm` beside the images or in the `_gt` tree, optional
/// `calib.txt` and `mask0nocc.png`).
pub(crate) fn scan(
    root: &Path,
    format: DatasetFormat,
    variant: MiddleburyVariant,
) -> Result<Vec<SampleFiles>> {
    let (disp_name, disp_right_name) = match format {
        DatasetFormat::Eth3d => (ETH3D_LEFT_DISPARITY, None),
        _ => (LEFT_DISPARITY, Some(RIGHT_DISPARITY)),
    };
    let mut out = Vec::new();
    for e in walk(root, 5) {
        if file_name(e.path()) != disp_name {
            continue;
        }
        let gt_dir = e.path().parent().unwrap_or(root);
        if format == DatasetFormat::Middlebury && !variant_wanted(gt_dir, variant) {
            continue;
        }
        let dir = match format {
            DatasetFormat::Eth3d => eth3d_image_dir(gt_dir).unwrap_or_else(|| gt_dir.to_path_buf()),
            _ => gt_dir.to_path_buf(),
        };
        let left = require(dir.join(LEFT_IMAGE), "left image im0.png", gt_dir)?;
        let right = require(dir.join(RIGHT_IMAGE), "right image im1.png", gt_dir)?;
        let mut meta = SampleMeta::default();
        let calib = dir.join(CALIBRATION);
        if calib.is_file() {
            parse_calib(&calib, &mut meta)?;
        } else if format == DatasetFormat::Middlebury {
            return Err(Error::format(
                &calib,
                "missing: Middlebury scenes carry a calib.txt",
            ));
        }
        let disp_r = disp_right_name
            .map(|n| gt_dir.join(n))
            .filter(|p| p.is_file());
        let mask = gt_dir.join(NONOCCLUDED_MASK);
        out.push(SampleFiles {
            id: rel_id(root, &dir),
            left,
            right,
            disp_left: (e.path().to_path_buf(), DispKind::Pfm),
            disp_right: disp_r.map(|p| (p, DispKind::Pfm)),
            masks: if mask.is_file() {
                vec![(mask, MaskKind::Is255)]
            } else {
                vec![]
            },
            meta,
        });
    }
    Ok(out)
}

/// Writes each sample as a scene folder `<root>/Middlebury2014/train/<name with / and - as _>-perfect/`
/// (the layout the popular loaders look for; "perfect": a synthetic rig is exactly rectified):
/// `im0.png`, `im1.png`, `disp0.pfm`, `disp1.pfm` (where the sample has a right-view disparity)
/// and `calib.txt` (which needs the sample's focal length, baseline and principal point: an
/// error without). `calib.txt`'s principal point is in Middlebury's corner-origin convention
/// (see the module).
pub struct MiddleburyWriter {
    root: PathBuf,
    summary: WriteSummary,
}

impl MiddleburyWriter {
    pub fn new(root: &Path) -> Self {
        Self {
            root: root.to_path_buf(),
            summary: WriteSummary::default(),
        }
    }
}

impl DatasetWriter for MiddleburyWriter {
    fn summary(&self) -> &WriteSummary {
        &self.summary
    }

    fn write(&mut self, _n: usize, name: &str, s: &StereoSample) -> Result<()> {
        let scene = format!("{}{PERFECT_SUFFIX}", name.replace(['/', '-'], "_"));
        let dir = under(&self.root.join(WRITTEN_SCENES_DIR), &scene)?;
        let calib =
            Calibration::of_sample(s).map_err(|m| Error::format(dir.join(CALIBRATION), m))?;
        mkdir(&dir)?;
        place_png_pair(
            s,
            &dir.join(LEFT_IMAGE),
            &dir.join(RIGHT_IMAGE),
            &mut self.summary,
        )?;
        crate::pfm::write_disparity_pfm(&dir.join(LEFT_DISPARITY), &s.disp_left)?;
        let right = dir.join(RIGHT_DISPARITY);
        write_right_disparity(&right, s, &mut self.summary, |d, sum| {
            sum.written += 1;
            crate::pfm::write_disparity_pfm(&right, d)
        })?;
        crate::atomic::write_bytes_atomically(&dir.join(CALIBRATION), calib.to_text().as_bytes())?;
        self.summary.written += 2;
        self.summary.samples += 1;
        Ok(())
    }
}
