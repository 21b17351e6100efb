//! Recognising a layout from its root folder, by the file names each layout's module defines.

use std::path::Path;

use super::scan::{file_name, walk};
use super::{
    DatasetFormat, crestereo, falling_things, instereo2k, kitti, middlebury, sceneflow, sintel,
    stereogen,
};
use crate::error::{Error, Result};

/// Recognises a layout from the files under `root`, most specific first: `manifest.jsonl`
/// (ours), Sintel's and KITTI's fixed folders, SceneFlow's `frames_*pass`, Falling Things'
/// `_camera_settings.json`, ETH3D's `disp0GT.pfm`, Middlebury's `disp0.pfm`, CREStereo's
/// `*_left.disp.png`, InStereo2K's `left_disp.png`.
pub fn detect_format(root: &Path) -> Result<DatasetFormat> {
    if root.join(stereogen::MANIFEST_FILE).is_file() {
        return Ok(DatasetFormat::Stereogen);
    }
    if let Some(e) = stereogen::DatasetLayout::new(root).unmerged_error(root) {
        return Err(e);
    }
    if let Some(e) = super::webdataset::WebDataset::unfinished_error(root) {
        return Err(e);
    }
    if super::webdataset::WebDataset::is_webdataset(root) {
        return Ok(DatasetFormat::WebDataset);
    }
    if sintel::sintel_base(root).is_some() {
        return Ok(DatasetFormat::Sintel);
    }
    if kitti::training_dir(root, &kitti::KITTI_2015).is_some() {
        return Ok(DatasetFormat::Kitti2015);
    }
    if kitti::training_dir(root, &kitti::KITTI_2012).is_some() {
        return Ok(DatasetFormat::Kitti2012);
    }
    let mut found: Option<DatasetFormat> = None;
    let mut rank = usize::MAX;
    let mut note = |f: DatasetFormat, r: usize| {
        if r < rank {
            rank = r;
            found = Some(f);
        }
    };
    for e in walk(root, 6).take(200_000) {
        let name = file_name(e.path());
        if e.file_type().is_dir()
            && (name == sceneflow::CLEAN_PASS_DIR || name == sceneflow::FINAL_PASS_DIR)
        {
            note(DatasetFormat::SceneFlow, 0);
            break;
        }
        match name.as_str() {
            falling_things::CAMERA_SETTINGS => note(DatasetFormat::FallingThings, 1),
            middlebury::ETH3D_LEFT_DISPARITY => note(DatasetFormat::Eth3d, 2),
            middlebury::LEFT_DISPARITY => note(DatasetFormat::Middlebury, 3),
            instereo2k::LEFT_DISPARITY => note(DatasetFormat::InStereo2k, 4),
            n if n.ends_with(crestereo::LEFT_DISPARITY_SUFFIX) => note(DatasetFormat::Crestereo, 5),
            _ => {}
        }
    }
    found.ok_or_else(|| {
        Error::format(root, "cannot recognise the dataset layout (stereogen, crestereo, sceneflow, middlebury, eth3d, kitti2012, kitti2015, sintel, fallingthings, instereo2k, webdataset); pass the format explicitly")
    })
}
