//! KITTI 2012 and 2015 stereo: fixed folders under `training/` (or the root itself), frames
//! named `NNNNNN_10.png` (the reference frame, the one with ground truth) and `NNNNNN_11.png`
//! (the next frame in time); disparity as 16-bit PNG, d·256, 0 = no ground truth (the devkit's
//! `disp_read`: `d = v/256`, invalid where `v = 0`).
//!
//! | release | left | right | all pixels | non-occluded |
//! | --- | --- | --- | --- | --- |
//! | 2012 | `colored_0` | `colored_1` | `disp_occ` | `disp_noc` |
//! | 2015 | `image_2` | `image_3` | `disp_occ_0` | `disp_noc_0` |
//!
//! KITTI has no right-view disparity. KITTI 2015's `disp_occ_1`/`disp_noc_1` belong to its scene
//! flow benchmark: the disparity of the *second* frame (t+1, `_11`) of each point, stored at that
//! point's pixel in the *first* frame's left image. Reading it as the right view's disparity
//! would be silently wrong, so they are never read. They are written for sources whose pairs
//! are single captures of a still scene (ours, CREStereo's, Middlebury, ETH3D, InStereo2K): with
//! nothing moving, frame t+1 is frame t and its disparity at the reference pixels is the
//! reference disparity itself. Loaders expect the folders (torchvision's `Kitti2015Stereo`
//! refuses a tree without `disp_occ_1`). Sources with motion between frames (KITTI, SceneFlow,
//! Sintel, Falling Things) leave them out.

use std::path::{Path, PathBuf};

use super::scan::{file_name, rel_id, require, walk};
use super::write::{DatasetWriter, WriteSummary, mkdir, place_png_pair, write_png16};
use super::{DatasetFormat, DispKind, MaskKind, SampleFiles, SampleMeta, StereoSample};
use crate::disparity::{DisparityMap, LEFT_RIGHT_TOLERANCE_PX};
use crate::error::{Error, Result};
use crate::png_disp::KITTI_SCALE;

/// The folder below the root that holds the folders of a [`KittiFolders`].
pub const TRAINING_DIR: &str = "training";
/// The frame of a pair that has ground truth.
pub const REFERENCE_FRAME_SUFFIX: &str = "_10.png";

/// The folders of one KITTI release.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KittiFolders {
    pub left: &'static str,
    pub right: &'static str,
    /// Left-view disparity of all pixels with ground truth.
    pub disp_occ: &'static str,
    /// Left-view disparity of the non-occluded pixels only: read as a mask.
    pub disp_noc: &'static str,
    /// KITTI 2015's frame-t+1 disparities at the reference pixels (all, non-occluded): written
    /// for still sources only, never read (see the module notes).
    pub next_frame: Option<(&'static str, &'static str)>,
}

pub const KITTI_2015: KittiFolders = KittiFolders {
    left: "image_2",
    right: "image_3",
    disp_occ: "disp_occ_0",
    disp_noc: "disp_noc_0",
    next_frame: Some(("disp_occ_1", "disp_noc_1")),
};
pub const KITTI_2012: KittiFolders = KittiFolders {
    left: "colored_0",
    right: "colored_1",
    disp_occ: "disp_occ",
    disp_noc: "disp_noc",
    next_frame: None,
};

/// The file name of the `n`-th reference frame.
pub fn frame_name(n: usize) -> String {
    format!("{n:06}{REFERENCE_FRAME_SUFFIX}")
}

/// The folder that holds `folders` (`root/training` or `root`), if any.
pub(crate) fn training_dir(root: &Path, folders: &KittiFolders) -> Option<PathBuf> {
    [root.join(TRAINING_DIR), root.to_path_buf()]
        .into_iter()
        .find(|d| d.join(folders.left).is_dir() && d.join(folders.disp_occ).is_dir())
}

