//! MPI Sintel stereo: `training/{clean,final}_{left,right}/<scene>/frame_NNNN.png`,
//! `disparities/` (RGB-packed), `occlusions/` and `outofframe/` masks (0 = keep).

use std::path::{Path, PathBuf};

use super::scan::{rel_id, require, walk};
use super::{DispKind, MaskKind, SampleFiles, SampleMeta};
use crate::error::{Error, Result};

pub(crate) fn sintel_base(root: &Path) -> Option<PathBuf> {
    [root.join("training"), root.to_path_buf()]
        .into_iter()
        .find(|d| {
            d.join("disparities").is_dir()
                && (d.join("clean_left").is_dir() || d.join("final_left").is_dir())
        })
}

pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    let base = sintel_base(root).ok_or_else(|| {
        Error::format(
            root,
            "no clean_left|final_left and disparities/ folders (here or under training/)",
        )
    })?;
    let pass = if base.join("clean_left").is_dir() {
        "clean"
    } else {
        "final"
    };
    let left_root = base.join(format!("{pass}_left"));
    let mut out = Vec::new();
    for e in walk(&left_root, 2) {
        let p = e.path();
        if !e.file_type().is_file() || p.extension().is_none_or(|x| x != "png") {
            continue;
        }
        let rel = p.strip_prefix(&left_root).expect("under the left folder");
        let right = require(
            base.join(format!("{pass}_right")).join(rel),
            "right image",
            p,
        )?;
        let disp = require(base.join("disparities").join(rel), "disparity", p)?;
        let masks = [
            ("occlusions", MaskKind::IsZero),
            ("outofframe", MaskKind::IsZero),
        ]
        .into_iter()
        .map(|(d, k)| (base.join(d).join(rel), k))
        .filter(|(p, _)| p.is_file())
        .collect();
        out.push(SampleFiles {
            id: rel_id(root, p),
            left: p.to_path_buf(),
            right,
            disp_left: (disp, DispKind::Sintel),
            disp_right: None,
            masks,
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}
