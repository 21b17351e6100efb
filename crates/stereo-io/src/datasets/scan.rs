//! Finding the samples of a layout: the dispatch to each layout's reader and the folder walking
//! they share.

use std::path::{Path, PathBuf};

use walkdir::WalkDir;

use super::{DatasetFormat, ReadOptions, SampleFiles};
use crate::error::{Error, Result};

pub(crate) fn scan(
    format: DatasetFormat,
    root: &Path,
    opts: &ReadOptions,
) -> Result<Vec<SampleFiles>> {
    let mut samples = match format {
        DatasetFormat::Stereogen => super::stereogen::scan(root)?,
        DatasetFormat::Crestereo => super::crestereo::scan(root)?,
        DatasetFormat::SceneFlow => super::sceneflow::scan(root)?,
        DatasetFormat::Middlebury | DatasetFormat::Eth3d => {
            super::middlebury::scan(root, format, opts.middlebury_variant)?
        }
        DatasetFormat::Kitti2012 => super::kitti::scan(root, &super::kitti::KITTI_2012)?,
        DatasetFormat::Kitti2015 => super::kitti::scan(root, &super::kitti::KITTI_2015)?,
        DatasetFormat::Sintel => super::sintel::scan(root)?,
        DatasetFormat::FallingThings => super::falling_things::scan(root)?,
        DatasetFormat::InStereo2k => super::instereo2k::scan(root)?,
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

/// `path` relative to `root`, as text: the stable id of a sample.
pub(crate) fn rel_id(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .to_string_lossy()
        .into_owned()
}

/// The entries under `root`, sorted by name, following links.
pub(crate) fn walk(root: &Path, max_depth: usize) -> impl Iterator<Item = walkdir::DirEntry> {
    WalkDir::new(root)
        .max_depth(max_depth)
        .follow_links(true)
        .sort_by_file_name()
        .into_iter()
        .filter_map(|e| e.ok())
}

pub(crate) fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// `path` if it is a file; else an error naming it as the `what` of `for_`.
pub(crate) fn require(path: PathBuf, what: &str, for_: &Path) -> Result<PathBuf> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(Error::format(
            &path,
            format!("missing: the {what} of {}", for_.display()),
        ))
    }
}