pub(crate) fn scan(root: &Path, f: &KittiFolders) -> Result<Vec<SampleFiles>> {
    let base = training_dir(root, f).ok_or_else(|| {
        Error::format(
            root,
            format!(
                "no {}/ and {}/ folders (here or under {TRAINING_DIR}/)",
                f.left, f.disp_occ
            ),
        )
    })?;
    let mut out = Vec::new();
    for e in walk(&base.join(f.left), 1) {
        let name = file_name(e.path());
        if !name.ends_with(REFERENCE_FRAME_SUFFIX) {
            continue;
        }
        let right = require(base.join(f.right).join(&name), "right image", e.path())?;
        let disp = require(base.join(f.disp_occ).join(&name), "disparity", e.path())?;
        let noc = base.join(f.disp_noc).join(&name);
        out.push(SampleFiles {
            id: rel_id(root, e.path()),
            left: e.path().to_path_buf(),
            right,
            disp_left: (disp, DispKind::Png16(KITTI_SCALE)),
            disp_right: None,
            masks: if noc.is_file() {
                vec![(noc, MaskKind::Png16NonZero)]
            } else {
                vec![]
            },
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

/// Writes the `n`-th sample as `training/<left>/NNNNNN_10.png` with the right image and the
/// left-view disparity beside it in the release's folders (see the module's table). `disp_noc*`
/// is the disparity restricted to the non-occluded pixels: the sample's own stricter mask where
/// it has one (a KITTI `disp_noc`, an ETH3D or Middlebury `mask0nocc`), else the left–right
/// check of its two ground-truth maps ([`DisparityMap::left_right_consistent`], the check `eval`
/// uses); a sample with neither gets no `disp_noc*` (nothing more is known). KITTI 2015's
/// `disp_occ_1`/`disp_noc_1` repeat `disp_occ_0`/`disp_noc_0` for still sources (module notes).
/// No `_11` frame and no right-view disparity: KITTI has neither. Disparities of 256 px or more
/// do not fit: those pixels become invalid, counted.
pub struct KittiWriter {
    root: PathBuf,
    folders: KittiFolders,
    summary: WriteSummary,
}

impl KittiWriter {
    pub fn new(root: &Path, folders: KittiFolders) -> Self {
        Self {
            root: root.to_path_buf(),
            folders,
            summary: WriteSummary::default(),
        }
    }
}

/// Whether a pair of `format` is a single capture of a scene in which nothing moves, so that
/// the next frame's disparity at the reference pixels equals the reference disparity.
fn is_still_capture(format: Option<DatasetFormat>) -> bool {
    matches!(
        format,
        Some(
            DatasetFormat::Stereogen
                | DatasetFormat::Crestereo
                | DatasetFormat::Middlebury
                | DatasetFormat::Eth3d
                | DatasetFormat::InStereo2k
        )
    )
}

/// `disp` with only the pixels `keep` says are valid.
fn restricted(disp: &DisparityMap, keep: &[bool]) -> DisparityMap {
    let mut out = disp.clone();
    for (v, k) in out.valid.iter_mut().zip(keep) {
        *v &= *k;
    }
    out
}

impl DatasetWriter for KittiWriter {
    fn summary(&self) -> &WriteSummary {
        &self.summary
    }

    fn write(&mut self, n: usize, _name: &str, s: &StereoSample) -> Result<()> {
        let f = self.folders;
        let base = self.root.join(TRAINING_DIR);
        let name = frame_name(n);
        let dir = |d: &str| -> Result<PathBuf> {
            mkdir(&base.join(d))?;
            Ok(base.join(d).join(&name))
        };
        place_png_pair(s, &dir(f.left)?, &dir(f.right)?, &mut self.summary)?;
        write_png16(
            &dir(f.disp_occ)?,
            &s.disp_left,
            KITTI_SCALE,
            &mut self.summary,
        )?;
        let non_occluded = s.valid_left.clone().or_else(|| {
            let right = s.disp_right.as_ref()?;
            Some(
                s.disp_left
                    .left_right_consistent(right, LEFT_RIGHT_TOLERANCE_PX),
            )
        });
        let noc = non_occluded.map(|keep| restricted(&s.disp_left, &keep));
        let mut more = vec![];
        if let Some(noc) = &noc {
            more.push((f.disp_noc, noc));
        }
        if let Some((occ_next, noc_next)) = f.next_frame
            && is_still_capture(s.meta.format)
        {
            more.push((occ_next, &s.disp_left));
            more.extend(noc.as_ref().map(|noc| (noc_next, noc)));
        }
        for (folder, map) in more {
            // Out-of-range pixels were counted once, with disp_occ; the same ones here are not.
            write_png16(
                &dir(folder)?,
                map,
                KITTI_SCALE,
                &mut WriteSummary::default(),
            )?;
            self.summary.written += 1;
        }
        self.summary.without_right_disparity += 1;
        self.summary.samples += 1;
        Ok(())
    }
}
