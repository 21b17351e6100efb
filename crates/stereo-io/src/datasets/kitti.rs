//! KITTI 2012 and 2015 stereo: fixed folders under `training/` (or the root itself), frames
//! named `NNNNNN_10.png` (the reference frame, the one with ground truth) and `NNNNNN_11.png`;
//! disparity as 16-bit PNG, d·256, 0 = invalid; `disp_noc*` marks the non-occluded pixels.

use std::path::{Path, PathBuf};

use super::scan::{file_name, rel_id, require, walk};
use super::write::{DatasetWriter, ImageEncoding, ImageFile, WriteSummary, mkdir, place_image, write_png16, write_right_disparity};
use super::{DispKind, MaskKind, SampleFiles, SampleMeta, StereoSample};
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
    /// Disparity of all pixels with ground truth (left view).
    pub disp_occ: &'static str,
    /// A second `disp_occ` folder, read as the right view's disparity.
    pub disp_occ_right: Option<&'static str>,
    /// Disparity of the non-occluded pixels only: used as a mask.
    pub disp_noc: &'static str,
}

pub const KITTI_2015: KittiFolders = KittiFolders { left: "image_2", right: "image_3", disp_occ: "disp_occ_0", disp_occ_right: Some("disp_occ_1"), disp_noc: "disp_noc_0" };
pub const KITTI_2012: KittiFolders = KittiFolders { left: "colored_0", right: "colored_1", disp_occ: "disp_occ", disp_occ_right: None, disp_noc: "disp_noc" };

/// The file name of the `n`-th reference frame.
pub fn frame_name(n: usize) -> String {
    format!("{n:06}{REFERENCE_FRAME_SUFFIX}")
}

/// The folder that holds `folders` (`root/training` or `root`), if any.
pub(crate) fn training_dir(root: &Path, folders: &KittiFolders) -> Option<PathBuf> {
    [root.join(TRAINING_DIR), root.to_path_buf()].into_iter().find(|d| d.join(folders.left).is_dir() && d.join(folders.disp_occ).is_dir())
}

pub(crate) fn scan(root: &Path, f: &KittiFolders) -> Result<Vec<SampleFiles>> {
    let base = training_dir(root, f).ok_or_else(|| Error::format(root, format!("no {}/ and {}/ folders (here or under {TRAINING_DIR}/)", f.left, f.disp_occ)))?;
    let mut out = Vec::new();
    for e in walk(&base.join(f.left), 1) {
        let name = file_name(e.path());
        if !name.ends_with(REFERENCE_FRAME_SUFFIX) {
            continue;
        }
        let right = require(base.join(f.right).join(&name), "right image", e.path())?;
        let disp = require(base.join(f.disp_occ).join(&name), "disparity", e.path())?;
        let disp_r = f.disp_occ_right.map(|d| base.join(d).join(&name)).filter(|p| p.is_file());
        let noc = base.join(f.disp_noc).join(&name);
        out.push(SampleFiles {
            id: rel_id(root, e.path()),
            left: e.path().to_path_buf(),
            right,
            disp_left: (disp, DispKind::Png16(KITTI_SCALE)),
            disp_right: disp_r.map(|p| (p, DispKind::Png16(KITTI_SCALE))),
            masks: if noc.is_file() { vec![(noc, MaskKind::Png16NonZero)] } else { vec![] },
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

/// Writes the `n`-th sample as `training/image_2/NNNNNN_10.png`, `image_3/`, `disp_occ_0/` and,
/// where the sample has a right-view disparity, `disp_occ_1/` (the folder this crate reads the
/// right view from). No `disp_noc_0`: the sample's own validity is all that is known. KITTI
/// cannot hold disparities of 256 px or more: those pixels become invalid and are counted.
pub struct Kitti2015Writer {
    root: PathBuf,
    summary: WriteSummary,
}

impl Kitti2015Writer {
    pub fn new(root: &Path) -> Self {
        Self { root: root.to_path_buf(), summary: WriteSummary::default() }
    }
}

impl DatasetWriter for Kitti2015Writer {
    fn summary(&self) -> &WriteSummary {
        &self.summary
    }

    fn write(&mut self, n: usize, _name: &str, s: &StereoSample) -> Result<()> {
        let f = KITTI_2015;
        let base = self.root.join(TRAINING_DIR);
        let name = frame_name(n);
        let dir = |d: &str| -> Result<PathBuf> {
            mkdir(&base.join(d))?;
            Ok(base.join(d).join(&name))
        };
        let png = [ImageFile::PngRgb8];
        place_image(&s.meta.left_path, &s.left, &dir(f.left)?, &png, ImageEncoding::Lossless, &mut self.summary)?;
        place_image(&s.meta.right_path, &s.right, &dir(f.right)?, &png, ImageEncoding::Lossless, &mut self.summary)?;
        write_png16(&dir(f.disp_occ)?, &s.disp_left, KITTI_SCALE, &mut self.summary)?;
        let right = base.join(f.disp_occ_right.expect("KITTI 2015 has a second disparity folder")).join(&name);
        if s.disp_right.is_some() {
            mkdir(right.parent().expect("a folder"))?;
        }
        write_right_disparity(&right, s, &mut self.summary, |d, sum| write_png16(&right, d, KITTI_SCALE, sum))?;
        self.summary.samples += 1;
        Ok(())
    }
}
