//! SceneFlow (FlyingThings3D, Driving, Monkaa): `frames_cleanpass|frames_finalpass/…/left/*.png`,
//! the right view under `right/`, disparity as PFM under `disparity/…/{left,right}/`.

use std::path::{Path, PathBuf};

use super::scan::{file_name, rel_id, require, walk};
use super::{DispKind, SampleFiles, SampleMeta};
use crate::error::Result;

/// The folders of the two render passes; a dataset is read in one of them (clean where present).
pub const CLEAN_PASS_DIR: &str = "frames_cleanpass";
pub const FINAL_PASS_DIR: &str = "frames_finalpass";
const DISPARITY_DIR: &str = "disparity";

/// Replaces one path component.
fn swap_component(path: &Path, from: &str, to: &str) -> Option<PathBuf> {
    let mut swapped = false;
    let out: PathBuf = path
        .components()
        .map(|c| {
            if !swapped && c.as_os_str() == from {
                swapped = true;
                std::ffi::OsStr::new(to).to_owned()
            } else {
                c.as_os_str().to_owned()
            }
        })
        .collect();
    swapped.then_some(out)
}

/// The last `left` component of `path` (the camera folder) replaced by `right`.
fn left_to_right(path: &Path) -> Option<PathBuf> {
    let comps: Vec<_> = path.components().collect();
    let at = comps.iter().rposition(|c| c.as_os_str() == "left")?;
    Some(
        comps
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if i == at {
                    std::ffi::OsStr::new("right")
                } else {
                    c.as_os_str()
                }
            })
            .collect(),
    )
}

pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    // Clean pass where present, else final: one pass, so a pair is not counted twice.
    let pass_dirs: Vec<PathBuf> = walk(root, 4)
        .filter(|e| e.file_type().is_dir() && file_name(e.path()) == CLEAN_PASS_DIR)
        .map(|e| e.into_path())
        .collect();
    let pass_dirs = if pass_dirs.is_empty() {
        walk(root, 4)
            .filter(|e| e.file_type().is_dir() && file_name(e.path()) == FINAL_PASS_DIR)
            .map(|e| e.into_path())
            .collect()
    } else {
        pass_dirs
    };
    let mut out = Vec::new();
    for pass_dir in pass_dirs {
        let pass = file_name(&pass_dir);
        for e in walk(&pass_dir, 12) {
            let p = e.path();
            if !e.file_type().is_file()
                || p.extension().is_none_or(|x| x != "png")
                || p.parent().is_none_or(|d| file_name(d) != "left")
            {
                continue;
            }
            let right = require(left_to_right(p).unwrap_or_default(), "right image", p)?;
            let disp = swap_component(p, &pass, DISPARITY_DIR)
                .unwrap_or_default()
                .with_extension("pfm");
            let disp = require(disp, "disparity (disparity/…/left/*.pfm)", p)?;
            let disp_r = left_to_right(&disp).unwrap_or_default();
            let rel = rel_id(root, p);
            // Sensor 32 mm wide at 960 px: 35 mm lenses give 1050 px, Driving's 15 mm 450 px.
            let f_px = if rel.contains("15mm_focallength") {
                450.0
            } else {
                1050.0
            };
            out.push(SampleFiles {
                id: rel,
                left: p.to_path_buf(),
                right,
                disp_left: (disp, DispKind::Pfm),
                disp_right: disp_r.is_file().then_some((disp_r, DispKind::Pfm)),
                masks: vec![],
                meta: SampleMeta {
                    f_px: Some(f_px),
                    ..Default::default()
                },
            });
        }
    }
    Ok(out)
}
